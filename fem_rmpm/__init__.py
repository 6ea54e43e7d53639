"""fem_rmpm: the Random Material Point Method on a structured grid (see README.md)."""
from fem_rmpm.runtime import numba_cache as _numba_cache

# before any kernel is decorated: numba's disk cache also keyed on the sources it inlines
_numba_cache.install()
