"""Memory of circulant embeddings: the cache of set-up embeddings, bounded by the bytes
its entries hold (least recently used out first), and the estimate of a 3-D embedding's
peak memory before anything is allocated.

The cache bound is :data:`CACHE_FRACTION` of the memory limit
(:func:`fem_rmpm.runtime.budget.memory_limit_bytes`, ``$FEM_RMPM_MEMORY_LIMIT_GB`` or 75 %
of the RAM), at most :data:`CACHE_MAX_BYTES`.  An entry larger than the bound is returned
but not kept.  The 2-D embeddings of a slope hold a few MB each, so in practice the
cache keeps every configuration of a campaign; one 3-D embedding of 10^7 lattice points
holds 40 MB (:func:`embedding_bytes_3d`).
"""
from __future__ import annotations

import functools
import threading
from collections import OrderedDict

import numpy as np

from fem_rmpm.runtime.budget import memory_limit_bytes

__all__ = ["ByteBoundedCache", "bytes_cached", "cache_limit_bytes", "CACHE_FRACTION",
           "CACHE_MAX_BYTES", "entry_bytes"]

#: Fraction of the memory limit the embedding cache may hold.
CACHE_FRACTION = 0.25
#: Upper bound of the cache (B) whatever the memory limit.
CACHE_MAX_BYTES = 4 * 2**30


def cache_limit_bytes() -> float:
    """The cache bound (B): :data:`CACHE_FRACTION` of the memory limit, at most
    :data:`CACHE_MAX_BYTES`."""
    return min(CACHE_FRACTION * memory_limit_bytes(), CACHE_MAX_BYTES)


def entry_bytes(obj) -> int:
    """Bytes of the numpy arrays an embedding holds (its attributes)."""
    total = 0
    for v in vars(obj).values() if hasattr(obj, "__dict__") else ():
        if isinstance(v, np.ndarray):
            total += v.nbytes
    return total


class ByteBoundedCache:
    """Least-recently-used cache whose entries hold at most ``limit()`` bytes together."""

    def __init__(self, limit=cache_limit_bytes):
        self._limit = limit
        self._data: OrderedDict = OrderedDict()
        self._sizes: dict = {}
        self._lock = threading.Lock()
        self.hits = self.misses = 0

    @property
    def nbytes(self) -> int:
        return sum(self._sizes.values())

    def __len__(self) -> int:
        return len(self._data)

    def get_or_make(self, key, make):
        with self._lock:
            if key in self._data:
                self._data.move_to_end(key)
                self.hits += 1
                return self._data[key]
        value = make()
        size = entry_bytes(value)
        limit = float(self._limit())
        with self._lock:
            self.misses += 1
            if size > limit:
                return value
            self._data[key] = value
            self._sizes[key] = size
            while sum(self._sizes.values()) > limit and len(self._data) > 1:
                old, _ = self._data.popitem(last=False)
                del self._sizes[old]
        return value

    def clear(self) -> None:
        with self._lock:
            self._data.clear()
            self._sizes.clear()
            self.hits = self.misses = 0


def bytes_cached(func):
    """Decorator: memoise ``func(*args)`` (hashable arguments) in a
    :class:`ByteBoundedCache`; ``func.cache_clear()`` and ``func.cache`` as for lru_cache."""
    cache = ByteBoundedCache()

    @functools.wraps(func)
    def wrapper(*args):
        return cache.get_or_make(args, lambda: func(*args))
    wrapper.cache = cache
    wrapper.cache_clear = cache.clear
    return wrapper
