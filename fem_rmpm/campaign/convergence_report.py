"""The figure and page of a mesh-convergence study (:mod:`fem_rmpm.campaign.convergence`):
``convergence.png`` (P(failure) and the given-failure means against the cell size, per
case) and ``convergence.html`` (one self-contained page: the tables and the figure)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fem_rmpm.campaign.html_parts import esc, html_figure, html_table, num
from fem_rmpm.io.output import _atomic_write_bytes
from fem_rmpm.io.plots import _plt
from fem_rmpm.measures import table

__all__ = ["plot_convergence_mesh", "write_html", "convergence_text"]


def plot_convergence_mesh(path: Path, st: dict) -> Path:
    """Four panels against the cell size (log axis): P(failure) with its Wilson 95 %
    interval, and the given-failure mean ± 1.96 SE of each measure of ``GIVEN_FAILURE``."""
    plt = _plt()
    keys = st["given_failure_measures"]
    fig, axes = plt.subplots(1, 1 + len(keys), figsize=(4.2 * (1 + len(keys)), 3.8))
    for k, c in enumerate(st["cases"]):
        col, dx = f"C{k}", 1.0 + 0.03 * (k - (len(st["cases"]) - 1) / 2)
        h = np.array([m["cell"] for m in c["meshes"]]) * dx
        p = np.array([np.nan if m["p_failure"] is None else m["p_failure"]
                      for m in c["meshes"]])
        w = np.array([m["wilson95"] or [np.nan, np.nan] for m in c["meshes"]], float)
        axes[0].errorbar(h, p, yerr=[p - w[:, 0], w[:, 1] - p], fmt="o-", color=col,
                         capsize=3, label=f"{c['name']} (N = "
                         f"{'/'.join(str(m['n']) for m in c['meshes'])})")
        for ax, key in zip(axes[1:], keys):
            g = [m["given_failure"][key] for m in c["meshes"]]
            y = np.array([np.nan if v["mean"] is None else v["mean"] for v in g])
            e = np.array([np.nan if v["se"] is None else 1.96 * v["se"] for v in g])
            ax.errorbar(h, y, yerr=e, fmt="o-", color=col, capsize=3, label=c["name"])
    axes[0].set_ylabel("P(failure) (Wilson 95 %)")
    axes[0].set_ylim(-0.03, 1.03)
    axes[0].legend(fontsize=7)
    for ax, key in zip(axes[1:], keys):
        ax.set_ylabel(f"given failure: {table.axis_label(key)}")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xticks(st["cells"])
        ax.set_xticklabels([f"{h:g}" for h in st["cells"]])
        ax.minorticks_off()
        ax.set_xlabel("cell size (m)")
        ax.invert_xaxis()
    fig.suptitle("Mesh convergence: the same realizations on every mesh"
                 + ("" if st["paired_fields"] else " (fields NOT paired: no [random_field] box)"),
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _ci(w) -> str:
    return "–" if not w else f"[{num(w[0])}, {num(w[1])}]"


def _tables(st: dict) -> str:
    keys = st["given_failure_measures"]
    rows, prow = [], []
    for c in st["cases"]:
        for m in c["meshes"]:
            g = m["given_failure"]
            rows.append([esc(c["name"]), num(m["cell"]), num(m["n"]), num(m["failures"]),
                         f"{num(m['p_failure'])} ± {num(m['se'])}", _ci(m["wilson95"])]
                        + [f"{num(g[k]['mean'])} ± {num(g[k]['se'])} <small>(n "
                           f"{g[k]['n']})</small>" for k in keys])
        for p in c["pairs"]:
            prow.append([esc(c["name"]), f"{num(p['cells'][0])} / {num(p['cells'][1])}",
                         num(p["n_paired"]),
                         f"{p['fail_first_only']} / {p['fail_second_only']}",
                         num(p["mcnemar_p"]),
                         f"{num(p['paired_difference'])} ± {num(p['paired_se'])}",
                         f"{num(p['p_difference'])} ± {num(p['unpaired_se'])}",
                         num(p["within_2se"])])
    head = (["case", "cell (m)", "N", "failures", "P(failure) ± SE", "Wilson 95 %"]
            + [f"given failure: {esc(table.label(k))} ({esc(table.unit(k))}) mean ± SE"
               for k in keys])
    phead = ("case", "cells (m)", "paired N", "discordant: fail on coarse only / fine only",
             "exact McNemar p", "paired ΔP ± SE", "ΔP ± unpaired SE", "|ΔP| ≤ 2 SE")
    return html_table(head, rows) + "<h2>Paired discordance</h2>" + html_table(phead, prow)


def convergence_text(st: dict) -> str:
    """The paragraph ``fem-rmpm converge`` prints: P(failure) per case and mesh, and the
    discordance of each pair of meshes."""
    lines = []
    for c in st["cases"]:
        ps = ", ".join(f"{m['cell']:g} m: {num(m['p_failure'])} [{_ci(m['wilson95'])[1:-1]}]"
                       f" (N {m['n']})" for m in c["meshes"])
        pr = "; ".join(f"{p['cells'][0]:g}/{p['cells'][1]:g} m: {p['discordant']} discordant "
                       f"of {p['n_paired']} ({p['fail_first_only']}/{p['fail_second_only']}), "
                       f"McNemar p {num(p['mcnemar_p'])}" for p in c["pairs"])
        lines.append(f"{c['name']}: P(failure) {ps}; {pr}")
    return "\n".join(lines)


def write_html(path: Path, st: dict, figure: Path) -> Path:
    """Write the convergence page (atomically) and return its path."""
    note = ("Realization i is the same random field on every mesh (the field's box), so the "
            "meshes are compared pair by pair." if st["paired_fields"] else
            "The scene's random field has no box: the same seed draws unrelated fields on "
            "different meshes, so the pairs are not paired fields; only the unpaired "
            "comparison of P(failure) is meaningful.")
    dirs = " · ".join(f'<a href="{esc(m["directory"])}/report.html">{esc(m["directory"])}</a>'
                      for m in st["meshes"])
    body = ("<h1>Mesh convergence</h1><p>" + esc(note) + " P(failure): Wilson 95 % "
            "interval; given-failure means over the failures run to rest. Discordant pairs: "
            "realizations that fail on one mesh and stand on the other; exact McNemar test "
            "(two-sided binomial, p = 1/2). Campaign of each mesh: " + dirs + "</p>"
            "<h2>P(failure) and given-failure means per mesh</h2>" + _tables(st)
            + (html_figure(figure, "P(failure) and given-failure means against the cell size.",
                       figure.name) if figure.is_file() else ""))
    page = (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>Mesh '
            f"convergence</title><style>body{{font-family:sans-serif;max-width:1300px;"
            f"margin:2em auto}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;"
            f"padding:.3em .6em}}img{{max-width:100%}}</style></head><body>{body}</body>"
            "</html>\n")
    _atomic_write_bytes(path, page.encode("utf-8"))
    return path
