"""SIGINT (Ctrl-C) and SIGTERM (``timeout``, a batch system's wall-time limit) sent to the
``fem-rmpm`` command at start-up, in the middle of a run and in the middle of a campaign,
once and twice in a row: prints one table row per case (exit code, lines on stderr, a
traceback or not, the run's summary status, the campaign lock free or not, the statuses
of the campaign's kept-VTK runs, seconds from the first signal to the exit).

The signal goes to the command's whole process group, as a terminal's Ctrl-C does (the
campaign's local worker processes get it too).  Expected: exit 130 (SIGINT) or 143
(SIGTERM), one line on stderr, no traceback, a run's ``summary.json`` saying
``"interrupted"``, the campaign lock free, no kept-VTK run of a campaign left
``"running"`` (its worker process got the signal too).

    python validation/signals.py            # about a minute or two
"""
from __future__ import annotations

import fcntl
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests" / "data" / "mc_slow.toml"
COMMAND = [sys.executable, "-m", "fem_rmpm_entry"]


def _start(args: list[str], cwd: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.Popen(COMMAND + args, cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)


def _wait_for(test, limit: float = 180.0) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < limit:
        if test():
            return True
        time.sleep(0.1)
    return False


def _running(out: Path) -> bool:
    try:
        return json.loads((out / "summary.json").read_text())["status"] == "running"
    except (OSError, ValueError, KeyError):
        return False


def _records(out: Path) -> int:
    return len(list((out / "records").glob("realization_*.json"))) if out.exists() else 0


def _lock_free(out: Path) -> str:
    path = out / ".campaign.lock"
    if not path.exists():
        return "-"
    with open(path) as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return "HELD"
        fcntl.flock(fh, fcntl.LOCK_UN)
    return "free"


def _status(out: Path) -> str:
    try:
        return json.loads((out / "summary.json").read_text()).get("status", "?")
    except (OSError, ValueError):
        return "-"


def _kept_vtk(out: Path) -> str:
    """The statuses of a campaign's kept-VTK runs, e.g. ``ok 3, interrupted 2``."""
    found: dict[str, int] = {}
    for path in sorted(out.glob("vtk/**/realization_*/summary.json")):
        try:
            status = json.loads(path.read_text()).get("status", "?")
        except (OSError, ValueError):
            status = "unreadable"
        found[status] = found.get(status, 0) + 1
    return ", ".join(f"{k} {v}" for k, v in found.items()) or "-"


def case(where: str, sig: signal.Signals, times: int, work: Path) -> dict:
    """Start the command of ``where`` (start-up, run, campaign), wait for its moment, send
    ``sig`` ``times`` times (0.3 s apart) to its process group; what it left."""
    out = work / f"{where}-{sig.name}-{times}"
    if where == "campaign":
        args = ["mc", str(TINY), "-n", "400", "--out", str(out), "--quiet", "--keep-vtk", "12"]
        ready = lambda: _records(out) >= 2          # noqa: E731
    else:
        args = ["run", str(TINY), "--out", str(out), "--quiet", "--set", "solver.t_end=400"]
        ready = (lambda: True) if where == "start-up" else (lambda: _running(out))
    p = _start(args, work)
    if where == "start-up":
        time.sleep(0.3)                            # inside the package imports
    elif not _wait_for(ready):
        p.kill()
        return {"case": where, "signal": sig.name, "times": times, "exit": "no start"}
    t0 = time.monotonic()
    for k in range(times):
        if p.poll() is None:
            os.killpg(p.pid, sig)
        if k + 1 < times:
            time.sleep(0.3)
    try:
        _, err = p.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        _, err = p.communicate()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    return {"case": where, "signal": sig.name, "times": times, "exit": p.returncode,
            "stderr lines": len(lines), "traceback": "Traceback" in err,
            "summary": _status(out), "lock": _lock_free(out), "kept VTK": _kept_vtk(out),
            "seconds": round(time.monotonic() - t0, 1),
            "first line": lines[0][:70] if lines else ""}


def main() -> int:
    rows = []
    with tempfile.TemporaryDirectory(prefix="fem_rmpm_signals_") as tmp:
        for where in ("start-up", "run", "campaign"):
            for sig in (signal.SIGINT, signal.SIGTERM):
                for times in (1, 2):
                    rows.append(case(where, sig, times, Path(tmp)))
                    print(rows[-1], file=sys.stderr, flush=True)
    keys = ["case", "signal", "times", "exit", "stderr lines", "traceback", "summary", "lock",
            "kept VTK", "seconds", "first line"]
    width = {k: max(len(k), *(len(str(r.get(k, ""))) for r in rows)) for k in keys}
    print(" | ".join(k.ljust(width[k]) for k in keys))
    print("-|-".join("-" * width[k] for k in keys))
    for r in rows:
        print(" | ".join(str(r.get(k, "")).ljust(width[k]) for k in keys))
    bad = [r for r in rows if r.get("exit") not in (130, 143) or r.get("traceback")
           or r.get("stderr lines") != 1 or r.get("lock") == "HELD"
           or r.get("summary") == "running" or "running" in r.get("kept VTK", "")]
    print(f"\n{len(rows) - len(bad)} of {len(rows)} cases clean")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
