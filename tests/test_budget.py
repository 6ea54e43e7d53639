"""Run size and cost estimate (fem_rmpm.runtime.budget): refuse a run too large before allocating.

References are exact counts: the seeded material points of the shipped scenes and the
grid's node count; the CFL step from its formula dt = cfl h / sqrt(M / rho).
"""
from __future__ import annotations

import math

import pytest

from fem_rmpm.api import prepare
from fem_rmpm.cli import main
from fem_rmpm.runtime import budget
from fem_rmpm.runtime.machine import cpu_signature
from fem_rmpm.scene import load_scene, with_value, with_values


@pytest.mark.parametrize("name", ["slope_reference", "column", "footing"])
def test_estimate_counts_points_and_nodes(meshes, name):
    """Points from polygon areas agree with the seeded count (slope: 18 301 vs 18 260,
    0.22 %; asserts 1 %); nodes are exact."""
    scene = load_scene(meshes / f"{name}.toml")
    est = budget.estimate_run(scene)
    grid, pts = prepare(scene)
    assert est.nodes == grid.n_nodes and est.cells == grid.n_cells
    assert abs(est.points - pts.n) <= 0.01 * pts.n


def test_estimate_cfl_step_and_steps(meshes):
    """The explicit step at rest is cfl h / c_p with c_p = sqrt(M / rho) (26.96 m/s for
    the seed clay), steps = ceil(t_end / dt), and the wall time counts the failing slope's
    extra steps (STEPS_FACTOR) on one thread (threads = 0, auto, is resolved by a run)."""
    scene = load_scene(meshes / "slope_reference.toml")
    so = scene.soils[0]
    cp = math.sqrt(so.constrained_modulus / (so.unit_weight / scene.scene.gravity))
    est = budget.estimate_run(scene)
    assert est.dt == pytest.approx(0.5 * 0.25 / cp, rel=1e-12)
    assert est.steps == math.ceil(scene.solver.t_end / est.dt)
    assert est.threads == 1 and est.steps_factor == budget.STEPS_FACTOR
    ns, _ = budget.explicit_cost(cpu_signature())
    assert est.wall_time == pytest.approx(est.steps * budget.STEPS_FACTOR * est.points
                                          * ns * 1e-9, rel=1e-12)


def test_estimate_on_two_threads_and_its_line(meshes):
    """Two threads divide the wall time by 2 x THREAD_EFFICIENCY (the per-point-step cost
    stays the one-thread figure), the numpy kernel runs on one thread, and the printed
    line says the steps are counted at rest and how many threads the wall time is for
    (it said "up to" N steps, which a failing slope exceeds: 11 944 against 8 627)."""
    scene = load_scene(meshes / "slope_reference.toml")
    one = budget.estimate_run(with_value(scene, "solver.threads", 1))
    two = budget.estimate_run(with_value(scene, "solver.threads", 2))
    assert two.threads == 2 and two.ns_per_point_step == one.ns_per_point_step
    assert two.wall_time == pytest.approx(one.wall_time / (2 * budget.THREAD_EFFICIENCY),
                                          rel=1e-12)
    line = two.describe()
    assert "up to" not in line and f"{two.steps:,} explicit steps" in line
    assert "at rest, x1.3 on a failing slope" in line and "wall on 2 threads" in line
    assert "on 1 thread" not in one.describe()
    numpy = budget.estimate_run(with_values(scene, {"solver.threads": 2,
                                                     "solver.kernel": "numpy"}))
    assert numpy.threads == 1


def test_fine_reference_slope_refused_with_estimate(tmp_path, capsys):
    """A 0.001 m cell on the reference slope (5.5e9 nodes) is refused with exit 2, one
    line carrying the estimate, and no output directory (measured: 1.2 s for the whole
    command, most of it imports)."""
    out = tmp_path / "fine"
    code = main(["run", "--out", str(out), "--quiet", "--set", "grid.cell=0.001"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert "run too large" in err and "grid nodes" in err and "TiB memory" in err
    assert "FEM_RMPM_MEMORY_LIMIT_GB" in err
    assert not out.exists()


def test_memory_limit_from_environment(meshes, monkeypatch):
    """$FEM_RMPM_MEMORY_LIMIT_GB lowers the limit; a bad value is an input error."""
    scene = load_scene(meshes / "column.toml")
    monkeypatch.setenv(budget.MEMORY_LIMIT_ENV, "0.01")
    with pytest.raises(budget.BudgetError, match="run too large"):
        budget.check_budget(scene)
    monkeypatch.setenv(budget.MEMORY_LIMIT_ENV, "lots")
    with pytest.raises(budget.SceneError, match="not a memory size"):
        budget.check_budget(scene)
    monkeypatch.delenv(budget.MEMORY_LIMIT_ENV)
    assert budget.check_budget(scene).points == 80


def test_estimate_scales_with_refinement(meshes):
    """Halving the cell quadruples points and (about) nodes; the step halves."""
    scene = load_scene(meshes / "slope_reference.toml")
    a = budget.estimate_run(scene)
    b = budget.estimate_run(with_value(scene, "grid.cell", 0.125))
    assert b.points == pytest.approx(4 * a.points, rel=0.01)
    assert b.nodes == pytest.approx(4 * a.nodes, rel=0.01)
    assert b.dt == pytest.approx(a.dt / 2, rel=1e-12)


def test_cost_per_point_step_composes_basis_remedy_and_model(meshes):
    """The explicit cost per point-step is the Q4 von Mises figure times the factors of
    what the scene adds (uGIMP, F-bar, a Mohr-Coulomb soil), each measured on the same
    machine (module docstring of fem_rmpm.runtime.budget)."""
    c = budget.NS_PER_POINT_STEP
    q4 = budget.explicit_cost(cpu_signature())[0]
    ref = load_scene(meshes / "slope_reference.toml")
    assert budget.estimate_run(ref).ns_per_point_step == q4
    both = with_value(with_value(ref, "solver.shape", "gimp"), "solver.fbar", True)
    assert budget.estimate_run(both).ns_per_point_step == pytest.approx(
        q4 * c["explicit_gimp_factor"] * c["explicit_fbar_factor"], rel=1e-15)
    drained = load_scene(meshes / "slope_drained.toml")
    assert drained.soils[0].model == "mohr_coulomb_softening"
    assert budget.estimate_run(drained).ns_per_point_step == pytest.approx(
        q4 * c["explicit_mohr_coulomb_factor"], rel=1e-15)


def test_explicit_cost_is_the_measured_figure_of_the_runs_cpu(meshes):
    """The explicit step's cost is the one of the run's kind of CPU in the table
    (:data:`fem_rmpm.runtime.budget.EXPLICIT_NS_BY_CPU`: case (i), one thread, whole runs):
    39 ns on the Intel Xeon (family 6, model 167), 104 ns on the AMD EPYC Zen 1 (family
    23, model 1), 53 ns on the AMD EPYC Zen 4 (family 25, model 17), each machine named on
    the printed line.  A CPU not in the table gets the slowest figure, and the line says
    so.  The estimated wall time of case (i) is within 10 % of the whole runs' on the Zen 1
    (21.4-22.6 s) and within their range on the Zen 4 (10.7-14.8 s)."""
    ref = load_scene(meshes / "slope_reference.toml")
    intel = budget.estimate_run(ref, ("GenuineIntel", 6, 167))
    epyc = budget.estimate_run(ref, ("AuthenticAMD", 23, 1))
    other = budget.estimate_run(ref, ("AuthenticAMD", 25, 1))
    assert (intel.ns_per_point_step, epyc.ns_per_point_step) == (39.0, 104.0)
    assert "Intel Xeon VM" in intel.describe() and "AMD EPYC VM, Zen 1" in epyc.describe()
    assert other.ns_per_point_step == max(intel.ns_per_point_step, epyc.ns_per_point_step)
    assert "slowest machine measured" in other.describe()
    assert budget.explicit_cost(None) == (other.ns_per_point_step, other.machine)
    assert 0.9 * 21.4 <= epyc.wall_time <= 1.1 * 22.6
    zen4 = budget.estimate_run(ref, ("AuthenticAMD", 25, 17))
    assert zen4.ns_per_point_step == 53.0 and "Zen 4" in zen4.describe()
    assert 10.7 <= zen4.wall_time <= 14.8
