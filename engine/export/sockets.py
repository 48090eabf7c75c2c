"""What feeds a shader node socket and what it holds: the vocabulary the material table (materials.py), the
world (world.py) and the node program compiler (nodes.py) share.

source_of follows the links into an input socket to the node computing its value, seeing through reroutes,
muted links, muted nodes and node groups as Blender evaluates them, and leaving out links Blender marks
invalid, as Cycles does; output_node finds the output a tree renders from. The colour helpers read a socket's
own value the way every reader falls back to it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .graph import links_into

# Cycles renders a missing or unreadable image in magenta.
MISSING_IMAGE_COLOR = (1.0, 0.0, 1.0)
BLACK3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Source:
    """What feeds an input socket, once reroutes, muted links, muted nodes and groups are seen through.

    node : the node computing the value, or None when the value is a constant.
    socket : the node's output socket; when node is None, the input socket whose default_value applies.
    groups : the group nodes the node sits inside, outermost first (needed to follow the node's inputs).
    """
    node: object
    socket: object
    groups: tuple = ()

    @property
    def kind(self) -> str | None:
        return self.node.bl_idname if self.node is not None else None


def source_of(socket, groups: tuple = ()) -> Source:
    """Follow the links into an input socket to the node that computes its value."""
    while True:
        link = _live_link(socket)
        if link is None:
            return Source(None, socket, groups)
        node, output = link.from_node, link.from_socket
        if node.bl_idname == "NodeReroute":
            step = node.inputs[0], groups
        elif node.mute:
            step = _passed_through(node, output), groups
        elif node.bl_idname == "ShaderNodeGroup":
            step = _by_identifier(_group_output(node.node_tree), output.identifier), groups + (node,)
        elif node.bl_idname == "NodeGroupInput" and groups:
            step = _by_identifier(groups[-1], output.identifier), groups[:-1]
        else:
            return Source(node, output, groups)
        if step[0] is None:  # nothing passes through (muted node, empty group): the input's own value
            return Source(None, socket, groups)
        socket, groups = step


def converted(source: Source) -> tuple | None:
    """(the shader socket it feeds, "VALUE" or "RGBA") for a colour, vector or value output linked into a shader
    socket: Cycles' ShaderGraph::connect puts an Emission node between them (a value as its Strength under white,
    a colour or vector as its Color at Strength 1), which every reader of shader sockets renders so. None for a
    shader output, a constant, or an output whose link is not found."""
    socket = source.socket
    if source.node is None or getattr(socket, "type", "SHADER") == "SHADER":
        return None
    consumer = next((link.to_socket for link in socket.links if not link.is_muted), None)
    return None if consumer is None else (consumer, "VALUE" if socket.type == "VALUE" else "RGBA")

def output_node(tree):
    """The output node Cycles renders from (its own target first, then 'All'), or None."""
    return tree.get_output_node("CYCLES") or tree.get_output_node("ALL")


def _live_link(socket):
    return next((lk for lk in links_into(socket) if lk.is_valid and not lk.is_muted), None)


def _passed_through(node, output):
    """The input a muted node passes to `output`, or None."""
    return next((lk.from_socket for lk in node.internal_links if lk.to_socket == output), None)


def _group_output(tree):
    if tree is None:
        return None
    outputs = [n for n in tree.nodes if n.bl_idname == "NodeGroupOutput"]
    return next((n for n in outputs if n.is_active_output), outputs[0] if outputs else None)


def _by_identifier(node, identifier: str):
    """The node's input socket with that identifier (group sockets match by identifier, not name)."""
    if node is None:
        return None
    return next((s for s in node.inputs if s.identifier == identifier), None)


def rgb(value) -> tuple:
    """A colour socket value as a non-negative, finite RGB triple (alpha dropped)."""
    c = np.nan_to_num(np.asarray(value[:3], np.float64))
    return tuple(float(x) for x in np.maximum(c, 0.0))


def socket_has_nan(socket) -> bool:
    """Whether an unlinked socket's value is, in part, not a number (a script or a file can set one)."""
    value = getattr(socket, "default_value", 0.0)
    return bool(np.isnan(np.asarray(value[:] if hasattr(value, "__len__") else value, np.float64)).any())
