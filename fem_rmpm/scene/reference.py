"""The scene reference: every section and key a scene file accepts, written as Markdown
from the code that reads the file, so that the two cannot differ.

What each row says comes from where the key is declared:

* the sections and their order: ``_SECTIONS`` of :mod:`fem_rmpm.scene.schema`;
* a key's type and default: its dataclass field in :mod:`fem_rmpm.scene.spec`; its unit
  and description: the field's metadata (:func:`~fem_rmpm.scene.spec.scene_key`), or
  else the comment beside the field in the source;
* its range or choices: the tables of :mod:`fem_rmpm.scene.values`;
* the keys of a ``[[soil]]`` that belong to its material model: the model's declared
  ``PARAMETERS`` (:mod:`fem_rmpm.materials.protocol`), one table per registered model.

The documentation's Sphinx extension (``docs/_ext/scene_reference.py``) writes
:func:`scene_reference` to ``docs/reference/scene.md`` at every build.
"""
from __future__ import annotations

import ast
import dataclasses
import inspect
import io
import math
import re
import textwrap
import tokenize
from pathlib import Path
from typing import Any

from fem_rmpm import materials
from fem_rmpm.scene.fields import _PER_PROPERTY
from fem_rmpm.scene.schema import _LISTS, _SECTIONS
from fem_rmpm.scene.spec import PropertyFieldSpec, RandomFieldSpec, SoilSpec
from fem_rmpm.scene.values import _CHOICES, _INFINITE_OK, _RANGES

__all__ = ["scene_reference", "write_scene_reference"]

COLUMNS = ("key", "type", "default", "unit", "allowed", "description")

_TYPES = {
    "float": "number", "float|None": "number", "int": "integer", "int|None": "integer",
    "bool": "boolean", "str": "string", "str|None": "string",
    "tuple[str,...]": "list of strings", "tuple[float,float]": "[x, y]",
    "tuple[float,float,float,float]|None": "[x0, y0, x1, y1]",
    "tuple[tuple[float,float],...]": "list of [x, y]",
    "tuple[float,...]": "[x, y] or [x, y, z]", "tuple[float,float]|None": "[z0, z1]",
    "tuple[tuple[float,float],...]|None": "list of [x, z]",
    "tuple[PropertyFieldSpec,...]": "array of tables",
    "tuple[tuple[float,...],...]": "list of rows of numbers",
}

#: units a field comment may start with (see :func:`_unit_first`)
_UNITS = ("m", "s", "kPa", "kN/m3", "deg", "-", "m/s", "m/s2", "m2")

_INTRO = """\
# Scene files

A scene is a TOML file (see `meshes/*.toml`) with the sections below; every key not
given takes its default, and a key marked *required* must be given.  Unknown sections
and keys, values of the wrong type and values out of range are refused with a one-line
error naming the file, the key and what is allowed.  Units: m, s, kPa (stress, modulus,
cohesion), kN/m3 (unit weight), deg (angles); "-" is dimensionless.  `[[name]]` is an
array of tables: the section may be given several times.

This page is generated from the code that reads the scene files
(`fem_rmpm.scene.reference`), each time the documentation is built.
"""


# ------------------------------------------------------------------------- cell text

def _number(x: float) -> str:
    """A bound or default as written in TOML: integers plainly, infinities as ``inf``."""
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    if x == 2**63 - 1:
        return "2^63 - 1"
    if float(x).is_integer() and abs(x) < 1e7:
        return str(int(x))
    return f"{x:g}"


def _value(v: Any) -> str:
    """A default value as a TOML literal (in a code span); ``None``: not set."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "not set"
    if isinstance(v, bool):
        text = "true" if v else "false"
    elif isinstance(v, (int, float)):
        text = _number(v)
    elif isinstance(v, str):
        text = f'"{v}"'
    elif isinstance(v, tuple):
        text = "[" + ", ".join(_value(x).strip("`") for x in v) + "]"
    else:
        text = str(v)
    return f"`{text}`"


def _interval(lo: float, hi: float, lo_in: bool, hi_in: bool) -> str:
    return ("[" if lo_in else "(") + f"{_number(lo)}, {_number(hi)}" + ("]" if hi_in else ")")


def _choices(options) -> str:
    return " or ".join(f'`"{c}"`' for c in options)


def _cell(text: str) -> str:
    """Text safe in a Markdown table cell: pipes escaped, reST roles as code spans."""
    text = re.sub(r":\w+:`~?([^`]+)`", r"`\1`", text)
    return " ".join(text.split()).replace("|", "\\|")


def _row(cells) -> str:
    return "| " + " | ".join(_cell(c) for c in cells) + " |"


def _table(rows: list[tuple[str, ...]]) -> list[str]:
    return [_row(COLUMNS), "|" + "---|" * len(COLUMNS)] + [_row(r) for r in rows]


# ------------------------------------------------------------------- section keys

def _comments(cls: type) -> dict[str, str]:
    """``{field: comment}`` of the comments beside the fields of dataclass ``cls`` in its
    source (a comment-only line under a field continues its comment): the description of
    a field declared without :func:`~fem_rmpm.scene.spec.scene_key`."""
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    at_line = {n.lineno: n.target.id for n in ast.parse(source).body[0].body
               if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name)}
    out: dict[str, str] = {}
    current = None
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        line = tok.start[0]
        if tok.type == tokenize.NAME and line in at_line:
            current = at_line[line]
        elif tok.type == tokenize.COMMENT and current is not None:
            text = tok.string.lstrip("#").strip()
            out[current] = f"{out[current]} {text}" if current in out else text
        elif tok.type not in (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE,
                              tokenize.INDENT, tokenize.DEDENT) and line not in at_line:
            current = None
    return out


def _allowed(key: str, f: dataclasses.Field) -> str:
    """The range or choices of scene key ``key`` (``section.name``)."""
    if key in _CHOICES:
        return _choices(_CHOICES[key])
    if key == "soil.model":
        return _choices(materials.names())
    if key in _RANGES:
        text = _interval(*_RANGES[key])
        return text + (", or `inf`" if key in _INFINITE_OK else "")
    if key in _INFINITE_OK:
        return "a number, or `inf`"
    if key.endswith(".property"):
        return "one of " + ", ".join(f"`{p}`" for p in random_properties())
    return ""


def _field_row(section: str, f: dataclasses.Field, comments: dict[str, str]) -> tuple:
    """The row of one dataclass field of ``[section]``."""
    ann = str(f.type).replace(" ", "")
    if f.default is not dataclasses.MISSING:
        default = _value(f.default)
    elif f.default_factory is not dataclasses.MISSING:
        default = _value(f.default_factory())
    else:
        default = "*required*"
    unit, doc = f.metadata.get("unit", ""), f.metadata.get("doc", "")
    if not doc:
        unit, doc = _unit_first(comments.get(f.name, ""))
    return (f"`{f.name}`", _TYPES.get(ann, ann), default, unit,
            _allowed(f"{section}.{f.name}", f), doc)


def _unit_first(comment: str) -> tuple[str, str]:
    """``(unit, description)`` of a field comment that starts with its unit
    (``"kPa (undrained shear strength)"``), else ``("", comment)``."""
    first, _, rest = comment.partition(" ")
    if first.rstrip(";,") in _UNITS:
        return first.rstrip(";,"), rest.strip().removeprefix("(").removesuffix(")")
    return "", comment


def _intro(cls: type) -> list[str]:
    """The first paragraph of a section class's docstring, without a leading
    ``[section]:`` (the heading says it); none for a class without a docstring."""
    doc = inspect.getdoc(cls) or ""
    if doc.startswith(cls.__name__ + "("):         # the dataclass's generated signature
        return []
    first = re.sub(r"^``\[[\w.]+\]``: *", "", doc.split("\n\n")[0])
    return [_cell(first[:1].upper() + first[1:]).replace("\\|", "|"), ""] if first else []


def _section(section: str, cls: type, skip: tuple[str, ...] = ()) -> list[str]:
    comments = _comments(cls)
    rows = [_field_row(section, f, comments) for f in dataclasses.fields(cls)
            if f.name not in skip]
    return _intro(cls) + _table(rows) + [""]


# ---------------------------------------------------------------- material models

def random_properties() -> list[str]:
    """The parameters a random field may draw: numeric, not a residual (which follows its
    peak), of some registered model (:mod:`fem_rmpm.scene.fields` checks the soil's)."""
    out: list[str] = []
    for m in materials.models():
        out += [p.name for p in m.PARAMETERS if not p.choices
                and not p.name.endswith("_residual") and p.name not in out]
    return out


def _parameter_row(p) -> tuple:
    """The row of a material model's declared parameter."""
    if p.choices:
        allowed = _choices(p.choices)
    else:
        allowed = _interval(p.low, p.high, p.low_inclusive, p.high_inclusive)
        allowed += ", or `inf`" if p.allow_inf and not math.isinf(p.high) else ""
    kind = "string" if p.choices else "number"
    default = "*required*" if p.default is None else _value(p.default)
    return (f"`{p.name}`", kind, default, p.unit, allowed, p.description)


def _soil() -> list[str]:
    """``[[soil]]``: the keys of every soil, then one table per registered model."""
    declared = {p.name for m in materials.models() for p in m.PARAMETERS}
    common = tuple(f.name for f in dataclasses.fields(SoilSpec)
                   if f.name in declared or f.name == "parameters")
    lines = ["One table per soil region: the keys of every soil, then those of its "
             "material model (`model`), declared by the model itself.", ""]
    lines += _section("soil", SoilSpec, skip=common)[len(_intro(SoilSpec)):]
    for m in materials.models():
        lines += [f'### [[soil]] model = "{m.NAME}"', ""]
        doc = (m.__doc__ or "").strip().split("\n\n")[0]
        if doc:
            lines += [_cell(doc).replace("\\|", "|"), ""]
        if m.PARAMETERS:
            lines += _table([_parameter_row(p) for p in m.PARAMETERS]) + [""]
        else:
            lines += ["No keys of its own.", ""]
    return lines


# ----------------------------------------------------------------------- the page

def _heading(section: str) -> str:
    return f"## [[{section}]]" if section in _LISTS else f"## [{section}]"


def _random_field() -> list[str]:
    """``[random_field]`` and its ``[[random_field.properties]]`` tables."""
    lines = _section("random_field", RandomFieldSpec)
    lines += ["## [[random_field.properties]]", ""] + _intro(PropertyFieldSpec)
    lines += ["The keys " + ", ".join(f"`{k}`" for k in _PER_PROPERTY) + " of one property "
              "go in these tables when there are several properties, not in "
              "`[random_field]`; the other keys here, when given, replace the shared ones "
              "of `[random_field]` for that property.", ""]
    return lines + _section("random_field.properties", PropertyFieldSpec)[
        len(_intro(PropertyFieldSpec)):]


def scene_reference() -> str:
    """The reference of every scene section and key, as one Markdown page."""
    lines = [_INTRO]
    for section, cls in _SECTIONS.items():
        lines += [_heading(section), ""]
        if section == "soil":
            lines += _soil()
        elif section == "random_field":
            lines += _random_field()
        else:
            lines += _section(section, cls)
    return "\n".join(lines).rstrip() + "\n"


def write_scene_reference(path: str | Path) -> bool:
    """Write :func:`scene_reference` to ``path`` unless it already holds that text
    (so that Sphinx rebuilds the page only when it changed); True if written."""
    path = Path(path)
    text = scene_reference()
    if path.exists() and path.read_text(encoding="utf-8") == text:
        return False
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return True
