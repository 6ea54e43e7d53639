"""Column under self-weight: closed form vs scikit-fem FEM vs explicit MPM.

Prints the error figures and writes ``validation/out/column_fem_vs_mpm.png`` (sigma_yy
against depth).  Reference: the closed form sigma_yy = -gamma (H - y), K0 = nu/(1-nu),
u_y = -(gamma/M)(H y - y^2/2).  Run: ``python validation/column_fem_vs_mpm.py``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fem_rmpm import api
from fem_rmpm.scene import with_values
from fem_rmpm.schemes.fem import solve_static

HERE = Path(__file__).parent
OUT = HERE / "out"


def rel_l2(a, b, w):
    return float(np.sqrt(np.sum((a - b) ** 2 * w) / np.sum(b ** 2 * w)))


def study(cell: float):
    scene = api.load_scene(HERE.parent / "meshes" / "column.toml")
    scene = with_values(scene, {"grid.cell": [cell, cell], "grid.size": [cell, 5.5],
                                "soil.polygon": [[0, 0], [cell, 0], [cell, 5], [0, 5]]})
    res = api.run(scene)
    p = res.particles
    fem = solve_static(scene, res.grid)
    order = np.lexsort((fem.points[:, 0], fem.points[:, 1]))
    mpm_order = np.lexsort((p.x0[:, 0], p.x0[:, 1]))
    s_fem = fem.stress[order][:, 1]
    s_mpm = p.stress[mpm_order][:, 1]
    y = p.x0[mpm_order][:, 1]
    w = p.volume0[mpm_order]
    exact = -20.0 * (5.0 - y)
    k0 = float(np.sum(p.stress[:, 0] * p.volume0) / np.sum(p.stress[:, 1] * p.volume0))
    row = {"cell": cell, "points": p.n, "steps": res.record.steps,
           "mpm_vs_fem": rel_l2(s_mpm, s_fem, w), "mpm_vs_exact": rel_l2(s_mpm, exact, w),
           "fem_vs_exact": rel_l2(s_fem, exact, w), "k0_error": k0 / (0.33 / 0.67) - 1,
           "settlement_mpm": float(p.displacement[:, 1].min()),
           "settlement_fem": float(fem.displacement[:, 1].min()),
           "wall": res.record.wall_time}
    return row, (y, s_mpm, s_fem, exact)


def main():
    OUT.mkdir(exist_ok=True)
    rows, curves = [], None
    for cell in (0.25, 0.125, 0.0625):
        row, c = study(cell)
        rows.append(row)
        curves = curves or c
    print(f"{'cell m':>7} {'points':>6} {'MPM-FEM':>9} {'MPM-exact':>9} {'FEM-exact':>9} "
          f"{'K0 err':>8} {'u_top MPM':>10} {'u_top FEM':>10} {'wall s':>7}")
    for r in rows:
        print(f"{r['cell']:7.4f} {r['points']:6d} {r['mpm_vs_fem']:9.2e} {r['mpm_vs_exact']:9.2e} "
              f"{r['fem_vs_exact']:9.2e} {r['k0_error']:8.1e} {r['settlement_mpm']:10.5f} "
              f"{r['settlement_fem']:10.5f} {r['wall']:7.2f}")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    y, s_mpm, s_fem, exact = curves
    fig, ax = plt.subplots(figsize=(5, 6))
    ax.plot(exact, y, "k-", label="closed form -gamma (H - y)")
    ax.plot(s_fem, y, "bs", mfc="none", label="scikit-fem Q4 (Gauss points)")
    ax.plot(s_mpm, y, "r.", label="explicit MPM at rest")
    ax.set_xlabel("sigma_yy (kPa)")
    ax.set_ylabel("initial height y (m)")
    ax.set_title("Column under self-weight, 0.25 m cells")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(OUT / "column_fem_vs_mpm.png", dpi=120)
    print(f"wrote {OUT / 'column_fem_vs_mpm.png'}")


if __name__ == "__main__":
    main()
