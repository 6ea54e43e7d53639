"""Command line: ``fem-rmpm run | fem | mc | converge | fs | field | report``.

It parses the arguments, calls :mod:`fem_rmpm.api`, :mod:`fem_rmpm.campaign` or
:mod:`fem_rmpm.io.field_output`, and prints their results.  Exit codes: 0 success, 2 bad
input (scene, data file, options), 3 the simulation failed (unstable, Newton did not
converge, ...), 130 interrupted (Ctrl-C), 143 terminated (SIGTERM).
Errors are one line on stderr, never a traceback (``--debug`` shows it).
The CLI is the top layer: nothing in the package imports it.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import time
import tomllib

import numpy as np

from fem_rmpm import (
    api,
    campaign,  # its cluster and runner modules (dask) load on first use
)
from fem_rmpm.campaign.cases import campaign_cases, default_scene_path
from fem_rmpm.campaign.three_d import check_campaign_3d
from fem_rmpm.io.output import OutputError
from fem_rmpm.io.rundir import output_dir_for
from fem_rmpm.runtime.errors import InputError
from fem_rmpm.runtime.signals import graceful_interrupts, interrupt_exit_code, interrupt_name
from fem_rmpm.scene import (
    Scene,
    SceneError,
    check_seed,
    load_scene,
    with_value,
    with_values,
)
from fem_rmpm.scene.dimension import refuse_three_d
from fem_rmpm.schemes.common import SimulationError

__all__ = ["main", "default_scene_path", "build_parser", "parse_settings", "summary_text",
           "campaign_cases", "InputError"]

# The modules of one command only are imported by that command (``fem-rmpm run`` of an
# explicit scene loads neither the implicit scheme, the campaign's statistics and report,
# the random fields' figures nor the measures' table before its first step:
# ``tests/test_start_up.py``); ``summary_text`` stays a name of this module (PEP 562).


def __getattr__(name: str):
    if name == "summary_text":
        from fem_rmpm.campaign.summary_text import summary_text  # lazy: mc only
        return summary_text
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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
    from fem_rmpm.measures import table as measure_table  # lazy: loaded after the run
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
    res = api.fem(scene, out=a.out, force=a.force)
    print(f"{scene.scene.name}: static FEM on {len(res.cells)} Q4 elements; max |u| = "
          f"{np.abs(res.displacement).max():.4g} m, min sigma_yy = {res.stress[:, 1].min():.4g} "
          f"kPa. Output: {a.out}")
    return 0


# --------------------------------------------------------------------------- mc

def _cmd_mc_response(a, scene: Scene, cluster: campaign.ClusterSpec) -> int:
    """``fem-rmpm mc --method subset``: P(response beyond threshold) by a response method
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
                                       progress=not a.quiet, cluster=cluster,
                                       method=a.method)
    from fem_rmpm.campaign.summary_text import subset_summary_text  # lazy: mc only
    print(subset_summary_text(res))
    return 3 if res.lost else 0


def _cmd_mc(a) -> int:
    """``fem-rmpm mc``: returns 0, or 3 if realizations were lost (re-run to finish)."""
    scene = scene_from_args(a)
    check_campaign_3d(scene, fs=a.fs, fs_only=a.fs_only, method=a.method)
    if a.fs and a.fs_only:
        raise InputError("--fs and --fs-only: give one (--fs: FS before each MPM run; "
                         "--fs-only: FS instead of it)")
    cluster = campaign.ClusterSpec(kind=a.cluster, queue=a.queue, account=a.account,
                                   cores=a.cores, memory=a.memory, walltime=a.walltime,
                                   interface=a.interface,
                                   job_directives=tuple(a.job_directive or ()),
                                   adapt=campaign.parse_adapt(a.adapt))
    if a.no_softening:
        scene = campaign.perfectly_plastic(scene)
    if campaign.METHODS[a.method].response:
        if a.fs or a.fs_only:
            raise InputError("--fs / --fs-only: only for crude campaigns (--method crude); "
                             "use --response factor_of_safety for subset simulation")
        return _cmd_mc_response(a, scene, cluster)
    if (getattr(a, "default_scene", False) and not (a.case or a.set or a.fs_only or a.fs
                                                    or a.no_softening)):
        return _cmd_main_job(a, cluster)
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
                                         keep_vtk=a.keep_vtk, cluster=cluster,
                                         fs_only=a.fs_only)
        print(campaign.estimate_text(est))
        return 0
    res = campaign.run_campaign(scene, a.out, realizations=a.realizations, cases=cases,
                                workers=a.workers, scheduler=a.scheduler, force=a.force,
                                keep_vtk=a.keep_vtk, progress=not a.quiet, cluster=cluster,
                                fs_only=a.fs_only, method=a.method)
    from fem_rmpm.campaign.summary_text import summary_text  # lazy: mc only
    print(summary_text(res))
    return 3 if res.lost else 0


def _cmd_converge(a) -> int:
    """``fem-rmpm converge SCENE --cells 0.5,0.25,0.125 -n N --out DIR``: one campaign per
    cell size (``DIR/cell_<h>``), then the paired comparison; 3 if realizations were lost."""
    # lazy: the campaign runner (dask) loads only for this command
    from fem_rmpm.campaign.convergence import mesh_directory, mesh_scene, parse_cells
    from fem_rmpm.campaign.convergence_report import convergence_text  # lazy: as above
    scene = scene_from_args(a)
    refuse_three_d(scene, "converge")      # its meshes are square plane-strain cells
    cells = parse_cells(a.cells)
    if a.no_softening:
        scene = campaign.perfectly_plastic(scene)
    cases = list(a.case) if a.case else campaign_cases(scene, a.scene)
    if a.dry_run:
        for h in cells:
            est = campaign.estimate_campaign(mesh_scene(scene, h), mesh_directory(a.out, h),
                                             realizations=a.realizations, cases=cases,
                                             workers=a.workers, scheduler=a.scheduler,
                                             force=a.force, keep_vtk=a.keep_vtk)
            print(f"cell {h:g} m: " + campaign.estimate_text(est))
        return 0
    res = campaign.run_convergence(scene, a.out, cells, a.realizations, cases,
                                   workers=a.workers, scheduler=a.scheduler, force=a.force,
                                   keep_vtk=a.keep_vtk, progress=not a.quiet)
    print(convergence_text(res.statistics))
    print(f"Mesh convergence: {res.files[-1]} (table and figure), {res.files[0]}")
    return 3 if any(r.lost for r in res.campaigns) else 0


def _cmd_main_job(a, cluster: campaign.ClusterSpec) -> int:
    """``fem-rmpm mc`` without SCENE, --case, --set: the main job
    (:mod:`fem_rmpm.campaign.main_job`): the risk slope with its factor of safety in
    ``--out``, the seed slope's four cases in ``--out/seed_slope``."""
    from fem_rmpm.campaign import main_job   # lazy: the campaign runner (dask) loads here
    risk = load_scene(main_job.main_scene_path())
    opts = dict(workers=a.workers, scheduler=a.scheduler, force=a.force, cluster=cluster)
    if a.dry_run:
        seed = load_scene(default_scene_path())
        for sc, out, n, cases, keep in (
                (risk, a.out, a.realizations, list(risk.montecarlo.cases), a.keep_vtk),
                (seed, os.path.join(a.out, main_job.SEED_DIRECTORY), 1,
                 list(campaign.LITERATURE_CASES), 1)):
            print(campaign.estimate_text(campaign.estimate_campaign(
                sc, out, realizations=n, cases=cases, keep_vtk=keep, **opts)))
        return 0
    main, side = main_job.run_main_job(a.out, a.realizations, scene=risk, keep_vtk=a.keep_vtk,
                                       progress=not a.quiet, **opts)
    from fem_rmpm.campaign.summary_text import summary_text  # lazy: mc only
    print(summary_text(main))
    print(summary_text(side))
    print(f"Main job: {os.path.join(a.out, 'report.html')} (the risk slope, its fragility "
          f"and the seed slope's four cases); the full study: {main_job.FULL_STUDY}")
    return 3 if main.lost or side.lost else 0


# --------------------------------------------------------------------------- field

def _cmd_fs(a) -> int:
    scene = scene_from_args(a)
    refuse_three_d(scene, "fs")
    grid, pts = api.prepare(scene, a.seed)
    from fem_rmpm.schemes.implicit.strength_reduction import fs_cli  # lazy: fs only
    return fs_cli(a, scene, grid, pts)


def _cmd_field(a) -> int:
    """``fem-rmpm field [SCENE] --seed S --out DIR [--data CSV] [--fit CSV]``."""
    t0 = time.perf_counter()
    refuse_three_d(load_scene(a.scene), "field")
    from fem_rmpm.io import field_output  # lazy: field only
    scene, note = field_output.field_scene(a.scene)
    k, rf = field_output.field_property(scene, getattr(a, "property", None))
    seed = scene.montecarlo.seed if getattr(a, "seed", None) is None else check_seed(a.seed)
    with output_dir_for(a.out, force=a.force) as out:   # bad input leaves no directory behind
        fit_line, fit_text = "", ""
        with field_output.staged_outputs(out) as stage:   # all files or none
            if getattr(a, "fit", None):
                fit_line, fit_text = field_output.fit_measurements(a.fit, rf, stage, out)
            text = field_output.write_field(scene, stage, seed, k, rf, getattr(a, "data", None),
                                            t0)
        if fit_line:
            print(fit_line)
        print(text + f"{note}{fit_text} Output: "
              f"{out / 'field.vtu'}, {out / 'field.png'}, {out / 'field.json'} "
              f"({time.perf_counter() - t0:.2f} s).")
    return 0


def _cmd_report(a) -> int:
    """``fem-rmpm report DIR``: write DIR/report.html from a campaign directory."""
    from fem_rmpm.campaign.report import ReportError, write_report  # lazy: report only
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
  130  interrupted (Ctrl-C): finished output is kept
  143  terminated (SIGTERM, e.g. a batch system's time limit): as 130"""
_SET_HELP = ("change a scene value before running, e.g. --set solver.t_end=5 --set "
             "'grid.cell=[0.5, 0.5]' --set soil[0].cohesion_peak=20 (repeatable; values are "
             "TOML literals, a bare word is a string)")

_FORCE_HELP = "write into a directory holding another result (default: refuse a non-empty one)"


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
    f.add_argument("--out", required=True, help="output directory: new or empty (created), "
                   "or one holding a result with --force: fem.vtu, summary.json")
    f.add_argument("--force", action="store_true", help=_FORCE_HELP)
    f.add_argument("--set", action="append", metavar="KEY=VALUE", help=_SET_HELP)
    f.set_defaults(func=_cmd_fem)


def _add_mc(sub) -> None:
    m = _subcommand(sub, "mc", "Monte Carlo campaign on Dask (default: the main job)",
                    "Run realizations 0..N-1 of one or more cases of a scene on Dask; "
                    "resumable (re-run the same command to finish or extend it).  Without "
                    "SCENE, --case, --set and --fs: the main job, the risk slope (case xi = "
                    "12, N = 16, each with its factor of safety, runs stopped once decided) "
                    "in --out and the reference slope's four literature cases (one "
                    "realization each) in --out/seed_slope, in one report.")
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
    m.add_argument("--no-softening", action="store_true", help="switch softening off: every "
                   "residual strength a soil's model declares set to its peak (perfectly "
                   "plastic at peak, as the strength reduction assumes); with --fs the report "
                   "gives the agreement of stand/fail with FS < 1 (use its own --out)")
    m.add_argument("--method", choices=tuple(campaign.METHODS), default="crude",
                   help="; ".join(f"{k}: {e.help}" for k, e in campaign.METHODS.items())
                   + " (default crude; for subset -n is the samples per level, default 1000)")
    m.add_argument("--response", default=None, action=_ResponseArgument)
    m.add_argument("--threshold", type=float, default=None,
                   help="subset: the failure threshold, in the response's unit")
    m.add_argument("--p0", type=float, default=None,
                   help="subset: level probability in (0, 0.5] (default 0.1)")
    m.set_defaults(func=_cmd_mc)


class _ResponseArgument(argparse.Action):
    """``mc --response``, stored as given; its help (the responses of the measures' table)
    is made when shown, so that building the parser does not import the measures."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values)

    @property
    def help(self) -> str:
        from fem_rmpm.measures import table as measure_table  # lazy: when shown
        return (f"subset: {measure_table.responses_text()}; failure above or below "
                "--threshold (factor_of_safety: default 1)")

    @help.setter
    def help(self, value) -> None:       # (argparse sets None: the property answers)
        pass


def _add_converge(sub) -> None:
    cv = _subcommand(sub, "converge", "mesh convergence: the same realizations on two or "
                     "three cell sizes",
                     "Run the same cases and realizations (the same random fields when "
                     "[random_field] box is set) on two or three cell sizes, one campaign "
                     "per mesh in DIR/cell_<h> (resumable), and compare them: P(failure) "
                     "per mesh, discordant pairs with an exact McNemar test, given-failure "
                     "means; DIR/convergence.html, .png, .json.")
    _scene_arg(cv, optional=True)
    cv.add_argument("--cells", required=True, help="cell sizes in m, coarse to fine, e.g. "
                    "0.5,0.25,0.125 (two or three)")
    cv.add_argument("-n", "--realizations", type=int, default=None,
                    help="realizations per random case and mesh (default: the scene's)")
    cv.add_argument("--out", required=True, help="study directory (one campaign per mesh)")
    cv.add_argument("--case", action="append", metavar="SPEC", help="a case (repeatable), "
                    "as for mc (default: the scene's [montecarlo] cases)")
    cv.add_argument("--set", action="append", metavar="KEY=VALUE", help=_SET_HELP)
    cv.add_argument("--workers", type=int, default=None, help="local worker processes")
    cv.add_argument("--scheduler", default=None, help="address of a running Dask scheduler")
    cv.add_argument("--keep-vtk", default=None, help="as for mc")
    cv.add_argument("--no-softening", action="store_true", help="as for mc")
    cv.add_argument("--force", action="store_true", help="recompute finished realizations")
    cv.add_argument("--quiet", action="store_true", help="no progress bar")
    cv.add_argument("--dry-run", action="store_true", help="print each mesh's campaign "
                    "size and cost and exit (nothing written)")
    cv.set_defaults(func=_cmd_converge)


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
    fs.add_argument("--out", required=True, help="output directory: new or empty (created), "
                    "or one holding a result with --force")
    fs.add_argument("--force", action="store_true", help=_FORCE_HELP)
    fs.add_argument("--tolerance", type=float, default=0.005,
                    help="stop when the bracket F_hi / F_lo - 1 is below this (default 0.005)")
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
                    help="output directory: new or empty (created), or one holding a "
                    "result with --force: field.vtu, field.png, field.json")
    fl.add_argument("--force", action="store_true", help=_FORCE_HELP)
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


class _OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (exit 2), like every other bad input:
    the usage it would print first is ``--help``'s."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} "
                     "--help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``fem-rmpm`` argument parser (one sub-parser per command)."""
    p = _OneLineParser(prog="fem-rmpm", description="Random Material Point Method "
                                "for slope run-out risk (MPM on scikit-fem).",
                                epilog=EXIT_CODES,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = p.add_subparsers(dest="command", required=True, title="commands")
    for add in (_add_run, _add_fem, _add_mc, _add_converge, _add_fs, _add_field,
                _add_report):
        add(sub)
    return p


def _check_paths(a) -> None:
    """Refuse an empty ``--out`` (it would write into the current directory) and an empty
    ``--case`` (it would silently run the scene's own case)."""
    if getattr(a, "out", None) is not None and not a.out.strip():
        raise InputError(f"--out {a.out!r}: [] empty path; allowed: a directory path")
    for spec in getattr(a, "case", None) or ():
        if not spec.strip():
            raise InputError(f"--case {spec!r}: [] empty case; allowed: 'homogeneous', "
                             "'xi=12', 'scene' or '<section.key>=<value>' changes joined by ';'")


def main(argv: list[str] | None = None) -> int:
    with graceful_interrupts():          # SIGTERM takes Ctrl-C's path: exit 143
        return _main(argv)


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    a = parser.parse_args(argv)
    if getattr(a, "scene", "x") is None:
        a.scene, a.default_scene = str(default_scene_path()), True
    try:
        _check_paths(a)
        code = int(a.func(a) or 0)
        sys.stdout.flush()       # a closed pipe is reported here, not at the interpreter's exit
        return code
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
    except KeyboardInterrupt as exc:
        print(f"fem-rmpm: interrupted ({interrupt_name(exc)}); finished output is kept",
              file=sys.stderr)
        return interrupt_exit_code(exc)
    except BrokenPipeError:      # the reader of stdout left (`| head -1`): end quietly
        _quiet_stdout()
        return 128 + signal.SIGPIPE


def _quiet_stdout() -> None:
    """Point stdout at /dev/null, so that the interpreter's final flush into the closed
    pipe does not report a second BrokenPipeError."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
