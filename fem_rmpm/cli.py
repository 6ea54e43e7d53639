"""Command line: ``fem-rmpm run | fem | mc | field``.

Exit codes: 0 success, 2 bad input (scene, data file, options), 3 the
simulation failed (unstable, Newton did not converge, ...), 130 interrupted.
Errors are one line on stderr, never a traceback (``--debug`` shows it).
"""
from __future__ import annotations

import argparse
import sys
from importlib import resources
from pathlib import Path

from .run import SimulationError
from .output import OutputError
from .scene import SceneError, load_scene

__all__ = ["main", "default_scene_path"]


def default_scene_path() -> Path:
    """The embedded default scene: the reference slope of the RMPM paper (DESIGN section 6)."""
    return Path(str(resources.files("fem_rmpm") / "data" / "slope_reference.toml"))


class InputError(ValueError):
    """Bad command-line input other than the scene file."""


def _scene_arg(p: argparse.ArgumentParser, optional: bool = False) -> None:
    p.add_argument("scene", nargs="?" if optional else None,
                   default=None, help="scene file (TOML); default: the embedded reference slope"
                   if optional else "scene file (TOML)")


def parse_settings(items: list[str] | None, source: str) -> dict:
    """``--set key=value`` pairs; values are TOML literals (parsed by tomllib, never eval)."""
    import tomllib
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
    from .scene import with_values
    scene = load_scene(a.scene)
    changes = parse_settings(getattr(a, "set", None), a.scene)
    return with_values(scene, changes) if changes else scene


def _cmd_run(a) -> int:
    from . import api
    scene = scene_from_args(a)
    res = api.run(scene, out=a.out, seed=a.seed, progress=not a.quiet)
    s, m = res.summary, res.measures
    if s["stop_reason"] == "load applied":
        steps = f"{s['steps']} load steps (load factor 1)"
    else:
        steps = f"{s['steps']} steps to t = {s['simulated_time']:.3g} s ({s['stop_reason']})"
    print(f"{scene.scene.name}: {s['scheme']} run of {s['particles']} material points, {steps} "
          f"in {s['wall_time']:.1f} s wall ({s['ns_per_particle_step']:.0f} ns per point-step); "
          f"max displacement {m['max_displacement']:.3g} m, failed = {m['failed']}, run-out "
          f"{m['runout_distance']:.2f} m, retrogression {m['retrogression_distance']:.2f} m, "
          f"sliding area {m['sliding_area']:.1f} m2; {s['frozen_points']['count']} points "
          f"frozen at the grid edge. Output: {a.out}")
    return 0


def _cmd_fem(a) -> int:
    import numpy as np
    from . import api
    scene = scene_from_args(a)
    res = api.fem(scene, out=a.out)
    print(f"{scene.scene.name}: static FEM on {len(res.cells)} Q4 elements; max |u| = "
          f"{np.abs(res.displacement).max():.4g} m, min sigma_yy = {res.stress[:, 1].min():.4g} "
          f"kPa. Output: {a.out}")
    return 0


def _cmd_mc(a) -> int:
    from .montecarlo import run_campaign_cli
    return run_campaign_cli(a)


def _cmd_field(a) -> int:
    from .random_field import field_cli
    return field_cli(a)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fem-rmpm", description="Random Material Point Method "
                                "for slope run-out risk (MPM on scikit-fem).")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="one realization (explicit or implicit MPM)")
    _scene_arg(r, optional=True)
    r.add_argument("--out", required=True, help="output directory")
    r.add_argument("--seed", type=int, default=None, help="random-field seed (default: scene's)")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="change a scene value, e.g. --set solver.scheme=implicit "
                   "--set 'grid.cell=[0.5, 0.5]' (repeatable; TOML values)")
    r.set_defaults(func=_cmd_run)

    f = sub.add_parser("fem", help="static small-strain FEM gravity reference (scikit-fem)")
    _scene_arg(f, optional=True)
    f.add_argument("--out", required=True)
    f.add_argument("--set", action="append", metavar="KEY=VALUE", help="as for run")
    f.set_defaults(func=_cmd_fem)

    m = sub.add_parser("mc", help="Monte Carlo campaign on Dask (default: small campaign of "
                       "the reference slope)")
    _scene_arg(m, optional=True)
    m.add_argument("-n", "--realizations", type=int, default=None,
                   help="number of realizations (default: scene's [montecarlo] realizations)")
    m.add_argument("--out", default="runs/mc", help="campaign directory (default runs/mc)")
    m.add_argument("--workers", type=int, default=None, help="local worker processes")
    m.add_argument("--scheduler", default=None, help="address of a running Dask scheduler")
    m.add_argument("--force", action="store_true", help="recompute finished realizations")
    m.add_argument("--keep-vtk", default=None,
                   help="VTK for the first k realizations (integer) or a list like 0,5,9")
    m.add_argument("--quiet", action="store_true")
    m.set_defaults(func=_cmd_mc)

    fl = sub.add_parser("field", help="one random field on the material points (VTU + PNG)")
    _scene_arg(fl, optional=True)
    fl.add_argument("--seed", type=int, default=None)
    fl.add_argument("--out", required=True)
    fl.add_argument("--data", default=None, help="CSV x,y,value to condition on (kriging)")
    fl.add_argument("--fit", default=None, help="CSV x,y,value: estimate theta_v, theta_h")
    fl.set_defaults(func=_cmd_field)
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
