"""numba decorators and constants shared by the kernel modules."""
from __future__ import annotations

from numba import njit

MASS_TOL = 1e-14     # as explicit._MASS_TOL: nodes lighter than this carry no velocity
jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
# The step kernels allocate nothing, so they run without numba's reference counting
# (NRT): with it, every array handed to an inlined per-point helper is incref'd and
# decref'd (atomic operations) once per point, which made G2P ~4x slower (56 vs 13
# ns per point, measured).  A kernel that allocated would fail to compile, not misbehave.
kernel = njit(cache=True, fastmath=False, nogil=True, error_model="numpy", _nrt=False)
inline = njit(inline="always", fastmath=False, error_model="numpy")
# The same loops compiled for several threads: per-point loops written with ``prange``
# (plain ``range`` in the serial compile), so the parallel version computes every point
# with the same arithmetic and gives bitwise the serial result.
kernel_parallel = njit(cache=True, fastmath=False, nogil=True, error_model="numpy", _nrt=False,
                       parallel=True)


#: parallel dispatcher -> its serial twin (same loop).  numba's parfor array analysis
#: crashed (IndexError in array_analysis._gen_shape_call) when a parallel twin was compiled
#: in a process that had not yet compiled or loaded its serial twin (a fresh cache with
#: ``threads > 1`` from the first step); with the serial twin loaded first it compiles.
#: :meth:`fem_rmpm.kernels.arrays.Workspace.call` loads the twin first.
SERIAL_TWIN: dict = {}


def serial_and_parallel(py_func):
    """``(serial, parallel)`` compiled versions of one per-point loop."""
    serial, parallel = kernel(py_func), kernel_parallel(py_func)
    SERIAL_TWIN[parallel] = serial
    return serial, parallel
