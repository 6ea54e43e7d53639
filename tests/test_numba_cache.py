"""numba's disk cache stays fresh when a file a kernel inlines changes
(:mod:`fem_rmpm.runtime.numba_cache`).

numba's own rule keys a cached function on its own source file only: the kernel
``transfer.map_to_nodes`` inlines ``basis.q4``, so under that rule an edit of ``basis.py``
alone would leave the cached ``map_to_nodes`` running the old basis (and a stale model
update can return NaN after a model gains a state column).  The functional test edits ``basis.py`` in a copy of the package
between two fresh processes and checks that the second runs the new code.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fem_rmpm.runtime import numba_cache

PACKAGE = Path(numba_cache.__file__).resolve().parents[1]

_CHILD = """
import numpy as np
from fem_rmpm.schemes.explicit.kernels import arrays as A, transfer as T
M = A.Mesh(0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 2, 2, np.zeros(2), np.full(2, 2.0),
           np.zeros((9, 2), bool))
z = np.zeros((1, 2))
P = A.PointArrays(np.array([[0.5, 0.5]]), z.copy(), np.ones(1), np.ones(1), np.ones(1),
                  np.zeros((1, 4)), np.ones(1, bool), np.full((1, 2), 0.25),
                  np.zeros((1, 4)), np.zeros((1, 1)), z.copy(),
                  np.zeros(1, np.int64), np.zeros((1, 2)))
N = A.node_arrays(9, A.node_arrays(9))
T.map_to_nodes(False, P, M, N, A.scratch_for(1, 4),
               A.StepOptions(0.0, 0.0, 0.0, 0.0, 1.0, False, False, False))
print(N.m[0] + N.half.m[0])     # the one point is the second half's (n // 2 = 0)
"""


def _node_mass(root: Path) -> float:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["PYTHONPATH"] = str(root)
    out = subprocess.run([sys.executable, "-c", _CHILD], env=env, cwd=root, check=True,
                         capture_output=True, text=True, timeout=300)
    return float(out.stdout.split()[-1])


def test_edit_of_an_inlined_file_recompiles_the_kernels_using_it(tmp_path):
    """A point at the centre of cell 0 gives node 0 a quarter of its mass (Q4); after
    ``basis.q4`` is edited to double its weights, a fresh process must give half (the
    cached ``map_to_nodes`` of the unedited basis would still give a quarter)."""
    shutil.copytree(PACKAGE, tmp_path / "fem_rmpm",
                    ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    assert _node_mass(tmp_path) == 0.25
    assert _node_mass(tmp_path) == 0.25          # from the cache this time
    basis = tmp_path / "fem_rmpm" / "schemes" / "explicit" / "kernels" / "basis.py"
    src = basis.read_text()
    old = "(fs * ft, s * ft, s * t, fs * t)"
    assert old in src
    basis.write_text(src.replace(old, "(2.0 * fs * ft, s * ft, s * t, fs * t)"))
    assert _node_mass(tmp_path) == 0.5


def test_every_module_with_compiled_code_is_in_the_hashed_sources():
    """Each package module that defines numba functions (``njit`` or the kernel
    decorators of ``kernels.common``) lies in :data:`numba_cache.COMPILED_SOURCES`."""
    listed = []
    for rel in numba_cache.COMPILED_SOURCES:
        p = PACKAGE / rel
        listed += list(p.glob("*.py")) if p.is_dir() else [p]
    uses = re.compile(r"@(njit|jit|kernel|inline|kernel_parallel)\b|serial_and_parallel\(|"
                      r"\bnjit\(")
    compiled = [f for f in PACKAGE.rglob("*.py")
                if f.name != "numba_cache.py" and uses.search(f.read_text())]
    assert compiled, "the pattern finds the kernels"
    missing = sorted(str(f.relative_to(PACKAGE)) for f in compiled if f not in listed)
    assert not missing, f"modules with numba code not in COMPILED_SOURCES: {missing}"


def test_package_locators_are_first():
    from numba.core.caching import CacheImpl
    assert numba_cache.install()
    assert CacheImpl._locator_classes[0].__name__.startswith("FemRmpm")


def test_functions_the_kernels_can_call_set_their_own_flags():
    """Every numba function of ``fem_rmpm.materials`` and ``fem_rmpm.schemes.explicit.kernels`` that is
    called rather than inlined sets ``fastmath`` and ``error_model`` itself.  numba
    compiles a function without them with the flags of the caller that compiles it
    first, and caches that: a helper compiled first by a kernel and first by the implicit
    scheme's numpy-level update could then round differently, and a run's result would
    depend on which came first (and which one the cache kept)."""
    unset = [name for name, f in _dispatchers(("fem_rmpm.materials", "fem_rmpm.schemes.explicit.kernels"))
             if (f.targetoptions.get("inline", "never") != "always"
                 and not {"fastmath", "error_model"} <= set(f.targetoptions))]
    assert not unset, f"numba functions that would take their caller's flags: {unset}"


def _dispatchers(packages, modules=()):
    """``(qualified name, dispatcher)`` of every numba function defined at module level in
    the modules of ``packages`` and in ``modules`` (dotted names)."""
    import importlib
    import pkgutil

    from numba.core.registry import CPUDispatcher
    mods = [importlib.import_module(m) for m in modules]
    for pkg in packages:
        root = importlib.import_module(pkg)
        mods += [importlib.import_module(i.name)
                 for i in pkgutil.iter_modules(root.__path__, pkg + ".")]
    for mod in mods:
        for name, f in vars(mod).items():
            if isinstance(f, CPUDispatcher) and f.__module__ == mod.__name__:
                yield f"{mod.__name__}.{name}", f


def _fastmath_flags(option) -> set:
    """The LLVM flags of a numba ``fastmath`` option (bool, set or FastMathOptions)."""
    if option is True:
        return {"fast"}
    if not option:
        return set()
    return set(getattr(option, "flags", option))


def test_no_compiled_function_lets_llvm_change_a_value():
    """Every numba function of the package (and the shared decorators' flags) carries at
    most ``nsz``: no ``contract``, ``arcp``, ``reassoc`` or ``fast``.  numba links a copy of
    each compiled callee into every caller, optimized again there, and which copy runs
    depends on what the process loaded first; with FMA contraction allowed the copies of
    the stress pass can fuse differently (AVX2 code), and a run compiled in its process and
    the same run from the cache it wrote then differ by one ulp
    (``validation/load_order.py --cpu znver1``: two hashes).  Fails with
    ``FASTMATH = {"contract", "arcp", "nsz"}``."""
    from fem_rmpm.runtime import compiled
    allowed = {"nsz"}
    bad = [] if compiled.FASTMATH <= allowed else [f"compiled.FASTMATH {compiled.FASTMATH}"]
    found = _dispatchers(("fem_rmpm.materials", "fem_rmpm.schemes.explicit.kernels", "fem_rmpm.schemes.implicit"),
                         ("fem_rmpm.runtime.compiled", "fem_rmpm.schemes.regularisation"))
    for name, f in found:
        flags = _fastmath_flags(f.targetoptions.get("fastmath"))
        if not flags <= allowed:
            bad.append(f"{name} {sorted(flags)}")
    assert not bad, f"numba functions with value-changing fast-math flags: {bad}"


def _fill_index(path: str, keys: list, start) -> None:
    """One process saving ``keys`` into the cache index ``path/kernel.nbi`` once ``start``
    is set, each entry's data naming its key."""
    from numba.core.caching import IndexDataCacheFile
    import fem_rmpm.runtime.numba_cache  # noqa: F401 - installs the package's save
    f = IndexDataCacheFile(path, "kernel", "stamp")
    start.wait()
    for k in keys:
        f.save(k, ("code of", k))


@pytest.mark.parametrize("safe", [True, False])
def test_cache_entries_saved_by_two_processes_at_once_name_their_own_code(tmp_path, safe,
                                                                          monkeypatch):
    """Two processes add 150 entries each to one numba cache index at the same time (as two
    test or campaign workers, or a run and its compile helper, compiling variants of one
    kernel): with the package's save every entry is kept and its data file holds its own
    code; numba's own save (``safe`` False, the reference this test can tell from it)
    loses entries or lets an entry name another's data, in one round of 150 each here."""
    import multiprocessing
    from numba.core.caching import IndexDataCacheFile
    if not safe:
        monkeypatch.setattr(IndexDataCacheFile, "save", numba_cache._NUMBA_SAVE[0])
    ctx = multiprocessing.get_context("fork")
    start = ctx.Event()
    keys = [[(w, i) for i in range(150)] for w in range(2)]
    procs = [ctx.Process(target=_fill_index, args=(str(tmp_path), k, start)) for k in keys]
    for p in procs:
        p.start()
    start.set()
    for p in procs:
        p.join(120)
        assert p.exitcode == 0
    f = IndexDataCacheFile(str(tmp_path), "kernel", "stamp")
    got = {k: f.load(k) for ks in keys for k in ks}
    wrong = [k for k, v in got.items() if v != ("code of", k)]
    if safe:
        assert not wrong, wrong[:5]
    else:
        assert wrong, "numba's own save kept every entry: the race was not provoked"
