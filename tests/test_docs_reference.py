"""The generated scene reference names every key a scene file accepts.

The keys are read from the schema itself (the dataclass fields of every section of
``fem_rmpm.scene.schema._SECTIONS``, the declared ``PARAMETERS`` of every registered
material model, the tables of ``[[random_field.properties]]``) and looked up as rows of
the Markdown page :func:`fem_rmpm.scene.reference.scene_reference` writes; the check is
shown to fail on a page without a key, and the page to follow a key added to the schema.
"""
from __future__ import annotations

import dataclasses
import re

from fem_rmpm import materials
from fem_rmpm.scene import reference, schema
from fem_rmpm.scene.reference import scene_reference, write_scene_reference
from fem_rmpm.scene.spec import PropertyFieldSpec, SoilSpec, scene_key


def accepted_keys() -> set[str]:
    """Every key the schema accepts, as ``section.key`` (``soil[model].key`` for the
    keys of a material model)."""
    keys = set()
    for section, cls in schema._SECTIONS.items():
        if section == "soil":
            continue
        keys |= {f"{section}.{f.name}" for f in dataclasses.fields(cls)}
    keys |= {f"random_field.properties.{f.name}" for f in dataclasses.fields(PropertyFieldSpec)}
    declared = set()
    for m in materials.models():
        keys |= {f"soil[{m.NAME}].{p.name}" for p in m.PARAMETERS}
        declared |= {p.name for p in m.PARAMETERS}
    keys |= {f"soil.{f.name}" for f in dataclasses.fields(SoilSpec)
             if f.name not in declared and f.name != "parameters"}
    return keys


def documented_keys(page: str) -> set[str]:
    """The keys of the rows of the page's tables, qualified by the heading above them
    (``## [section]``, ``## [[section]]``, ``### [[soil]] model = "name"``)."""
    out, where = set(), None
    for line in page.splitlines():
        if line.startswith("#"):
            section = re.search(r"\[\[?([\w.]+)\]\]?", line)
            model = re.search(r'model = "(\w+)"', line)
            if section:
                where = f"{section.group(1)}[{model.group(1)}]" if model else section.group(1)
        elif (row := re.match(r"\| `(\w+)` \|", line)) and where:
            out.add(f"{where}.{row.group(1)}")
    return out


def missing_keys(page: str) -> list[str]:
    return sorted(accepted_keys() - documented_keys(page))


def test_every_accepted_key_is_in_the_reference():
    page = scene_reference()
    assert not missing_keys(page), missing_keys(page)
    assert len(accepted_keys()) > 80
    for section in schema._SECTIONS:
        assert f"[{section}]" in page
    rows = {m.group(1): m.group(0) for m in re.finditer(r"\| `(\w+)` \|.*", page)}
    assert "[0, 1]" in rows["flip"] and "`1`" in rows["flip"]         # range, default
    assert '`"explicit"` or `"implicit"`' in rows["scheme"]           # choices
    assert "\\|v\\|" in rows["cfl"]                                    # pipes escaped


def test_the_check_finds_a_missing_key():
    """The check can fail: a page without the row of ``solver.cfl`` (or of a model's
    parameter) is missing exactly that key."""
    page = scene_reference()
    without = "\n".join(line for line in page.splitlines() if not line.startswith("| `cfl`"))
    assert missing_keys(without) == ["solver.cfl"]
    mc = re.sub(r"\| `tension_cutoff` \|.*\n", "", page)
    assert missing_keys(mc) == ["soil[mohr_coulomb_softening].tension_cutoff"]


def test_a_key_added_to_the_schema_appears_in_the_reference(monkeypatch):
    """A new key (a field of a section's dataclass) is missing from the old page and
    present in the page generated afterwards, with its unit and description."""
    old = scene_reference()

    @dataclasses.dataclass(frozen=True)
    class FakeSpec:
        fake_key: float = scene_key(1.5, "a key made for this test", "kPa")

    monkeypatch.setitem(schema._SECTIONS, "fake_section", FakeSpec)
    assert missing_keys(old) == ["fake_section.fake_key"]
    new = scene_reference()
    assert missing_keys(new) == []
    assert "| `fake_key` | number | `1.5` | kPa |  | a key made for this test |" in new


def test_field_comments_give_a_description_without_metadata():
    """A field declared without ``scene_key`` is described by the comment beside it, a
    leading unit taken as its unit (how ``[[soil]]``'s own keys are written)."""
    comments = reference._comments(SoilSpec)
    assert comments["youngs_modulus"] == "kPa"
    assert reference._unit_first("kPa (undrained shear strength)") == \
        ("kPa", "undrained shear strength")
    assert reference._unit_first("name of the soil") == ("", "name of the soil")


def test_the_page_is_written_only_when_it_changed(tmp_path):
    page = tmp_path / "reference" / "scene.md"
    assert write_scene_reference(page) is True
    assert page.read_text(encoding="utf-8") == scene_reference()
    assert write_scene_reference(page) is False
