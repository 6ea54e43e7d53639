"""Drained infinite slope with water: strength-reduction FS against the closed forms.

Cases on ``meshes/infinite_slope_water.toml`` (b = 30 deg, H = 5 m, c' = 8 kPa,
phi' = 26 deg, gamma = 18, gamma_sat = 20, gamma_w = 9.81 kN/m3): a water table parallel
to the slope at m = 0.5 and 1 (and 0.25 hydrostatic) with ``"hydrostatic"`` and
``"parallel_seepage"`` pore pressure, dry (m = 0), and the slope fully submerged below a
horizontal free water level;
``h1-strong``: m = 1 hydrostatic with c' = 30 kPa, phi' = psi = 35 deg (FS > 1).
Closed forms: the scene's header (limit equilibrium on the slope-parallel plane; the
collapse load of an associated-flow layer).  A trial F < 1 raises c and phi; the soil,
declared with psi = phi, stays associated at every trial (the strength reduction's
rule).  The table gives phi_F at the closed form's FS and the Davis (1968) estimate of
the collapse had psi stayed at its declared value (c*, phi* of :func:`davis_fs`).  "band h/2
up": the closed form on the plane half a cell row above the bedrock, where a
displacement-based mesh puts the shear band (:func:`band_depth`).  Prints a markdown table
(FS bracketed to 0.5 %) and writes it as JSON to ``--out``.

    python validation/water_infinite_slope.py [--cases a,b] [--out water_fs.json]
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

from fem_rmpm import api
from fem_rmpm.scene import load_scene, with_values

SCENE = Path(__file__).parents[1] / "meshes" / "infinite_slope_water.toml"
B, H, C, PHI, G, GSAT, GW = 30.0, 5.0, 8.0, 26.0, 18.0, 20.0, 9.81


def slip_plane_stresses(m: float | None, mode: str, depth: float = H) -> tuple[float, float]:
    """(sigma'_n, tau) on the slope-parallel plane at true-vertical ``depth`` (m) below
    the ground, kPa (compression positive); the slip plane (bedrock) at depth H.  u
    depends on the normal coordinate only (the phreatic line is parallel to the slope, or
    horizontal over a submerged slope), so the water's side forces on a slice cancel."""
    b = math.radians(B)
    if m is None:
        W = (GSAT - GW) * depth
        return W * math.cos(b) ** 2, W * math.sin(b) * math.cos(b)
    wet = max(0.0, depth - (1 - m) * H)                 # water table (1 - m) H deep
    W = G * (depth - wet) + GSAT * wet
    u = GW * wet * (1.0 if mode == "hydrostatic" else math.cos(b) ** 2)
    return W * math.cos(b) ** 2 - u, W * math.sin(b) * math.cos(b)


def closed_form(m: float | None, mode: str, c: float = C, phi: float = PHI,
                depth: float = H) -> float:
    """FS of the infinite slope (c' kPa, phi' deg) on the plane at ``depth`` (m, the
    bedrock by default); ``m`` None: fully submerged.  At the bedrock it is the scene
    header's forms: tau = (c' + sigma'_n tan phi') / FS."""
    sig, tau = slip_plane_stresses(m, mode, depth)
    return (c + sig * math.tan(math.radians(phi))) / tau


def davis_fs(m: float | None, mode: str, c: float = C, phi: float = PHI,
             psi: float = PHI) -> float:
    """FS with the trial soil's non-associated flow accounted for by Davis's reduced
    strengths (Davis 1968, "Theories of plasticity and the failure of soil masses", in
    Lee (ed.) Soil Mechanics: Selected Topics; Drescher & Detournay 1993, Geotechnique
    43(3), for translational mechanisms of non-associative materials): at a trial F,
    c_F = c / F, tan phi_F = tan phi / F, psi_F = min(psi, phi_F),
    k = cos psi_F / (1 - sin psi_F sin phi_F), c* = k c_F cos phi_F,
    tan phi* = k sin phi_F; FS solves tau = c* + sigma'_n tan phi*.  Equals
    :func:`closed_form` when psi_F = phi_F (every F >= 1 with psi = phi)."""
    sig, tau = slip_plane_stresses(m, mode)

    def excess(F: float) -> float:
        pf = math.atan(math.tan(math.radians(phi)) / F)
        ps = min(math.radians(psi), pf)
        k = math.cos(ps) / (1.0 - math.sin(ps) * math.sin(pf))
        return k * (c / F) * math.cos(pf) + sig * k * math.sin(pf) - tau
    lo, hi = 0.01, 100.0                   # excess > 0 at lo, < 0 at hi: bisect in ln F
    for _ in range(200):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if excess(mid) > 0 else (lo, mid)
    return math.sqrt(lo * hi)


def case_scene(m: float | None, mode: str, c: float = C, phi: float = PHI):
    """The scene of one case: the water table at m H cos(b) in the frame, or (None) a
    horizontal free water level 1 m above the slope's highest point; the layer's c'
    (kPa) and every soil's phi' = psi (deg) as given (the scene's own by default)."""
    s = load_scene(SCENE)
    if (c, phi) != (C, PHI):
        s = with_values(s, {"soil[0].cohesion_peak": c, "soil[0].cohesion_residual": c,
                            **{f"soil.{k}_{stage}": phi for k in ("friction_angle",
                               "dilation_angle") for stage in ("peak", "residual")}})
    L, t = s.grid.size[0], H * math.cos(math.radians(B))
    b = math.radians(B)
    if m is None:       # true-horizontal level Y = t cos(b) + 1 m (the top corner x = 0
        Y = t * math.cos(b) + 1.0       # is highest): in the frame y = (Y + x sin b) / cos b
        line = [[0.0, Y / math.cos(b)], [L, (Y + L * math.sin(b)) / math.cos(b)]]
    elif m == 0:
        return with_values(s, {"water.phreatic_surface": [[0.0, -1.0], [L, -1.0]]})
    else:
        line = [[0.0, m * t], [L, m * t]]
    return with_values(s, {"water.phreatic_surface": line, "water.pore_pressure": mode})


def band_depth(scene) -> float:
    """True-vertical depth (m) of a shear band half a cell row above the bedrock (a
    displacement-based mesh cannot place it lower; the strength reduction's docstring):
    H - (h / 2) / cos b, h the cell height normal to the slope."""
    return H - 0.5 * scene.grid.cell[1] / math.cos(math.radians(B))


#: name: (m, pore pressure, c' kPa, phi' = psi deg)
CASES = {"dry": (0.0, "hydrostatic", C, PHI), "h0.25": (0.25, "hydrostatic", C, PHI),
         "h0.5": (0.5, "hydrostatic", C, PHI),
         "h1": (1.0, "hydrostatic", C, PHI), "p0.5": (0.5, "parallel_seepage", C, PHI),
         "p1": (1.0, "parallel_seepage", C, PHI), "submerged": (None, "hydrostatic", C, PHI),
         "h1-strong": (1.0, "hydrostatic", 30.0, 35.0)}


def run_case(name: str, tolerance: float = 0.005) -> dict:
    m, mode, c, phi = CASES[name]
    scene = case_scene(m, mode, c, phi)
    t0 = time.process_time()
    res = api.factor_of_safety(scene, tolerance=tolerance)
    ref = closed_form(m, mode, c, phi)
    phi_f = math.degrees(math.atan(math.tan(math.radians(phi)) / ref))
    band = closed_form(m, mode, c, phi, band_depth(scene))
    return {"case": name, "m": m, "pore_pressure": mode, "c": c, "phi": phi, "fs": res.fs,
            "closed_form": ref, "error": res.fs / ref - 1, "phi_at_fs": phi_f,
            "band_closed_form": band, "band_error": res.fs / band - 1,
            "davis": davis_fs(m, mode, c, phi, phi), "cpu_s": time.process_time() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--out", default=None)
    ap.add_argument("--tolerance", type=float, default=0.005, help="FS bracket width")
    args = ap.parse_args()
    rows = []
    print("| case | m | pore pressure | c', phi' = psi | FS | closed form | error | "
          "band h/2 up | error | phi_F at FS | Davis | CPU s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name in args.cases.split(","):
        r = run_case(name, args.tolerance)
        rows.append(r)
        print(f"| {r['case']} | {r['m']} | {r['pore_pressure']} | {r['c']:g}, {r['phi']:g} | "
              f"{r['fs']:.4f} | {r['closed_form']:.4f} | {100 * r['error']:+.2f} % | "
              f"{r['band_closed_form']:.4f} | {100 * r['band_error']:+.2f} % | "
              f"{r['phi_at_fs']:.1f} | {r['davis']:.4f} | {r['cpu_s']:.0f} |", flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
