"""Material points: seeding in the cells the soil covers, and their state arrays.

A cell belongs to a soil when its centre lies inside the soil polygon; all of
its ``n x n`` points are then seeded

* for the standard Q4 basis at the Gauss-Legendre points of the cell with the
  Gauss weights as volumes (``n = 2``: the 2x2 Gauss points, each with volume
  ``area / 4``), so at t = 0 the MPM integrates exactly like a Q4 finite element
  on the same cells, which is what the FEM comparisons rely on;
* for uGIMP at the centres of ``n x n`` equal sub-cells, whose domains (half
  size ``h / 2n``) tile the cell.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fem_rmpm.discretise.grid import Grid, points_in_polygon
from fem_rmpm.materials import MaterialPoints, cohesion, material_points, new_state
from fem_rmpm.scene import Scene, SceneError
from fem_rmpm.schemes.regularisation import prepare_softening

__all__ = ["Particles", "seed_particles", "density"]


def density(unit_weight: float, gravity: float) -> float:
    """Mass density (t/m3) from unit weight (kN/m3): rho = gamma / g (g = 9.81 if gravity is 0)."""
    return unit_weight / (gravity if gravity > 0 else 9.81)


@dataclass
class Particles:
    """State of n material points (grid frame; m, s, kPa, t)."""
    x: np.ndarray                      # (n, 2) position
    x0: np.ndarray                     # (n, 2) initial position
    velocity: np.ndarray               # (n, 2) m/s
    mass: np.ndarray                   # (n,) t
    volume0: np.ndarray                # (n,) m3 per m (initial)
    volume: np.ndarray                 # (n,) current
    log_strain: np.ndarray             # (n, 4) elastic Hencky strain [xx, yy, zz, xy]
    stress: np.ndarray                 # (n, 4) Cauchy stress [xx, yy, zz, xy] kPa
    state: np.ndarray                  # (n, S) state variables of the material models;
    #                                    column 0: plastic shear strain invariant (-)
    soil: MaterialPoints               # model id and parameter row per point
    soil_id: np.ndarray                # (n,) index into scene.soils
    cell0: np.ndarray                  # (n,) host cell at seeding
    active: np.ndarray                 # (n,) False once frozen at the grid edge
    half_width: np.ndarray = field(default=None)  # (n, 2) particle half-size lp (uGIMP), m
    F: np.ndarray = field(default=None)  # (n, 2, 2) deformation gradient (implicit scheme;
    #                                      the explicit one does not track it: NaN after a run)
    u_geostatic: np.ndarray = field(default=None)  # (n, 2) displacement of the geostatic phase, m

    def __post_init__(self):
        if self.F is None:
            self.F = np.tile(np.eye(2), (len(self.mass), 1, 1))
        if self.u_geostatic is None:
            self.u_geostatic = np.zeros((len(self.mass), 2))

    @property
    def n(self) -> int:
        return len(self.mass)

    @property
    def displacement(self) -> np.ndarray:
        """Total displacement (m): geostatic phase (points fixed) plus motion since."""
        return self.x - self.x0 + self.u_geostatic

    @property
    def plastic_shear_strain(self) -> np.ndarray:
        """(n,) plastic shear strain invariant (-): a view of ``state[:, 0]``."""
        return self.state[:, 0]

    @plastic_shear_strain.setter
    def plastic_shear_strain(self, value: np.ndarray) -> None:
        self.state[:, 0] = value

    @property
    def cohesion(self) -> np.ndarray:
        """Current cohesion c(gamma_p) per point, kPa (inf for elastic points)."""
        return cohesion(self.state, self.soil)

    def copy(self) -> "Particles":
        """A deep copy (the material's arrays too: the explicit time loop reorders them in
        place, :mod:`fem_rmpm.discretise.point_order`)."""
        arrays = {k: (v.copy(order="K") if isinstance(v, np.ndarray) else v)
                  for k, v in self.__dict__.items()}
        arrays["soil"] = self.soil.replace()
        return Particles(**arrays)


def _gauss_1d(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre points and weights on [0, 1]."""
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1), 0.5 * w


def _seeding_1d(n: int, shape: str) -> tuple[np.ndarray, np.ndarray]:
    """Standard Q4: Gauss points (FEM-equal at t = 0).  uGIMP: the centres of n equal
    sub-cells, so the particle domains tile the cell exactly (none sticks out of the soil)."""
    if shape == "gimp":
        return (np.arange(n) + 0.5) / n, np.full(n, 1.0 / n)
    return _gauss_1d(n)


def soil_cells(scene: Scene, grid: Grid) -> np.ndarray:
    """(n_cells,) soil index of each cell (-1: empty); later soils overwrite earlier ones,
    and a cell whose centre is inside a ``[[bedrock]]`` polygon is empty (rigid, no points)."""
    owner = np.full(grid.n_cells, -1)
    centres = grid.cell_centres()
    for k, soil in enumerate(scene.soils):
        owner[points_in_polygon(centres, np.array(soil.polygon))] = k
    for rock in scene.bedrock:
        owner[points_in_polygon(centres, np.array(rock.polygon))] = -1
    return owner


def seed_particles(scene: Scene, grid: Grid) -> Particles:
    """Seed the material points of all soils of a scene on its grid."""
    owner = soil_cells(scene, grid)
    xs, cells, vols, ids, half = [], [], [], [], []
    area = grid.cell[0] * grid.cell[1]
    for k, soil in enumerate(scene.soils):
        c = np.nonzero(owner == k)[0]
        if len(c) == 0:
            raise SceneError(f"{scene.source}: [soil[{k}].polygon] covers no cell centre of the "
                             "grid; allowed: a polygon enclosing at least one cell (m)")
        g, w = _seeding_1d(soil.points_per_cell_dir, scene.solver.shape)
        gx, gy = np.meshgrid(g, g, indexing="xy")
        wx, wy = np.meshgrid(w, w, indexing="xy")
        local = np.stack([gx.ravel(), gy.ravel()], axis=1)          # (q, 2)
        lower = grid.nodes[grid.cells[c, 0]]                        # (nc, 2)
        pts = lower[:, None, :] + local[None] * grid.cell           # (nc, q, 2)
        xs.append(pts.reshape(-1, 2))
        cells.append(np.repeat(c, len(local)))
        vols.append(np.tile((wx * wy).ravel() * area, len(c)))
        ids.append(np.full(len(c) * len(local), k))
        half.append(np.tile(grid.cell / (2 * soil.points_per_cell_dir), (len(c) * len(local), 1)))
    x = np.vstack(xs)
    soil_id = np.concatenate(ids)
    volume = np.concatenate(vols)
    sp = scene.soils
    rho = np.array([density(s.unit_weight, scene.scene.gravity) for s in sp])[soil_id]
    soil = prepare_softening(scene, grid, material_points(sp, soil_id), soil_id)
    n = len(x)
    return Particles(x=x.copy(), x0=x.copy(), velocity=np.zeros((n, 2)), mass=rho * volume,
                     volume0=volume.copy(), volume=volume.copy(), log_strain=np.zeros((n, 4)),
                     stress=np.zeros((n, 4)), state=new_state(soil), soil=soil,
                     soil_id=soil_id, cell0=np.concatenate(cells), active=np.ones(n, dtype=bool),
                     half_width=np.concatenate(half))
