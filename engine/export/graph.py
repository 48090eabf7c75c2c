"""Walking node graphs of any depth and size: the export's recursive reads of node trees (closures under
Mix and Add Shaders, node programs, world shaders) run here on an explicit stack; links are looked up in an
index rather than by bpy's scan of the whole tree; and a tree holding a loop is found before it is read.

A step is a generator. Where a recursive function would call itself, the step yields the generator of
that call and is sent back what it returned; an exception raised inside is thrown into the yielding step,
as a call would raise it there. The steps run in exactly the order the recursion would run them, so a
chain of thousands of nodes compiles as a short one does (Python's own recursion stops near a thousand
frames).

    def depth(node):
        children = [(yield depth(c)) for c in node.children]
        return 1 + max(children, default=0)

    run_nested(depth(root))
"""
from __future__ import annotations

import threading
from contextlib import contextmanager
from types import GeneratorType

# Nodes whose inputs are what a tree computes: Blender's shader inlining (which Cycles renders from)
# evaluates the tree from these.
OUTPUT_NODES = ("ShaderNodeOutputMaterial", "ShaderNodeOutputWorld", "ShaderNodeOutputLight",
                "ShaderNodeOutputAOV", "NodeGroupOutput")


def run_nested(step):
    """Run a step (a generator, or a value already computed) and the steps it yields; its return value."""
    if not isinstance(step, GeneratorType):
        return step
    stack = [step]
    value, error = None, None
    while True:
        try:
            if error is None:
                item = stack[-1].send(value)
            else:
                failed, error = error, None
                item = stack[-1].throw(failed)
        except StopIteration as stop:
            stack.pop()
            if not stack:
                return stop.value
            value = stop.value
            continue
        except BaseException as failed:  # noqa: BLE001 - handed to the step that yielded this one
            stack.pop()
            if not stack:
                raise
            value, error = None, failed
            continue
        if isinstance(item, GeneratorType):
            stack.append(item)
            value = None
        else:  # a value already computed (a step that needed no walking)
            value = item


# ---------------------------------------------------------------- links
_indexes = threading.local()


@contextmanager
def indexed_links():
    """Inside, links_into() reads an index of each tree, built on first use: bpy's socket.links scans every
    link of the tree, which makes reading a chain of N nodes take N^2 steps. The trees must not change
    inside (one material or world is read)."""
    outer = getattr(_indexes, "trees", None)
    if outer is None:
        _indexes.trees = {}
    try:
        yield
    finally:
        if outer is None:
            _indexes.trees = None


def links_into(socket):
    """socket.links of an input socket (in the order bpy gives them), from the tree's index inside
    indexed_links()."""
    trees = getattr(_indexes, "trees", None)
    if trees is None:
        return socket.links
    tree = socket.id_data
    index = trees.get(tree.as_pointer())
    if index is None:
        index = trees[tree.as_pointer()] = {}
        for link in tree.links:
            index.setdefault(link.to_socket.as_pointer(), []).append(link)
        for links in index.values():  # the order socket.links gives a multi-input socket's links
            links.sort(key=lambda lk: lk.multi_input_sort_id, reverse=True)
    return index.get(socket.as_pointer(), ())


# ---------------------------------------------------------------- trees
def node_trees(tree):
    """A node tree and the trees of the groups inside it, each once, however deeply nested."""
    seen, pending = set(), [tree]
    while pending:
        tree = pending.pop()
        if tree is None or tree.as_pointer() in seen:
            continue
        seen.add(tree.as_pointer())
        yield tree
        pending.extend(node.node_tree for node in tree.nodes if node.bl_idname == "ShaderNodeGroup")


def tree_nodes(tree):
    """Every node of a node tree and of the groups inside it."""
    for t in node_trees(tree):
        yield from t.nodes


def invalid_links(tree) -> list[str]:
    """What to tell about the links Blender marks invalid in a tree and its groups (sockets that cannot
    connect, or a loop): Cycles leaves them out, and so does sockets.source_of."""
    return [f"the link from {lk.from_node.bl_label} '{lk.from_node.name}' to {lk.to_node.bl_label} "
            f"'{lk.to_node.name}' {lk.to_socket.name} is invalid, ignored as in Cycles"
            for t in node_trees(tree) for lk in t.links if not lk.is_valid and not lk.is_muted]


# ---------------------------------------------------------------- loops
def node_loop(tree) -> str | None:
    """A loop in a node tree, or in a group tree its outputs read, as text ("Math 'A' -> Math 'B' ->
    Math 'A'"); None without one. Blender's shader inlining, which Cycles renders from, gives up on
    such a tree: the material or world renders black."""
    root = tree.as_pointer()
    seen, pending = set(), [tree]
    while pending:
        tree = pending.pop()
        if tree.as_pointer() in seen:
            continue
        seen.add(tree.as_pointer())
        loop = _loop_in(tree)
        if loop is not None:
            where = "" if tree.as_pointer() == root else f" in node group '{tree.name}'"
            return " -> ".join(f"{n.bl_label} '{n.name}'" for n in loop + loop[:1]) + where
        pending.extend(_used_groups(tree))
    return None


def _edges(tree, *, muted: bool):
    """(from node pointer, to node pointer) of the tree's links between available sockets."""
    for lk in tree.links:
        if lk.from_socket.enabled and lk.to_socket.enabled and (muted or not lk.is_muted):
            yield lk.from_node.as_pointer(), lk.to_node.as_pointer()


def _loop_in(tree) -> list | None:
    """The nodes of one loop of links in the tree (muted links count, as Blender counts them), or None:
    a depth-first search on an explicit stack."""
    nodes = {n.as_pointer(): n for n in tree.nodes}
    after: dict = {}
    for a, b in _edges(tree, muted=True):
        after.setdefault(a, []).append(b)
    state: dict = {}  # 1 on the current path, 2 finished
    for start in nodes:
        if start in state:
            continue
        path, branches = [start], [iter(after.get(start, ()))]
        state[start] = 1
        while path:
            nxt = next(branches[-1], None)
            if nxt is None:
                state[path.pop()] = 2
                branches.pop()
            elif state.get(nxt) == 1:
                return [nodes[p] for p in path[path.index(nxt):]]
            elif nxt not in state:
                state[nxt] = 1
                path.append(nxt)
                branches.append(iter(after.get(nxt, ())))
    return None


def _used_groups(tree):
    """The group trees of the unmuted group nodes the tree's output nodes read, directly or not."""
    nodes = {n.as_pointer(): n for n in tree.nodes}
    before: dict = {}
    for a, b in _edges(tree, muted=False):
        before.setdefault(b, []).append(a)
    pending = [p for p, n in nodes.items() if n.bl_idname in OUTPUT_NODES]
    reached = set(pending)
    while pending:
        for p in before.get(pending.pop(), ()):
            if p not in reached:
                reached.add(p)
                pending.append(p)
    return [nodes[p].node_tree for p in reached
            if nodes[p].bl_idname == "ShaderNodeGroup" and not nodes[p].mute and nodes[p].node_tree is not None]
