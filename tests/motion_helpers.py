"""Builders the motion-blur tests share: geometry-node modifiers whose output changes with the frame or carries a
`velocity` attribute, and an object sliding over the frames."""
from __future__ import annotations

import bpy

from test_motion_blur import _linear


def node_modifier(ob, name: str, tree_name: str, geometry_in: bool = True):
    """A geometry-node tree `tree_name` put on ob as its modifier `name`, with a Geometry socket out (and in, unless
    geometry_in is False); returns the tree, its Group Input node (None without it) and its Group Output node."""
    tree = bpy.data.node_groups.new(tree_name, "GeometryNodeTree")
    if geometry_in:
        tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    into = tree.nodes.new("NodeGroupInput") if geometry_in else None
    out = tree.nodes.new("NodeGroupOutput")
    ob.modifiers.new(name, "NODES").node_group = tree
    return tree, into, out


def time_driven(tree, frame_scale: float, plus: float | None = None):
    """A Scene Time node's frame times frame_scale (plus `plus`, through an Add node), as a float socket of tree."""
    time = tree.nodes.new("GeometryNodeInputSceneTime")
    scale = tree.nodes.new("ShaderNodeMath")
    scale.operation = "MULTIPLY"
    scale.inputs[1].default_value = frame_scale
    tree.links.new(time.outputs["Frame"], scale.inputs[0])
    if plus is None:
        return scale.outputs[0]
    add = tree.nodes.new("ShaderNodeMath")
    add.operation = "ADD"
    add.inputs[1].default_value = plus
    tree.links.new(scale.outputs[0], add.inputs[0])
    return add.outputs[0]


def x_from_height(tree, operation: str, *operands):
    """A vector socket (f(z), 0, 0) of tree: each point's height z (object space) through a Math node `operation`
    whose next inputs are `operands` (numbers, or sockets linked in)."""
    position = tree.nodes.new("GeometryNodeInputPosition")
    split = tree.nodes.new("ShaderNodeSeparateXYZ")
    tree.links.new(position.outputs[0], split.inputs[0])
    math = tree.nodes.new("ShaderNodeMath")
    math.operation = operation
    for k, operand in enumerate(operands, start=1):
        if isinstance(operand, bpy.types.NodeSocket):
            tree.links.new(operand, math.inputs[k])
        else:
            math.inputs[k].default_value = operand
    tree.links.new(split.outputs["Z"], math.inputs[0])
    vector = tree.nodes.new("ShaderNodeCombineXYZ")
    tree.links.new(math.outputs[0], vector.inputs["X"])
    return vector.outputs[0]


def store_velocity(tree, geometry, velocity):
    """geometry with the vector socket `velocity` stored on its points as the `velocity` attribute."""
    store = tree.nodes.new("GeometryNodeStoreNamedAttribute")
    store.data_type, store.domain = "FLOAT_VECTOR", "POINT"
    store.inputs["Name"].default_value = "velocity"
    tree.links.new(geometry, store.inputs["Geometry"])
    tree.links.new(velocity, store.inputs["Value"])
    return store.outputs[0]


def offset_positions(tree, geometry, offset):
    """geometry with its points moved by the vector socket `offset` (a Set Position node)."""
    setter = tree.nodes.new("GeometryNodeSetPosition")
    tree.links.new(geometry, setter.inputs["Geometry"])
    tree.links.new(offset, setter.inputs["Offset"])
    return setter.outputs[0]


def with_material(tree, geometry, material):
    """geometry given `material` (a Set Material node)."""
    setter = tree.nodes.new("GeometryNodeSetMaterial")
    setter.inputs["Material"].default_value = material
    tree.links.new(geometry, setter.inputs["Geometry"])
    return setter.outputs[0]


def slide_along_x(ob, distance: float) -> None:
    """Key ob's location at frame 0 and `distance` further along x at frame 2, linearly."""
    ob.keyframe_insert("location", frame=0)
    ob.location.x += distance
    ob.keyframe_insert("location", frame=2)
    _linear(ob)
