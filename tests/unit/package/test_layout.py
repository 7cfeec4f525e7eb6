"""The package's layout (docs/architecture.md): the layer map, no upward import, no import cycle, unique basenames.

The imports are read from the source (``ast``), not by importing: module-level imports, imports deferred into
functions, and imports under ``if TYPE_CHECKING:`` all count for the layer rule; the module-level ones (the ones that
run at import) also for the cycle rule.
"""

from __future__ import annotations

import ast
import re
from collections import Counter
from pathlib import Path

import pytest

import lightemma

ROOT = Path(lightemma.__file__).parent
DOC = ROOT.parents[1] / "docs" / "architecture.md"

# The layer map: a module may import modules of its own layer and of the layers below it, never above. Each entry is a
# top-level module or package of lightemma (a package: everything in it). docs/architecture.md shows the same list in
# its table (test_the_docs_layer_table_is_this_map).
LAYERS: tuple[tuple[str, ...], ...] = (
    ("_core", "errors", "definitions", "_arrays", "_text", "_signals", "_litellm", "_files"),
    ("actions", "kinematics", "metrics", "corruptions", "models"),
    ("nuscenes", "frames", "synth", "inputs", "prompts", "runs", "cache"),
    ("backends", "pipeline"),
    ("evaluation", "planning", "explanations"),
    ("report", "offline_demo"),
    ("cli", "__main__"),
)
LAYER_OF = {name: layer for layer, names in enumerate(LAYERS) for name in names}
# Leaf data: modules that import nothing of lightemma at all (the paper's tables).
LEAVES = ("lightemma.models.paper",)


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(p): p for p in sorted(ROOT.rglob("*.py"))}
PACKAGES = {_module_name(p) for p in ROOT.rglob("__init__.py")}


def _exports() -> dict[str, str]:
    """``lightemma``'s lazily exported names → the module that defines each (``__init__._EXPORTS``)."""
    for node in ast.parse((ROOT / "__init__.py").read_text()).body:
        if isinstance(node, ast.AnnAssign) and getattr(node.target, "id", None) == "_EXPORTS":
            return ast.literal_eval(node.value)
    raise AssertionError("lightemma/__init__.py has no _EXPORTS")


EXPORTS = _exports()


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _import_nodes(tree: ast.AST) -> list[tuple[ast.Import | ast.ImportFrom, str]]:
    """Every import statement with where it runs: ``module`` (at import), ``deferred`` (in a function body) or
    ``typing`` (under ``if TYPE_CHECKING:``, never at run time)."""
    found: list[tuple[ast.Import | ast.ImportFrom, str]] = []

    def visit(node: ast.AST, where: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                found.append((child, where))
            elif isinstance(child, ast.If) and _is_type_checking(child.test):
                for c in child.body:
                    visit_one(c, "typing")
                for c in child.orelse:
                    visit_one(c, where)
                continue
            if not isinstance(child, (ast.Import, ast.ImportFrom)):
                inner = "deferred" if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)) else where
                visit(child, "typing" if where == "typing" else inner)

    def visit_one(child: ast.AST, where: str) -> None:
        if isinstance(child, (ast.Import, ast.ImportFrom)):
            found.append((child, where))
        else:
            visit(child, where)

    visit(tree, "module")
    return found


def _targets(importer: str, node: ast.Import | ast.ImportFrom) -> list[str]:
    """The lightemma modules an import statement loads (``from pkg import sub`` names the submodule; ``from lightemma
    import name`` the module that defines the exported name)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names if a.name == "lightemma" or a.name.startswith("lightemma.")]
    if node.level:
        base = importer.split(".") if importer in PACKAGES else importer.split(".")[:-1]
        base = base[: len(base) - node.level + 1]
        source = ".".join(base + ([node.module] if node.module else []))
    else:
        source = node.module or ""
    if source != "lightemma" and not source.startswith("lightemma."):
        return []
    out = []
    for alias in node.names:
        if f"{source}.{alias.name}" in MODULES:
            out.append(f"{source}.{alias.name}")
        elif source == "lightemma" and alias.name in EXPORTS:
            out.append(EXPORTS[alias.name])
        else:
            out.append(source)
    return out


def import_edges() -> list[tuple[str, str, str, int]]:
    """(importer, imported, where, line) for every import of a lightemma module by a lightemma module."""
    edges = []
    for name, path in MODULES.items():
        for node, where in _import_nodes(ast.parse(path.read_text(), str(path))):
            edges += [(name, target, where, node.lineno) for target in _targets(name, node)]
    return edges


def deferred_imports() -> list[tuple[str, int]]:
    """(module, line) of each import statement of lightemma's own modules inside a function body."""
    return sorted({(a, line) for a, _, where, line in import_edges() if where == "deferred"})


def _layer(module: str) -> int | None:
    parts = module.split(".")
    return None if len(parts) < 2 else LAYER_OF.get(parts[1])


def _cycles(edges: list[tuple[str, str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    graph: dict[str, set[str]] = {}
    for a, b in edges:
        if a != b:
            graph.setdefault(a, set()).add(b)
            graph.setdefault(b, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        out.append(sorted(component))
            elif child not in index:
                index[child] = low[child] = len(index)
                stack.append(child)
                on_stack.add(child)
                work.append((child, iter(sorted(graph[child]))))
            elif child in on_stack:
                low[node] = min(low[node], index[child])
    return out


def _with_packages(edges: list[tuple[str, str]]) -> list[tuple[str, str]]:
    """Each edge plus the packages whose ``__init__`` importing its target runs (those the importer is not inside)."""
    out = []
    for a, b in edges:
        out.append((a, b))
        parts = b.split(".")
        for i in range(2, len(parts)):
            package = ".".join(parts[:i])
            if package in PACKAGES and not (a == package or a.startswith(package + ".")):
                out.append((a, package))
    return out


def test_every_module_has_a_layer_and_the_map_names_only_modules():
    tops = {name.split(".")[1] for name in MODULES if "." in name} | {"_core"}  # _core: the compiled core
    assert sorted(tops - set(LAYER_OF)) == [], "add these to LAYERS (and docs/architecture.md's table)"
    assert sorted(set(LAYER_OF) - tops) == [], "no such modules: drop them from LAYERS"


def test_no_module_imports_a_layer_above_its_own():
    upward = [
        f"{a}:{line} ({where}) imports {b} (layer {_layer(a)} → {_layer(b)})"
        for a, b, where, line in import_edges()
        if _layer(a) is not None and _layer(b) is not None and _layer(b) > _layer(a)
    ]
    assert upward == []


def test_no_import_cycle_among_module_level_imports():
    edges = [(a, b) for a, b, where, _ in import_edges() if where == "module"]
    assert _cycles(_with_packages(edges)) == []


def test_the_paper_tables_are_leaf_data():
    for leaf in LEAVES:
        assert [f"{b} (line {line})" for a, b, _, line in import_edges() if a == leaf] == []


def test_no_two_modules_share_a_basename():
    names = Counter(p.stem for p in ROOT.rglob("*.py") if p.stem != "__init__")
    assert sorted(name for name, count in names.items() if count > 1) == []


def test_the_docs_layer_table_is_this_map():
    """docs/architecture.md's layer table lists exactly LAYERS, layer by layer."""
    rows = re.findall(r"^\| *(\d+) *\| *(.+?) *\| *.+\|$", DOC.read_text(encoding="utf-8"), flags=re.M)
    documented = tuple(tuple(n.rstrip("/") for n in re.findall(r"`([^`]+)`", modules)) for _, modules in rows)
    assert [int(layer) for layer, _ in rows] == list(range(len(LAYERS)))
    assert documented == LAYERS


# The checks above must be able to fail: each is run on a made-up graph that breaks it.


def test_the_cycle_check_finds_a_cycle_through_a_package_init():
    edges = [("lightemma.a", "lightemma.b.c"), ("lightemma.b", "lightemma.a")]
    real = set(PACKAGES)
    PACKAGES.add("lightemma.b")
    try:
        assert _cycles(_with_packages(edges)) == [["lightemma.a", "lightemma.b"]]
    finally:
        PACKAGES.clear()
        PACKAGES.update(real)
    assert _cycles([("x", "y"), ("y", "z")]) == []


@pytest.mark.parametrize(
    ("source", "where"),
    [
        ("from lightemma.report import tables\n", "module"),
        ("def f():\n    from lightemma.report import tables\n", "deferred"),
        ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from lightemma.report import tables\n", "typing"),
    ],
)
def test_the_walker_sees_module_level_deferred_and_typing_imports(source, where):
    ((node, found),) = [(n, w) for n, w in _import_nodes(ast.parse(source)) if getattr(n, "module", "") != "typing"]
    assert found == where
    assert _targets("lightemma.frames.model", node) == ["lightemma.report.tables"]
    assert _layer("lightemma.frames.model") < _layer("lightemma.report.tables")  # an upward import, were it real


def test_relative_imports_and_lazy_exports_resolve_to_their_modules():
    (node,) = ast.parse("from ..report import tables").body
    assert _targets("lightemma.evaluation.core", node) == ["lightemma.report.tables"]
    (node,) = ast.parse("from lightemma import integrate").body
    assert _targets("lightemma.cli.run", node) == ["lightemma.kinematics"]
