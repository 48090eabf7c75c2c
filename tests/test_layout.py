"""engine/ and kernels/ keep their dependencies one way: read from the source (ast), every import of one module
of a package by another, lazy ones inside functions too (imports only for type checkers aside), forms no cycle;
no module reaches for another module's private (underscore) names; no engine module imports the add-on's root
package, which imports engine/; and kernels/ never imports engine/ or Blender's modules."""
from __future__ import annotations

import ast
import graphlib
import os

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGES = ("engine", "kernels")
BLENDER_MODULES = ("bpy", "mathutils", "gpu", "bmesh", "bpy_extras")


def package_modules(package: str) -> dict[str, str]:
    """Dotted name relative to the checkout ('engine.export.materials', 'engine' for engine/__init__.py) ->
    its file."""
    modules = {}
    for folder, _, files in os.walk(os.path.join(ROOT, package)):
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


def _runtime_nodes(tree: ast.AST):
    """Every node of the tree but those under `if TYPE_CHECKING:` (imports for type checkers only)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        yield node
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                continue
            stack.append(child)


class Imports:
    """What one module imports of its package: edges (the package's modules), private (names starting with
    '_', as 'module._name'), root (lines importing the root package), outside (other top-level packages and
    modules it imports, by name)."""

    def __init__(self, module: str, path: str, modules: dict[str, str]):
        with open(path, encoding="utf-8") as f:
            tree = ast.parse(f.read(), path)
        self.edges: set[str] = set()
        self.private: list[str] = []
        self.root: list[int] = []
        self.outside: set[str] = set()
        bound: dict[str, str] = {}   # local name -> the package's module it stands for
        for node in _runtime_nodes(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    self.outside.add(alias.name.split(".")[0])
                    target = alias.name.removeprefix("ember.")
                    if target in modules:
                        self.edges.add(target)
                        if alias.asname:
                            bound[alias.asname] = target
            elif isinstance(node, ast.ImportFrom):
                target = resolve(module, path, node)
                self.outside.add(target.split(".")[0])
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
        for node in _runtime_nodes(tree):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in bound \
                    and _private(node.attr):
                self.private.append(f"{bound[node.value.id]}.{node.attr}")
        self.edges.discard(module)


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def import_graph(package: str) -> dict[str, Imports]:
    modules = package_modules(package)
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


@pytest.mark.parametrize("package", PACKAGES)
def test_imports_form_no_cycle(package):
    graph = import_graph(package)
    cycle = find_cycle({module: imports.edges for module, imports in graph.items()})
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


@pytest.mark.parametrize("package", PACKAGES)
def test_no_module_uses_another_ones_private_names(package):
    found = {module: imports.private for module, imports in import_graph(package).items() if imports.private}
    assert not found, found


def test_no_engine_module_imports_the_root_package():
    found = {module: imports.root for module, imports in import_graph("engine").items() if imports.root}
    assert not found, f"modules importing the add-on's root package (lines): {found}"


def test_kernels_never_import_engine_or_blender():
    found = {module: sorted(imports.outside & {"engine", "", *BLENDER_MODULES})
             for module, imports in import_graph("kernels").items()
             if imports.outside & {"engine", "", *BLENDER_MODULES}}
    assert not found, found
