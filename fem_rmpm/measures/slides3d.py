"""Separate slides along the strike of a 3-D deposit, from the displaced points.

Pure functions over point arrays (positions in m, axes ``x`` along the slope, ``y``
vertical, ``z`` along the strike); the measures of a 3-D run read them
(:func:`fem_rmpm.measures.deposit3d.compute_measures_3d`: bins one cell long, a bin
sliding when it holds at least the failure area x the bin width of sliding volume).

A *slide* is a maximal run along the strike of displaced material: the strike axis is
cut into bins of ``bin_width`` (m, e.g. the cell size along z), a bin is *sliding* when
it holds at least ``min_points`` displaced points and at least ``min_volume`` (m3) of
their volume, and consecutive sliding bins (gaps of fewer than ``gap_bins`` empty bins
bridged) form one slide.  Per slide: its length along the strike (from the smallest to
the largest strike coordinate of its displaced points, m), the strike range of its bins
(``bins``, ``b0``, ``b1``: ``slices x bin_width`` is its strike length by whole bins),
its volume (sum of the displaced points' volumes in its bins, m3).  Hicks &
Spencer (2010) count discrete slides this way along a long slope (a short horizontal scale
of fluctuation gives several short slides, a long one a single slide along the slope).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Slide", "displaced_points", "slides_along_strike"]


@dataclass(frozen=True)
class Slide:
    """One slide: strike range ``[z0, z1]`` (m) of its displaced points, length ``z1 - z0``
    (m), volume (m3), number of displaced points, strike range ``[b0, b1]`` (m) of its
    bins."""
    z0: float
    z1: float
    volume: float
    points: int
    b0: float = float("nan")
    b1: float = float("nan")

    @property
    def length(self) -> float:
        return self.z1 - self.z0


def displaced_points(x0, x, threshold: float) -> np.ndarray:
    """Mask of points (n, 3) whose displacement ``|x - x0|`` exceeds ``threshold`` (m)."""
    d = np.linalg.norm(np.asarray(x, float) - np.asarray(x0, float), axis=1)
    return d > threshold


def slides_along_strike(z, volume, displaced, bin_width: float, z_range=None,
                        min_points: int = 1, gap_bins: int = 1,
                        min_volume: float = 0.0) -> list[Slide]:
    """The separate slides along the strike (see the module docstring).

    ``z`` (n,) strike coordinates of the points (their initial positions, so a slide is
    where the material came from; m), ``volume`` (n,) or a number (m3 per point),
    ``displaced`` (n,) mask; ``z_range`` = (z_min, z_max) of the slope (default the points'
    range); ``gap_bins``: runs of fewer empty bins than this inside a slide are bridged
    (1: any empty bin separates two slides); ``min_volume`` (m3): the least displaced
    volume of a sliding bin (a bin below it is empty; its points belong to no slide)."""
    z = np.asarray(z, float)
    disp = np.asarray(displaced, bool)
    vol = np.broadcast_to(np.asarray(volume, float), z.shape)
    if not bin_width > 0:
        raise ValueError(f"bin_width must be positive (m), got {bin_width}")
    if z.shape != disp.shape:
        raise ValueError(f"z and displaced differ in length: {z.shape} vs {disp.shape}")
    if not disp.any():
        return []
    lo, hi = (float(z.min()), float(z.max())) if z_range is None else map(float, z_range)
    nb = max(int(np.ceil((hi - lo) / bin_width - 1e-9)), 1)
    zb = np.clip(((z[disp] - lo) / bin_width).astype(np.int64), 0, nb - 1)
    counts = np.bincount(zb, minlength=nb)
    vbin = np.bincount(zb, vol[disp], minlength=nb)
    sliding = (counts >= max(min_points, 1)) & (vbin >= min_volume)
    # runs of sliding bins, bridging gaps shorter than gap_bins
    label = np.full(nb, -1)
    current, last = -1, -10 ** 9
    for b in np.nonzero(sliding)[0]:
        if b - last > gap_bins:
            current += 1
        label[b] = current
        last = b
    slides = []
    zd, vd = z[disp], vol[disp]
    which = label[zb]
    for k in range(current + 1):
        sel = which == k
        bins = np.nonzero(label == k)[0]
        slides.append(Slide(z0=float(zd[sel].min()), z1=float(zd[sel].max()),
                            volume=float(vd[sel].sum()), points=int(sel.sum()),
                            b0=lo + bins[0] * bin_width, b1=lo + (bins[-1] + 1) * bin_width))
    return slides
