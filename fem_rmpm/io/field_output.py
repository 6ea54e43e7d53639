"""What ``fem-rmpm field`` computes and writes: a realization of a scene's random field on
its material points (``field.vtu``, ``field.png``, ``field.json``), optionally conditioned
on measurements, the variogram fit of measurements (``fit.json``, ``variogram.png``) and
the paragraph that describes them."""
from __future__ import annotations

import contextlib
import shutil
import signal
import tempfile
import time
from pathlib import Path

import numpy as np

from fem_rmpm import materials
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.io.output import (
    particle_fields,
    to_true_frame,
    write_json,
    write_points_vtu,
)
from fem_rmpm.io.plots import _plt, plot_field
from fem_rmpm.random_field import (
    FitResult,
    apply_to_points,
    embeddings_for,
    field_layout,
    fit_scales,
    point_fields,
    read_measurements,
)
from fem_rmpm.random_field.conditioning import resolve_data_path
from fem_rmpm.runtime.errors import InputError
from fem_rmpm.scene import RandomFieldSpec, Scene, load_scene, scene_to_dict, with_value

__all__ = ["plot_realization", "plot_variogram", "write_field_vtu", "field_scene",
           "field_property", "fit_measurements", "write_field", "staged_outputs"]


def plot_realization(path, scene, pts, values, mask, title, label="peak cohesion (kPa)"):
    plt = _plt()
    X = to_true_frame(pts.x0, scene.scene.frame_angle_deg)
    span = np.ptp(X, axis=0) + 1e-9
    fig, ax = plt.subplots(figsize=(11, float(np.clip(1.4 + 8.5 * span[1] / span[0], 2.5, 9.0))))
    # Gauss points are not evenly spaced: squares 1.3x the mean spacing leave no gaps
    spacing = 1.3 * float(np.min(pts.half_width)) * 2.0 if pts.half_width is not None else 0.1
    if (~mask).any():
        plot_field(ax, X[~mask], np.zeros((~mask).sum()), spacing, cmap="Greys", vmin=-1, vmax=4)
    sc = plot_field(ax, X[mask], values[mask], spacing, cmap="jet")
    ax.set_aspect("equal")
    ax.set_xlabel("X, true horizontal (m)")
    ax.set_ylabel("Y (m)")
    ax.set_title(title, fontsize=10)
    fig.colorbar(sc, ax=ax, label=label, shrink=0.8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_variogram(path, fit: FitResult, title: str):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    for h, g, th, lab, mk in ((fit.lags_x, fit.gamma_x, fit.theta_h, "x (horizontal)", "o"),
                              (fit.lags_y, fit.gamma_y, fit.theta_v, "y (vertical)", "s")):
        ax.plot(h, g, mk, ms=4, label=f"empirical along {lab}")
        hh = np.linspace(0, h.max(), 200)
        ax.plot(hh, fit.sill * -np.expm1(-2 * hh / th), "-", label=f"fit, theta = {th:.3g} m")
    ax.set_xscale("symlog", linthresh=max(min(fit.lags_y.min(), fit.lags_x.min()), 1e-3))
    ax.set_xlabel("lag (m)")
    ax.set_ylabel("semivariance" + (" of ln(value)" if fit.log else ""))
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_field_vtu(path: Path, pts, shown: np.ndarray) -> None:
    """The material points with the usual point data plus ``random_field`` (the field value,
    -1 where the field does not apply), written atomically."""
    fields = particle_fields(pts)
    fields["random_field"] = shown
    write_points_vtu(path, np.hstack([pts.x, np.zeros((pts.n, 1))]), fields)


# --------------------------------------------------------------------------- the command

@contextlib.contextmanager
def staged_outputs(out: Path):
    """A hidden staging directory inside ``out`` for the files of one ``field`` command;
    on a normal exit from the block they are moved into ``out`` as one set (the renames
    run with SIGINT and SIGTERM held back, so a signal lands before or after the whole
    set, never between two files), and the staging directory is removed in every case:
    an error or an interrupt part-way leaves ``out`` as it was (no ``field.vtu`` or
    ``field.png`` without its ``field.json``)."""
    stage = Path(tempfile.mkdtemp(prefix=".field-partial-", dir=out))
    try:
        yield stage
        names = sorted(p.name for p in stage.iterdir())
        held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        moved: list[Path] = []
        try:
            for name in names:
                (stage / name).replace(out / name)
                moved.append(out / name)
        except BaseException:
            for path in moved:                  # all or nothing (the old set is gone)
                path.unlink(missing_ok=True)
            raise
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, held)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def field_scene(path: str | Path) -> tuple[Scene, str]:
    """The scene of ``fem-rmpm field``; without a ``[random_field]``, the literature's
    default field (and a note saying so)."""
    scene = load_scene(path)
    if scene.random_field is not None:
        return scene, ""
    scene = with_value(scene, "random_field.anisotropy", RandomFieldSpec().anisotropy)
    return scene, (" The scene has no [random_field] section, so this is the default field "
                   "(add [random_field] to use a field in runs).")


def fit_measurements(path: str, rf: RandomFieldSpec, out: Path,
                     shown: Path | None = None) -> tuple[str, str]:
    """``--fit CSV``: fit the scales, write ``fit.json`` and ``variogram.png`` in ``out``;
    returns the line that tells the result (naming the files in ``shown``, default
    ``out``: where they end up) and the sentence for the final summary."""
    meas = read_measurements(path, key="fit")
    fit = fit_scales(meas.x, meas.y, meas.value, log=rf.distribution == "lognormal",
                     source=meas.source, group=meas.group)
    write_json(out / "fit.json", {"data": meas.source, **fit.as_dict()})
    plot_variogram(out / "variogram.png", fit, f"{Path(meas.source).name}: Markov fit")
    line = (f"fit of {meas.source}: theta_v = {fit.theta_v:.4g} m, theta_h = "
            f"{fit.theta_h:.4g} m (xi = {fit.anisotropy:.3g}), sill {fit.sill:.3g}"
            f"{' of ln(value)' if fit.log else ''}; written {(shown or out) / 'fit.json'}")
    return line, (f" The variogram fit of {Path(meas.source).name} gives theta_v = "
            f"{fit.theta_v:.3g} m and theta_h = {fit.theta_h:.3g} m (set them with "
            "random_field.theta_v / anisotropy to use them).")


def _shown_on_points(pts, name: str, values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Give the points the realization's value of property ``name`` (as ``api.prepare``, a
    residual in proportion); returns the value shown per point: the field on the field's
    soils, the soil's value elsewhere, -1 where that is infinite (linear elastic)."""
    base = getattr(pts.soil, name)
    finite = np.isfinite(base)
    pts.soil = apply_to_points(pts.soil, {name: np.where(mask & finite, values, base)})
    return np.where(mask, values, np.where(finite, base, -1.0))


def field_property(scene: Scene, name: str | None) -> tuple[int, RandomFieldSpec]:
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


def write_field(scene: Scene, out: Path, seed: int, k: int, rf: RandomFieldSpec,
                data: str | None, t0: float) -> str:
    """Write ``field.vtu``, ``field.png`` and ``field.json`` of the realization ``seed`` of
    field ``k`` (``rf``) of ``scene`` in ``out`` (conditioned on ``data`` or the scene's
    own measurements, if any); returns the summary paragraph (without note, fit and
    output).  ``t0``: when the command started (``time.perf_counter()``)."""
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    layout = field_layout(scene, grid)
    emb = embeddings_for(scene, layout)[k]
    path = resolve_data_path(scene, data, rf)
    meas = read_measurements(path) if path is not None else None
    values, mask = point_fields(scene, grid, pts, seed, meas, data_index=k)
    values = values[rf.property]
    shown = _shown_on_points(pts, rf.property, values, mask)
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
    return _field_text(scene, rf, seed, layout, emb, meas, v)
