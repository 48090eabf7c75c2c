"""The emission a shader socket's tree gives, as a node program value: a world's Background radiance, a
light's emission (Cycles' background and light shaders are emission closures, summed by Add Shader and
weighed by Mix Shader)."""
from __future__ import annotations

from .sockets import BLACK3, Source, converted, source_of


def emission_of(builder, source: Source, issues: list[str], where: str, other):
    """Step (engine/export/graph.py): the colour x strength of the Background and Emission nodes feeding a
    shader socket, through Add and Mix Shaders (a colour or value linked there: an emission of it, as Cycles
    converts it): a Ref (RGBA) or a constant triple. A node of another kind
    gives `other` (a constant triple), with a warning naming it and `where` ("a world", "a light") when
    `other` is not black."""
    node, groups = source.node, source.groups
    if node is None:
        return BLACK3
    if source.kind in ("ShaderNodeBackground", "ShaderNodeEmission"):
        color = builder.input(node.inputs["Color"], groups, "RGBA")
        strength = builder.input(node.inputs["Strength"], groups, "VALUE")
        return builder.vector_op("SCALE", color, strength)
    if source.kind == "ShaderNodeAddShader":
        a = yield emission_of(builder, source_of(node.inputs[0], groups), issues, where, other)
        b = yield emission_of(builder, source_of(node.inputs[1], groups), issues, where, other)
        return builder.vector_op("ADD", a, b)
    if source.kind == "ShaderNodeMixShader":
        fac = builder.input(node.inputs[0], groups, "VALUE")
        a = yield emission_of(builder, source_of(node.inputs[1], groups), issues, where, other)
        b = yield emission_of(builder, source_of(node.inputs[2], groups), issues, where, other)
        return builder.mix(fac, a, b)
    fed = converted(source)
    if fed is not None:   # a colour or value linked into a shader socket: the Emission Cycles puts there
        consumer, socket_type = fed
        read = builder.input(consumer, groups, socket_type)
        return builder.vector_op("SCALE", (1.0, 1.0, 1.0), read) if socket_type == "VALUE" else read
    if tuple(other) != tuple(BLACK3):
        issues.append(f"{node.bl_label} is not supported in {where}, rendered as constant grey")
    elif source.kind == "ShaderNodeBsdfPrincipled":
        issues.append(f"{node.bl_label} '{node.name}' in {where}: its emission is not read, rendered black")
    return other
