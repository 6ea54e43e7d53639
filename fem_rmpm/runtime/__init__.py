"""Run-time support: compiled-code configuration, numba's cache, the machine, size and cost
estimates, and the input error."""
