"""The machine named in a run's ``summary.json`` (:mod:`fem_rmpm.runtime.machine`)."""
from __future__ import annotations

import json
import os
import platform

from fem_rmpm.runtime.machine import cpu_model, cpu_signature, describe, tally, usable_cores


def test_cpu_model_is_the_first_model_name_of_cpuinfo(tmp_path):
    """Linux's ``/proc/cpuinfo`` format: ``key<TAB>: value`` per line, one block per logical
    CPU; the first non-empty ``model name`` is the machine's CPU."""
    f = tmp_path / "cpuinfo"
    f.write_text("processor\t: 0\nvendor_id\t: AuthenticAMD\nmodel name\t: \n"
                 "model name\t: AMD EPYC 7B13\nflags\t\t: fpu: vme\n\n"
                 "processor\t: 1\nmodel name\t: other\n")
    assert cpu_model(str(f)) == "AMD EPYC 7B13"


def test_cpu_signature_is_vendor_family_and_model(tmp_path):
    """``vendor_id``, ``cpu family`` and ``model`` of the first CPU block (an AMD EPYC of
    the Zen 1 generation: AuthenticAMD, 23, 1; a virtual machine may name it just "AMD
    EPYC"); None where a field is missing or not a number, or there is no file."""
    f = tmp_path / "cpuinfo"
    f.write_text("processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 23\n"
                 "model\t\t: 1\nmodel name\t: AMD EPYC\n\n"
                 "processor\t: 1\nvendor_id\t: AuthenticAMD\ncpu family\t: 25\nmodel\t\t: 1\n")
    assert cpu_signature(str(f)) == ("AuthenticAMD", 23, 1)
    f.write_text("vendor_id\t: GenuineIntel\ncpu family\t: 6\nmodel name\t: Intel Xeon\n")
    assert cpu_signature(str(f)) is None
    f.write_text("vendor_id\t: GenuineIntel\ncpu family\t: six\nmodel\t\t: 167\n")
    assert cpu_signature(str(f)) is None
    assert cpu_signature(str(tmp_path / "missing")) is None


def test_cpu_model_without_cpuinfo_falls_back_to_platform(tmp_path):
    got = cpu_model(str(tmp_path / "missing"))
    assert got == (platform.processor() or platform.machine() or "unknown") and got


def test_describe_is_json_and_names_cores_load_and_versions():
    m = json.loads(json.dumps(describe()))
    assert set(m) == {"cpu_model", "logical_cores", "usable_cores", "load_average", "platform",
                      "node", "python", "numpy", "numba", "cpu_signature"}
    assert m["cpu_signature"] == (list(cpu_signature()) if cpu_signature() else None)
    assert m["usable_cores"] == usable_cores() and 1 <= m["usable_cores"] <= os.cpu_count()
    assert m["load_average"] is None or (len(m["load_average"]) == 3
                                         and min(m["load_average"]) >= 0)
    assert m["python"] == platform.python_version() and m["node"] == platform.machine()


def test_tally_counts_runs_per_host_and_cpu():
    """Worker descriptions (a campaign record's ``worker``) counted per (host, CPU), most
    runs first; records without a worker are skipped, an old worker without a CPU is "?"."""
    a = {"host": "node1", "cpu_model": "AMD EPYC 9B14", "pid": 1}
    b = {"host": "node2", "cpu_model": "Intel Xeon", "pid": 2}
    got = tally([a, b, dict(a, pid=3), None, "x", {"host": "node3"}, dict(b, pid=4), a])
    assert got == [{"host": "node1", "cpu_model": "AMD EPYC 9B14", "runs": 3},
                   {"host": "node2", "cpu_model": "Intel Xeon", "runs": 2},
                   {"host": "node3", "cpu_model": "?", "runs": 1}]
    assert tally([]) == [] and tally([None]) == []


def test_slow_threading_layer_warning_names_the_cause_and_the_remedy(monkeypatch):
    """Only numba's ``workqueue`` layer on two or more threads is warned about, with what
    to change: the OpenMP runtime when numba fell back to it, the environment variable
    when that asked for it."""
    import numba

    from fem_rmpm.runtime.machine import slow_threads_warning
    assert slow_threads_warning("omp", 2) is None and slow_threads_warning("tbb", 2) is None
    assert slow_threads_warning("workqueue", 1) is None and slow_threads_warning(None, 2) is None
    monkeypatch.setattr(numba.config, "THREADING_LAYER", "default")
    text = slow_threads_warning("workqueue", 2)
    assert "\n" not in text and "libgomp.so.1" in text and "apt install libgomp1" in text
    assert "threads = 1" in text
    monkeypatch.setattr(numba.config, "THREADING_LAYER", "workqueue")
    assert "unset NUMBA_THREADING_LAYER" in slow_threads_warning("workqueue", 2)


def test_a_threaded_run_records_its_threading_layer_and_warns_once(monkeypatch, capsys):
    """A two-thread run books numba's layer in ``solver.threading_layer``; on the slow
    layer it warns on stderr once per process, not at every run; a one-thread run books
    none."""
    import fem_rmpm.schemes.explicit.threads as threads_mod
    from fem_rmpm.discretise.grid import make_grid
    from fem_rmpm.discretise.points import seed_particles
    from fem_rmpm.scene import load_scene, with_values
    from fem_rmpm.schemes.explicit.loop import run_explicit
    monkeypatch.setattr(threads_mod, "threading_layer", lambda: "workqueue")
    monkeypatch.setattr(threads_mod, "_THREADS_WARNED", set())
    base = load_scene(os.path.join(os.path.dirname(__file__), "..", "meshes", "column.toml"))
    records = []
    for threads in (2, 2, 1):
        scene = with_values(base, {"solver.t_end": 0.02, "solver.threads": threads})
        grid = make_grid(scene)
        records.append(run_explicit(scene, grid, seed_particles(scene, grid)))
    assert [r.solver.get("threading_layer") for r in records] == ["workqueue", "workqueue", None]
    assert capsys.readouterr().err.count("slow 'workqueue' layer") == 1
