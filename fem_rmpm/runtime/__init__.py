"""Run-time support: compiled-code configuration, numba's cache, the machine, size and cost
estimates (``budget``, ``budget3d``), and the input error."""
