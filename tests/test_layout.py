"""engine/ keeps its dependencies one way: read from the source (ast), every import of one engine module by
another, lazy ones inside functions too, forms no cycle; no module reaches for another engine module's private
(underscore) names; and no engine module imports the add-on's root package, which imports engine/."""
from __future__ import annotations

import ast
import graphlib
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGE = "engine"


def engine_modules() -> dict[str, str]:
    """Dotted name relative to the checkout ('engine.export.materials', 'engine' for engine/__init__.py) ->
    its file."""
    modules = {}
    for folder, _, files in os.walk(os.path.join(ROOT, PACKAGE)):
        for name in files:
            if name.endswith(".py"):
                path = os.path.join(folder, name)
                dotted = os.path.relpath(path, ROOT)[:-3].replace(os.sep, ".")
                modules[dotted.removesuffix(".__init__")] = path
    return modules


def resolve(module: str, path: str, node: ast.ImportFrom) -> str:
    """The dotted name an `from ... import` reads from ('' for the checkout's root package)."""
    if node.level == 0:
        name = node.module or ""
        return name.removeprefix("ember.") if name.startswith("ember.") else ("" if name == "ember" else "?" + name)
    parts = module.split(".")
    if not path.endswith("__init__.py"):
        parts = parts[:-1]
    parts = parts[:len(parts) - (node.level - 1)]
    return ".".join(parts + ([node.module] if node.module else []))


class Imports:
    """What one module imports of engine/: edges (the engine modules), private (names starting with '_',
    as 'module._name'), root (lines importing the root package)."""

    def __init__(self, module: str, path: str, modules: dict[str, str]):
        with open(path, encoding="utf-8") as f:
            tree = ast.parse(f.read(), path)
        self.edges: set[str] = set()
        self.private: list[str] = []
        self.root: list[int] = []
        bound: dict[str, str] = {}   # local name -> the engine module it stands for
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    target = alias.name.removeprefix("ember.")
                    if target in modules:
                        self.edges.add(target)
                        if alias.asname:
                            bound[alias.asname] = target
            elif isinstance(node, ast.ImportFrom):
                target = resolve(module, path, node)
                for alias in node.names:
                    sub = f"{target}.{alias.name}" if target else alias.name
                    if sub in modules:
                        self.edges.add(sub)
                        bound[alias.asname or alias.name] = sub
                    elif target in modules:
                        self.edges.add(target)
                        if _private(alias.name):
                            self.private.append(f"{target}.{alias.name}")
                    elif target == "" and not os.path.isdir(os.path.join(ROOT, alias.name)):
                        self.root.append(node.lineno)
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in bound \
                    and _private(node.attr):
                self.private.append(f"{bound[node.value.id]}.{node.attr}")
        self.edges.discard(module)


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def import_graph() -> dict[str, Imports]:
    modules = engine_modules()
    return {module: Imports(module, path, modules) for module, path in sorted(modules.items())}


def find_cycle(edges: dict[str, set[str]]) -> list[str] | None:
    """One cycle of the graph as a path along its edges that returns to its start, or None. graphlib finds it
    (it reads edges as predecessors, so its path runs backwards)."""
    try:
        tuple(graphlib.TopologicalSorter(edges).static_order())
    except graphlib.CycleError as cycle:
        return list(reversed(cycle.args[1]))
    return None


def test_find_cycle_finds_one_and_only_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
    cycle = find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}})
    assert cycle in (["a", "b", "c", "a"], ["b", "c", "a", "b"], ["c", "a", "b", "c"])


def test_engine_imports_form_no_cycle():
    graph = import_graph()
    cycle = find_cycle({module: imports.edges for module, imports in graph.items()})
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_no_engine_module_uses_another_ones_private_names():
    found = {module: imports.private for module, imports in import_graph().items() if imports.private}
    assert not found, found


def test_no_engine_module_imports_the_root_package():
    found = {module: imports.root for module, imports in import_graph().items() if imports.root}
    assert not found, f"modules importing the add-on's root package (lines): {found}"
