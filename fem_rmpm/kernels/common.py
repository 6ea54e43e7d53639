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
# The threaded drivers: a ``prange`` loop over chunks of the points whose body calls a
# compiled (``kernel``) chunk function, the same one the serial kernel runs, so every point
# is computed with the same arithmetic and the result is bitwise the serial one.  The loop
# body is a call, not the per-point code itself: numba 0.68's parfor array analysis
# crashed on those bodies inline (IndexError in array_analysis._gen_shape_call), and the
# threaded loop takes no nested named tuple (pass ``N._replace(half=None)`` and ``N.half``).
# A threaded driver must be a Python function of its own: numba names its cache files
# after the function's qualified name and its cache key does not contain the ``parallel``
# flag, so a serial and a parallel compile of ONE function share one cache entry and
# whichever compiled first is loaded by both (the threaded kernels had run serial that way).
# One ``prange`` loop per threaded function: numba fuses two ``prange`` loops of the same
# length into one when it sees no dependency between them, and it cannot see into the
# chunk calls (g2p's nodal velocities ran before the other half's re-map had finished
# that way).  ``parallel={"fusion": False}`` does not stop it: numba 0.68 pops the key
# from the options dict that all dispatchers of this decorator share, at the first compile.
kernel_parallel = njit(cache=True, fastmath=False, nogil=True, error_model="numpy", _nrt=False,
                       parallel=True)
