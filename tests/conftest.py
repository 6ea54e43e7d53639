"""Shared fixtures: paths to the shipped scenes and a helper to write scene variants."""
import functools
import signal
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MESHES = ROOT / "meshes"


@pytest.fixture(autouse=True)
def _signal_dispositions():
    """Every test starts with the worker's SIGINT and SIGTERM handlers and no pending
    interrupt: a test whose command was interrupted in this process leaves both ignored
    (the command's clean-up state), which must not reach the next test."""
    before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    yield
    for sig, handler in before.items():
        if handler is not None:
            signal.signal(sig, handler)
    from fem_rmpm.runtime import signals   # lazy: the package loads with the first test
    signals._pending.clear()


@pytest.fixture
def meshes() -> Path:
    return MESHES


@pytest.fixture
def column_text() -> str:
    return (MESHES / "column.toml").read_text()


# Scope "package": tests/ is the one test directory, so a fixture of this scope is made once
# for the whole test run.
@pytest.fixture(scope="package")
def meshes_dir_fx():
    """The reference slope grid (shared, read-only)."""
    from fem_rmpm.discretise.grid import make_grid
    from fem_rmpm.scene import load_scene
    return make_grid(load_scene(MESHES / "slope_elastic.toml"))


@pytest.fixture(scope="package")
def dask_client():
    """One local Dask cluster (2 single-thread worker processes) for the whole test run.

    Tests that run campaigns in this process use it (``client=`` or ``--scheduler`` its
    address) instead of starting their own: each start costs seconds, and a second
    in-process LocalCluster can fail in distributed's loop start (under load, in CI).
    Tests of cluster start-up itself run the CLI in a subprocess.

    Before the workers start, a 2-step run of the campaign tests' scene compiles the
    explicit kernels here into numba's disk cache: on a cold cache (a fresh clone) the two
    workers would otherwise compile the same kernels at the same time as each other and as
    this process, which makes the first campaign test's set-up cost minutes under load."""
    from fem_rmpm.campaign import start_local_cluster
    from fem_rmpm.discretise.grid import make_grid
    from fem_rmpm.discretise.points import seed_particles
    from fem_rmpm.scene import load_scene, with_values
    from fem_rmpm.schemes.explicit.loop import run_explicit
    scene = with_values(load_scene(ROOT / "tests" / "data" / "mc_tiny.toml"),
                        {"solver.t_end": 0.01, "solver.threads": 1})
    grid = make_grid(scene)
    run_explicit(scene, grid, seed_particles(scene, grid))
    client, cluster = start_local_cluster(2)
    yield client
    client.close(timeout=10)
    cluster.close(timeout=10)


@pytest.fixture(scope="package")
def mc_tiny_campaign(tmp_path_factory) -> Path:
    """A finished two-realization campaign of ``tests/data/mc_tiny.toml`` made by the
    command line (``python -m fem_rmpm.cli mc ... -n 2 --workers 1``: its own LocalCluster
    of one worker process), once per test process.  Read-only: a module whose tests change a
    campaign works on a copy of its own (``shutil.copytree``)."""
    import os
    import subprocess
    import sys
    out = tmp_path_factory.mktemp("mc_tiny_campaign") / "mc"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, "-m", "fem_rmpm.cli", "mc",
                        str(ROOT / "tests" / "data" / "mc_tiny.toml"), "-n", "2",
                        "--workers", "1", "--out", str(out)],
                       env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture(scope="package")
def dask_scheduler(dask_client) -> str:
    """The address of :func:`dask_client`'s scheduler (for ``mc --scheduler``)."""
    return dask_client.scheduler.address


def _controller_refuses(conf_path: str | None = None) -> str | None:
    """``host:port`` of the slurmctld that slurm.conf names when that port refuses a TCP
    connection right now (nothing listens: SLURM is installed but not running), else None
    (it accepts, or slurm.conf / the host cannot be read: then `sinfo` decides).  Without
    this, `sinfo` retries the absent controller for ~9 s before it fails."""
    import os
    import re
    import socket
    path = Path(conf_path or os.environ.get("SLURM_CONF") or "/etc/slurm/slurm.conf")
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError):
        return None
    host, port = None, 6817                                  # SLURM's default port
    for line in lines:
        key, _, value = line.split("#", 1)[0].partition("=")
        key, value = key.strip().lower(), value.strip()
        m = re.match(r"([^()\s,]+)(?:\(([^)\s]+)\))?", value)
        if key in ("slurmctldhost", "controlmachine") and host is None and m:
            host = m.group(2) or m.group(1)                  # name(address): the address
        elif key == "slurmctldport" and re.match(r"\d+", value):
            port = int(re.match(r"\d+", value).group())     # a range: its first port
    if host is None:
        return None
    try:
        with socket.create_connection((host, port), timeout=2):
            return None
    except ConnectionRefusedError:
        return f"{host}:{port}"
    except OSError:                                          # unknown host, time-out, ...
        return None


@functools.lru_cache(maxsize=None)
def _slurm_missing() -> str | None:
    """Why SLURM cannot be used here (None: `sinfo` lists a node that takes jobs); asked
    once per test process."""
    import shutil
    import subprocess
    if shutil.which("sbatch") is None or shutil.which("sinfo") is None:
        return "SLURM is not installed (no sbatch/sinfo on PATH; .ci/slurm-start.sh installs it)"
    import os
    in_ci = os.environ.get("CI", "").lower() in ("1", "true", "yes")
    refused = None if in_ci else _controller_refuses()        # CI: always ask sinfo
    if refused:
        return (f"SLURM is not running (no slurmctld listens at {refused}; "
                ".ci/slurm-start.sh starts one)")
    try:
        res = subprocess.run(["sinfo", "-h", "-N", "-o", "%t"], capture_output=True, text=True,
                             timeout=30)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"sinfo failed: {exc}"
    states = res.stdout.split()
    if res.returncode != 0 or not any(s.rstrip("*~#") in ("idle", "mix", "mixed", "alloc",
                                                           "allocated") for s in states):
        return ("no SLURM node takes jobs (sinfo: "
                + (" ".join((res.stderr or res.stdout).split())[:200] or "no node") + ")")
    return None


def pytest_runtest_setup(item):
    """Tests marked `slurm` need a running SLURM: skip without one, fail under CI=true."""
    if item.get_closest_marker("slurm") is None:
        return
    why = _slurm_missing()
    if why is None:
        return
    import os
    if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
        pytest.fail(f"CI=true but {why}", pytrace=False)
    pytest.skip(why)
