"""Scene specification: the frozen dataclasses a validated scene file becomes.

A scene describes everything one run needs.  Every key carries its unit in its name
or in the comment beside its field.  Units: m, s, kPa (stress, modulus, cohesion),
kN/m3 (unit weight); the density used by the dynamics is ``unit_weight / gravity``
in t/m3.  Reading and validating a TOML file into these classes is
:mod:`fem_rmpm.scene.schema`; changing values of a scene is :mod:`fem_rmpm.scene`
(which re-exports every public name of both).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "SceneError", "Scene", "SceneInfo", "GridSpec", "BoundarySpec", "SoilSpec",
    "BedrockSpec", "PrescribedSpec", "RandomFieldSpec", "PropertyFieldSpec", "SolverSpec",
    "MonteCarloSpec", "OutputSpec",
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


@dataclass(frozen=True)
class SceneInfo:
    name: str = "scene"
    gravity: float = 9.81          # m/s2
    frame_angle_deg: float = 0.0   # angle of the grid x axis below the true horizontal (deg)
    description: str = ""


@dataclass(frozen=True)
class GridSpec:
    origin: tuple[float, float] = (0.0, 0.0)   # m
    size: tuple[float, float] = (1.0, 1.0)     # m
    cell: tuple[float, float] = (0.25, 0.25)   # m
    file: str | None = None                    # quad mesh read by meshio (path relative to scene)


@dataclass(frozen=True)
class BoundarySpec:
    left: str = "roller"
    right: str = "roller"
    bottom: str = "fixed"
    top: str = "free"


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
                "softening_strain")


@dataclass(frozen=True)
class BedrockSpec:
    """A rigid region: every grid node inside or on the polygon is fixed (no particles)."""
    polygon: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class PrescribedSpec:
    """Displacement control of grid nodes (a rigid footing, a moving wall): every grid node
    in or on ``polygon`` gets the displacement ``displacement`` (m) in the components
    ``components`` ("xy": both, e.g. a rough footing; "y" or "x": one, e.g. a smooth
    footing).  The displacement is reached at the end of loading: with implicit
    quasi-static (or geostatic) load steps each step adds its share (the load factor
    increment times ``displacement``).  A component prescribed here wins over a fixed
    or roller boundary.  The reaction (kN per m) of each region is recorded per step."""
    polygon: tuple[tuple[float, float], ...]
    displacement: tuple[float, float]    # m, at load factor 1
    components: str = "xy"
    name: str = "prescribed"


@dataclass(frozen=True)
class PropertyFieldSpec:
    """One ``[[random_field.properties]]`` table: the marginal of one property of the
    field's soils and, where given, its own correlation structure (None: the value of
    ``[random_field]``, shared by the properties)."""
    property: str                        # a parameter of the soil's model, e.g. friction_angle_peak
    distribution: str = "lognormal"      # "normal" | "lognormal" | "beta" (bounded: low, high)
    cov: float = 0.25                    # coefficient of variation (-)
    low: float | None = None             # beta: lower bound (property units)
    high: float | None = None            # beta: upper bound (property units)
    theta_v: float | None = None         # m
    anisotropy: float | None = None      # -
    correlation: str | None = None
    layering_angle_deg: float | None = None
    data: str | None = None              # CSV of x, y, value of this property (kriging)


@dataclass(frozen=True)
class RandomFieldSpec:
    """``[random_field]``: one random property (``property`` ... ``data`` here), or several
    cross-correlated ones (``properties``, one :class:`PropertyFieldSpec` each, and the
    correlation matrix ``cross_correlation`` of their standard Gaussian fields, default
    the identity).  The other keys are shared by the properties."""
    property: str = "cohesion_peak"
    distribution: str = "lognormal"      # "normal" | "lognormal" | "beta" (bounded: low, high)
    cov: float = 0.25                    # coefficient of variation (-)
    theta_v: float = 0.5                 # vertical scale of fluctuation (m)
    anisotropy: float = 1.0              # xi = theta_h / theta_v (-)
    correlation: str = "markov_elliptic"  # "markov_elliptic" | "markov_separable"
    layering_angle_deg: float = 0.0      # angle of the layering to the grid x axis (deg)
    cell_size: float | None = None       # field cell size (m); default: the grid cell
    box: tuple[float, float, float, float] | None = None  # [x0, y0, x1, y1] m, with cell_size:
    # the field's rectangle, fixed (default: the soil cells' bounding box, which moves with
    # the grid cell, so each mesh draws another field from the same seed)
    local_averaging: bool = True
    soil: str | None = None              # name of the soil the field applies to (default: all)
    data: str | None = None              # CSV of x, y, value to condition on (kriging)
    low: float | None = None             # beta: lower bound (property units)
    high: float | None = None            # beta: upper bound (property units)
    properties: tuple[PropertyFieldSpec, ...] = ()
    cross_correlation: tuple[tuple[float, ...], ...] = ()   # p x p, rows in properties' order

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
    scheme: str = "explicit"
    shape: str = "standard"              # "standard" Q4 or "gimp"
    cfl: float = 0.5                     # explicit: dt = cfl * h / (c_p + |v|max)
    damping: float = 0.7                 # local (Cundall) damping coefficient (-)
    damping_time: float = math.inf       # s; damping is switched off after this time
    gravity_ramp_time: float = 1.0       # s; gravity grows linearly to full over this time
    gravity_phase: str = "dynamic"       # "geostatic": in-situ stresses on the fixed geometry first
    geostatic_time: float = 20.0         # s; longest geostatic phase (ends earlier at rest)
    t_end: float = 10.0                  # s; simulated time limit
    rest_velocity: float = 1e-3          # m/s; at rest when max particle speed below this ...
    rest_energy_ratio: float = 1e-6      # ... and kinetic energy below this fraction of its peak
    output_interval: float = 0.5         # s between particle snapshots
    flip: float = 1.0                    # FLIP fraction of the particle velocity update (1 = FLIP,
    #                                      0 = PIC)
    kernel: str = "numba"                # explicit step: "numba" (compiled) | "numpy" (reference)
    threads: int = 0                     # explicit numba step: threads (0: auto = the idle cores,
    #                                      1 in a campaign; any count: bitwise the same run)
    edge_policy: str = "freeze"          # what happens to points reaching the grid edge
    # implicit
    load_steps: int = 1                  # quasi-static: number of load steps
    dynamic: bool = False                # implicit: Newmark trapezoidal dynamics
    #                                      (else quasi-static)
    dt: float = 0.05                     # implicit dynamic time step (s)
    max_iterations: int = 15
    tolerance: float = 1e-9              # relative residual
    max_cuts: int = 4                    # step cuts before giving up
    linear_solver: str = "cholmod"       # "cholmod" | "superlu" | "pyamg" (implicit)
    fbar: bool = False                   # F-bar locking remedy (cell-averaged volume change)
    locking_constraint: str = "volume"   # geostatic steps with fbar: "volume" (B-bar: one volume
    #                                      change per cell) | "pressure" (one in-plane mean stress)
    adaptive: bool = True                # implicit: step size follows Newton and kinematic limits
    dt_max: float = 0.1                  # implicit dynamic: largest adaptive time step (s)
    max_displacement_fraction: float = 0.5   # implicit dynamic: point displacement per step (cells)
    hht_alpha: float = 0.0               # implicit dynamic: HHT-alpha numerical damping, 0 .. 1/3
    min_mass_fraction: float = 1e-2      # implicit dynamic: nodal mass floor
    #                                      (fraction of rho A_cell)


@dataclass(frozen=True)
class MonteCarloSpec:
    realizations: int = 8
    seed: int = 2017
    failure_displacement: float = 0.5    # m; a point with |u| above this counts as sliding
    intact_block_area: float = 1.0       # m2; least area of an intact block (measures)
    keep_vtk: int = 2                    # keep VTK output of the first k realizations
    factor_of_safety: bool = False       # strength-reduction FS of every realization first
    runs_to_rest: int | None = None      # realizations with index >= this stop once decided
    #                                      (fem_rmpm.campaign: "Runs stopped once decided");
    #                                      None: every realization runs to rest
    cases: tuple[str, ...] = ()          # variants run side by side: "homogeneous", "xi=12",
    #                                      "<section.key>=<value>" (fem_rmpm.campaign.parse_case)


@dataclass(frozen=True)
class OutputSpec:
    vtk: bool = True
    png: bool = True


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

    @property
    def gravity_vector(self) -> tuple[float, float]:
        """Gravity in the grid frame (m/s2): grid x axis points down-slope at frame_angle_deg."""
        a = math.radians(self.scene.frame_angle_deg)
        g = self.scene.gravity
        return (g * math.sin(a), -g * math.cos(a))

