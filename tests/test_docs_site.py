"""The documentation site's sources, checked without building it (``.ci/run`` builds it
with ``sphinx-build -W``): the build fetches nothing, the front page's table of contents
names the site's parts, and every object the API reference documents exists."""
from __future__ import annotations

import importlib
import re
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"
PARTS = ["guide/index", "method/index", "validation/index", "benchmarks/index",
         "reference/index"]


def _toctree_entries(page: Path) -> list[str]:
    """The entries of the ``{toctree}`` blocks of a Markdown page, in order."""
    out = []
    for block in re.findall(r"```\{toctree\}\n(.*?)```", page.read_text(encoding="utf-8"), re.S):
        out += [ln.strip() for ln in block.splitlines()
                if ln.strip() and not ln.strip().startswith(":")]
    return out


def test_the_build_fetches_nothing():
    """No intersphinx and no address in the configuration: the build runs offline."""
    conf = (DOCS / "conf.py").read_text(encoding="utf-8")
    assert "intersphinx" not in conf
    assert not re.search(r"https?://", conf)


def test_the_front_page_lists_the_parts_of_the_site():
    assert _toctree_entries(DOCS / "index.md") == PARTS


def test_the_reference_pages_exist():
    """Every page of the reference's table of contents is a file, or the generated scene
    reference (written by docs/_ext/scene_reference.py at build time)."""
    for entry in _toctree_entries(DOCS / "reference" / "index.md"):
        assert entry == "scene" or (DOCS / "reference" / f"{entry}.md").exists(), entry


def _documented() -> list[tuple[str, str, str]]:
    """``(page, directive, target)`` of every autodoc directive of the reference, with a
    ``:members:`` list expanded to one target per member."""
    out = []
    for page in sorted((DOCS / "reference").glob("*.md")):
        text = page.read_text(encoding="utf-8")
        for kind, target, options in re.findall(r"\.\. (auto\w+):: (\S+)\n((?:   :.*\n)*)", text):
            out.append((page.name, kind, target))
            members = re.search(r"^   :members: *(\S.*)$", options, re.M)
            if members:
                out += [(page.name, "member", f"{target}.{m.strip()}")
                        for m in members.group(1).split(",")]
    return out


def _resolve(target: str):
    """The object of a dotted name: the longest importable module, then attributes."""
    parts = target.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ImportError:
            continue
        for name in parts[k:]:
            obj = getattr(obj, name)
        return obj
    raise ImportError(target)


def test_every_documented_object_exists():
    documented = _documented()
    assert len(documented) >= 10
    missing = []
    for page, kind, target in documented:
        try:
            _resolve(target)
        except (ImportError, AttributeError) as exc:
            missing.append(f"{page}: {kind} {target} ({exc})")
    assert not missing, "\n".join(missing)


def test_the_public_names_of_the_documented_modules_exist():
    """A module documented with ``:members:`` lists its ``__all__``: each name must be
    there (a lazily imported one included)."""
    bad = []
    for page, kind, target in _documented():
        if kind != "automodule":
            continue
        module = importlib.import_module(target)
        bad += [f"{page}: {target}.{n}" for n in getattr(module, "__all__", ())
                if not hasattr(module, n)]
    assert not bad, bad
