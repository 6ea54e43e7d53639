"""Sphinx extension: the package's modules as autodoc reads them.

* A module docstring may have section titles (a line underlined with ``-`` or ``=``),
  which read well in ``help()`` but are not allowed inside an autodoc directive.  Each
  becomes a rubric (a heading that does not enter the table of contents), text unchanged.
* A package may import some public names on first use (a module ``__getattr__``, PEP
  562); autodoc lists only the names already there, so every name of the module's
  ``__all__`` is looked up first.
"""
from __future__ import annotations

import re

_UNDERLINE = re.compile(r"^([-=~^\"'`#*+])\1{2,}\s*$")


def titles_to_rubrics(lines: list[str]) -> None:
    """Replace, in place, ``Title`` / ``-----`` pairs by ``.. rubric:: Title``."""
    out: list[str] = []
    i = 0
    while i < len(lines):
        line = lines[i]
        nxt = lines[i + 1] if i + 1 < len(lines) else ""
        if (line.strip() and not line.startswith(" ") and _UNDERLINE.match(nxt)
                and len(nxt.strip()) >= len(line.strip())):
            out += [f".. rubric:: {line.strip()}", ""]
            i += 2
            continue
        out.append(line)
        i += 1
    lines[:] = out


def process(app, what, name, obj, options, lines) -> None:
    """``autodoc-process-docstring``: runs on a module before its members are listed."""
    if what == "module":
        titles_to_rubrics(lines)
        for public in getattr(obj, "__all__", ()):
            getattr(obj, public, None)          # imports a lazily imported name


def setup(app) -> dict:
    app.connect("autodoc-process-docstring", process)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
