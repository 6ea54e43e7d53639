"""Campaigns on three-dimensional scenes: what they support, and what they refuse.

A 3-D campaign is a crude Monte Carlo campaign like a plane-strain one: the same
``fem-rmpm mc`` command, the same records, resumption, seeds (realization ``i`` of a case
is a pure function of the scene and its seed), runs stopped once decided
(:mod:`.decide`: the moved *volume* against ``failure_area`` times the grid's strike cell
``hz``), ``--dry-run`` (the budget's 3-D estimate, :mod:`fem_rmpm.runtime.budget3d`, and a
probe of 3-D runs on this machine) and the report, which adds the 3-D views
(:mod:`.report3d`).  The records of a 3-D realization carry ``dimension = 3`` and its
``slides`` [(z0, z1, volume)]; its measures are those of :mod:`fem_rmpm.measures.deposit3d`.

Refused with one line (exit 2 on the command line), before anything is written: the
strength-reduction factor of safety (``--fs``, ``--fs-only``, ``[montecarlo]
factor_of_safety``; the implicit strength reduction is plane strain only) and subset
simulation (its Markov chains move in the noise of the whole 3-D embedding lattice,
:func:`fem_rmpm.random_field.field3d.subset_noise_3d`).
"""
from __future__ import annotations

from fem_rmpm.campaign.cases import CampaignError
from fem_rmpm.scene import Scene

__all__ = ["check_campaign_3d", "is_three_d"]


def is_three_d(scene: Scene) -> bool:
    """True for a three-dimensional scene (``[grid] size = [Lx, Ly, Lz]``)."""
    return scene.grid.dimension == 3


def check_campaign_3d(scene: Scene, *, fs: bool = False, fs_only: bool = False,
                      method: str = "crude") -> None:
    """Raise :class:`CampaignError` (one line) when a campaign of the 3-D ``scene`` asks
    for what 3-D campaigns do not do (module docstring); nothing for a 2-D scene."""
    if not is_three_d(scene):
        return
    where = f"{scene.source}: a three-dimensional scene"
    if fs or fs_only or getattr(scene.montecarlo, "factor_of_safety", False):
        opt = "--fs-only" if fs_only else ("--fs" if fs else "[montecarlo] factor_of_safety")
        raise CampaignError(f"{opt}: {where}; allowed: campaigns of 3-D scenes without the "
                            "factor of safety (strength reduction is plane strain only; the "
                            "plane-strain FS of the section: 'fem-rmpm fs' on the 2-D scene)")
    if method != "crude":
        raise CampaignError(f"--method {method}: {where}; allowed: --method crude (subset "
                            "simulation moves in the noise of the whole 3-D embedding "
                            "lattice, which no reduced representation spans yet)")
