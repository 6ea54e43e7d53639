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
