"""Sphinx configuration of the fem_rmpm documentation.

Build (offline: nothing is fetched while building)::

    sphinx-build -W --keep-going -b html docs docs/_build/html

The scene reference (``reference/scene.md``) is generated from the code at every build
by the extension ``_ext/scene_reference.py``.
"""
from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(HERE.parent))          # the package of this checkout

project = "fem_rmpm"
author = "the fem_rmpm developers"
copyright = "the fem_rmpm developers, BSD-3-Clause"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx-mathjax-offline",   # MathJax served from the site itself: equations render offline
    "sphinx.ext.viewcode",
    "docstrings",
    "scene_reference",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
templates_path: list[str] = []

# Markdown pages (MyST): $...$ and $$...$$ maths, amsmath environments, heading anchors
myst_enable_extensions = ["dollarmath", "amsmath"]
myst_heading_anchors = 3

# API reference: the docstrings are reST (``code``, :func:`name`) with numpy-style
# sections in places; napoleon reads those, nothing stricter
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_preserve_defaults = True
napoleon_google_docstring = False
napoleon_numpy_docstring = True
python_use_unqualified_type_names = True
add_module_names = False

html_theme = "furo"
html_title = "fem_rmpm"
html_static_path: list[str] = []
html_show_sourcelink = False
