"""Material points of a three-dimensional scene: 2 x 2 x 2 (``points_per_cell_dir`` cubed)
points at the Gauss-Legendre points of each soil cell of the hexahedral grid, with the
Gauss weights times the cell volume as their volumes, so that at t = 0 the MPM integrates
like a trilinear hexahedral finite element on the same cells (the FEM reference's
quadrature, :mod:`fem_rmpm.schemes.fem3d`).  Stress and strain are six components
``[xx, yy, zz, xy, yz, xz]``."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fem_rmpm.discretise.grid3d import Grid3D, soil_cells_3d
from fem_rmpm.discretise.points import _gauss_1d, density
from fem_rmpm.materials import MaterialPoints, cohesion, material_points, new_state
from fem_rmpm.scene import Scene, SceneError

__all__ = ["Particles3D", "seed_particles_3d", "MODEL_NUMBERS_3D"]

#: The 3-D step's number of each material model it updates: the ``MODEL_*`` constants of
#: :mod:`fem_rmpm.schemes.explicit3d.plastic` (which this layer does not import: the
#: scheme's package imports the points).
MODEL_NUMBERS_3D = {"linear_elastic": 0, "von_mises_softening": 1,
                    "mohr_coulomb_softening": 2}


@dataclass
class Particles3D:
    """State of n material points in 3-D (m, s, kPa, t)."""
    x: np.ndarray                      # (n, 3) position
    x0: np.ndarray                     # (n, 3) initial position
    velocity: np.ndarray               # (n, 3) m/s
    mass: np.ndarray                   # (n,) t
    volume0: np.ndarray                # (n,) m3 (initial)
    volume: np.ndarray                 # (n,) m3
    log_strain: np.ndarray             # (n, 6) elastic Hencky strain (tensor shear)
    stress: np.ndarray                 # (n, 6) Cauchy stress [xx, yy, zz, xy, yz, xz] kPa
    state: np.ndarray                  # (n, S) model state; column 0: plastic shear strain
    soil: MaterialPoints               # model id and parameter row per point
    soil_id: np.ndarray                # (n,) index into scene.soils
    cell0: np.ndarray                  # (n,) host cell at seeding
    active: np.ndarray                 # (n,) False once frozen at the grid edge
    lame: np.ndarray                   # (n, 2) Lame constants lambda, mu (kPa)
    model: np.ndarray                  # (n,) 0 linear elastic, 1 von Mises softening,
    #                                    2 Mohr-Coulomb softening (explicit3d.plastic)
    plastic: np.ndarray                # (n, P - 2) the 2-D parameter row without G and K:
    #                                    von Mises c_p, c_r (kPa), softening strain,
    #                                    exponential (1) or linear (0), ...; Mohr-Coulomb
    #                                    c_p, c_r (kPa), phi_p, phi_r, psi_p, psi_r (deg),
    #                                    softening strain, law, tension cut-off (kPa)
    u_geostatic: np.ndarray            # (n, 3) displacement of the geostatic phase, m

    @property
    def n(self) -> int:
        return len(self.mass)

    @property
    def displacement(self) -> np.ndarray:
        """Total displacement (m): geostatic phase plus motion since."""
        return self.x - self.x0 + self.u_geostatic

    @property
    def plastic_shear_strain(self) -> np.ndarray:
        return self.state[:, 0]

    @property
    def cohesion(self) -> np.ndarray:
        return cohesion(self.state, self.soil)


def seed_particles_3d(scene: Scene, grid: Grid3D) -> Particles3D:
    """Seed the points of every soil of a three-dimensional scene on its grid."""
    owner = soil_cells_3d(scene, grid)
    xs, cells, vols, ids = [], [], [], []
    cell_volume = float(np.prod(grid.cell))
    for k, soil in enumerate(scene.soils):
        c = np.nonzero(owner == k)[0]
        if len(c) == 0:
            raise SceneError(f"{scene.source}: [soil[{k}].polygon] covers no cell centre of the "
                             "grid (section, strike and plan); allowed: a soil enclosing at "
                             "least one cell (m)")
        g, w = _gauss_1d(soil.points_per_cell_dir)
        gz, gy, gx = np.meshgrid(g, g, g, indexing="ij")
        wz, wy, wx = np.meshgrid(w, w, w, indexing="ij")
        local = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)     # (q, 3)
        lower = grid.cell_centres(c) - 0.5 * grid.cell                     # (nc, 3)
        xs.append((lower[:, None, :] + local[None] * grid.cell).reshape(-1, 3))
        cells.append(np.repeat(c, len(local)))
        vols.append(np.tile((wx * wy * wz).ravel() * cell_volume, len(c)))
        ids.append(np.full(len(c) * len(local), k))
    x = np.vstack(xs)
    soil_id = np.concatenate(ids)
    volume = np.concatenate(vols)
    sp = scene.soils
    rho = np.array([density(s.unit_weight, scene.scene.gravity) for s in sp])[soil_id]
    E = np.array([s.youngs_modulus for s in sp])[soil_id]
    nu = np.array([s.poisson_ratio for s in sp])[soil_id]
    lame = np.stack([E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))], axis=1)
    soil = material_points(sp, soil_id)
    model = np.array([MODEL_NUMBERS_3D[s.model] for s in sp])[soil_id]
    plastic = _plastic_rows(soil)
    n = len(x)
    return Particles3D(x=x.copy(), x0=x.copy(), velocity=np.zeros((n, 3)), mass=rho * volume,
                       volume0=volume.copy(), volume=volume.copy(),
                       log_strain=np.zeros((n, 6)), stress=np.zeros((n, 6)),
                       state=new_state(soil), soil=soil, soil_id=soil_id,
                       cell0=np.concatenate(cells), active=np.ones(n, dtype=bool),
                       lame=lame, model=model.astype(np.int64), plastic=plastic,
                       u_geostatic=np.zeros((n, 3)))


def _plastic_rows(soil) -> np.ndarray:
    """The points' parameter rows for the 3-D returns (:mod:`fem_rmpm.schemes.explicit3d.
    plastic`): the 2-D rows of :func:`fem_rmpm.materials.material_points` without the
    moduli G and K (the step carries Lame's constants), row-major, at least four columns
    (a linear elastic scene's rows are NaN: its points never read them)."""
    rows = soil.params[:, 2:]
    if rows.shape[1] < 4:
        rows = np.hstack([rows, np.full((len(rows), 4 - rows.shape[1]), np.nan)])
    return np.ascontiguousarray(rows, dtype=float)
