"""HTML pieces of the campaign pages (the report, the mesh-convergence page): escaping,
numbers as the tables print them, figures embedded as ``data:`` URIs, tables, and the
style sheet and the small checking script every page carries."""
from __future__ import annotations

import base64
import html
import math
from pathlib import Path
from typing import Any, Iterable, Sequence

__all__ = ["esc", "num", "html_figure", "html_table", "png_data_uri", "CSS", "SCRIPT"]


def esc(x: Any) -> str:
    """``x`` as HTML text (quotes escaped too)."""
    return html.escape(str(x), quote=True)


def num(x: Any, digits: int = 3) -> str:
    """A number as the tables print it: ``digits`` significant digits, "–" for None,
    yes/no for a flag, anything else escaped."""
    if x is None:
        return "–"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int):
        return str(x)
    try:
        v = float(x)
    except (TypeError, ValueError):
        return esc(x)
    if not math.isfinite(v):
        return esc(v)
    if v != 0 and (abs(v) >= 1e5 or abs(v) < 1e-3):
        return f"{v:.{digits}g}"
    return (f"{v:.{digits}g}" if abs(v) < 1
            else f"{v:.{max(digits - 1, 1)}f}".rstrip("0").rstrip("."))


def png_data_uri(path: Path) -> str:
    """The PNG file ``path`` as a ``data:`` URI (the page needs no other file)."""
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def html_figure(path: Path, caption: str, alt: str) -> str:
    """A ``<figure>`` of the PNG ``path``, embedded, with its caption."""
    return (f'<figure><img src="{png_data_uri(path)}" alt="{esc(alt)}">'
            f"<figcaption>{esc(caption)}</figcaption></figure>")


def html_table(header: Sequence[str], rows: Iterable[Iterable[str]], cls: str = "") -> str:
    """A table of ``header`` and ``rows`` (cells are HTML already), CSS class ``cls``."""
    head = "".join(f"<th>{h}</th>" for h in header)
    head = f"<thead><tr>{head}</tr></thead>" if any(header) else ""
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f'<table class="{cls}">{head}<tbody>{body}</tbody></table>'


CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:2em auto;max-width:1300px;
color:#222;line-height:1.4;padding:0 1em}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:1px solid #ccc;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
td,th{border:1px solid #ccc;padding:.3em .6em;text-align:left;vertical-align:top}
th{background:#f2f2f2}table.kv td:first-child{font-weight:600;white-space:nowrap}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #ddd}
figcaption{font-size:.9em;color:#555}.reps{display:flex;gap:1.5em;flex-wrap:wrap}
.rep{flex:1 1 500px}small{color:#666}code{background:#f4f4f4;padding:0 .2em}
"""

SCRIPT = """
var femRmpmErrors = 0;
window.addEventListener('error', function () {
  femRmpmErrors += 1;
  if (document.body) { document.body.setAttribute('data-errors', String(femRmpmErrors)); }
}, true);
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  document.body.setAttribute('data-images-loaded', ok + '/' + imgs.length);
  document.body.setAttribute('data-errors', String(femRmpmErrors));
});
"""
