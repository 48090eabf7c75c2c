"""Whether a material's emission is light-sampled under Emission Sampling Auto, as Cycles decides it
(scene/shader.cpp: output_estimate_emission, Shader::estimate_emission).

Cycles estimates a shader's emission from its graph after constant folding: an Emission or Background node (or
a Principled BSDF's emission) gives its Color times its Strength, a linked Color counting as white and a linked
Strength as 1 (or as the Strength of the Light Falloff or IES Texture node feeding it); Add Shader sums, Mix Shader weighs
by a constant Fac and sums where Fac is linked; other closures give nothing. Under Auto the material's emitters
are light-sampled only where the estimate's largest channel is above 0.5, and only a tenth of it counts when the
Surface output is a colour or value turned into an emission (Cycles' auto-conversion, likely a preview): weak
glows are left to BSDF rays, which find them well, and stay out of the light tree.
"""
from __future__ import annotations

from .sockets import converted, source_of

# Cycles' threshold on the estimate's largest channel (Shader::estimate_emission).
AUTO_THRESHOLD = 0.5
# Weight of an emission made from a colour or value linked into the Surface output.
AUTO_CONVERSION_SCALE = 0.1

_EMITTERS = {"ShaderNodeEmission": ("Color", "Strength"), "ShaderNodeBackground": ("Color", "Strength"),
             "ShaderNodeBsdfPrincipled": ("Emission Color", "Emission Strength")}
_STRENGTH_NODES = ("ShaderNodeLightFalloff", "ShaderNodeTexIES")


def light_sampled(reader, surface_socket, setting: str) -> bool:
    """Whether next-event estimation samples the material's emitters, for its Emission Sampling setting (Cycles'
    material.cycles.emission_sampling): never under None, under Auto by the estimate, always otherwise (Front and
    Back on one side: Shader.emission_sides).
    reader: the material's _MaterialReader, whose param() says which inputs fold to constants."""
    if setting == "NONE":
        return False
    if setting != "AUTO":
        return True
    return max(abs(v) for v in surface_estimate(reader, surface_socket)) > AUTO_THRESHOLD


def surface_estimate(reader, surface_socket) -> tuple:
    """Cycles' emission estimate of a Surface output (3 floats): estimate() of what feeds it, a tenth of it where a
    colour or value is turned into an emission. Cycles' light tree weighs the material's emitting triangles by it
    (Shader.emission_estimate)."""
    source = source_of(surface_socket)
    scale = AUTO_CONVERSION_SCALE if source.node is not None and source.socket.type != "SHADER" else 1.0
    return tuple(v * scale for v in estimate(reader, source))


def estimate(reader, source) -> tuple:
    """Cycles' emission estimate (3 floats) of the shader tree feeding a shader socket (source: sockets.Source)."""
    total = [0.0, 0.0, 0.0]
    pending = [(source, 1.0)]
    while pending:
        source, weight = pending.pop()
        node, groups, kind = source.node, source.groups, source.kind
        if node is None or weight == 0.0:
            continue
        if kind == "ShaderNodeAddShader":
            pending += [(source_of(node.inputs[i], groups), weight) for i in (0, 1)]
        elif kind == "ShaderNodeMixShader":
            fac = reader.param(node.inputs[0], groups, 1, node)
            weights = (1.0, 1.0) if fac.varies else (1.0 - fac.value[0], fac.value[0])
            pending += [(source_of(node.inputs[i], groups), weight * w) for i, w in ((1, weights[0]), (2, weights[1]))]
        elif kind in _EMITTERS:
            color_name, strength_name = _EMITTERS[kind]
            color = reader.param(node.inputs[color_name], groups, 3, node)
            value = (1.0, 1.0, 1.0) if color.varies else color.value
            strength = weight * _strength(reader, node.inputs[strength_name], groups, node)
            total = [t + strength * v for t, v in zip(total, value)]
        elif (fed := converted(source)) is not None:
            # A colour or value into a shader socket: the Emission node Cycles' graph puts there, its Color
            # the colour (at Strength 1) or its Strength the value (under white).
            consumer, socket_type = fed
            channels = 1 if socket_type == "VALUE" else 3
            read = reader.program.input(consumer, groups, socket_type)
            if channels == 1 and not isinstance(read, tuple):
                value = (weight * _linked_strength(reader, source),) * 3
            else:
                value = tuple(weight * v for v in (read * 3 if channels == 1 else read)) \
                    if isinstance(read, tuple) else (weight,) * 3
            total = [t + v for t, v in zip(total, value)]
    return tuple(total)


class SocketReader:
    """A reader for estimate() that takes inputs from their sockets alone (a linked one varies, an unlinked one is its
    value): for the world's estimate, whose images need not be decoded for it. What a linked input would fold to
    is not looked for (the world's Surface takes a Background or an Emission, whose linked inputs Cycles counts as
    white and 1 in any case)."""

    class _Param:
        __slots__ = ("varies", "value")

        def __init__(self, varies: bool, value: tuple):
            self.varies, self.value = varies, value

    @property
    def program(self):
        return self

    def input(self, socket, groups, want):
        return None   # not a constant: what feeds a shader socket is linked

    def param(self, socket, groups, channels: int, node):
        if source_of(socket, groups).node is not None:
            return self._Param(True, (1.0,) * channels)
        value = socket.default_value
        value = tuple(float(v) for v in value)[:channels] if hasattr(value, "__len__") else (float(value),)
        return self._Param(False, value)


def _strength(reader, socket, groups, node) -> float:
    """An emitter's Strength as Cycles' estimate reads it: its folded value, or what feeds it."""
    strength = reader.param(socket, groups, 1, node)
    if not strength.varies:
        return strength.value[0]
    return _linked_strength(reader, source_of(socket, groups))


def _linked_strength(reader, source) -> float:
    """A linked Strength: a Light Falloff's or IES Texture's own Strength, 1 for any other node."""
    if source.kind in _STRENGTH_NODES:
        return _strength(reader, source.node.inputs["Strength"], source.groups, source.node)
    return 1.0
