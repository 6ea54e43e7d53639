"""Mutation testing of the modules that carry the physics and the risk, with mutmut.

    python validation/mutation.py statistics            # one target (see TARGETS)
    python validation/mutation.py measures --survivors  # and print every surviving mutant
    python validation/mutation.py all --max-children 2
    python validation/mutation.py materials --rerun before.json   # after adding tests

Each target names the source files to mutate and the tests that guard them.  The run
happens in a scratch copy of the repository (``--workdir``, default a temporary
directory), so the checkout is never touched: mutmut writes ``mutants/`` there, runs the
selected tests once to learn which test reaches which function, then runs, for each
mutant, only the tests that reach the mutated function, under ``nice``.  The score is
killed / (killed + survived + timeouts and the other outcomes); a timeout counts as
killed, as mutmut counts it.  Results go to ``validation/out/mutation_<target>.json``
(score, counts, surviving mutant names and their diffs).

Why mutmut: it is maintained (3.x, 2025), needs no configuration file in the repository
(the section is written into the scratch copy), mutates at function level with a
trampoline so one import serves every mutant, and runs only the tests that reach each
mutant — which keeps a run bounded on 2 cores.

Numba functions: mutmut 3 never mutates a decorated function (its trampoline would be
copied through the decorator), so every ``@njit`` function — the explicit kernels in
``fem_rmpm/schemes/explicit/kernels/``, the models' ``point_update`` and Mohr–Coulomb's whole return
mapping (``_update_all`` and below, one numba function for the numpy, complex-step and
kernel paths) — is left out by the tool itself; nothing to configure.  What is mutated is
the numpy side: von Mises' ``update`` / ``cohesion`` / ``check``, the shared Hencky
kinematics, Mohr–Coulomb's checks, strength laws and the numpy wrapper of its update,
the explicit step's numpy reference (``explicit_step_numpy``, ``map_to_nodes``,
``solve_on_mesh``, the step, the time loop), ``schemes/explicit/reference.py``,
``step.py``, ``loop.py``, ``schemes/common.py``
and ``measures/deposit.py``.  The compiled code is
guarded by the kernel-equality tests (numba = numpy to 1e-12, tests/test_kernels.py,
test_material_extension.py, test_mohr_coulomb.py), so a mutant of the numpy reference
that those tests catch also stands for the same change in the kernel; Mohr–Coulomb's
return mapping has no numpy twin and is tested by its closed forms, not by mutation.

One mutant by hand (after a run, in its work directory): run pytest from the ``mutants/``
tree, where the trampolines are — ``cd WORKDIR/TARGET/mutants && MUTANT_UNDER_TEST=
fem_rmpm.materials.hencky.x__atanh_x_over_x__mutmut_18 python -m pytest -q tests/...``.
From ``WORKDIR/TARGET`` itself the working directory comes first on ``sys.path`` and the
unmutated copy is imported, so every mutant seems to survive.  The trampoline reads
``MUTANT_UNDER_TEST`` at every call, so one process may set it in turn for many mutants.

Cost on the shared 2-core machine (load 8-16): see the notes of each run in
validation/out/mutation_<target>.json (``--rerun`` reruns only the survivors and the
mutants no test reached, after tests were added).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: target -> (files to mutate, pytest selection).  Slow tests that reach everything (the
#: reference slope, campaigns on Dask clusters) are left out: each mutant would cost
#: minutes; the fast tests named here are the ones meant to catch these modules.
TARGETS: dict[str, tuple[list[str], list[str]]] = {
    "statistics": (["fem_rmpm/campaign/statistics.py"],
                   ["tests/test_montecarlo.py::test_statistics_standard_error_and_wilson_interval",
                    "tests/test_statistics.py",
                    "tests/test_campaign_decide.py::test_measure_sample_is_the_runs_to_rest_below_k"]),
    "measures": (["fem_rmpm/measures/deposit.py", "fem_rmpm/measures/table.py",
                  "fem_rmpm/measures/geometry.py", "fem_rmpm/measures/blocks.py"],
                 ["tests/test_measures.py", "tests/test_measures_details.py",
                  "tests/test_measures_reference.py", "-k",
                  "not reference_slope and not leaving and not ends_cleanly and not "
                  "summary_reports"]),
    "materials": (["fem_rmpm/materials/von_mises.py", "fem_rmpm/materials/hencky.py",
                   "fem_rmpm/materials/mohr_coulomb.py"],
                  ["tests/test_material.py", "tests/test_mohr_coulomb.py",
                   "tests/test_material_details.py", "tests/test_material_exact.py",
                   "tests/test_kernels.py",
                   "tests/test_implicit.py",
                   "tests/test_strength_reduction.py::test_strength_parameters_are_declared_per_model",
                   "tests/test_strength_reduction.py::test_reduce_strength_peak_and_softening",
                   "tests/test_strength_reduction.py::test_mohr_coulomb_reduces_c_and_tan_phi",
                   "tests/test_regularisation.py::test_bad_regularisation_input",
                   "tests/test_regularisation.py::test_displacement_scaled_softening_strain_is_u_over_h",
                   "tests/test_regularisation.py::"
                   "test_local_points_keep_both_columns_equal_and_numba_equals_numpy",
                   "-k",
                   "not explicit_scheme and not drained_infinite and not implicit_scheme and "
                   "not block_in_simple_shear and not step_ and not run_ and not slope and "
                   "not column and not newton and not nonconvergence and not summary and "
                   "not pyamg and not newmark and not geostatic and not gimp and not q4 and "
                   "not one_static"]),
    "explicit": (["fem_rmpm/schemes/explicit/loop.py", "fem_rmpm/schemes/explicit/step.py",
                  "fem_rmpm/schemes/explicit/reference.py", "fem_rmpm/schemes/common.py"],
                 ["tests/test_explicit.py", "tests/test_kernels.py", "tests/test_documented.py",
                  "tests/test_explicit_details.py", "tests/test_run_guards.py",
                  "tests/test_locking.py", "tests/test_explicit_wiring.py",
                  "-k", "not grid_file and not line_search and not exit_130 and not refuses_nan"]),
    # the same files against the fast tests only (one or a few steps, numba = numpy, the
    # run guards, short column runs): the "explicit" selection runs slope columns for every
    # mutant of the step and the CFL step, about a minute each on 2 cores
    "explicit_step": (["fem_rmpm/schemes/explicit/loop.py", "fem_rmpm/schemes/common.py"],
                      ["tests/test_kernels.py", "tests/test_locking.py", "tests/test_threads.py",
                       "tests/test_explicit_details.py", "tests/test_stability.py",
                       "tests/test_explicit_wiring.py", "tests/test_run_guards.py"]),
    "random_field": (["fem_rmpm/random_field/embedding.py", "fem_rmpm/random_field/model.py",
                      "fem_rmpm/random_field/points.py"],
                     ["tests/test_random_field.py", "tests/test_random_field_model.py",
                      "tests/test_random_field_exact.py", "-k",
                      "not cli and not subprocess"]),
}


def _copy_repo(dest: Path) -> None:
    """The tracked files plus the working-tree changes, without outputs or mutants."""
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT,
                           capture_output=True, text=True, check=True).stdout.split()
    for f in files:
        if f.startswith(("validation/out/", "runs/", "mutants/")) or not (ROOT / f).is_file():
            continue
        (dest / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / f, dest / f)


def _toml_list(items: list[str]) -> str:
    return "[" + ", ".join(json.dumps(i) for i in items) + "]"


def _configure(work: Path, mutate: list[str], tests: list[str],
               timeout_multiplier: float = 15.0) -> None:
    tests = [t for t in tests if not t.startswith("tests/") or (work / t.split("::")[0]).exists()]
    section = (f"\n[tool.mutmut]\nsource_paths = [\"fem_rmpm\"]\nonly_mutate = "
               f"{_toml_list(mutate)}\nalso_copy = [\"meshes\", \"validation\", \"README.md\"]\n"
               f"pytest_add_cli_args_test_selection = {_toml_list(tests)}\n"
               "pytest_add_cli_args = [\"-p\", \"no:cacheprovider\", \"-q\", \"-x\"]\n"
               f"timeout_multiplier = {float(timeout_multiplier)}\n"
               # each mutant in a process forked from a clean fork server, not from the
               # process that ran the stats: numba's workqueue threading layer, once its
               # pool has started there, terminates a forked child that uses it (SIGTERM,
               # which mutmut reports as "suspicious")
               "process_isolation = \"forkserver\"\n")
    with open(work / "pyproject.toml", "a") as fh:
        fh.write(section)


def _status(listing: str, status: str) -> list[str]:
    return [ln.split(":")[0].strip() for ln in listing.splitlines()
            if ln.strip().endswith(f": {status}")]


def run_target(name: str, work: Path, max_children: int, show: bool,
               only: list[str] | None = None, niceness: int = 19,
               timeout_multiplier: float = 15.0) -> dict:
    """Mutate ``name``'s files and run its tests (``only``: these mutant names alone)."""
    mutate, tests = TARGETS[name]
    work.mkdir(parents=True, exist_ok=True)
    _copy_repo(work)
    _configure(work, mutate, tests, timeout_multiplier)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}   # import the mutants
    env["NUMBA_CACHE_DIR"] = str(work / ".numba_cache")
    log = work / "mutmut.log"
    with open(log, "w") as fh:
        subprocess.run(["nice", "-n", str(niceness), "mutmut", "run", "--max-children", str(max_children),
                        *(only or [])],
                       cwd=work, env=env, stdout=fh, stderr=subprocess.STDOUT, check=False)
    subprocess.run(["mutmut", "export-cicd-stats"], cwd=work, env=env, capture_output=True)
    stats = json.loads((work / "mutants" / "mutmut-cicd-stats.json").read_text())
    # ``--all true``: without it mutmut lists only the mutants that were not killed
    listing = subprocess.run(["mutmut", "results", "--all", "true"], cwd=work, env=env,
                             capture_output=True, text=True).stdout
    survivors, no_tests = _status(listing, "survived"), _status(listing, "no tests")
    if only:                 # a rerun: count the named mutants only (the others: not checked)
        names = set(only)
        survivors = [m for m in survivors if m in names]
        no_tests = [m for m in no_tests if m in names]
        killed = [m for m in _status(listing, "killed") + _status(listing, "timeout")
                  if m in names]
        stats = {"total": len(names), "skipped": 0, "killed": len(killed), "timeout": 0,
                 "survived": len(survivors), "no_tests": len(no_tests)}
    tested = stats["total"] - stats["skipped"]
    score = (stats["killed"] + stats["timeout"]) / tested if tested else 0.0
    diffs = {}
    if show:
        for m in survivors:
            diffs[m] = subprocess.run(["mutmut", "show", m], cwd=work, env=env,
                                      capture_output=True, text=True).stdout
    return {"target": name, "files": mutate, "tests": tests, "score": score, "stats": stats,
            "survivors": survivors, "no_tests": no_tests, "diffs": diffs}


def combine(before: dict, rerun: dict) -> dict:
    """The score after new tests: the first run's killed mutants plus those of a rerun of
    its survivors and untested mutants (``--rerun``)."""
    s = before["stats"]
    tested = s["total"] - s["skipped"]
    killed = s["killed"] + s["timeout"] + rerun["stats"]["killed"] + rerun["stats"]["timeout"]
    return {**rerun, "before_score": before["score"], "before_stats": s,
            "score": killed / tested if tested else 0.0,
            "stats": {**s, "killed": killed, "timeout": 0, "survived": len(rerun["survivors"]),
                      "no_tests": len(rerun["no_tests"])}}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("target", choices=[*TARGETS, "all"])
    p.add_argument("--workdir", default=None, help="scratch directory (default: a temp dir)")
    p.add_argument("--max-children", type=int, default=1, help="parallel mutant runs")
    p.add_argument("--survivors", action="store_true", help="print each surviving mutant")
    p.add_argument("--nice", type=int, default=19, help="niceness of the mutant runs")
    p.add_argument("--timeout-multiplier", type=float, default=15.0,
                   help="a mutant's tests are stopped after this many times their clean run "
                        "(mutmut's default 15; raise it on a loaded machine, where a slow run "
                        "is not a kill)")
    p.add_argument("--only", nargs="*", default=None, metavar="NAME",
                   help="mutant names (as mutmut lists them, e.g. 'fem_rmpm.schemes.explicit.loop.x_stable_time_step"
                        "__mutmut_3') to run instead of all")
    p.add_argument("--rerun", default=None, metavar="JSON",
                   help="an earlier result of this target: run only its survivors and "
                        "untested mutants (with the current tests) and report the combined "
                        "score")
    a = p.parse_args(argv)
    out = ROOT / "validation" / "out"
    out.mkdir(parents=True, exist_ok=True)
    for name in (TARGETS if a.target == "all" else [a.target]):
        base = Path(a.workdir) if a.workdir else Path(tempfile.mkdtemp(prefix="mutmut_"))
        if a.rerun:
            before = json.loads(Path(a.rerun).read_text())
            only = before["survivors"] + before.get("no_tests", [])
            res = combine(before, run_target(name, base / name, a.max_children, True, only,
                                                    a.nice, a.timeout_multiplier))
        else:
            res = run_target(name, base / name, a.max_children, show=True, only=a.only,
                             niceness=a.nice, timeout_multiplier=a.timeout_multiplier)
        (out / f"mutation_{name}.json").write_text(json.dumps(res, indent=1))
        s = res["stats"]
        print(f"{name}: mutation score {res['score']:.1%} ({s['killed']} killed, "
              f"{s['timeout']} timeouts, {s['survived']} survived, {s['no_tests']} without a "
              f"test, of {s['total']}); details in validation/out/mutation_{name}.json")
        if a.survivors:
            for m in res["survivors"]:
                print(res["diffs"].get(m, m))
    return 0


if __name__ == "__main__":
    sys.exit(main())
