"""Command line: ``fem-rmpm run | fem | mc | fs | field``.

Exit codes: 0 success, 2 bad input (scene, data file, options), 3 the
simulation failed (unstable, Newton did not converge, ...), 130 interrupted.
Errors are one line on stderr, never a traceback (``--debug`` shows it).
The CLI is the top layer: nothing in the package imports it.
"""
from __future__ import annotations

import argparse
import sys
import time
import tomllib
from dataclasses import replace
from importlib import resources
from pathlib import Path

import numpy as np

from fem_rmpm import (
    api,
    campaign,  # its cluster and runner modules (dask, ~0.65 s) load on first use
    materials,
)
from fem_rmpm.campaign.report import ReportError, write_report
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.io.field_output import plot_realization, plot_variogram, write_field_vtu
from fem_rmpm.io.output import OutputError, write_json
from fem_rmpm.io.rundir import output_dir_for
from fem_rmpm.measures import table as measure_table
from fem_rmpm.random_field import (
    apply_to_points,
    embeddings_for,
    field_layout,
    fit_scales,
    point_fields,
    read_measurements,
)
from fem_rmpm.random_field.conditioning import resolve_data_path
from fem_rmpm.runtime.errors import InputError
from fem_rmpm.scene import (
    RandomFieldSpec,
    Scene,
    SceneError,
    check_seed,
    load_scene,
    scene_to_dict,
    with_value,
    with_values,
)
from fem_rmpm.schemes.common import SimulationError
from fem_rmpm.schemes.implicit.strength_reduction import fs_cli

__all__ = ["main", "default_scene_path", "build_parser", "parse_settings", "summary_text",
           "campaign_cases", "InputError"]


def default_scene_path() -> Path:
    """The embedded default scene: the reference slope of the RMPM paper (Wang, Vardon &
    Hicks 2017; ``fem_rmpm/data/slope_reference.toml``)."""
    return Path(str(resources.files("fem_rmpm") / "data" / "slope_reference.toml"))


def _scene_arg(p: argparse.ArgumentParser, optional: bool = False) -> None:
    p.add_argument("scene", nargs="?" if optional else None,
                   default=None, help="scene file (TOML); default: the embedded reference slope"
                   if optional else "scene file (TOML)")


def parse_settings(items: list[str] | None, source: str) -> dict:
    """``--set key=value`` pairs; values are TOML literals (parsed by tomllib, never eval)."""
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise InputError(f"--set {item!r}: expected KEY=VALUE, e.g. solver.scheme=\"implicit\"")
        try:
            out[key] = tomllib.loads(f"v = {value.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            try:   # a bare word is taken as a string: solver.scheme=implicit
                out[key] = tomllib.loads(f'v = "{value.strip()}"')["v"]
            except tomllib.TOMLDecodeError:
                raise InputError(f"--set {item!r}: {value!r} is not a TOML value") from None
    return out


def scene_from_args(a):
    """Load the scene named on the command line and apply its ``--set`` changes."""
    scene = load_scene(a.scene)
    changes = parse_settings(getattr(a, "set", None), a.scene)
    return with_values(scene, changes) if changes else scene


def _cmd_run(a) -> int:
    scene = scene_from_args(a)
    res = api.run(scene, out=a.out, seed=a.seed, progress=not a.quiet, force=a.force)
    s, m = res.summary, res.measures
    if s["stop_reason"] == "load applied":
        steps = f"{s['steps']} load steps (load factor 1)"
    else:
        steps = f"{s['steps']} steps to t = {s['simulated_time']:.3g} s ({s['stop_reason']})"
    print(f"{scene.scene.name}: {s['scheme']} run of {s['particles']} material points, {steps} "
          f"in {s['wall_time']:.1f} s wall ({s['ns_per_particle_step']:.0f} ns per point-step); "
          f"{measure_table.value_text('max_displacement', m['max_displacement'], '.3g')}, "
          f"failed = {m['failed']}, "
          + ", ".join(measure_table.value_text(k, m[k]) for k in measure_table.headline())
          + f"; {s['frozen_points']['count']} points "
          f"frozen at the grid edge. Output: {a.out}")
    return 0


def _cmd_fem(a) -> int:
    scene = scene_from_args(a)
    res = api.fem(scene, out=a.out)
    print(f"{scene.scene.name}: static FEM on {len(res.cells)} Q4 elements; max |u| = "
          f"{np.abs(res.displacement).max():.4g} m, min sigma_yy = {res.stress[:, 1].min():.4g} "
          f"kPa. Output: {a.out}")
    return 0


# --------------------------------------------------------------------------- mc

def _is_default_scene(path: str | Path) -> bool:
    try:
        return Path(path).resolve() == default_scene_path().resolve()
    except OSError:  # pragma: no cover
        return False


def campaign_cases(scene: Scene, scene_path: str | Path | None = None) -> list[str]:
    """Cases of a campaign run from the command line: ``[montecarlo] cases`` if the scene
    has that key, the four :data:`LITERATURE_CASES` for the embedded default scene,
    else the scene itself."""
    listed = tuple(getattr(scene.montecarlo, "cases", ()) or ())
    if listed:
        return list(listed)
    if scene_path is not None and _is_default_scene(scene_path):
        return list(campaign.LITERATURE_CASES)
    return ["scene"]


def summary_text(res: campaign.CampaignResult) -> str:
    """The final one-paragraph-per-case summary printed by ``fem-rmpm mc``."""
    lines = []
    rph = res.realizations_per_hour
    head = (f"Campaign in {res.out}: {sum(res.realizations.values())} realizations in "
            f"{len(res.cases)} case(s); ")
    if res.computed or res.lost:
        head += (f"this run computed {res.computed} (skipped {res.skipped} already "
                 f"finished) on {res.workers} in {res.wall_time:.1f} s"
                 + (f" ({rph:.0f} realizations/hour)" if rph else "") + ".")
    else:
        head += f"all {res.skipped} had finished before; tables and figures rebuilt."
    lines.append(head)
    for c in res.cases:
        s = res.stats[c.name]
        head = f"  {c.label}: " + ("deterministic (no random field), 1 realization; "
                                   if c.deterministic else f"N = {s['ok']} ok")
        if not c.deterministic:
            head += (f", {s['numerical_failures']} failed numerically" if
                     s["numerical_failures"] else "") + "; "
        if s["ok"] == 0:
            lines.append(head + "no realization finished"
                         + (f" (first error: {s['errors'][0]['error']})" if s["errors"] else ""))
            continue
        if not s.get("mpm_runs"):                      # --fs-only
            lines.append(head + campaign.fs_text(s.get("fs")))
            continue
        if c.deterministic:
            lines.append(head + f"failed = {bool(s['slope_failures'])}, " + ", ".join(
                measure_table.value_text(k, s[k]["mean"]) for k in
                measure_table.headline() + measure_table.mechanism() if k in s)
                         + (f"; {campaign.fs_text(s['fs'])}" if s.get("fs") else ""))
            continue
        lo, hi = s["wilson95"]
        txt = (f"P(failure) = {s['p_failure']:.3f} +- {s['se']:.3f} (SE sqrt(p(1-p)/N); "
               f"Wilson 95 % [{lo:.2f}, {hi:.2f}])")
        if s.get("measure_runs", s["ok"]) < s["mpm_runs"]:    # [montecarlo] runs_to_rest
            txt += f"; measures over the {s['measure_runs']} run(s) to rest"
        for key in measure_table.headline():
            d = s[key]
            txt += "" if d["mean"] is None else (
                f"; {measure_table.label(key)} mean {d['mean']:.2f} +- {d['se']:.2f} "
                f"{measure_table.unit(key)} "
                f"(5/50/95 %: {d['q05']:.2f}/{d['q50']:.2f}/{d['q95']:.2f})")
        mech = [k for k in measure_table.mechanism() if k in s]
        if mech:
            txt += "; mean " + ", ".join(measure_table.value_text(k, s[k]["mean"])
                                         for k in mech)
        conv = s.get("convergence")
        if conv and s["ok"] >= 4:
            idx = sorted({s["ok"] // 4 - 1, s["ok"] // 2 - 1, s["ok"] - 1})
            txt += ("; with N = " + ", ".join(str(conv["n"][i]) for i in idx)
                    + ": P(failure) " + ", ".join(f"{conv['p_failure'][i]:.2f}" for i in idx)
                    + ("" if len(conv["mean_runout"]) < len(conv["n"]) else ", mean run-out "
                       + ", ".join(f"{conv['mean_runout'][i]:.1f}" for i in idx) + " m"))
        lines.append(head + txt + (f"; {campaign.fs_text(s['fs'])}" if s.get("fs") else ""))
        if s["numerical_failures"]:
            e = s["errors"][0]
            lines.append(f"    first failed realization: #{e['index']} (seed {e['seed']}): "
                         f"{e['error']}")
    if res.lost:
        lines.append(f"  {len(res.lost)} realization(s) LOST (their workers died; no record): "
                     + "; ".join(res.lost[:3]) + " -- re-run the same command to compute them")
    figs = ", ".join(p.name for p in res.figures)
    lines.append(f"Output: results.csv, summary.json, records/"
                 + (", vtk/" if (res.out / "vtk").exists() else "")
                 + (f", {figs}" if figs else "") + f" in {res.out}")
    return "\n".join(lines)


def _cmd_mc_subset(a, scene: Scene, cluster: campaign.ClusterSpec) -> int:
    """``fem-rmpm mc --method subset``: P(response beyond threshold) by subset simulation
    on the same cluster options as crude Monte Carlo (``--cluster``, ``--scheduler``)."""
    for opt, val in (("--keep-vtk", a.keep_vtk), ("--case", a.case)):
        if val is not None:
            raise InputError(f"{opt}: only for crude campaigns (--method crude)")
    if a.dry_run:
        raise InputError("--dry-run: only for crude campaigns (--method crude); the runs of a "
                         "subset campaign depend on how many levels it needs (n per level)")
    res = campaign.run_subset_campaign(scene, a.out, a.response, a.threshold,
                                       p0=0.1 if a.p0 is None else a.p0,
                                       n=a.realizations, workers=a.workers,
                                       scheduler=a.scheduler, force=a.force,
                                       progress=not a.quiet, cluster=cluster)
    print(campaign.subset_summary_text(res))
    return 3 if res.lost else 0


def _cmd_mc(a) -> int:
    """``fem-rmpm mc``: returns 0, or 3 if realizations were lost (re-run to finish)."""
    scene = scene_from_args(a)
    if a.fs and a.fs_only:
        raise InputError("--fs and --fs-only: give one (--fs: FS before each MPM run; "
                         "--fs-only: FS instead of it)")
    cluster = campaign.ClusterSpec(kind=a.cluster, queue=a.queue, account=a.account,
                                   cores=a.cores, memory=a.memory, walltime=a.walltime,
                                   interface=a.interface,
                                   job_directives=tuple(a.job_directive or ()),
                                   adapt=campaign.parse_adapt(a.adapt))
    if a.method == "subset":
        if a.fs or a.fs_only:
            raise InputError("--fs / --fs-only: only for crude campaigns (--method crude); "
                             "use --response factor_of_safety for subset simulation")
        return _cmd_mc_subset(a, scene, cluster)
    if a.fs:
        scene = with_value(scene, "montecarlo.factor_of_safety", True)
    given = [o for o, v in (("--response", a.response), ("--threshold", a.threshold),
                            ("--p0", a.p0)) if v is not None]
    if given:
        raise InputError(f"{given[0]}: only with --method subset")
    cases = list(a.case) if a.case else campaign_cases(scene, a.scene)
    if a.dry_run:
        est = campaign.estimate_campaign(scene, a.out, realizations=a.realizations,
                                         cases=cases, workers=a.workers,
                                         scheduler=a.scheduler, force=a.force,
                                         keep_vtk=a.keep_vtk, cluster=cluster)
        print(campaign.estimate_text(est))
        return 0
    res = campaign.run_campaign(scene, a.out, realizations=a.realizations, cases=cases,
                                workers=a.workers, scheduler=a.scheduler, force=a.force,
                                keep_vtk=a.keep_vtk, progress=not a.quiet, cluster=cluster,
                                fs_only=a.fs_only)
    print(summary_text(res))
    return 3 if res.lost else 0


# --------------------------------------------------------------------------- field

def _field_scene(a) -> tuple[Scene, str]:
    """The scene of ``fem-rmpm field``; without a ``[random_field]``, the literature's
    default field (and a note saying so)."""
    scene = load_scene(a.scene)
    if scene.random_field is not None:
        return scene, ""
    scene = with_value(scene, "random_field.anisotropy", RandomFieldSpec().anisotropy)
    return scene, (" The scene has no [random_field] section, so this is the default field "
                   "(add [random_field] to use a field in runs).")


def _field_fit(path: str, rf: RandomFieldSpec, out: Path) -> str:
    """``--fit CSV``: fit the scales, write ``fit.json`` and ``variogram.png``, print the
    result; returns the sentence for the final summary."""
    meas = read_measurements(path, key="fit")
    fit = fit_scales(meas.x, meas.y, meas.value, log=rf.distribution == "lognormal",
                     source=meas.source, group=meas.group)
    write_json(out / "fit.json", {"data": meas.source, **fit.as_dict()})
    plot_variogram(out / "variogram.png", fit, f"{Path(meas.source).name}: Markov fit")
    print(f"fit of {meas.source}: theta_v = {fit.theta_v:.4g} m, theta_h = "
          f"{fit.theta_h:.4g} m (xi = {fit.anisotropy:.3g}), sill {fit.sill:.3g}"
          f"{' of ln(value)' if fit.log else ''}; written {out / 'fit.json'}")
    return (f" The variogram fit of {Path(meas.source).name} gives theta_v = "
            f"{fit.theta_v:.3g} m and theta_h = {fit.theta_h:.3g} m (set them with "
            "random_field.theta_v / anisotropy to use them).")


def _field_on_points(pts, name: str, values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Give the points the realization's value of property ``name`` (as ``api.prepare``, a
    residual in proportion); returns the value shown per point: the field on the field's
    soils, the soil's value elsewhere, -1 where that is infinite (linear elastic)."""
    base = getattr(pts.soil, name)
    finite = np.isfinite(base)
    pts.soil = apply_to_points(pts.soil, {name: np.where(mask & finite, values, base)})
    return np.where(mask, values, np.where(finite, base, -1.0))


def _field_property(scene: Scene, name: str | None) -> tuple[int, RandomFieldSpec]:
    """``--property``: the index and spec of the field shown (default: the first)."""
    fields = scene.random_field.fields()
    names = [f.property for f in fields]
    if name is None:
        return 0, fields[0]
    if name not in names:
        raise InputError(f"--property {name}: [property] not a random property of "
                         f"{scene.source}; allowed: {' | '.join(names)}")
    return names.index(name), fields[names.index(name)]


def _field_text(scene: Scene, rf: RandomFieldSpec, seed: int, layout, emb, meas,
                v: np.ndarray) -> str:
    """The one-paragraph summary of ``fem-rmpm field`` (without note, fit and output)."""
    unit = materials.registry.parameter(rf.property).unit
    xi = rf.anisotropy
    avg = (f"local averages over {layout.cell[0]:g} x {layout.cell[1]:g} m cells (variance "
           f"{emb.variance:.3f})" if rf.local_averaging else
           f"point values at the centres of {layout.cell[0]:g} x {layout.cell[1]:g} m cells")
    return (f"{scene.scene.name}: {rf.distribution} random field of {rf.property} (COV "
            f"{rf.cov:g}, theta_v {rf.theta_v:g} m, theta_h {rf.theta_v * xi:g} m, xi {xi:g}, "
            f"{rf.correlation.replace('markov_', '')} Markov, layering "
            f"{rf.layering_angle_deg:g} deg to the grid x axis) as {avg} on {layout.shape[0]} x "
            f"{layout.shape[1]} field cells, seed {seed}, circulant embedding {emb.padded[0]} x "
            f"{emb.padded[1]} (lambda_min/lambda_max {emb.lambda_min / emb.lambda_max:.1e}, "
            f"{'exact' if emb.clipped == 0 else f'clipped {emb.clipped:.1e}'})"
            + _cross_text(scene, rf)
            + (f", conditioned on {len(meas.x)} measurements of {meas.source}" if meas else "")
            + f"; {len(v)} material points get {v.min():.3g} to {v.max():.3g} {unit} "
            f"(mean {v.mean():.3g}, COV {v.std() / v.mean():.3g}).")


def _cross_text(scene: Scene, rf: RandomFieldSpec) -> str:
    """``, cross-correlated with X (rho r), ...`` when the field has several properties."""
    names = [f.property for f in scene.random_field.fields()]
    R, k = scene.random_field.cross_correlation or np.eye(len(names)), names.index(rf.property)
    return "" if len(names) == 1 else ", cross-correlated with " + ", ".join(
        f"{n} (rho {R[k][j]:g})" for j, n in enumerate(names) if j != k)


def _cmd_fs(a) -> int:
    scene = scene_from_args(a)
    grid, pts = api.prepare(scene, a.seed)
    return fs_cli(a, scene, grid, pts)


def _cmd_field(a) -> int:
    """``fem-rmpm field [SCENE] --seed S --out DIR [--data CSV] [--fit CSV]``."""
    t0 = time.perf_counter()
    scene, note = _field_scene(a)
    k, rf = _field_property(scene, getattr(a, "property", None))
    seed = scene.montecarlo.seed if getattr(a, "seed", None) is None else check_seed(a.seed)
    with output_dir_for(a.out) as out:          # bad input leaves no directory behind
        fit_text = _field_fit(a.fit, rf, out) if getattr(a, "fit", None) else ""
        grid = make_grid(scene)
        pts = seed_particles(scene, grid)
        layout = field_layout(scene, grid)
        emb = embeddings_for(scene, layout)[k]
        path = resolve_data_path(scene, getattr(a, "data", None), rf)
        meas = read_measurements(path) if path is not None else None
        values, mask = point_fields(scene, grid, pts, seed, meas, data_index=k)
        values = values[rf.property]
        shown = _field_on_points(pts, rf.property, values, mask)
        write_field_vtu(out / "field.vtu", pts, shown)
        unit = materials.registry.parameter(rf.property).unit
        label = f"{rf.property.replace('_', ' ')} ({unit})"
        title = (f"{scene.scene.name}: {label}, {rf.distribution}, COV {rf.cov:g}, "
                 f"theta_v {rf.theta_v:g} m, xi = {rf.anisotropy:g}, seed {seed}"
                 + (f", conditioned on {len(meas.x)} data" if meas is not None else ""))
        plot_realization(out / "field.png", scene, pts, shown, mask, title, label=label)
        v = values[mask]
        write_json(out / "field.json", {
            "scene_file": scene.source, "seed": seed, "property": rf.property,
            "random_field": scene_to_dict(scene)["random_field"],
            "field_cells": list(layout.shape), "field_cell_size": layout.cell.tolist(),
            "embedding": list(emb.padded), "lambda_min": emb.lambda_min,
            "lambda_min_over_max": emb.lambda_min / emb.lambda_max, "clipped": emb.clipped,
            "cell_variance": emb.variance, "points": int(mask.sum()),
            "min": float(v.min()), "mean": float(v.mean()), "max": float(v.max()),
            "std": float(v.std()), "conditioned_on": None if meas is None else meas.source,
            "wall_time": time.perf_counter() - t0})
        print(_field_text(scene, rf, seed, layout, emb, meas, v) + f"{note}{fit_text} Output: "
              f"{out / 'field.vtu'}, {out / 'field.png'}, {out / 'field.json'} "
              f"({time.perf_counter() - t0:.2f} s).")
    return 0


def _cmd_report(a) -> int:
    """``fem-rmpm report DIR``: write DIR/report.html from a campaign directory."""
    try:
        path = write_report(a.campaign)
    except ReportError as exc:
        raise InputError(f"report: {exc}") from None
    print(f"Report: {path} (one self-contained page; open it in a browser)")
    return 0


# --------------------------------------------------------------------------- parser and main

def _cluster_arguments(m: argparse.ArgumentParser) -> None:
    """``mc`` options for batch-system workers (:mod:`fem_rmpm.campaign.backends`); unset
    options come from the Dask configuration (jobqueue.yaml)."""
    g = m.add_argument_group("cluster", "worker jobs on a batch system through dask-jobqueue; "
                             "options not given come from the Dask configuration "
                             "(~/.config/dask/jobqueue.yaml, jobqueue.<kind>.*)")
    g.add_argument("--cluster", default="local", metavar="KIND",
                   help="local (default) | slurm | pbs | sge | lsf")
    g.add_argument("--queue", help="queue or partition of the worker jobs")
    g.add_argument("--account", help="account (SLURM, PBS) or project (SGE, LSF) to charge")
    g.add_argument("--cores", type=int, help="cores per job (one single-thread worker per "
                   "core; default 1)")
    g.add_argument("--memory", help="memory per job, e.g. 8GB (default: from the estimate)")
    g.add_argument("--walltime", help="wall-time limit per job, e.g. 04:00:00")
    g.add_argument("--interface", help="network interface of the scheduler and workers, "
                   "e.g. ib0 (lo on one machine)")
    g.add_argument("--job-directive", action="append", metavar="TEXT",
                   help="extra batch directive, e.g. --job-directive=--constraint=skylake "
                   "(repeatable)")
    g.add_argument("--adapt", metavar="MIN:MAX", help="let Dask keep between MIN and MAX "
                   "workers (instead of --workers)")
    g.add_argument("--dry-run", action="store_true", help="print the campaign's size and cost "
                   "(realizations, points, steps, core-hours, memory, wall time) and exit: "
                   "nothing is written, no worker starts")


EXIT_CODES = """exit codes:
  0    success
  2    bad input (scene, data file or option): one line on stderr, nothing written
  3    the simulation failed (unstable, Newton did not converge, ...); for mc:
       realizations were lost (their workers died): re-run the command to finish
  130  interrupted (Ctrl-C): finished output is kept"""
_SET_HELP = ("change a scene value before running, e.g. --set solver.t_end=5 --set "
             "'grid.cell=[0.5, 0.5]' --set soil[0].cohesion_peak=20 (repeatable; values are "
             "TOML literals, a bare word is a string)")


def _subcommand(sub, name: str, help: str, description: str | None = None):
    """A subcommand parser with the exit codes in its ``--help``."""
    return sub.add_parser(name, help=help, description=description or help, epilog=EXIT_CODES,
                          formatter_class=argparse.RawDescriptionHelpFormatter)


def _add_run(sub) -> None:
    r = _subcommand(sub, "run", "one realization (explicit or implicit MPM)",
                    "Run one realization of a scene: VTK time series, summary.json, figures.")
    _scene_arg(r, optional=True)
    r.add_argument("--out", required=True, help="output directory: new or empty (created), "
                   "or one holding a run with --force")
    r.add_argument("--seed", type=int, default=None,
                   help="random-field seed, an integer >= 0 (default: the scene's "
                   "[montecarlo] seed); no effect without a [random_field]")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--force", action="store_true",
                   help="replace the run already in --out (default: refuse a non-empty directory)")
    r.add_argument("--set", action="append", metavar="KEY=VALUE", help=_SET_HELP)
    r.set_defaults(func=_cmd_run)


def _add_fem(sub) -> None:
    f = _subcommand(sub, "fem", "static small-strain FEM gravity reference (scikit-fem)")
    _scene_arg(f, optional=True)
    f.add_argument("--out", required=True, help="output directory (created): fem.vtu, "
                   "summary.json")
    f.add_argument("--set", action="append", metavar="KEY=VALUE", help=_SET_HELP)
    f.set_defaults(func=_cmd_fem)


def _add_mc(sub) -> None:
    m = _subcommand(sub, "mc", "Monte Carlo campaign on Dask (default: the four literature "
                    "cases of the reference slope)",
                    "Run realizations 0..N-1 of one or more cases of a scene on Dask; "
                    "resumable (re-run the same command to finish or extend it).")
    _scene_arg(m, optional=True)
    m.add_argument("-n", "--realizations", type=int, default=None,
                   help="realizations per random case (default: the scene's [montecarlo] "
                   "realizations; a case without a random field runs 1)")
    m.add_argument("--out", default="runs/mc", help="campaign directory (default runs/mc)")
    m.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help=_SET_HELP + "; applied to every case and recorded in campaign.json")
    m.add_argument("--case", action="append", metavar="SPEC",
                   help="a case to run (repeatable), replacing the scene's [montecarlo] "
                   "cases: 'homogeneous' (no random field), 'xi=12' (anisotropy), 'scene', "
                   "or '<section.key>=<value>' changes joined by ';'")
    m.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: usable CPUs, at most the "
                   "realizations to run); with --cluster: the workers to keep on the batch "
                   "system (default: one job)")
    m.add_argument("--scheduler", default=None,
                   help="address of a running Dask scheduler, e.g. tcp://host:8786, "
                   "instead of a local cluster")
    _cluster_arguments(m)
    m.add_argument("--force", action="store_true",
                   help="recompute finished realizations (each record replaced when its "
                   "new one is complete)")
    m.add_argument("--keep-vtk", default=None,
                   help="VTK for the first K realizations of each case (integer) or for "
                   "indices like 0,5,9 (default: the scene's [montecarlo] keep_vtk)")
    m.add_argument("--quiet", action="store_true", help="no progress bar")
    m.add_argument("--fs", action="store_true", help="also the strength-reduction factor of "
                   "safety of every realization, before its MPM run (= [montecarlo] "
                   "factor_of_safety = true)")
    m.add_argument("--fs-only", action="store_true", help="the factor of safety of every "
                   "realization instead of its MPM run")
    m.add_argument("--method", choices=("crude", "subset"), default="crude",
                   help="crude Monte Carlo (default) or subset simulation of a small "
                   "probability (then -n is the samples per level, default 1000)")
    m.add_argument("--response", default=None,
                   help=f"subset: {measure_table.responses_text()}; failure above or below "
                   "--threshold (factor_of_safety: default 1)")
    m.add_argument("--threshold", type=float, default=None,
                   help="subset: the failure threshold, in the response's unit")
    m.add_argument("--p0", type=float, default=None,
                   help="subset: level probability in (0, 0.5] (default 0.1)")
    m.set_defaults(func=_cmd_mc)


def _add_fs(sub) -> None:
    fs = _subcommand(sub, "fs", "factor of safety by strength reduction (Griffiths & Lane "
                     "1999)", "Divide the strengths by trial factors F and apply gravity "
                     "with the implicit static solver (small strain, in-situ geometry) until "
                     "Newton fails: FS to a stated tolerance, fs.json, max displacement "
                     "against F (fs_displacement.png) and the mechanism (mechanism.vtu/.png).")
    _scene_arg(fs, optional=True)
    fs.add_argument("--seed", type=int, default=None,
                    help="random-field seed, an integer >= 0 (default: the scene's "
                    "[montecarlo] seed)")
    fs.add_argument("--out", required=True, help="output directory (created)")
    fs.add_argument("--tolerance", type=float, default=0.01,
                    help="stop when the bracket F_hi / F_lo - 1 is below this (default 0.01)")
    fs.add_argument("--softening", action="store_true",
                    help="keep the softening law (default: peak strength, perfectly plastic)")
    fs.add_argument("--set", action="append", metavar="KEY=VALUE", help=_SET_HELP)
    fs.add_argument("--quiet", action="store_true", help="no line per static solve")
    fs.set_defaults(func=_cmd_fs)


def _add_field(sub) -> None:
    fl = _subcommand(sub, "field", "one random field on the material points (VTU + PNG)")
    _scene_arg(fl, optional=True)
    fl.add_argument("--seed", type=int, default=None,
                    help="random-field seed, an integer >= 0 (default: the scene's "
                    "[montecarlo] seed)")
    fl.add_argument("--out", required=True,
                    help="output directory (created): field.vtu, field.png, field.json")
    fl.add_argument("--data", default=None,
                    help="CSV with header x,y,value (grid frame m, kPa) to condition the "
                    "field on (simple kriging); default: the scene's [random_field] data")
    fl.add_argument("--property", default=None,
                    help="the random property to show, condition (--data) and fit (--fit) "
                    "when [random_field] has several (default: the first)")
    fl.add_argument("--fit", default=None,
                    help="CSV with header x,y,value[,group]: estimate theta_v and theta_h "
                    "from its semivariograms (writes fit.json, variogram.png)")
    fl.set_defaults(func=_cmd_field)


def _add_report(sub) -> None:
    rp = _subcommand(sub, "report", "write report.html (one self-contained page) for a "
                     "campaign directory; `mc` writes it at the end of every campaign")
    rp.add_argument("campaign", metavar="DIR", help="campaign directory (holds summary.json)")
    rp.set_defaults(func=_cmd_report)


def build_parser() -> argparse.ArgumentParser:
    """The ``fem-rmpm`` argument parser (one sub-parser per command)."""
    p = argparse.ArgumentParser(prog="fem-rmpm", description="Random Material Point Method "
                                "for slope run-out risk (MPM on scikit-fem).",
                                epilog=EXIT_CODES,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = p.add_subparsers(dest="command", required=True, title="commands")
    for add in (_add_run, _add_fem, _add_mc, _add_fs, _add_field, _add_report):
        add(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    a = parser.parse_args(argv)
    if getattr(a, "scene", "x") is None:
        a.scene = str(default_scene_path())
    try:
        return int(a.func(a) or 0)
    except (SceneError, InputError) as exc:
        if a.debug:
            raise
        print(f"fem-rmpm: error: {exc}", file=sys.stderr)
        return 2
    except (SimulationError, OutputError) as exc:
        if a.debug:
            raise
        print(f"fem-rmpm: simulation failed: {exc}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print("fem-rmpm: interrupted; finished output is kept", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
