"""The package's structure, read from its source with ``ast``.

* The import graph of ``fem_rmpm`` (every ``import`` / ``from ... import`` in every
  module, at top level or inside a function) has no cycle, and no module of the package
  imports the command line ``fem_rmpm.cli`` (the CLI is the top layer).  The material
  models (``fem_rmpm.materials``) and the numba decorators (``fem_rmpm.runtime.compiled``)
  do not import the explicit kernels (``fem_rmpm.schemes.explicit.kernels``): the kernels
  are built on the models, and a new model is written against the protocol, not the
  kernels' internals.
* Sizes are guidelines, with a generous limit as a guard: no module has more than 800
  lines; no function more than 80 lines unless a comment ``# long function: <why>`` on
  its ``def`` line, the line above it or the first line of its body says why.  No line
  is longer than 100 characters.
* Imports sit at the top of a module.  An import inside a function is allowed only with
  a comment saying why it is lazy (on its line or the line above it, containing
  ``lazy``): an optional or heavy third-party module (matplotlib only for figures,
  dask-jobqueue only for a cluster, pyamg only when chosen).
* The package root holds only ``__init__.py``, ``api.py``, ``cli.py``, subpackages and
  the package data folder ``data/``.
* The module map of the documentation (``docs/reference/layout.md``, "Module map")
  names exactly the package's modules: a row per top-level module (``name.py``) and
  subpackage (``name/``), the row of a subpackage naming each of its modules.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "fem_rmpm"
MAX_MODULE_LINES = 800
MAX_FUNCTION_LINES = 80
MAX_LINE_COLUMNS = 100
MARK = "long function:"
LAYOUT = ROOT / "docs" / "reference" / "layout.md"
#: what the package root may hold besides subpackages (``data/``: the embedded scene)
ROOT_FILES = {"__init__.py", "api.py", "cli.py"}
ROOT_FOLDERS = {"data", "__pycache__"}


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(PKG.rglob("*.py"))}


def _resolve(mod: str, is_pkg: bool, node: ast.ImportFrom) -> str:
    """Absolute module of a ``from X import ...`` in module ``mod``."""
    if node.level == 0:
        return node.module or ""
    base = mod.split(".") if is_pkg else mod.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def import_graph() -> dict[str, set[str]]:
    """``{module: modules of fem_rmpm it imports}``; ``from pkg import sub`` counts as an
    import of the submodule ``pkg.sub`` when that is a module, else of ``pkg``."""
    mods = _modules()
    graph: dict[str, set[str]] = {}
    for mod, path in mods.items():
        is_pkg = path.name == "__init__.py"
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                deps.update(a.name for a in node.names if a.name.split(".")[0] == "fem_rmpm")
            elif isinstance(node, ast.ImportFrom):
                target = _resolve(mod, is_pkg, node)
                if target.split(".")[0] != "fem_rmpm":
                    continue
                subs = [f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in mods]
                deps.update(subs)
                if len(subs) < len(node.names):
                    deps.add(target)
        graph[mod] = {d for d in deps if d in mods and d != mod}
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle (as a list of modules, first = last) or None (iterative DFS)."""
    state: dict[str, int] = {}          # 1 on the stack, 2 done
    for start in sorted(graph):
        if state.get(start):
            continue
        stack = [(start, iter(sorted(graph[start])))]
        path = [start]
        state[start] = 1
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                stack.pop()
                path.pop()
                state[node] = 2
            elif state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            elif not state.get(nxt):
                state[nxt] = 1
                path.append(nxt)
                stack.append((nxt, iter(sorted(graph[nxt]))))
    return None


def _long_in(source: str, mod: str) -> dict[str, int]:
    """``{"mod:qualname": lines}`` of the functions of ``source`` over the limit without a
    why-comment (on the ``def`` line, the line above it or up to the first body line)."""
    lines = source.splitlines()
    out = {}

    def visit(node, prefix):
        for child in ast.iter_child_nodes(node):
            name = prefix
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}{child.name}."
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = child.end_lineno - child.lineno + 1
                first = min([child.lineno] + [d.lineno for d in child.decorator_list])
                near = lines[max(first - 2, 0):child.body[0].lineno]
                if n > MAX_FUNCTION_LINES and not any(MARK in ln for ln in near):
                    out[f"{mod}:{name[:-1]}"] = n
            visit(child, name)

    visit(ast.parse(source), "")
    return out


def _unjustified_imports_in(source: str, mod: str) -> list[str]:
    """``["mod:line: import ..."]`` of the imports inside functions of ``source`` without
    a comment containing ``lazy`` on their line or the line above."""
    lines = source.splitlines()
    out = []
    for fn in ast.walk(ast.parse(source)):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(fn):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                near = lines[max(node.lineno - 2, 0):node.end_lineno]
                if not any("#" in ln and "lazy" in ln.split("#", 1)[1] for ln in near):
                    out.append(f"{mod}:{node.lineno}: {lines[node.lineno - 1].strip()}")
    return out


def long_functions() -> dict[str, int]:
    """Functions over the limit without a why-comment, in the whole package."""
    out = {}
    for mod, path in _modules().items():
        out.update(_long_in(path.read_text(), mod))
    return out


def test_import_graph_has_no_cycle():
    graph = import_graph()
    assert len(graph) > 20 and "fem_rmpm.api" in graph["fem_rmpm.campaign.task"]
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def layering_violations(graph: dict[str, set[str]]) -> list[str]:
    """``["a -> b"]`` for each import of the kernels by a material model or by
    ``fem_rmpm.runtime.compiled``."""
    kernels = "fem_rmpm.schemes.explicit.kernels"
    lower = [m for m in graph
             if m.startswith("fem_rmpm.materials") or m == "fem_rmpm.runtime.compiled"]
    return sorted(f"{m} -> {d}" for m in lower for d in graph[m]
                  if d == kernels or d.startswith(kernels + "."))


def test_materials_and_decorators_do_not_import_the_kernels():
    graph = import_graph()
    assert "fem_rmpm.runtime.compiled" in graph["fem_rmpm.materials.von_mises"]
    bad = layering_violations(graph)
    assert not bad, "imports of the kernels below them: " + ", ".join(bad)


def test_the_layering_check_finds_an_import_of_the_kernels():
    """The check can fail: a hand-made graph where a model imports a kernel module."""
    common = "fem_rmpm.schemes.explicit.kernels.common"
    graph = {"fem_rmpm.materials.x": {common, "fem_rmpm.runtime.compiled"},
             "fem_rmpm.runtime.compiled": set(), common: {"fem_rmpm.runtime.compiled"}}
    assert layering_violations(graph) == [f"fem_rmpm.materials.x -> {common}"]


def test_the_cycle_finder_finds_a_cycle():
    """The check can fail: a hand-made graph with a cycle b -> c -> d -> b."""
    graph = {"a": {"b"}, "b": {"c"}, "c": {"d"}, "d": {"b"}, "e": set()}
    assert find_cycle(graph) == ["b", "c", "d", "b"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_the_length_check_finds_a_long_function():
    """The check can fail: an 85-line method is found, the same with the comment is not."""
    body = "".join(f"        x{i} = {i}\n" for i in range(83))
    src = f"class A:\n    def f(self):\n        \"\"\"doc\"\"\"\n{body}"
    assert _long_in(src, "m") == {"m:A.f": 85}
    marked = src.replace("def f(self):", "def f(self):  # long function: one table")
    assert _long_in(marked, "m") == {}
    short = "".join(f"        x{i} = {i}\n" for i in range(70))
    assert _long_in(src.replace(body, short), "m") == {}


def test_imports_inside_functions_say_why_they_are_lazy():
    bad = [b for mod, path in _modules().items()
           for b in _unjustified_imports_in(path.read_text(), mod)]
    assert not bad, "imports inside functions without a '# lazy: <why>' comment:\n" + \
        "\n".join(bad)


def test_the_import_check_finds_a_function_level_import():
    """The check can fail: an import in a function body is found, with the comment not."""
    src = "import os\n\n\ndef f():\n    import json\n    return json\n"
    assert _unjustified_imports_in(src, "m") == ["m:5: import json"]
    marked = src.replace("import json\n", "import json  # lazy: only here\n")
    assert _unjustified_imports_in(marked, "m") == []
    above = src.replace("    import json\n", "    # lazy: optional\n    import json\n")
    assert _unjustified_imports_in(above, "m") == []


def test_nothing_in_the_package_imports_the_cli():
    graph = import_graph()
    users = sorted(m for m, deps in graph.items()
                   if any(d == "fem_rmpm.cli" or d.startswith("fem_rmpm.cli.") for d in deps)
                   and not (m == "fem_rmpm.cli" or m.startswith("fem_rmpm.cli.")))
    assert not users, f"modules importing the CLI: {users}"


def test_no_module_over_800_lines():
    big = {m: n for m, p in _modules().items()
           if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not big, f"modules over {MAX_MODULE_LINES} lines: {big}"


def test_no_function_over_80_lines_without_a_reason():
    long = long_functions()
    assert not long, (f"functions over {MAX_FUNCTION_LINES} lines without a "
                      f"'# {MARK} <why>' comment: {long}")


def test_no_line_over_100_columns():
    long = [f"{p.relative_to(ROOT)}:{i} ({len(line)})" for p in _modules().values()
            for i, line in enumerate(p.read_text(encoding="utf-8").split("\n"), 1)
            if len(line) > MAX_LINE_COLUMNS]
    assert not long, f"lines over {MAX_LINE_COLUMNS} characters:\n" + "\n".join(long)


def _layout_map(text: str) -> dict[str, str]:
    """``{first cell name: rest of the row}`` of the table under the "Module map" heading
    of the layout page ``text``."""
    m = re.search(r"^## Module map\n(.*?)(?=^## |\Z)", text, re.S | re.M)
    assert m, f"{LAYOUT.relative_to(ROOT)} has no '## Module map' section"
    rows = {}
    for line in m.group(1).splitlines():
        cells = line.split("|")
        if line.startswith("|") and len(cells) > 2:
            for name in re.findall(r"`([A-Za-z_][\w/]*(?:\.py|/))`", cells[1]):
                rows[name] = "|".join(cells[2:])
    return rows


def _package_map() -> dict[str, set[str]]:
    """``{"mod.py": set(), "pkg/": {its submodules}}`` of the top level of ``fem_rmpm``."""
    out: dict[str, set[str]] = {}
    for p in sorted(PKG.iterdir()):
        if p.suffix == ".py" and p.name not in ("__init__.py", "__main__.py"):
            out[p.name] = set()
        elif p.is_dir() and (p / "__init__.py").exists():
            out[p.name + "/"] = {q.stem for q in p.glob("*.py")
                                 if q.name not in ("__init__.py", "__main__.py")}
    return out


def map_problems(layout: dict[str, str], package: dict[str, set[str]]) -> list[str]:
    """What the module map ``layout`` gets wrong about the package's modules."""
    out = [f"missing in the module map: {n}" for n in sorted(set(package) - set(layout))]
    out += [f"the module map names no such module: {n}"
            for n in sorted(set(layout) - set(package))]
    for name, subs in package.items():
        if name.endswith("/") and name in layout:
            named = set(re.findall(r"`([a-z_][a-z0-9_]*)`", layout[name]))
            if named != subs:
                out.append(f"row {name}: names {sorted(named)}, the package has {sorted(subs)}")
    return out


def test_the_module_map_lists_every_module():
    """Every top-level module and subpackage has a row of the layout page's module map; a
    subpackage's row names exactly its modules (as `name` in backticks)."""
    problems = map_problems(_layout_map(LAYOUT.read_text(encoding="utf-8")), _package_map())
    assert not problems, "\n".join(problems)


def test_the_module_map_check_finds_a_missing_module():
    """The check can fail: a map without a module of a subpackage, or without a row."""
    package = {"api.py": set(), "scene/": {"spec", "schema"}}
    table = "## Module map\n\n| module | what |\n|---|---|\n" \
            "| `scene/` | `spec` (dataclasses) |\n| `api.py` | the API |\n"
    assert map_problems(_layout_map(table), package) == \
        ["row scene/: names ['spec'], the package has ['schema', 'spec']"]
    table = table.replace("`spec` (dataclasses)", "`spec`, `schema`")
    assert map_problems(_layout_map(table), package) == []
    no_api = table.replace("| `api.py` | the API |\n", "")
    assert map_problems(_layout_map(no_api), package) == \
        ["missing in the module map: api.py"]


def root_problems(names: dict[str, bool]) -> list[str]:
    """The entries of the package root (``{name: is a subpackage}``) that do not belong
    there: a module other than ``__init__``, ``api`` and ``cli``, or a folder that is not
    a subpackage (other than the package data)."""
    return sorted(n for n, is_pkg in names.items()
                  if not is_pkg and n not in ROOT_FILES and n not in ROOT_FOLDERS)


def test_the_package_root_holds_only_the_api_the_cli_and_subpackages():
    names = {p.name: p.is_dir() and (p / "__init__.py").exists() for p in PKG.iterdir()}
    assert not root_problems(names), f"fem_rmpm/ should not hold {root_problems(names)}"
    assert root_problems({"api.py": False, "scene": True, "helpers.py": False,
                          "notes": False}) == ["helpers.py", "notes"]
