"""The fault matrix: a new user's mistakes, each tried as a new user would, with the
installed ``fem-rmpm`` command in a fresh empty folder, printed as one table row per case
(exit code, lines on stderr, a traceback or not, files left behind, verdict).

The categories: file-system errors (the permission cases run as ``nobody`` through
``setpriv`` when this runs as root: permissions mean nothing to root), inputs that broke
a library, unbounded work (each must be refused at once), wrong answers or lost data, and
representative bad input of every command (run, fem, field, fs, mc, report).  Bad input
must end with exit 2, one line on stderr, no traceback and nothing written; the other
cases state what they expect.  The signal cases (SIGINT, SIGTERM at start-up, mid-run,
mid-campaign, twice) are ``validation/signals.py``.

    python validation/fault_matrix.py            # a few minutes; --only NAME... for some
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MESHES, DATA = ROOT / "meshes", ROOT / "tests" / "data"
TINY, COLUMN = DATA / "mc_tiny.toml", MESHES / "column.toml"
REFERENCE = ROOT / "fem_rmpm" / "data" / "slope_reference.toml"
AS_NOBODY = ["setpriv", "--reuid=nobody", "--regid=nogroup", "--clear-groups"]


@dataclass
class Case:
    """One mistake: ``args`` of ``fem-rmpm`` run in a fresh folder that ``setup`` fills;
    ``expect``: allowed exit codes; ``lines``: stderr lines (None: any); ``left``: names
    that may stay behind; ``check``: extra test of the folder and output -> a problem or
    None; ``user``: run as ``nobody``; ``head``: stdout into ``head -1``."""
    name: str
    args: list[str]
    setup: Callable[[Path], None] | None = None
    expect: tuple[int, ...] = (2,)
    lines: int | None = 1
    left: tuple[str, ...] = ()
    check: Callable[[Path, str, str], str | None] | None = None
    user: bool = False
    head: bool = False
    timeout: float = 600.0
    category: str = "bad input"


@dataclass
class Row:
    case: Case
    code: int | None
    lines: int
    traceback: bool
    left: list[str] = field(default_factory=list)
    seconds: float = 0.0
    verdict: str = "ok"


# --------------------------------------------------------------------------- set-ups

def _copy(name: Path, to: str | None = None, extra: str = "") -> Callable[[Path], None]:
    def setup(d: Path) -> None:
        path = d / (to or name.name)
        path.write_text(name.read_text() + extra)
        path.chmod(0o644)
    return setup


def _all(*steps: Callable[[Path], None]) -> Callable[[Path], None]:
    def setup(d: Path) -> None:
        for s in steps:
            s(d)
    return setup


def _write(name: str, text: str, mode: int = 0o644) -> Callable[[Path], None]:
    def setup(d: Path) -> None:
        (d / name).write_text(text)
        (d / name).chmod(mode)
    return setup


def _mkdir(name: str, mode: int = 0o777) -> Callable[[Path], None]:
    def setup(d: Path) -> None:
        (d / name).mkdir(parents=True)
        (d / name).chmod(mode)
    return setup


def _symlink(name: str, target: str) -> Callable[[Path], None]:
    return lambda d: (d / name).symlink_to(d / target)


_CAMPAIGN: dict[str, Path] = {}


def _campaign(d: Path, name: str = "mc", change: Callable[[Path], None] | None = None,
              mode: int | None = None) -> None:
    """A finished two-realization campaign of mc_tiny (made once, copied per case)."""
    if "mc" not in _CAMPAIGN:
        base = Path(tempfile.mkdtemp(prefix="fault_matrix_campaign_"))
        r = subprocess.run(["fem-rmpm", "mc", str(TINY), "-n", "2", "--workers", "1",
                            "--out", str(base / "mc"), "--quiet"], capture_output=True,
                           text=True, timeout=900, cwd=base)
        if r.returncode != 0:
            raise SystemExit(f"the campaign of the set-up failed: {r.stderr.strip()}")
        _CAMPAIGN["mc"] = base / "mc"
    shutil.copytree(_CAMPAIGN["mc"], d / name)
    (d / name / "report.html").unlink(missing_ok=True)
    if change:
        change(d / name)
    if mode is not None:
        for p in [d / name, *(d / name).rglob("*")]:
            p.chmod(mode if p.is_dir() else 0o444)


def _finished_run(d: Path) -> None:
    """``prev/``: a finished short run of the column (its summary and VTK)."""
    r = subprocess.run(["fem-rmpm", "run", "column.toml", "--out", "prev", "--quiet",
                        "--set", "solver.t_end=0.05"], capture_output=True, text=True,
                       cwd=d, timeout=900)
    if r.returncode != 0:
        raise SystemExit(f"the run of the set-up failed: {r.stderr.strip()}")


def _two_soils(second: str) -> str:
    return f"""[scene]
name = "two"
[grid]
origin = [0.0, 0.0]
size = [4.0, 2.0]
cell = 0.5
[boundary]
left = "roller"
right = "roller"
bottom = "fixed"
top = "free"
[[soil]]
name = "clay"
polygon = [[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]]
unit_weight = 20.0
youngs_modulus = 1000.0
poisson_ratio = 0.3
[[soil]]
name = "sand"
polygon = {second}
unit_weight = 18.0
youngs_modulus = 2000.0
poisson_ratio = 0.3
"""


def _polygon_scene(points: np.ndarray, second: np.ndarray | None = None) -> str:
    """A scene of one soil (or two) with the given outline(s), grid around them."""
    def soil(name, p):
        body = ", ".join(f"[{x:.9g}, {y:.9g}]" for x, y in p)
        return (f'[[soil]]\nname = "{name}"\npolygon = [{body}]\nunit_weight = 20.0\n'
                "youngs_modulus = 10000.0\npoisson_ratio = 0.3\n")
    allp = points if second is None else np.vstack([points, second])
    lo, hi = np.floor(allp.min(axis=0)) - 1, np.ceil(allp.max(axis=0)) + 1
    return (f'[scene]\nname = "poly"\n[grid]\norigin = [{lo[0]:g}, {lo[1]:g}]\n'
            f"size = [{hi[0] - lo[0]:g}, {hi[1] - lo[1]:g}]\ncell = 1.0\n"
            '[boundary]\nleft = "roller"\nright = "roller"\nbottom = "fixed"\ntop = "free"\n'
            + soil("a", points) + ("" if second is None else soil("b", second)))


def _star(n: int, spikes: bool = False) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = 20 + 5 * np.sin(7 * t) + (3 * (np.arange(n) % 2) if spikes else 0)
    return np.c_[20 + r * np.cos(t), 20 + r * np.sin(t)]


def _bow_tie(n: int) -> str:
    p = _star(n)
    p[[n // 4, 3 * n // 4]] = p[[3 * n // 4, n // 4]]          # two points swapped: crossings
    return _polygon_scene(p)


def _touching_pair(n: int) -> str:
    x = np.linspace(0.0, 100.0, n)
    line = np.c_[x, 5.0 + np.sin(0.7 * x) + 0.3 * np.sin(13.1 * x)]
    lower = np.r_[[[0.0, 0.0], [100.0, 0.0]], line[::-1]]
    upper = np.r_[line, [[100.0, 12.0], [0.0, 12.0]]]
    return _polygon_scene(lower, upper)


def _huge_polygon(d: Path) -> None:
    n = 2_000_000
    with open(d / "huge.toml", "w") as fh:
        fh.write(_polygon_scene(_star(8)).split("[[soil]]")[0])
        fh.write('[[soil]]\nname = "a"\nunit_weight = 20.0\nyoungs_modulus = 1e4\n'
                 "poisson_ratio = 0.3\npolygon = [")
        p = _star(n)
        for k in range(0, n, 100_000):
            fh.write(", ".join(f"[{x:.6f}, {y:.6f}]" for x, y in p[k:k + 100_000]))
            fh.write(", " if k + 100_000 < n else "]\n")


# --------------------------------------------------------------------------- checks

def _unchanged(name: str) -> Callable[[Path, str, str], str | None]:
    """The set-up's ``name`` (a file or directory) is left exactly as it was."""
    def check(d: Path, out: str, err: str) -> str | None:
        return None if _digest(d / name) == _BEFORE.get(str(d / name)) else f"{name} changed"
    check.watch = name                                    # type: ignore[attr-defined]
    return check


def _not_in_output(*words: str) -> Callable[[Path, str, str], str | None]:
    def check(d: Path, out: str, err: str) -> str | None:
        bad = [w for w in words if w in out or w in err]
        return f"prints {bad}" if bad else None
    return check


_BEFORE: dict[str, str] = {}


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    for p in sorted([path, *path.rglob("*")] if path.is_dir() else [path]):
        h.update(str(p.relative_to(path.parent)).encode())
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()


# --------------------------------------------------------------------------- the cases

def cases() -> list[Case]:
    two = _two_soils
    fs_err = "file-system"
    return [
        # wrong answers and lost data
        Case("fs: drained infinite slope, free ends (numerical, not FS < 0.1)",
             ["fs", "infinite_slope_drained.toml", "--out", "fs", "--quiet"],
             _copy(MESHES / "infinite_slope_drained.toml"), expect=(0, 3), lines=None,
             left=("fs",), check=_not_in_output("FS < 0.1"), category="wrong answer"),
        Case("fem --out on a finished run", ["fem", "column.toml", "--out", "prev"],
             _all(_copy(COLUMN), _finished_run), check=_unchanged("prev"),
             category="lost data"),
        Case("two overlapping soils", ["fem", "two.toml", "--out", "out"],
             _write("two.toml", two("[[1.5, 0.5], [3.0, 0.5], [3.0, 1.5], [1.5, 1.5]]")),
             category="wrong answer"),
        Case("two touching soils (accepted)", ["mc", "two.toml", "-n", "1", "--dry-run"],
             _write("two.toml", two("[[2.0, 0.0], [4.0, 0.0], [4.0, 1.0], [2.0, 1.0]]")),
             expect=(0,), lines=0, category="wrong answer"),
        Case("two soils touching along 20 000 points (accepted)",
             ["mc", "pair.toml", "-n", "1", "--dry-run"],
             _write("pair.toml", _touching_pair(20_000)), expect=(0,), lines=0,
             category="unbounded work"),
        Case("two values at one --data point", ["field", "tiny.toml", "--data", "d.csv",
                                                 "--out", "out"],
             _all(_copy(TINY, "tiny.toml"), _write("d.csv", "x,y,value\n1,1,6\n2,0.5,7\n"
                                                             "1,1,9.5\n")),
             category="wrong answer"),
        # file-system errors
        Case("unreadable scene (chmod 000)", ["run", "column.toml", "--out", "new", "--quiet"],
             _all(_copy(COLUMN), lambda d: (d / "column.toml").chmod(0)), user=True,
             category=fs_err),
        *[Case(f"{cmd} --out a read-only {'parent' if below else 'directory'}",
               [cmd, scene, "--out", "ro/new" if below else "ro"]
               + (["--quiet"] if cmd == "run" else []),
               _all(_copy(COLUMN), _copy(TINY, "tiny.toml"), _mkdir("ro", 0o555)),
               user=True, check=_unchanged("ro"), category=fs_err)
          for cmd, scene in (("run", "column.toml"), ("fem", "column.toml"),
                             ("field", "tiny.toml")) for below in (False, True)],
        Case("--out a dangling symlink", ["run", "column.toml", "--out", "link", "--quiet"],
             _all(_copy(COLUMN), _symlink("link", "gone")), category=fs_err),
        Case("unreadable --data CSV", ["field", "tiny.toml", "--data", "d.csv", "--out", "out"],
             _all(_copy(TINY, "tiny.toml"), _write("d.csv", "x,y,value\n1,1,6\n", 0)),
             user=True, category=fs_err),
        Case("report on a read-only campaign", ["report", "mc"],
             lambda d: _campaign(d, mode=0o555), user=True, check=_unchanged("mc"),
             category=fs_err),
        # tracebacks
        Case("a 10 000-level nested array", ["run", "deep.toml", "--out", "out"],
             _write("deep.toml", "a = " + "[" * 10_000 + "]" * 10_000 + "\n"),
             category="traceback"),
        Case("report: campaign.json a JSON list", ["report", "mc"],
             lambda d: _campaign(d, change=lambda c: (c / "campaign.json").write_text("[1]")),
             check=_unchanged("mc"), category="traceback"),
        Case("field with theta_v = 1e-6", ["field", "ref.toml", "--out", "out"],
             _copy(REFERENCE, "ref.toml", "\n[random_field]\ntheta_v = 1e-6\n"),
             check=_not_in_output("Warning"), category="traceback"),
        Case("run with theta_v = 1e-6", ["run", "ref.toml", "--out", "out", "--quiet"],
             _copy(REFERENCE, "ref.toml", "\n[random_field]\ntheta_v = 1e-6\n"),
             check=_not_in_output("Warning"), category="traceback"),
        Case("mc ... | head -1 after a finished campaign",
             ["mc", "tiny.toml", "-n", "2", "--workers", "1", "--out", "mc", "--quiet"],
             _all(_copy(TINY, "tiny.toml"), _campaign), expect=(0, 141), lines=0, head=True,
             left=("mc",), category="traceback"),
        Case("mc --fs, runs stopped once decided",
             ["mc", "tiny.toml", "-n", "4", "--workers", "1", "--fs", "--out", "mc",
              "--quiet", "--set", "montecarlo.runs_to_rest=0"], _copy(TINY, "tiny.toml"),
             expect=(0,), lines=0, left=("mc",), category="traceback"),
        # unbounded work
        Case("mc -n 1000000000 --dry-run", ["mc", "tiny.toml", "-n", "1000000000",
                                            "--dry-run", "--out", "mc"],
             _copy(TINY, "tiny.toml"), timeout=60, category="unbounded work"),
        Case("self-intersecting polygon of 20 000 points", ["fem", "bow.toml", "--out", "out"],
             _write("bow.toml", _bow_tie(20_000)), timeout=60, category="unbounded work"),
        Case("polygon of 2 000 000 points", ["fem", "huge.toml", "--out", "out"],
             _huge_polygon, timeout=120, category="unbounded work"),
        Case("mc --scheduler 'not a url'", ["mc", "tiny.toml", "-n", "2", "--scheduler",
                                            "not a url", "--out", "mc"],
             _copy(TINY, "tiny.toml"), timeout=25, category="unbounded work"),
        # minor
        Case("solver.cfl = 5", ["run", "column.toml", "--set", "solver.cfl=5", "--out", "o"],
             _copy(COLUMN), category="minor"),
        Case("grid.origin = [nan, 0]", ["run", "column.toml", "--set", "grid.origin=[nan, 0.0]",
                                        "--out", "o"], _copy(COLUMN), category="minor"),
        Case("--set soil.model=mohr_coulomb_softening",
             ["run", "column.toml", "--set", "soil.model=mohr_coulomb_softening", "--out", "o"],
             _copy(COLUMN), check=_not_in_output("got inf"), category="minor"),
        Case("--out ''", ["fem", "column.toml", "--out", ""], _copy(COLUMN), category="minor"),
        Case("--case ''", ["mc", "tiny.toml", "--out", "x", "--case", ""],
             _copy(TINY, "tiny.toml"), category="minor"),
        Case("field, bad --data under a/b/c", ["field", "tiny.toml", "--data", "nope.csv",
                                                "--out", "a/b/c"],
             _copy(TINY, "tiny.toml"), category="minor"),
        Case("report on a run directory", ["report", "prev"],
             _all(_copy(COLUMN), _finished_run), check=_unchanged("prev"), category="minor"),
        Case("report: summary.json is {}", ["report", "mc"],
             lambda d: _campaign(d, change=lambda c: (c / "summary.json").write_text("{}")),
             check=_unchanged("mc"), category="minor"),
        # representative bad input of every command
        Case("run: no such scene", ["run", "nope.toml", "--out", "o"]),
        Case("run: unknown key", ["run", "column.toml", "--set", "solver.bogus=1", "--out", "o"],
             _copy(COLUMN)),
        Case("run: value out of range", ["run", "column.toml", "--set", "solver.cfl=-1",
                                         "--out", "o"], _copy(COLUMN)),
        Case("run: --set not a TOML value", ["run", "column.toml", "--set", "solver.cfl=x y",
                                             "--out", "o"], _copy(COLUMN)),
        Case("run: scene not TOML", ["run", "bad.toml", "--out", "o"],
             _write("bad.toml", "[grid\nsize = \n")),
        Case("run: no --out", ["run", "column.toml"], _copy(COLUMN)),
        Case("fem: unknown key in the file", ["fem", "column.toml", "--out", "o"],
             _copy(COLUMN, extra="\n[solver_typo]\nx = 1\n")),
        Case("fem: unknown option", ["fem", "column.toml", "--out", "o", "--bogus"],
             _copy(COLUMN)),
        Case("field: --seed -1", ["field", "tiny.toml", "--seed", "-1", "--out", "o"],
             _copy(TINY, "tiny.toml")),
        Case("field: --property not random", ["field", "tiny.toml", "--property", "density",
                                              "--out", "o"], _copy(TINY, "tiny.toml")),
        Case("field: --fit no such CSV", ["field", "tiny.toml", "--fit", "nope.csv",
                                          "--out", "o"], _copy(TINY, "tiny.toml")),
        Case("fs: no --out", ["fs", "column.toml"], _copy(COLUMN)),
        Case("fs: --tolerance 0", ["fs", "column.toml", "--tolerance", "0", "--out", "o"],
             _copy(COLUMN)),
        Case("mc: -n 0", ["mc", "tiny.toml", "-n", "0", "--out", "mc"], _copy(TINY, "tiny.toml")),
        Case("mc: --keep-vtk x", ["mc", "tiny.toml", "-n", "2", "--keep-vtk", "x",
                                  "--out", "mc"], _copy(TINY, "tiny.toml")),
        Case("mc: --workers 0", ["mc", "tiny.toml", "-n", "2", "--workers", "0",
                                 "--out", "mc"], _copy(TINY, "tiny.toml")),
        Case("report: no such directory", ["report", "nope"]),
        Case("report: a file", ["report", "f.txt"], _write("f.txt", "x\n")),
    ]


# --------------------------------------------------------------------------- running

def _tree(d: Path) -> set[str]:
    return {str(p.relative_to(d)) for p in d.rglob("*")} if d.exists() else set()


def _run(case: Case, home: Path) -> Row:
    d = Path(tempfile.mkdtemp(prefix="fault_matrix_"))
    d.chmod(0o777)
    cleanup = [d]
    try:
        if case.setup:
            case.setup(d)
        watch = getattr(case.check, "watch", None)
        if watch:
            _BEFORE[str(d / watch)] = _digest(d / watch)
        before = _tree(d)
        # a new user's home of their own (caches of matplotlib, numba), not the case folder;
        # a fresh one for ``nobody`` (who cannot write into root's caches)
        if case.user:
            home = Path(tempfile.mkdtemp(prefix="fault_matrix_home_", dir=d.parent))
            home.chmod(0o777)
            cleanup.append(home)
        env = {**os.environ, "HOME": str(home), "NUMBA_CACHE_DIR": str(home / "numba"),
               "PYTHONWARNINGS": "default"}
        argv = ["fem-rmpm", *case.args]
        if case.user and os.geteuid() == 0:
            argv = AS_NOBODY + argv
        t0 = time.perf_counter()
        try:
            if case.head:
                p = subprocess.Popen(argv, cwd=d, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
                p.stdout.close()                # the reader has gone (``| head -1``)
                err = p.stderr.read()
                code, out = p.wait(timeout=case.timeout), ""
            else:
                r = subprocess.run(argv, cwd=d, env=env, capture_output=True, text=True,
                                   timeout=case.timeout)
                code, out, err = r.returncode, r.stdout, r.stderr
        except subprocess.TimeoutExpired:
            return Row(case, None, 0, False, seconds=time.perf_counter() - t0,
                       verdict=f"DEFECT: no answer within {case.timeout:g} s")
        seconds = time.perf_counter() - t0
        for p in d.rglob("*"):          # let us read and remove what nobody made
            if p.is_dir() and not p.is_symlink():
                p.chmod(0o777)
        new = sorted(_tree(d) - before)
        left = [n for n in new if not any(n == k or n.startswith(k + "/") for k in case.left)]
        lines = len(err.strip().splitlines())
        row = Row(case, code, lines, "Traceback" in err, left, seconds)
        problems = []
        if code not in case.expect:
            problems.append(f"exit {code}, expected {'/'.join(map(str, case.expect))}")
        if case.lines is not None and lines != case.lines:
            problems.append(f"{lines} stderr lines, expected {case.lines}: "
                            f"{err.strip().splitlines()[:2]}")
        if row.traceback:
            problems.append("traceback")
        if left:
            problems.append(f"left behind: {left[:4]}")
        if case.check is not None and (p := case.check(d, out, err)):
            problems.append(p)
        row.verdict = "ok" if not problems else "DEFECT: " + "; ".join(problems)
        return row
    finally:
        for top in cleanup:
            for p in top.rglob("*"):
                if p.is_dir() and not p.is_symlink():
                    p.chmod(0o777)
            shutil.rmtree(top, ignore_errors=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", help="run the cases whose name holds one of these")
    a = ap.parse_args()
    if shutil.which("fem-rmpm") is None:
        raise SystemExit("fem-rmpm is not on PATH (install the package)")
    if os.geteuid() == 0 and shutil.which("setpriv") is None:
        print("note: root without setpriv: the permission cases run as root (no meaning)")
    home = Path(tempfile.mkdtemp(prefix="fault_matrix_home_"))
    home.chmod(0o777)
    chosen = [c for c in cases() if not a.only or any(w in c.name for w in a.only)]
    rows = []
    print(f"{'case':58s} {'exit':>4s} {'err':>3s} {'tb':>3s} {'left':>4s} {'s':>6s}  verdict")
    for c in chosen:
        row = _run(c, home)
        rows.append(row)
        print(f"{c.name[:58]:58s} {str(row.code):>4s} {row.lines:3d} "
              f"{'yes' if row.traceback else 'no':>3s} {len(row.left):4d} {row.seconds:6.1f}  "
              f"{row.verdict}", flush=True)
    shutil.rmtree(home, ignore_errors=True)
    for base in _CAMPAIGN.values():
        shutil.rmtree(base.parent, ignore_errors=True)
    bad = [r for r in rows if r.verdict != "ok"]
    by_cat: dict[str, list[int]] = {}
    for r in rows:
        by_cat.setdefault(r.case.category, [0, 0])[r.verdict != "ok"] += 1
    print(f"\n{len(rows)} cases: {len(rows) - len(bad)} ok, {len(bad)} defects; "
          f"tracebacks: {sum(r.traceback for r in rows)}; by category: "
          + ", ".join(f"{k} {v[0]} ok / {v[1]} defects" for k, v in by_cat.items()))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
