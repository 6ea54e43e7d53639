"""numba's on-disk cache, kept fresh for kernels that inline code from other files.

numba (``cache=True``) keeps a compiled function in ``__pycache__`` with an index that
is valid while *the function's own source file* is unchanged (its stamp is the hash of
that one file).  The explicit kernels inline helpers from other modules — the Q4/uGIMP
basis (:mod:`fem_rmpm.schemes.explicit.kernels.basis`) into the transfers, the Hencky helpers of
:mod:`fem_rmpm.schemes.explicit.kernels.strain` into the stress pass, the material models' point
functions through the dispatch — so under numba's rule an edit of ``basis.py``, a rebase
or an in-place upgrade leaves the kernels of the unchanged files running the old code (a
model file that gains a state column then gives NaN) until ``*.nbi`` / ``*.nbc`` are
deleted.

:func:`install` puts, in front of numba's cache locators, a copy of each that adds a
hash of source files to the stamp of functions defined in this package, so that an edit
of any file a kernel may inline makes that kernel's cache index stale (it compiles once
more and is cached again).  Which files: the explicit scheme's kernels and the material
models (:data:`EXPLICIT_SOURCES`) import nothing compiled from outside that group
(``tests/test_numba_cache.py`` checks it on their import statements), so a function
defined there is keyed on the hash of that group alone; every other compiled function
(the implicit scheme, the regularisation, the 3-D quadrature: they import from all over
the package) is keyed on the hash of *every* compiled source
(:data:`COMPILED_SOURCES`).  An edit of the implicit scheme therefore no longer makes
the explicit kernels compile again, while an edit of a material model or of a kernel
helper still recompiles every kernel that may inline it.
Functions of other packages keep numba's own rule.  It runs when :mod:`fem_rmpm` is
imported, before any kernel is decorated.  If numba's locator interface changes, the
package falls back to numba's rule (no error).

:func:`compile_aside` compiles kernels in a second process into the on-disk cache while
this one compiles others (numba's front end holds the GIL, so a thread would not run in
parallel); this process then loads them from the cache (the first step of an explicit run,
:func:`fem_rmpm.schemes.explicit.step.advance`).

:func:`install` also makes numba's cache save safe when several processes fill one index
at once (:func:`_save_between_processes`: numba's own save can leave an index entry naming
another entry's code), and counts numba's compiles in this process (numba's event API: a
function loaded from the on-disk cache is no compile), so a run and a campaign worker can
say whether their kernels came from the cache: :func:`compile_stats`.
"""
from __future__ import annotations

import functools
import hashlib
import importlib
import itertools
import json
import os
import select
import subprocess
import sys
import time
from pathlib import Path

from numba.core import types

try:
    from numba.core.caching import CacheImpl, IndexDataCacheFile
except ImportError:          # numba's internals moved: numba's own rule applies (install)
    CacheImpl = IndexDataCacheFile = None
try:
    import fcntl
except ImportError:          # not POSIX: numba's own save (install)
    fcntl = None
try:
    from numba.core import event as numba_event
except ImportError:          # no event API: no compile count (compile_stats)
    numba_event = None

__all__ = ["COMPILED_SOURCES", "EXPLICIT_SOURCES", "sources_hash", "stamp_group", "install",
           "compile_stats", "process_seconds", "cached", "Helper", "compile_aside", "type_to_json",
           "type_from_json"]

PACKAGE = Path(__file__).resolve().parents[1]
#: The package's compiled (numba) code, relative to the package directory: folders
#: (every ``.py`` in them) or files.  ``tests/test_numba_cache.py`` checks that every
#: module using numba is listed here.
COMPILED_SOURCES = ("runtime/compiled.py", "schemes/explicit/kernels", "materials",
                    "schemes/implicit",
                    "schemes/regularisation.py", "random_field/quadrature3d.py",
                    "schemes/explicit3d", "discretise/basis3d.py")


#: The explicit kernels' dependency group (relative to the package directory, a subset of
#: :data:`COMPILED_SOURCES`): its files import compiled code from this group only, so a
#: kernel defined here can inline nothing else of the package.
EXPLICIT_SOURCES = ("runtime/compiled.py", "schemes/explicit/kernels", "materials")


def _files(rel: str) -> list[Path]:
    p = PACKAGE / rel
    return sorted(p.glob("*.py")) if p.is_dir() else [p]


def stamp_group(py_file) -> tuple[str, ...]:
    """The sources whose hash keys the cache of a function defined in ``py_file`` (a
    file of this package): :data:`EXPLICIT_SOURCES` for a file of that group, else
    :data:`COMPILED_SOURCES` (module docstring)."""
    f = Path(py_file).resolve()
    if any(f == g for rel in EXPLICIT_SOURCES for g in _files(rel)):
        return EXPLICIT_SOURCES
    return COMPILED_SOURCES


@functools.lru_cache(maxsize=None)
def sources_hash(group: tuple[str, ...] = COMPILED_SOURCES) -> str:
    """sha256 over the names and contents of the files of ``group`` (folders or files
    relative to the package; once per process and group: numba, too, reads a source
    stamp once, when a function is decorated)."""
    h = hashlib.sha256()
    for rel in group:
        for f in _files(rel):
            h.update(f.relative_to(PACKAGE).as_posix().encode() + b"\0")
            h.update(f.read_bytes() + b"\0")
    return h.hexdigest()


def _ours(py_file) -> bool:
    try:
        return Path(py_file).resolve().is_relative_to(PACKAGE)
    except (OSError, TypeError, ValueError):
        return False


def _package_locator(base):
    """A subclass of numba locator ``base`` for this package's functions: same cache
    place, stamp = (numba's stamp, :func:`sources_hash` of the file's :func:`stamp_group`)."""
    class Locator(base):
        @classmethod
        def from_function(cls, py_func, py_file):
            if not _ours(py_file):
                return None
            loc = super().from_function(py_func, py_file)
            if loc is not None:
                loc._fem_rmpm_group = stamp_group(py_file)
            return loc

        def get_source_stamp(self):
            group = getattr(self, "_fem_rmpm_group", COMPILED_SOURCES)
            return (super().get_source_stamp(), sources_hash(group))

    Locator.__name__ = Locator.__qualname__ = f"FemRmpm{base.__name__}"
    return Locator


#: numba compiles in this process: [functions compiled, wall seconds in the outermost ones]
_COMPILES = [0, 0.0]
_OPEN: list = []        # start times of the compiles under way (nested: callees while typing)


def compile_stats() -> tuple[int, float]:
    """``(functions, seconds)``: the functions numba compiled in this process so far (each
    specialisation, callees included; loads from the on-disk cache do not count) and the
    wall time (s) spent in them (outermost compiles only, callees are inside).  (0, 0.0)
    where numba's event API is missing."""
    return _COMPILES[0], _COMPILES[1]


def process_seconds() -> float | None:
    """Wall seconds since this process started (the kernel's start time of the process,
    ``/proc/self/stat``, against the clock since boot; to the kernel's clock tick, 10 ms
    on Linux), so that the interpreter's start and the imports count; None where that
    cannot be read (not Linux)."""
    try:
        with open("/proc/self/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()
        started = int(fields[19]) / os.sysconf("SC_CLK_TCK")     # (field 22: starttime)
        return max(time.clock_gettime(time.CLOCK_BOOTTIME) - started, 0.0)
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def _count_compiles() -> bool:
    """Register the listener of :func:`compile_stats` with numba's event API (once)."""
    event = numba_event
    if event is None:
        return False

    class CompileCounter(event.Listener):
        def on_start(self, ev):
            _OPEN.append(time.perf_counter())

        def on_end(self, ev):
            t0 = _OPEN.pop() if _OPEN else time.perf_counter()
            _COMPILES[0] += 1
            if not _OPEN:
                _COMPILES[1] += time.perf_counter() - t0

    if not any(isinstance(x, event.Listener) and type(x).__name__ == "CompileCounter"
               for x in event._registered.get("numba:compile", ())):
        event.register("numba:compile", CompileCounter())
    return True


def _save_between_processes(self, key, data) -> None:
    """numba's ``IndexDataCacheFile.save``, safe when several processes fill one cache
    index at once (test workers, campaign workers, :func:`compile_aside`).  numba numbers
    a new entry's data file after the index it has read and writes the index before the
    data: two processes adding different entries (two argument types, or two closure
    variants of one kernel, which share an index) can pick the same file, and the index
    that is written last may then name the other entry's code; a reader may also find an
    entry before its data file is written.  Here the index is read, the file chosen, the
    data written and then the index, all under an exclusive lock on ``<index>.lock``, so
    an entry of the index always names its own, complete data."""
    try:
        lock = open(self._index_path + ".lock", "ab")
    except OSError:           # a cache directory we cannot write a lock in: numba's save
        return _NUMBA_SAVE[0](self, key, data)
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        overloads = self._load_index()
        name = overloads.get(key)
        if name is None:
            used = set(overloads.values())
            name = next(n for n in map(self._data_name, itertools.count(1)) if n not in used)
        self._save_data(name, data)
        if overloads.get(key) != name:
            overloads[key] = name
            self._save_index(overloads)
    return None


_NUMBA_SAVE: list = []      # numba's own IndexDataCacheFile.save, once replaced


def _install_save() -> bool:
    """Replace numba's cache save by :func:`_save_between_processes` (idempotent)."""
    if IndexDataCacheFile is None or fcntl is None:
        return False
    if not _NUMBA_SAVE:
        _NUMBA_SAVE.append(IndexDataCacheFile.save)
        IndexDataCacheFile.save = _save_between_processes
    return True


def install() -> bool:
    """Put the package's locators first in numba's list (idempotent), make numba's cache
    save safe between processes (:func:`_save_between_processes`) and count numba's
    compiles (:func:`compile_stats`).  False if numba's cache machinery does not look as
    expected (then numba's own rule applies)."""
    try:
        _count_compiles()
    except Exception:       # noqa: BLE001 - numba's event API moved: no count, never an error
        pass
    try:
        _install_save()
    except Exception:       # noqa: BLE001 - numba's cache file class moved: numba's save
        pass
    try:
        classes = list(CacheImpl._locator_classes)
    except AttributeError:   # also CacheImpl None
        return False
    if any(c.__name__.startswith("FemRmpm") for c in classes):
        return True
    CacheImpl._locator_classes = [_package_locator(c) for c in classes] + classes
    return True


def cached(dispatcher, sig: tuple) -> bool:
    """Whether numba's on-disk cache holds ``dispatcher`` (``cache=True``) for the argument
    types ``sig`` (its index read, nothing loaded); False where that cannot be told."""
    try:
        cache = dispatcher._cache
        key = cache._index_key(tuple(sig), dispatcher.targetctx.codegen())
        return key in cache._cache_file._load_index()
    except Exception:        # noqa: BLE001 - numba internals moved: say "not cached"
        return False


class Helper:
    """A second process compiling kernels into numba's on-disk cache
    (:func:`compile_aside`), one item after the other: :meth:`wait_items` for the first
    ``k`` before calling them, :meth:`done` to ask without waiting."""

    def __init__(self, proc: subprocess.Popen | None, items: int = 0):
        self.proc, self.items, self.reported = proc, items, 0

    def wait_items(self, k: int, timeout: float = 300.0) -> bool:
        """Wait (at most ``timeout`` s) until the helper has compiled its first ``k`` items;
        True if it has.  False if it failed, ended early or is late (then those kernels
        compile in this process when called, as without a helper)."""
        if self.proc is None or self.proc.stdout is None:
            return False
        end = time.monotonic() + timeout
        while self.reported < k:
            left = end - time.monotonic()
            try:
                ready = left > 0 and select.select([self.proc.stdout], [], [], left)[0]
            except (OSError, ValueError):    # no select on pipes (Windows): wait for the end
                return self.wait(max(left, 0.0))
            if not ready or not self.proc.stdout.readline():   # late, or ended before item k
                return False
            self.reported += 1
        return True

    def done(self) -> bool | None:
        """None while the helper runs; then True if it compiled every item, else False."""
        if self.proc is None:
            return False
        if self.proc.poll() is None:
            return None
        return self.proc.returncode == 0

    def stop(self) -> None:
        """Stop the helper now if it still runs."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def wait(self, timeout: float = 300.0) -> bool:
        """Wait (at most ``timeout`` s) for the helper to end; True if it compiled every item.
        A helper that is late is stopped (its locked saves leave no partial cache entry,
        :func:`_save_between_processes`)."""
        if self.proc is None:
            return False
        try:
            return self.proc.wait(timeout) == 0
        except subprocess.TimeoutExpired:
            self.stop()
            return False


def type_to_json(t):
    """numba type ``t`` as plain JSON data (:func:`type_from_json` makes it again): arrays,
    named tuples of a module-level class, tuples, literals, None and scalar types; the
    argument types a second process needs to compile a kernel (:func:`compile_aside`).
    ValueError for any other type."""
    if isinstance(t, types.Literal):
        return {"literal": t.literal_value}
    if isinstance(t, types.Array):
        return {"array": str(t.dtype), "ndim": t.ndim, "layout": t.layout,
                "mutable": bool(t.mutable), "aligned": bool(t.aligned)}
    if isinstance(t, types.BaseNamedTuple):
        cls = t.instance_class
        return {"namedtuple": [cls.__module__, cls.__qualname__],
                "fields": [type_to_json(x) for x in t.types]}
    if isinstance(t, types.BaseTuple):
        return {"tuple": [type_to_json(x) for x in t.types]}
    if t == types.none:
        return {"none": True}
    if isinstance(t, (types.Number, types.Boolean)):
        return {"scalar": str(t)}
    raise ValueError(f"no JSON form of the numba type {t}")


def type_from_json(d):
    """The numba type :func:`type_to_json` described (the named tuple's class imported
    from its module)."""
    if "literal" in d:
        return types.literal(d["literal"])
    if "array" in d:
        return types.Array(getattr(types, d["array"]), d["ndim"], d["layout"],
                           readonly=not d["mutable"], aligned=d["aligned"])
    if "namedtuple" in d:
        module, name = d["namedtuple"]
        cls = getattr(importlib.import_module(module), name)
        fields = [type_from_json(x) for x in d["fields"]]
        if fields and all(f == fields[0] for f in fields):
            return types.NamedUniTuple(fields[0], len(fields), cls)
        return types.NamedTuple(fields, cls)
    if "tuple" in d:
        return types.BaseTuple.from_types([type_from_json(x) for x in d["tuple"]])
    if "none" in d:
        return types.none
    if "scalar" in d:
        return getattr(types, d["scalar"])
    raise ValueError(f"not a numba type description: {d}")


def compile_aside(items: list[dict]) -> Helper:
    """Start a process that compiles each item of ``items`` into numba's on-disk cache, in
    order, with this process's package, interpreter and environment (so the same
    ``NUMBA_CACHE_DIR`` and cache keys).  An item: ``module`` and ``name`` of a dispatcher
    (``cache=True``), or of a factory called with the JSON values ``factory`` (a list) whose
    result, indexed by ``index`` when given, is the dispatcher; ``sig`` its numba argument
    types; optionally ``check`` = (module, function, value): the helper stops (failure)
    unless that function returns that value (e.g. the model registry's version: another
    registry would compile other code under this process's cache key).  The items go to
    the helper as JSON on its standard input (:func:`type_to_json`; nothing is unpickled);
    it prints a line after each.  Returns its :class:`Helper` (no process where a type has
    no JSON form)."""
    try:
        data = json.dumps([dict(item, sig=[type_to_json(t) for t in item["sig"]])
                           for item in items])
    except (TypeError, ValueError):      # a type without a JSON form: compile here
        return Helper(None)
    env = dict(os.environ)
    root = str(PACKAGE.parent)
    env["PYTHONPATH"] = os.pathsep.join([root] + [p for p in env.get("PYTHONPATH", "").split(
        os.pathsep) if p])
    try:
        proc = subprocess.Popen([sys.executable, "-c", _HELPER], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                env=env, cwd=root, text=True)
        proc.stdin.write(data)
        proc.stdin.close()
    except OSError:
        return Helper(None)
    return Helper(proc, len(items))


def _dispatcher(item: dict):
    """The dispatcher an item of :func:`compile_aside` names."""
    obj = getattr(importlib.import_module(item["module"]), item["name"])
    if item.get("factory") is not None:
        obj = obj(*item["factory"])
    return obj if item.get("index") is None else obj[item["index"]]


def compile_items(text: str) -> None:
    """The helper process of :func:`compile_aside`: compile each item of the JSON ``text``
    (numba saves each to its on-disk cache) and print a line after each; exit 1 at an
    item whose ``check`` fails."""
    for item in json.loads(text):
        if item.get("check") is not None:
            module, fn, value = item["check"]
            if getattr(importlib.import_module(module), fn)() != value:
                sys.exit(1)
        _dispatcher(item).compile(tuple(type_from_json(t) for t in item["sig"]))
        print("compiled", item["name"], flush=True)


_HELPER = """
import sys
from fem_rmpm.runtime.numba_cache import compile_items
compile_items(sys.stdin.read())
"""
