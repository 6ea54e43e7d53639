"""Sphinx extension: write ``reference/scene.md`` from the code before the sources are read.

The page is :func:`fem_rmpm.scene.reference.scene_reference`: every scene section and key
with its type, default, unit, allowed values and description, read from the dataclasses,
the value tables and the material models' declared parameters.  It is written only when
its text changed, so an unchanged page is not rebuilt.
"""
from __future__ import annotations

from pathlib import Path

PAGE = Path("reference") / "scene.md"


def write_page(app) -> None:
    """``builder-inited``: write the generated page into the source directory."""
    from fem_rmpm.scene.reference import write_scene_reference
    write_scene_reference(Path(app.srcdir) / PAGE)


def setup(app) -> dict:
    app.connect("builder-inited", write_page)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
