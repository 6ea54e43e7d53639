"""Cases of a campaign (variants of one scene) and the seed of each realization."""
from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from fem_rmpm.runtime.errors import InputError
from fem_rmpm.scene import Scene, scene_from_dict, scene_to_dict, with_value

__all__ = ["CampaignError", "Case", "LITERATURE_CASES", "parse_case", "literature_cases",
           "realization_seed", "without_random_field", "default_scene_path", "campaign_cases"]

#: The literature cases of the reference slope (Wang, Vardon & Hicks 2017).
LITERATURE_CASES = ("homogeneous", "xi=1", "xi=12", "xi=48")


class CampaignError(InputError):
    """Bad campaign input: N, workers, scheduler address, output directory (CLI exit 2)."""


@dataclass(frozen=True)
class Case:
    """One variant of the campaign's scene: ``name`` (used in file names), ``spec``
    (how it was given) and the scene it runs."""
    name: str
    spec: str
    scene: Scene

    @property
    def deterministic(self) -> bool:
        return self.scene.random_field is None

    @property
    def label(self) -> str:
        if self.spec.startswith("xi="):
            return "xi = " + self.spec[3:]
        return self.spec


def _plain_scene_dict(scene: Scene) -> dict:
    """scene_to_dict with the 'inf' strings turned back into floats (rebuildable)."""
    data = scene_to_dict(scene)
    for sec in data.values():
        for d in (sec if isinstance(sec, list) else [sec]):
            for k, v in list(d.items()):
                if v in ("inf", "-inf"):
                    d[k] = float(v)
    return data


def without_random_field(scene: Scene) -> Scene:
    """The scene with its ``[random_field]`` removed (homogeneous soil)."""
    data = _plain_scene_dict(scene)
    data.pop("random_field", None)
    return scene_from_dict(data, scene.source)


def parse_case(spec: str, scene: Scene) -> Case:
    """A case from its text: ``"homogeneous"`` (no random field), ``"xi=12"``
    (``random_field.anisotropy``; a scene without a field gets the defaults of
    :class:`fem_rmpm.scene.RandomFieldSpec`: lognormal, COV 0.25, theta_v 0.5 m) or
    ``"<section.key>=<TOML value>"``, several joined by ``;``
    (``"solver.cfl=0.3;soil.softening_strain=0.8"``)."""
    spec = spec.strip()
    if spec in ("", "scene", "base"):
        return Case("scene", "scene", scene)
    if spec == "homogeneous":
        return Case("homogeneous", spec, without_random_field(scene))
    out = scene
    for part in spec.split(";"):
        key, eq, text = part.partition("=")
        key, text = key.strip(), text.strip()
        if not eq or not key or not text:
            raise CampaignError(f"case {spec!r}: expected 'homogeneous', 'xi=<number>' or "
                                "'<section.key>=<value>'")
        if key == "xi":
            key = "random_field.anisotropy"
        try:
            value = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text                      # a bare word: a string value
        out = with_value(out, key, value)
    name = re.sub(r"[^A-Za-z0-9.=+-]+", "_", spec.replace("xi=", "xi")).strip("_")
    return Case(name, spec, out)


def literature_cases(scene: Scene) -> list[Case]:
    """The four cases of the reference slope: homogeneous and xi = theta_h/theta_v = 1, 12, 48."""
    return [parse_case(s, scene) for s in LITERATURE_CASES]


def realization_seed(campaign_seed: int, index: int) -> int:
    """Seed of realization ``index``: the first 63 bits of
    ``SeedSequence([campaign_seed, index]).generate_state(1, numpy.uint64)``.

    SeedSequence hashes its entropy, so neighbouring indices (and campaign seeds)
    give statistically independent streams (numpy's recommended way to key
    streams); the result fits ``[montecarlo] seed`` and ``fem-rmpm run --seed``,
    so ``fem-rmpm run SCENE --seed S`` reproduces a realization alone."""
    if campaign_seed < 0 or index < 0:
        raise ValueError("campaign seed and index must be >= 0")
    state = np.random.SeedSequence([int(campaign_seed), int(index)]).generate_state(1, np.uint64)
    return int(state[0] >> np.uint64(1))


def default_scene_path() -> Path:
    """The embedded default scene: the reference slope of the RMPM paper (Wang, Vardon &
    Hicks 2017; ``fem_rmpm/data/slope_reference.toml``)."""
    return Path(str(resources.files("fem_rmpm") / "data" / "slope_reference.toml"))


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
        return list(LITERATURE_CASES)
    return ["scene"]
