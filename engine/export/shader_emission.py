"""The emission a shader socket's tree gives, as a node program value: a world's Background radiance, a
light's emission (Cycles' background and light shaders are emission closures, summed by Add Shader and
weighed by Mix Shader)."""
from __future__ import annotations

from .sockets import BLACK3, Source, converted, source_of


def emission_of(builder, source: Source, issues: list[str], where: str, other):
    """Step (engine/export/graph.py): the colour x strength of the Background and Emission nodes feeding a
    shader socket, through Add and Mix Shaders (a colour or value linked there: an emission of it, as Cycles
    converts it): a Ref (RGBA) or a constant triple. A Principled BSDF gives its emission, a BSDF nothing, as in
    Cycles; a node of another kind gives `other` (a constant triple), with a warning naming it and `where` ("a
    world", "a light") when `other` is not black."""
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
    if source.kind == "ShaderNodeBsdfPrincipled":
        return _principled_emission(builder, node, groups, issues, where)
    if emits_nothing(source.kind):
        # A BSDF (or a volume shader) in a world's or a light's Surface: Cycles evaluates the background and
        # light shaders for their emission closures only, so it adds nothing (a world of one renders black).
        return BLACK3
    if tuple(other) != tuple(BLACK3):
        issues.append(f"{node.bl_label} is not supported in {where}, rendered as constant grey")
    return other


def emits_nothing(kind: str) -> bool:
    """Shader nodes with no emission closure: BSDFs, subsurface, holdout and volume shaders."""
    return ("Bsdf" in kind or kind.startswith("ShaderNodeVolume") or
            kind in ("ShaderNodeSubsurfaceScattering", "ShaderNodeHoldout"))


def _principled_emission(builder, node, groups, issues: list[str], where: str):
    """A Principled BSDF's emission in a world or a light: Emission Color x Emission Strength under its Alpha, as
    Cycles' principled closure emits it there (svm_node_closure_principled: the layers themselves add nothing).
    Cycles dims the emission by the Sheen and Coat layers above it; Ember does not here (warned)."""
    for name in ("Coat Weight", "Sheen Weight"):
        socket = node.inputs.get(name)
        if socket is not None and (socket.is_linked or float(socket.default_value) != 0.0):
            issues.append(f"{node.bl_label} '{node.name}' in {where}: its {name.split()[0]} does not dim its "
                          f"emission here, as it does in Cycles")
            break
    color = builder.input(node.inputs["Emission Color"], groups, "RGBA")
    strength = builder.input(node.inputs["Emission Strength"], groups, "VALUE")
    alpha = builder.input(node.inputs["Alpha"], groups, "VALUE")
    return builder.mix(alpha, BLACK3, builder.vector_op("SCALE", color, strength))
