"""Scene specification: the frozen dataclasses a validated scene file becomes.

A scene describes everything one run needs.  Each key is declared once, as a field of
its section's dataclass with its default, unit and one-line description
(:func:`scene_key`, read by :mod:`fem_rmpm.scene.reference`, which writes the scene
reference of the documentation).  Units: m, s, kPa (stress, modulus, cohesion), kN/m3
(unit weight); the density used by the dynamics is ``unit_weight / gravity`` in t/m3.
Reading and validating a TOML file into these classes is :mod:`fem_rmpm.scene.schema`;
changing values of a scene is :mod:`fem_rmpm.scene` (which re-exports every public name
of both).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "scene_key",
    "SceneError", "Scene", "SceneInfo", "GridSpec", "BoundarySpec", "SoilSpec",
    "BedrockSpec", "PrescribedSpec", "RandomFieldSpec", "PropertyFieldSpec", "SolverSpec",
    "MonteCarloSpec", "OutputSpec", "WaterSpec",
    "BOUNDARY_KINDS", "SCHEMES", "SHAPES", "EDGE_POLICIES", "DISTRIBUTIONS", "CORRELATIONS",
]


class SceneError(ValueError):
    """A scene file (or a value set on a scene) is invalid.

    The message is one line: ``<file>: [<key>] <what is wrong>; allowed: <...>``.
    """


BOUNDARY_KINDS = ("fixed", "roller", "free")
SCHEMES = ("explicit", "implicit")
SHAPES = ("standard", "gimp")
EDGE_POLICIES = ("freeze", "stop")
DISTRIBUTIONS = ("normal", "lognormal", "beta")
CORRELATIONS = ("markov_elliptic", "markov_separable")
PORE_PRESSURES = ("hydrostatic", "parallel_seepage")
DRAINAGE = ("drained", "undrained")


def scene_key(default: Any = dataclasses.MISSING, doc: str = "", unit: str = "") -> Any:
    """A scene key as a dataclass field: its ``default`` (none: the key is required), a
    one-line description ``doc`` and its ``unit`` ("-": dimensionless, "": not a
    quantity), kept in the field's metadata for the scene reference."""
    return field(default=default, metadata={"doc": doc, "unit": unit})


@dataclass(frozen=True)
class SceneInfo:
    """``[scene]``: the scene's name and gravity."""
    name: str = scene_key("scene", "name of the scene (in outputs and reports)")
    gravity: float = scene_key(9.81, "gravitational acceleration", "m/s2")
    frame_angle_deg: float = scene_key(
        0.0, "angle of the grid x axis below the true horizontal (a tilted frame)", "deg")
    description: str = scene_key("", "free text describing the scene")


@dataclass(frozen=True)
class GridSpec:
    """``[grid]``: the background grid of square or rectangular Q4 cells; with three
    sizes ``[Lx, Ly, Lz]`` a three-dimensional grid of hexahedra (y up, z the strike)."""
    origin: tuple[float, ...] = scene_key((0.0, 0.0), "lower left corner [x, y] (3-D: "
                                          "[x, y, z]; default the origin)", "m")
    size: tuple[float, ...] = scene_key((1.0, 1.0), "extent [width, height] (3-D: [width, "
                                        "height, length along the strike])", "m")
    cell: tuple[float, ...] = scene_key(
        (0.25, 0.25), "cell size [hx, hy] (3-D: [hx, hy, hz]; one number: square or cubic "
        "cells); size must be a whole number of cells", "m")
    file: str | None = scene_key(
        None, "a quad mesh read by meshio instead (path relative to the scene file; 2-D only)")

    @property
    def dimension(self) -> int:
        """2 (plane strain, Q4 cells) or 3 (hexahedra): the number of sizes given."""
        return len(self.size)


@dataclass(frozen=True)
class BoundarySpec:
    """``[boundary]``: the condition on each edge of the grid."""
    left: str = scene_key("roller", "left edge: fixed (no motion), roller (no normal motion) "
                          "or free")
    right: str = scene_key("roller", "right edge, as left")
    bottom: str = scene_key("fixed", "bottom edge, as left")
    top: str = scene_key("free", "top edge, as left")
    front: str | None = scene_key(None, "3-D only: the face z = z0 (strike start), as left "
                                  "(default roller)")
    back: str | None = scene_key(None, "3-D only: the face z = z0 + Lz (strike end), as left "
                                 "(default roller)")


@dataclass(frozen=True)
class SoilSpec:
    """One ``[[soil]]`` table.  Which keys belong to its material model (``model``) and
    their units and ranges are the model's declaration (``PARAMETERS``, see
    :mod:`fem_rmpm.materials`), against which the keys are validated.  Four keys that
    softening models share are fields here, with the defaults every model declaring them
    shares (``tests/test_material.py`` checks that); all other keys of a model are kept
    in ``parameters``.  Read any of them with :meth:`value`."""
    polygon: tuple[tuple[float, float], ...]
    unit_weight: float                  # kN/m3
    youngs_modulus: float               # kPa
    poisson_ratio: float                # -
    name: str = "soil"
    points_per_cell_dir: int = 2
    model: str = "linear_elastic"
    cohesion_peak: float = math.inf     # kPa, peak strength (its meaning: the model's)
    cohesion_residual: float = math.inf  # kPa, strength after softening
    softening: str = "linear"           # softening law: "linear" | "exponential"
    softening_strain: float = 0.5       # plastic shear strain (-) at which the strength
    #                                     reaches the residual (linear) or e-folding (exponential)
    parameters: tuple = ()              # ((name, value), ...) of the model's other parameters
    strike: tuple[float, float] | None = scene_key(
        None, "3-D only: the polygon (an x-y section) extruded along z from z0 to z1 "
        "(default: the whole grid)", "m")
    plan: tuple[tuple[float, float], ...] | None = scene_key(
        None, "3-D only: plan shape [[x, z], ...]; a cell is soil when its centre is in the "
        "section, the strike range and this polygon", "m")
    unit_weight_saturated: float | None = None  # kN/m3 below the phreatic surface ([water])
    drainage: str | None = None         # "drained" (effective stress) | "undrained" (total);
    #                                     None: the model's (fem_rmpm.scene.water.drainage_of)

    def value(self, name: str, default: Any = None) -> Any:
        """The value of parameter ``name`` of this soil's model (or ``default``)."""
        if name in _SOIL_FIELDS:
            return getattr(self, name)
        return dict(self.parameters).get(name, default)

    @property
    def shear_modulus(self) -> float:
        return self.youngs_modulus / (2.0 * (1.0 + self.poisson_ratio))

    @property
    def bulk_modulus(self) -> float:
        return self.youngs_modulus / (3.0 * (1.0 - 2.0 * self.poisson_ratio))

    @property
    def constrained_modulus(self) -> float:
        """Oedometric (P-wave) modulus M = E(1-nu)/((1+nu)(1-2nu)), kPa."""
        nu = self.poisson_ratio
        return self.youngs_modulus * (1 - nu) / ((1 + nu) * (1 - 2 * nu))


_SOIL_FIELDS = ("polygon", "unit_weight", "youngs_modulus", "poisson_ratio", "name",
                "points_per_cell_dir", "model", "cohesion_peak", "cohesion_residual", "softening",
                "softening_strain", "strike", "plan", "unit_weight_saturated",
                "drainage")


@dataclass(frozen=True)
class BedrockSpec:
    """A rigid region (no particles).  ``interface = "rough"`` (default): every grid node
    inside or on the polygon is fixed (the soil sticks to it).  ``"frictional"``: those
    nodes are contact nodes of a rigid surface with the normal of the polygon's nearest
    edge: no penetration, separation allowed, Coulomb friction ``friction`` plus
    ``adhesion`` along it (explicit scheme; :mod:`fem_rmpm.discretise.contact`)."""
    polygon: tuple[tuple[float, float], ...] = scene_key(
        doc="corners [[x, y], ...] of the rigid region", unit="m")
    interface: str = scene_key("rough", "soil-rock interface: rough (nodes fixed, no slip) or "
                               "frictional (Coulomb sliding, separation allowed)")
    friction: float | None = scene_key(None, "Coulomb friction coefficient of a frictional "
                                       "interface (tan of the interface friction angle)", "-")
    adhesion: float | None = scene_key(None, "adhesion of a frictional interface (shear "
                                       "strength at zero normal stress)", "kPa")


@dataclass(frozen=True)
class PrescribedSpec:
    """Displacement control of grid nodes (a rigid footing, a moving wall): every grid node
    in or on ``polygon`` gets the displacement ``displacement`` (m) in the components
    ``components`` ("xy": both, e.g. a rough footing; "y" or "x": one, e.g. a smooth
    footing).  The displacement is reached at the end of loading: with implicit
    quasi-static (or geostatic) load steps each step adds its share (the load factor
    increment times ``displacement``).  A component prescribed here wins over a fixed
    or roller boundary.  The reaction (kN per m) of each region is recorded per step."""
    polygon: tuple[tuple[float, float], ...] = scene_key(
        doc="corners [[x, y], ...] of the region whose grid nodes are moved", unit="m")
    displacement: tuple[float, float] = scene_key(
        doc="displacement [ux, uy] reached at load factor 1", unit="m")
    components: str = scene_key("xy", "the prescribed components: xy (both, a rough "
                                "footing), x or y (one, a smooth footing)")
    name: str = scene_key("prescribed", "name of the region (in the reaction records)")


@dataclass(frozen=True)
class PropertyFieldSpec:
    """One ``[[random_field.properties]]`` table: the marginal of one property of the
    field's soils and, where given, its own correlation structure (not set: the value of
    ``[random_field]``, shared by the properties)."""
    property: str = scene_key(doc="a numeric parameter of the soil's model, e.g. "
                              "friction_angle_peak")
    distribution: str = scene_key("lognormal", "marginal distribution (beta: bounded by "
                                  "low and high)")
    cov: float = scene_key(0.25, "coefficient of variation", "-")
    low: float | None = scene_key(None, "beta: lower bound", "property's unit")
    high: float | None = scene_key(None, "beta: upper bound", "property's unit")
    theta_v: float | None = scene_key(None, "its own vertical scale of fluctuation", "m")
    anisotropy: float | None = scene_key(None, "its own xi = theta_h / theta_v", "-")
    correlation: str | None = scene_key(None, "its own correlation function")
    layering_angle_deg: float | None = scene_key(None, "its own layering angle", "deg")
    data: str | None = scene_key(None, "CSV of x, y, value of this property to condition "
                                 "on (kriging)")


@dataclass(frozen=True)
class RandomFieldSpec:
    """``[random_field]``: one random property (``property`` ... ``data`` here), or several
    cross-correlated ones (``properties``, one :class:`PropertyFieldSpec` each, and the
    correlation matrix ``cross_correlation`` of their standard Gaussian fields, default
    the identity).  The other keys are shared by the properties."""
    property: str = scene_key("cohesion_peak", "the random parameter of the soil's model")
    distribution: str = scene_key("lognormal", "marginal distribution (beta: bounded by low "
                                  "and high)")
    cov: float = scene_key(0.25, "coefficient of variation", "-")
    theta_v: float = scene_key(0.5, "vertical scale of fluctuation", "m")
    anisotropy: float = scene_key(1.0, "xi = theta_h / theta_v", "-")
    correlation: str = scene_key("markov_elliptic", "correlation function")
    layering_angle_deg: float = scene_key(0.0, "angle of the layering to the grid x axis", "deg")
    cell_size: float | None = scene_key(None, "field cell size (default: the grid cell)", "m")
    box: tuple[float, ...] | None = scene_key(
        None, "the field's fixed rectangle [x0, y0, x1, y1] (3-D: box [x0, y0, z0, x1, y1, "
        "z1]), with cell_size (default: the soil cells' bounding box, which moves with the "
        "grid cell)", "m")
    theta_strike: float | None = scene_key(
        None, "3-D: scale of fluctuation along the strike (z) (default: theta_h = anisotropy "
        "x theta_v)", "m")
    local_averaging: bool = scene_key(True, "field values are local averages over the "
                                      "field cells")
    soil: str | None = scene_key(None, "name of the soil the field applies to (default: all)")
    data: str | None = scene_key(None, "CSV of x, y, value to condition on (kriging)")
    low: float | None = scene_key(None, "beta: lower bound", "property's unit")
    high: float | None = scene_key(None, "beta: upper bound", "property's unit")
    properties: tuple[PropertyFieldSpec, ...] = scene_key(
        (), "several cross-correlated properties: one [[random_field.properties]] table each")
    cross_correlation: tuple[tuple[float, ...], ...] = scene_key(
        (), "p x p correlation matrix of the properties' Gaussian fields, rows in the order "
        "of properties (default: the identity)", "-")

    def fields(self) -> tuple["RandomFieldSpec", ...]:
        """One single-property spec per random property, in order: this spec itself
        without ``properties``; else each property's keys over the shared ones."""
        if not self.properties:
            return (self,)
        return tuple(dataclasses.replace(
            self, properties=(), cross_correlation=(),
            **{k: v for k, v in dataclasses.asdict(p).items() if v is not None})
            for p in self.properties)


@dataclass(frozen=True)
class SolverSpec:
    """``[solver]``: the scheme and its time stepping, both schemes' keys in one table."""
    scheme: str = scene_key("explicit", "explicit (numba) or implicit (Newton MPM)")
    shape: str = scene_key("standard", "basis: standard Q4 or gimp (uGIMP)")
    cfl: float = scene_key(0.5, "explicit: dt = cfl * h / (c_p + |v|max)", "-")
    damping: float = scene_key(0.7, "local (Cundall) damping coefficient", "-")
    damping_time: float = scene_key(math.inf, "damping is switched off after this time", "s")
    gravity_ramp_time: float = scene_key(1.0, "gravity grows linearly to full over this time",
                                         "s")
    gravity_phase: str = scene_key("dynamic", "geostatic: in-situ stresses on the fixed "
                                   "geometry first")
    geostatic_time: float = scene_key(20.0, "longest geostatic phase (ends earlier at rest)",
                                      "s")
    t_end: float = scene_key(10.0, "simulated time limit", "s")
    rest_velocity: float = scene_key(1e-3, "at rest when the largest point speed is below "
                                     "this ...", "m/s")
    rest_energy_ratio: float = scene_key(1e-6, "... and the kinetic energy below this "
                                         "fraction of its peak", "-")
    output_interval: float = scene_key(0.5, "time between point snapshots", "s")
    flip: float = scene_key(1.0, "FLIP fraction of the point velocity update (1: FLIP, "
                            "0: PIC)", "-")
    kernel: str = scene_key("numba", "explicit step: numba (compiled) or numpy (reference)")
    threads: int = scene_key(0, "explicit numba step: threads (0: the idle cores, 1 in a "
                             "campaign; any count gives bitwise the same run)")
    edge_policy: str = scene_key("freeze", "a point reaching the grid edge: freeze (kept "
                                 "there, inactive) or stop (the run fails)")
    load_steps: int = scene_key(1, "implicit quasi-static: number of load steps")
    dynamic: bool = scene_key(False, "implicit: Newmark trapezoidal dynamics (else "
                              "quasi-static)")
    dt: float = scene_key(0.05, "implicit dynamic time step", "s")
    max_iterations: int = scene_key(15, "implicit: Newton iterations per step")
    tolerance: float = scene_key(1e-9, "implicit: relative residual of Newton", "-")
    max_cuts: int = scene_key(4, "implicit: step cuts before giving up")
    linear_solver: str = scene_key("cholmod", "implicit: cholmod, superlu or pyamg")
    fbar: bool = scene_key(False, "F-bar locking remedy (cell-averaged volume change)")
    locking_constraint: str = scene_key(
        "volume", "geostatic steps with fbar: volume (B-bar: one volume change per cell) or "
        "pressure (one in-plane mean stress)")
    adaptive: bool = scene_key(True, "implicit: the step size follows Newton and kinematic "
                               "limits")
    dt_max: float = scene_key(0.1, "implicit dynamic: largest adaptive time step", "s")
    max_displacement_fraction: float = scene_key(
        0.5, "implicit dynamic: largest point displacement per step (cells)", "-")
    hht_alpha: float = scene_key(0.0, "implicit dynamic: HHT-alpha numerical damping", "-")
    min_mass_fraction: float = scene_key(
        1e-2, "implicit dynamic: nodal mass floor (fraction of rho A_cell)", "-")


@dataclass(frozen=True)
class MonteCarloSpec:
    """``[montecarlo]``: a campaign of realizations and the measures' thresholds."""
    realizations: int = scene_key(8, "realizations per case")
    seed: int = scene_key(2017, "campaign seed (each realization's seed derives from it)")
    failure_displacement: float = scene_key(
        0.5, "a point displaced more than this counts as sliding", "m")
    failure_area: float = scene_key(
        1.0, "least sliding area that is a failure (a run stopped once decided stops at it; "
        "0: any sliding point)", "m2/m")
    intact_block_area: float = scene_key(1.0, "least area of an intact block (measures)", "m2")
    keep_vtk: int = scene_key(2, "keep the VTK output of the first k realizations")
    factor_of_safety: bool = scene_key(False, "the strength-reduction factor of safety of "
                                       "every realization first")
    runs_to_rest: int | None = scene_key(
        None, "realizations with an index from this on stop once decided (default: every "
        "realization runs to rest)")
    cases: tuple[str, ...] = scene_key(
        (), "variants run side by side: homogeneous, xi=12 or section.key=value")


@dataclass(frozen=True)
class OutputSpec:
    """``[output]``: the files a run writes."""
    vtk: bool = scene_key(True, "write VTK files of the points and the grid")
    png: bool = scene_key(True, "write PNG figures")


@dataclass(frozen=True)
class WaterSpec:
    """``[water]``: a steady phreatic surface and the pore pressure below it (effective
    stress; :mod:`fem_rmpm.scene.water`, :mod:`fem_rmpm.schemes.pore_pressure`).  Where the
    surface lies above the ground it is a free water level loading the soil surface."""
    phreatic_surface: tuple[tuple[float, float], ...] = scene_key(
        doc="polyline [[x, y], ...] in the grid frame, x increasing, spanning the grid's "
        "width (above the ground: a free water level)", unit="m")
    unit_weight: float = scene_key(9.81, "unit weight of the pore water", "kN/m3")
    pore_pressure: str = scene_key(
        "hydrostatic", "hydrostatic (gamma_w x true-vertical depth below the surface) or "
        "parallel_seepage (that times cos^2 of the surface's local true inclination)")


@dataclass(frozen=True)
class Scene:
    scene: SceneInfo
    grid: GridSpec
    boundary: BoundarySpec
    soils: tuple[SoilSpec, ...]
    bedrock: tuple[BedrockSpec, ...] = ()
    prescribed: tuple[PrescribedSpec, ...] = ()
    random_field: RandomFieldSpec | None = None
    solver: SolverSpec = field(default_factory=SolverSpec)
    montecarlo: MonteCarloSpec = field(default_factory=MonteCarloSpec)
    output: OutputSpec = field(default_factory=OutputSpec)
    source: str = "<dict>"
    water: WaterSpec | None = None

    @property
    def gravity_vector(self) -> tuple[float, float]:
        """Gravity in the grid frame (m/s2): grid x axis points down-slope at frame_angle_deg."""
        a = math.radians(self.scene.frame_angle_deg)
        g = self.scene.gravity
        return (g * math.sin(a), -g * math.cos(a))

