"""Imports point down the layers of docs/architecture.md, and never go round in a cycle.

The layer of every module is the table in ``docs/architecture.md`` (the one list; this test reads it). Each
module of ``src/picamcal`` is parsed with :mod:`ast` and every import it makes is collected: at the top,
inside functions, anywhere. Three rules:

(a) an import goes to the same layer or a lower one, never up;
(b) no import cycle among modules;
(c) every module is in the table (and every name in the table is a module or package that exists);
(d) every module an import names exists (``from .raw import npz`` inside a subpackage names a sibling ``raw``).

What counts as an import:

- ``from .raw import dng`` is an import of ``picamcal.raw.dng`` (a submodule); ``from .raw import read_raw`` is
  one of ``picamcal.raw``. Importing a submodule also runs its package's ``__init__``, but that edge is not
  added: a package's ``__init__`` that imports its own submodules would otherwise always be a cycle, and Python
  handles that case (the submodule sees the package half-initialised, and does not use it).
- An import under ``if TYPE_CHECKING:`` is never run. It counts for rule (a), because naming a higher layer's
  type still makes the lower layer know about the higher one, but not for rule (b): it cannot make a cycle at
  run time, and it is how a type can be named without one.
- ``importlib.import_module`` with a string is not seen; picamcal does not use it.
"""

from __future__ import annotations

import ast
import itertools
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
ARCHITECTURE = ROOT / "docs" / "architecture.md"
PACKAGE = "picamcal"

#: Violations already known, in files other helpers of issue 12 own, that the coordinator is fixing. An upward
#: import is (importer, imported); a cycle is the frozenset of the modules in it. Each entry must still be
#: found (test_pending_violations_are_still_there), so a fixed one is taken off the list. THE EXPECTED STATE OF
#: THE PROJECT IS AN EMPTY SET: when it is empty, test_layers_point_down_and_nothing_goes_round checks it all.
PENDING: set[tuple[str, str] | frozenset[str]] = set()


@dataclass(frozen=True)
class Import:
    """One import statement's target, where it is, and whether it only runs for the type checker."""

    importer: str
    imported: str
    file: str
    line: int
    type_only: bool

    def where(self) -> str:
        return f"{self.file}:{self.line}"


@dataclass(frozen=True)
class Violation:
    """A broken rule: ``key`` identifies it (for :data:`PENDING`), ``message`` says what and where."""

    kind: str
    key: tuple[str, str] | frozenset[str] | str
    message: str


def read_layer_table(text: str) -> dict[str, tuple[int, str]]:
    """The layer table of docs/architecture.md: table name -> (layer number, layer name)."""
    table: dict[str, tuple[int, str]] = {}
    for match in re.finditer(r"^\|\s*L(\d+)\s*\|\s*([^|]+?)\s*\|([^|\n]*)\|\s*$", text, re.MULTILINE):
        layer, name = int(match[1]), match[2]
        for module in re.findall(r"`([^`]+)`", match[3]):
            if module in table:
                raise AssertionError(f"docs/architecture.md puts {module} in two layers")
            table[module] = (layer, name)
    return table


def find_modules(src: Path, package: str = PACKAGE) -> dict[str, Path]:
    """Every module of the package under ``src``: dotted name -> file (a package is its ``__init__.py``)."""
    modules = {}
    for path in sorted((src / package).rglob("*.py")):
        parts = path.relative_to(src).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        modules[".".join(parts)] = path
    return modules


def _walk(node: ast.AST, type_only: bool = False) -> Iterator[tuple[ast.Import | ast.ImportFrom, bool]]:
    """Every import statement under ``node``, and whether it sits under ``if TYPE_CHECKING:``."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.Import, ast.ImportFrom)):
            yield child, type_only
        elif isinstance(child, ast.If) and _is_type_checking(child.test):
            for statement in child.body:
                yield from _walk_statement(statement, True)
            for statement in child.orelse:
                yield from _walk_statement(statement, type_only)
        else:
            yield from _walk(child, type_only)


def _walk_statement(statement: ast.stmt, type_only: bool) -> Iterator[tuple[ast.Import | ast.ImportFrom, bool]]:
    if isinstance(statement, (ast.Import, ast.ImportFrom)):
        yield statement, type_only
    else:
        yield from _walk(statement, type_only)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def find_imports(module: str, path: Path, modules: Mapping[str, Path], package: str = PACKAGE) -> list[Import]:
    """The imports of one module that land in the package, each resolved to the module it runs.

    ``from X import name`` imports the module ``X.name`` when there is one, else ``X`` (``name`` is then something
    ``X`` defines). An imported name that is no module of the package is kept as it is, for the caller to report.
    """
    file = path.relative_to(path.parents[module.count(".") + (path.name == "__init__.py")]).as_posix()
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    here = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for node, type_only in _walk(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        else:
            if node.level:
                base = here.split(".")
                base = base[: len(base) - node.level + 1]
                start = ".".join([*base, node.module] if node.module else base)
            else:
                start = node.module or ""
            targets = [f"{start}.{alias.name}" if f"{start}.{alias.name}" in modules else start for alias in node.names]
        for target in targets:
            if (target == package or target.startswith(package + ".")) and target != module:
                found.append(Import(module, target, file, node.lineno, type_only))
    return found


def layer_of(module: str, table: Mapping[str, tuple[int, str]], package: str = PACKAGE) -> tuple[int, str] | None:
    """The module's layer: that of the longest table name that is the module or a package holding it."""
    if module == package:
        return table.get("__init__")
    name = module[len(package) + 1 :]
    while name:
        if name in table:
            return table[name]
        name = name.rpartition(".")[0]
    return None


def _cycles(edges: Mapping[str, Mapping[str, Import]]) -> list[list[str]]:
    """One cycle (a path that returns to its start) in each strongly connected group of modules (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(edges.get(node, {})):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            group = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                group.append(member)
                if member == node:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for node in sorted(edges):
        if node not in index:
            visit(node)
    cycles = []
    for group in groups:
        members, start = set(group), group[0]
        # breadth-first from the first member back to itself, inside the group: the shortest cycle through it
        paths = {start: [start]}
        queue = [start]
        cycle = None
        while queue and cycle is None:
            node = queue.pop(0)
            for nxt in sorted(edges.get(node, {})):
                if nxt == start:
                    cycle = [*paths[node], start]
                    break
                if nxt in members and nxt not in paths:
                    paths[nxt] = [*paths[node], nxt]
                    queue.append(nxt)
        assert cycle is not None  # a strongly connected group has a cycle through each member
        cycles.append(cycle)
    return cycles


def check_layers(src: Path, table: Mapping[str, tuple[int, str]], package: str = PACKAGE) -> list[Violation]:
    """Every broken rule of the module docstring in the package under ``src``, given the layer table."""
    modules = find_modules(src, package)
    violations = []
    for module, path in modules.items():
        if layer_of(module, table, package) is None:
            violations.append(
                Violation(
                    "unlisted",
                    module,
                    f"{module} ({path.relative_to(src)}) is in no layer: add it to the table in docs/architecture.md",
                )
            )
    for name in table:
        full = package if name == "__init__" else f"{package}.{name}"
        if full not in modules:
            violations.append(
                Violation("stale", name, f"docs/architecture.md lists {name}, which is no module of {package}")
            )
    runtime: dict[str, dict[str, Import]] = {}
    for module, path in modules.items():
        for imp in find_imports(module, path, modules, package):
            if imp.imported not in modules:
                violations.append(
                    Violation(
                        "missing",
                        (imp.importer, imp.imported),
                        f"{imp.where()}: {imp.importer} imports {imp.imported}, which is no module of {package}",
                    )
                )
                continue
            if not imp.type_only:
                runtime.setdefault(module, {}).setdefault(imp.imported, imp)
            above, below = layer_of(imp.importer, table, package), layer_of(imp.imported, table, package)
            if above is not None and below is not None and below[0] > above[0]:
                violations.append(
                    Violation(
                        "upward",
                        (imp.importer, imp.imported),
                        f"{imp.where()}: {imp.importer} (L{above[0]} {above[1]}) imports {imp.imported} "
                        f"(L{below[0]} {below[1]}), a higher layer"
                        + (" (under TYPE_CHECKING)" if imp.type_only else ""),
                    )
                )
    for cycle in _cycles(runtime):
        steps = ", ".join(f"{a} -> {b} at {runtime[a][b].where()}" for a, b in itertools.pairwise(cycle))
        violations.append(Violation("cycle", frozenset(cycle), f"import cycle {' -> '.join(cycle)} ({steps})"))
    return violations


@pytest.fixture(scope="module")
def table() -> dict[str, tuple[int, str]]:
    return read_layer_table(ARCHITECTURE.read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def violations(table) -> list[Violation]:
    return check_layers(SRC, table)


def test_the_table_holds_the_six_layers(table):
    layers = {number: name for number, name in table.values()}
    assert layers == {0: "base", 1: "formats", 2: "model", 3: "products", 4: "workflows", 5: "skin"}
    assert table["raw"][0] == 1 and table["cli"][0] == 5 and table["__init__"][0] == 5


def test_the_layer_picture_agrees_with_the_table(table):
    boxes = re.findall(r'L(\d)\["L\d \w+<br/>([^"]+)"\]', ARCHITECTURE.read_text(encoding="utf-8"))
    assert len(boxes) == 6
    for layer, names in boxes:
        for name in names.split(", "):
            name = {"picamcal/__init__ (re-exports)": "__init__"}.get(name, name)
            if name != "...":
                assert table[name][0] == int(layer), f"the picture puts {name} in L{layer}, the table does not"


def test_layers_point_down_and_nothing_goes_round(violations):
    new = [v for v in violations if v.key not in PENDING]
    assert not new, "imports that break docs/architecture.md's rules:\n" + "\n".join(v.message for v in new)


def test_pending_violations_are_still_there(violations):
    fixed = PENDING - {v.key for v in violations}
    assert not fixed, f"fixed, take them off PENDING in tests/test_layers.py: {sorted(map(str, fixed))}"


def write_package(root: Path, files: dict[str, str]) -> Path:
    """A synthetic package ``pkg`` under ``root/src`` from {relative path: source}; returns ``root/src``."""
    for name, source in files.items():
        path = root / "src" / "pkg" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(source, encoding="utf-8")
    return root / "src"


SYNTHETIC_TABLE = """
| Layer | Name | Modules |
|---|---|---|
| L0 | base | `errors` |
| L1 | formats | `raw` |
| L2 | model | `calibrate`, `references`, `manifest` |
| L4 | workflows | `acquire` |
| L5 | skin | `cli`, `__init__` |
"""


def test_the_checker_passes_a_package_whose_imports_point_down(tmp_path):
    src = write_package(
        tmp_path,
        {
            "__init__.py": "from .calibrate import go\n",
            "errors.py": "",
            "raw/__init__.py": "from .dng import read\n",
            "raw/dng.py": "from ..errors import E\nfrom . import model\n",
            "raw/model.py": "import pkg.errors\n",
            "calibrate.py": "from .raw import read\nfrom pkg.raw.dng import read\n",
            "references.py": "",
            "manifest.py": "",
            "acquire/__init__.py": "",
            "cli.py": "def main():\n    from . import calibrate\n",
        },
    )
    assert check_layers(src, read_layer_table(SYNTHETIC_TABLE), "pkg") == []


def test_the_checker_catches_an_upward_import_inside_a_function(tmp_path):
    src = write_package(
        tmp_path,
        {
            "__init__.py": "",
            "errors.py": "",
            "raw/__init__.py": "",
            "calibrate.py": "",
            "references.py": "def find():\n    if True:\n        from .acquire.acquisition import read\n",
            "manifest.py": "",
            "acquire/__init__.py": "",
            "acquire/acquisition.py": "",
            "cli.py": "",
        },
    )
    found = check_layers(src, read_layer_table(SYNTHETIC_TABLE), "pkg")
    assert [(v.kind, v.key) for v in found] == [("upward", ("pkg.references", "pkg.acquire.acquisition"))]
    assert found[0].message == (
        "pkg/references.py:3: pkg.references (L2 model) imports pkg.acquire.acquisition (L4 workflows), a higher layer"
    )


def test_the_checker_reports_a_cycle_with_its_path(tmp_path):
    src = write_package(
        tmp_path,
        {
            "__init__.py": "",
            "errors.py": "",
            "raw/__init__.py": "",
            "calibrate.py": "from . import manifest\n",
            "references.py": "import pkg.calibrate\n",
            "manifest.py": "def f():\n    from .references import ROLES\n",
            "acquire/__init__.py": "",
            "cli.py": "",
        },
    )
    found = check_layers(src, read_layer_table(SYNTHETIC_TABLE), "pkg")
    assert [(v.kind, v.key) for v in found] == [
        ("cycle", frozenset({"pkg.calibrate", "pkg.manifest", "pkg.references"}))
    ]
    assert found[0].message == (
        "import cycle pkg.calibrate -> pkg.manifest -> pkg.references -> pkg.calibrate "
        "(pkg.calibrate -> pkg.manifest at pkg/calibrate.py:1, pkg.manifest -> pkg.references at pkg/manifest.py:2, "
        "pkg.references -> pkg.calibrate at pkg/references.py:1)"
    )


def test_type_checking_imports_count_for_layers_but_make_no_cycle(tmp_path):
    src = write_package(
        tmp_path,
        {
            "__init__.py": "",
            "errors.py": "",
            "raw/__init__.py": "",
            "calibrate.py": "from .references import ROLES\n",
            "references.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .calibrate import C\n",
            "manifest.py": "import typing\nif typing.TYPE_CHECKING:\n    from .acquire import Rig\n",
            "acquire/__init__.py": "",
            "cli.py": "",
        },
    )
    found = check_layers(src, read_layer_table(SYNTHETIC_TABLE), "pkg")
    assert [(v.kind, v.key) for v in found] == [("upward", ("pkg.manifest", "pkg.acquire"))]
    assert found[0].message.endswith("a higher layer (under TYPE_CHECKING)")


def test_the_checker_names_an_import_of_a_module_that_is_not_there(tmp_path):
    src = write_package(
        tmp_path,
        {
            "__init__.py": "",
            "errors.py": "",
            "raw/__init__.py": "",
            "raw/npz.py": "",
            "calibrate.py": "",
            "references.py": "",
            "manifest.py": "",
            "acquire/__init__.py": "def f():\n    from .raw.npz import is_raw_npz\n",
            "cli.py": "",
        },
    )
    found = check_layers(src, read_layer_table(SYNTHETIC_TABLE), "pkg")
    assert [(v.kind, v.key) for v in found] == [("missing", ("pkg.acquire", "pkg.acquire.raw.npz"))]
    assert found[0].message == (
        "pkg/acquire/__init__.py:2: pkg.acquire imports pkg.acquire.raw.npz, which is no module of pkg"
    )


def test_the_checker_names_unlisted_modules_and_stale_table_entries(tmp_path):
    src = write_package(
        tmp_path,
        {
            "__init__.py": "",
            "errors.py": "",
            "raw/__init__.py": "",
            "raw/new_format.py": "",
            "calibrate.py": "",
            "references.py": "",
            "acquire/__init__.py": "",
            "cli.py": "",
            "stray.py": "",
        },
    )
    found = check_layers(src, read_layer_table(SYNTHETIC_TABLE), "pkg")
    # raw/new_format.py is covered by its package's entry; stray.py by none; manifest is listed but gone
    assert sorted((v.kind, v.key) for v in found) == [("stale", "manifest"), ("unlisted", "pkg.stray")]
    assert "pkg.stray (pkg/stray.py) is in no layer" in " ".join(v.message for v in found)
