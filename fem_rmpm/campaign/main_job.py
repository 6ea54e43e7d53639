"""The main job, ``fem-rmpm mc --out DIR`` without a scene: a probability that means
something, and the seed paper's four mechanisms, in one report within minutes.

1. ``DIR``: the risk slope (``fem_rmpm/data/slope_risk.toml``: ``meshes/slope_risk.toml``
   with a small ``[montecarlo]``): its anisotropic case xi = 12 at N realizations (the
   file's ``realizations``), each with its strength-reduction factor of safety and its MPM
   run stopped once the failure is decided: P(failure) with its interval, P(FS < 1), the
   failure split and the fragility curve (:mod:`fem_rmpm.campaign.fragility`).
   Realization i is realization i of the full study (same campaign seed), which extends it.
2. ``DIR/seed_slope``: the reference slope of the RMPM paper (the embedded default scene,
   ``fem_rmpm/data/slope_reference.toml``), one realization of each literature case run to
   rest with its VTK: the four-case mechanism figure, shown in ``DIR/report.html`` under
   "Linked campaigns".

``DIR/main_job.json`` names the command of the full study (shown under "What N buys").
Both campaigns are resumable: re-running the command reuses every finished realization.
"""
from __future__ import annotations

from importlib import resources
from pathlib import Path

from fem_rmpm.campaign.case_campaign import pending_work, run_campaign
from fem_rmpm.campaign.cases import LITERATURE_CASES, default_scene_path
from fem_rmpm.campaign.report import write_report
from fem_rmpm.io.output import write_json
from fem_rmpm.scene import Scene, load_scene

__all__ = ["main_scene_path", "SEED_DIRECTORY", "FULL_STUDY", "run_main_job"]

#: The seed slope's campaign inside the main job's directory.
SEED_DIRECTORY = "seed_slope"
#: The command of the full study the main job is the start of.
FULL_STUDY = "fem-rmpm mc meshes/slope_risk.toml -n 280 --fs --out runs/risk"


def main_scene_path() -> Path:
    """The main job's scene: ``fem_rmpm/data/slope_risk.toml``."""
    return Path(str(resources.files("fem_rmpm") / "data" / "slope_risk.toml"))


def run_main_job(out: str | Path, realizations: int | None = None, *,
                 scene: Scene | None = None, **campaign_options) -> tuple:
    """Run (or finish) the main job in ``out`` (module docstring); returns the campaign
    results (:class:`~fem_rmpm.campaign.case_campaign.CampaignResult`) of the risk slope
    and of the seed slope.  Both directories are checked before anything runs.
    ``scene``: the risk scene (default :func:`main_scene_path`, its ``[montecarlo]
    factor_of_safety`` on); ``campaign_options`` go to ``run_campaign``."""
    out = Path(out)
    risk = scene if scene is not None else load_scene(main_scene_path())
    seed = load_scene(default_scene_path())
    n = risk.montecarlo.realizations if realizations is None else realizations
    cases = list(risk.montecarlo.cases or ["scene"])
    pending_work(risk, out, n, cases)                          # refuse before any run
    pending_work(seed, out / SEED_DIRECTORY, 1, list(LITERATURE_CASES), keep_vtk=1)
    main = run_campaign(risk, out, n, cases, **campaign_options)
    write_json(out / "main_job.json", {"full_study": FULL_STUDY,
                                       "seed_slope": SEED_DIRECTORY})
    opts = {k: v for k, v in campaign_options.items() if k != "keep_vtk"}
    side = run_campaign(seed, out / SEED_DIRECTORY, 1, list(LITERATURE_CASES), keep_vtk=1,
                        **opts)
    write_report(out)                                          # now with the seed slope
    return main, side
