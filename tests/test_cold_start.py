"""The cold start: a campaign's workers share the kernels one of them compiles
(:func:`fem_rmpm.campaign.cluster.warm_workers`), and numba's cache of the explicit
kernels is keyed on the sources they can inline only
(:mod:`fem_rmpm.runtime.numba_cache`).  No real cold compile here (tens of seconds):
``validation/bench_explicit.py`` measures it."""
from __future__ import annotations

import ast
import shutil
from pathlib import Path

import pytest

from fem_rmpm.campaign.cluster import warm_workers
from fem_rmpm.runtime import numba_cache
from fem_rmpm.runtime.numba_cache import (
    COMPILED_SOURCES,
    EXPLICIT_SOURCES,
    PACKAGE,
    sources_hash,
    stamp_group,
)


class _Future:
    def __init__(self, value):
        self.value = value

    def result(self):
        if isinstance(self.value, Exception):
            raise self.value
        return self.value


class _Client:
    """A Dask client stub: ``workers`` workers; ``submit`` runs the function here."""

    def __init__(self, workers: int):
        self.workers = workers
        self.submitted = []

    def nthreads(self):
        return {f"tcp://w{k}": 1 for k in range(self.workers)}

    def submit(self, fn, *args, **kw):
        self.submitted.append(args)
        try:
            return _Future(fn(*args))
        except Exception as exc:  # noqa: BLE001 - as a Dask future holds it
            return _Future(exc)


def _compiled(task):
    return {"compiled": True, "functions": 26, "seconds": 21.5, "cpu_seconds": 20.25}


def _loaded(task):
    return {"compiled": False, "functions": 0, "seconds": 0.75, "cpu_seconds": 0.5}


TASKS = [{"scene": "first", "seed": 1}, {"scene": "second", "seed": 2}]


def test_kernels_are_compiled_once_on_one_worker_before_the_others_start():
    """Two workers: the first task's kernels compiled by one submitted call, awaited, and
    a line saying so (its seconds as measured)."""
    client, said = _Client(2), []
    line = warm_workers(client, TASKS, run=_compiled, say=said.append, cold=lambda t: True,
                        load=_loaded)
    assert client.submitted == [(TASKS[0],), (TASKS[0],)], \
        "one warm-up task (the first one), then one load on the other worker"
    assert "once for all workers" in line and "21.5 s" in line and "20.2 s CPU" in line
    assert "26 functions" in line, line
    assert "1 other worker(s) loaded them" in line and "no function compiled" in line, line
    assert "0.8 s" in line and "compiled again" not in line, line
    assert len(said) == 1 and "compiling the kernels once" in said[0], said
    said.clear()
    warm_workers(_Client(2), TASKS, run=_compiled, say=said.append, cold=lambda t: False,
                 load=_loaded)
    assert said == [], "nothing announced when this process sees the kernels cached"


def test_a_worker_that_compiles_again_is_named_in_the_line():
    """Three workers, one of the two others compiling again (a cache of its own): the
    line says one loaded and one compiled, with its count and seconds; a load that
    fails is left out."""
    answers = iter([_loaded(None), {"compiled": True, "functions": 24, "seconds": 19.0,
                                    "cpu_seconds": 18.0}])
    line = warm_workers(_Client(3), TASKS, run=_compiled, load=lambda t: next(answers))
    assert "1 other worker(s) loaded them" in line, line
    assert "1 other worker(s) compiled again (24 functions, up to 19.0 s)" in line, line

    def lost(task):
        raise RuntimeError("worker died")
    line = warm_workers(_Client(2), TASKS, run=_compiled, load=lost)
    assert line.endswith("the others load them from numba's on-disk cache"), line


def test_no_warm_up_where_it_cannot_save_a_compile():
    """One worker, cached kernels, no scene in the task, a factor-of-safety-only task, a
    warm-up that raises: nothing printed (the realizations report their own errors)."""
    assert warm_workers(_Client(1), TASKS, run=_compiled) is None
    assert warm_workers(_Client(2), TASKS, run=lambda t: {"compiled": False}) is None
    assert warm_workers(_Client(2), [{"index": 0}], run=_compiled) is None
    assert warm_workers(_Client(2), [{"scene": "s", "fs": "only"}], run=_compiled) is None
    assert warm_workers(_Client(2), [], run=_compiled) is None

    def broken(task):
        raise RuntimeError("worker died")
    assert warm_workers(_Client(2), TASKS, run=broken) is None


def _group_files(group) -> set[Path]:
    out = set()
    for rel in group:
        p = PACKAGE / rel
        out |= set(p.glob("*.py")) if p.is_dir() else {p}
    return {f.resolve() for f in out}


def _module_file(name: str) -> set[Path]:
    parts = name.split(".")[1:]
    base = PACKAGE.joinpath(*parts)
    return {f.resolve() for f in (base.with_suffix(".py"), base / "__init__.py") if f.exists()}


def _outside(tree: ast.AST, group: set[Path]) -> list[str]:
    """The ``fem_rmpm`` names imported in ``tree`` (also inside functions) that come from
    no file of ``group``: a module imported, or a name taken from a module."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            pairs = [(a.name, None) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            pairs = [(node.module, a.name) for a in node.names]
        else:
            continue
        for mod, name in pairs:
            if mod.split(".")[0] != "fem_rmpm":
                continue
            sub = _module_file(f"{mod}.{name}") if name else set()
            source = sub or _module_file(mod)          # a submodule, else the module's name
            if not source & group:
                out.append(f"{mod}{'.' + name if name else ''}")
    return out


def test_explicit_kernels_import_compiled_code_from_their_own_group_only():
    """The explicit group's stamp is safe only if its files can inline nothing outside it:
    every ``fem_rmpm`` import in them (also inside functions) comes from a file of the
    group.  A failure names the file and the import: add that module's file to
    ``EXPLICIT_SOURCES`` or drop the import.  (The check itself flags an import of the
    implicit scheme.)"""
    group = _group_files(EXPLICIT_SOURCES)
    assert _outside(ast.parse("from fem_rmpm.schemes.implicit import tangent\n"
                              "from fem_rmpm.materials import registry"), group) == [
        "fem_rmpm.schemes.implicit.tangent"]
    bad = [f"{f.relative_to(PACKAGE)}: {name}" for f in sorted(group)
           for name in _outside(ast.parse(f.read_text()), group)]
    assert not bad, "explicit kernels import compiled code outside their group: " + "; ".join(bad)


def test_stamp_groups():
    """A kernel file and a material model keyed on the explicit group, the implicit scheme
    on every compiled source; the explicit group is part of the whole."""
    assert stamp_group(PACKAGE / "schemes/explicit/kernels/advance.py") == EXPLICIT_SOURCES
    assert stamp_group(PACKAGE / "materials/von_mises.py") == EXPLICIT_SOURCES
    assert stamp_group(PACKAGE / "runtime/compiled.py") == EXPLICIT_SOURCES
    assert stamp_group(PACKAGE / "schemes/regularisation.py") == COMPILED_SOURCES
    assert set(EXPLICIT_SOURCES) <= set(COMPILED_SOURCES)


def test_an_implicit_edit_keeps_the_explicit_stamp_and_a_material_edit_changes_it(
        tmp_path, monkeypatch):
    """In a copy of the package: an edit of the implicit scheme changes the whole stamp
    only; an edit of a material model changes both."""
    copy = tmp_path / "fem_rmpm"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__", "*.nb?"))
    monkeypatch.setattr(numba_cache, "PACKAGE", copy)
    h = sources_hash.__wrapped__

    def stamps():
        return h(EXPLICIT_SOURCES), h(COMPILED_SOURCES)
    e0, a0 = stamps()
    implicit = sorted((copy / "schemes/implicit").glob("*.py"))[0]
    implicit.write_text(implicit.read_text() + "\n# edited\n")
    e1, a1 = stamps()
    assert e1 == e0 and a1 != a0
    model = copy / "materials/von_mises.py"
    model.write_text(model.read_text() + "\n# edited\n")
    e2, a2 = stamps()
    assert e2 != e1 and a2 != a1


def test_the_cold_check_reads_the_cache_of_explicit_realizations_only():
    """An implicit realization never warms the workers (its kernels are not the explicit
    ones); an explicit one gets a yes or no from numba's cache index (no compile)."""
    from fem_rmpm.campaign.cluster import kernels_cold_here
    from fem_rmpm.scene import load_scene, with_values

    scene = load_scene(PACKAGE.parent / "meshes" / "slope_reference.toml")
    assert isinstance(kernels_cold_here({"scene": scene}), bool)
    implicit = with_values(scene, {"solver.scheme": "implicit"})
    assert kernels_cold_here({"scene": implicit}) is False


def test_compile_stats_count_numba_compiles_in_this_process():
    """A new numba function compiles once (one more function counted, seconds grow); its
    second call compiles nothing."""
    from numba import njit

    from fem_rmpm.runtime.numba_cache import compile_stats

    @njit
    def twice(x):
        return 2.0 * x
    n0, s0 = compile_stats()
    assert twice(1.5) == 3.0
    n1, s1 = compile_stats()
    assert n1 == n0 + 1 and s1 > s0
    twice(2.5)
    assert compile_stats() == (n1, s1)


def test_a_three_d_campaign_loads_nothing_ahead():
    """A 3-D scene: the one compile, and no one-step run on the other workers (each would
    set up the whole 3-D scene once more)."""
    from types import SimpleNamespace

    scene = SimpleNamespace(grid=SimpleNamespace(dimension=3))
    client = _Client(2)
    line = warm_workers(client, [{"scene": scene, "seed": 1}], run=_compiled, load=_loaded)
    assert len(client.submitted) == 1, "the warm-up only"
    assert line.endswith("the others load them from numba's on-disk cache"), line


def test_a_literal_flag_compiles_one_variant_and_a_run_time_flag_both():
    """:func:`.common.literal_variants`: a caller whose flag is a literal (a closure
    constant) compiles the kernel of that value alone; a flag from Python compiles both,
    behind ``if flag``; each gives what the written-out branch gives."""
    from numba import njit

    from fem_rmpm.schemes.explicit.kernels.common import literal_variants

    def make(double):
        @njit
        def scale(x):
            return 2.0 * x if double else x + 1.0
        return scale

    def scaled(double, x):
        raise NotImplementedError

    made = literal_variants(scaled, make)

    def caller(double):
        @njit
        def call(x):
            return scaled(double, x)
        return call

    assert caller(True)(1.5) == 3.0
    assert made(True).signatures and not made(False).signatures, "one variant compiled"

    @njit
    def at_run_time(double, x):
        return scaled(double, x)
    assert at_run_time(False, 1.5) == 2.5 and at_run_time(True, 1.5) == 3.0
    assert made(False).signatures, "a run-time flag compiles both"


_ASIDE = r"""
import sys
from numba import types
from fem_rmpm.runtime.numba_cache import cached, compile_aside, compile_stats
from fem_rmpm.schemes.explicit.kernels.basis import _gimp_1d
sig = (types.float64, types.float64, types.float64)
before = cached(_gimp_1d, sig)
ok = compile_aside([{"module": "fem_rmpm.schemes.explicit.kernels.basis", "name": "_gimp_1d",
                     "sig": sig}]).wait(120)
after = cached(_gimp_1d, sig)
w = _gimp_1d(0.1, 1.0, 0.25)
print(before, ok, after, compile_stats()[0], w[0])
"""


def test_a_kernel_compiled_aside_is_loaded_not_compiled(tmp_path):
    """:func:`.numba_cache.compile_aside`: a second process compiles a kernel into an
    empty on-disk cache; this process then finds it there and loads it (no compile here),
    with the value of the uGIMP weight (Bardenhagen & Kober 2004: 1 - (d^2 + lp^2) /
    (2 h lp) where |d| < lp: 1 - (0.01 + 0.0625) / 0.5 = 0.855 at d = 0.1, h = 1,
    lp = 0.25)."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=str(PACKAGE.parent))
    out = subprocess.run([sys.executable, "-c", _ASIDE], env=env, capture_output=True,
                         text=True, check=True, cwd=tmp_path).stdout.split()
    assert out[:4] == ["False", "True", "True", "0"], out
    assert abs(float(out[4]) - 0.855) < 1e-12


def test_kernel_argument_types_go_to_a_helper_as_json_and_come_back_equal():
    """:func:`.numba_cache.type_to_json`: the types of a step driver's arguments (named
    tuples of arrays, scalars, None, literals) survive JSON text unchanged; a type it does
    not describe is refused, and so is a helper item with such a type (no process)."""
    import json

    import numpy as np
    from numba import typeof, types

    from fem_rmpm.runtime.numba_cache import compile_aside, type_from_json, type_to_json
    from fem_rmpm.schemes.explicit.kernels.arrays import StepOptions

    o = StepOptions(0.1, 0.0, -9.81, 0.05, 1.0, False, True, False, 2, 1, True)
    sample = [typeof(o), typeof(np.zeros((3, 2))), typeof(np.zeros(4, dtype=np.uint64)),
              types.literal(7), types.literal(True), types.none, types.int64,
              types.UniTuple(types.float64, 2),
              types.NamedTuple([typeof(np.zeros(2)), types.none], StepOptions)]
    for t in sample:
        assert type_from_json(json.loads(json.dumps(type_to_json(t)))) == t, t
    with pytest.raises(ValueError):
        type_to_json(types.unicode_type)
    assert compile_aside([{"module": "m", "name": "f", "sig": (types.unicode_type,)}]).proc \
        is None


def test_a_stopped_run_stops_its_compile_helper_instead_of_waiting(monkeypatch):
    """A helper process still compiling a threaded driver is killed when the run stops on
    an interrupt or an error (:func:`cold_start.stop_helpers`, called by the time loop), so
    the command's exit does not wait up to 300 s for it at exit; the time loop calls it
    when its output callback raises."""
    import subprocess
    import sys

    from fem_rmpm import api
    from fem_rmpm.schemes.explicit import cold_start, loop
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    monkeypatch.setitem(cold_start._PENDING, "driver", numba_cache.Helper(proc, 1))
    cold_start.stop_helpers()
    assert proc.poll() is not None and not cold_start._PENDING
    calls = []
    monkeypatch.setattr(loop, "stop_helpers", lambda: calls.append(1))

    def interrupt(t, pts):
        if t > 0:
            raise KeyboardInterrupt
    scene = api.load_scene(Path(__file__).parent / "data" / "mc_tiny.toml")
    with pytest.raises(KeyboardInterrupt):
        api.run(scene, seed=1, stop_when=interrupt)
    assert calls == [1]
