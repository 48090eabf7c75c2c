"""Shader node trees -> node programs (kernels/programs.py), as Cycles' Blender layer compiles a shader
graph into SVM: the one place that walks the texture, colour, vector and input nodes of a material.

A closure input fed by such nodes becomes a Ref into the material's program. Every node is compiled once
per material (a subgraph shared by several inputs runs once per hit), in dependency order. Unlinked
inputs are constants; a node whose inputs are all constants and that reads nothing of the hit (math,
colour, a texture at a constant point) is evaluated here, once, and becomes a constant itself (constant
folding). Reroutes, muted nodes and groups are seen through (sockets.source_of). An unlinked Vector of
a procedural texture reads Generated coordinates, of an Image Texture the render UV map, as in Cycles.

A node Ember cannot evaluate gives its consumer that input's own value, with a warning naming the node
and the input. A tree holding a loop renders black before it gets here (graph.node_loop); one met while
compiling anyway is cut the same way. Compilers that read inputs are steps run by graph.run_nested,
so a chain of any length compiles without recursion.
"""
from __future__ import annotations

import inspect

import numpy as np

from ...kernels.programs import Op, Program, Ref
from ...kernels.shading import sky
from ...kernels.shading.ies import INVALID_PROFILE
from ...kernels.shading.input_ops import particle_attribute_name
from ...kernels.shading.normals import NORMAL_MAP_OBJECT_FRAME_FROM
from ...kernels.shading.ops import OPS, PURE_OPS
from ...kernels.shading.program import constant, convert
from ..version import blender_version
from . import ies, node_tables
from .graph import run_nested
from .sockets import socket_has_nan, source_of

F32 = np.float32

# Socket types as the program sees them.
_TYPES = {"VALUE": "VALUE", "INT": "VALUE", "BOOLEAN": "VALUE", "VECTOR": "VECTOR", "RGBA": "RGBA"}
# Inputs that default to a coordinate when unlinked (Cycles' LINK_TEXTURE_GENERATED / _UV).
_UV_DEFAULT = ("ShaderNodeTexImage",)
# Nodes whose options are read from their RNA properties as plain values (enums, booleans, numbers, strings).
_OPTION_TYPES = ("ENUM", "BOOLEAN", "INT", "FLOAT", "STRING")


class ProgramBuilder:
    """Compiles the nodes feeding one material's closure inputs into one program.

    images : images.ImageTextures of the export (image nodes register their images there).
    issues : the material's warning list (what cannot be evaluated, named).
    attributes : the export's set of attribute names the programs read (the mesh export reads them).
    layer_attribute : name -> (r, g, b, a), the View Layer attribute lookup (rgba_attributes.view_layer_attribute
        of the render's scene and view layer), or None without one.
    """

    def __init__(self, images, issues: list[str], attributes: set[str], tangent_uv_maps: list[str],
                 material_pass_index: int = 0, compilers: dict | None = None, layer_attribute=None,
                 traces: bool = True):
        self.images, self.issues, self.attributes = images, issues, attributes
        self.layer_attribute = layer_attribute
        # Whether the program may trace rays (a material's; not a world's, where Cycles evaluates its nodes
        # without KERNEL_FEATURE_NODE_RAYTRACE: Ambient Occlusion there is 1 and folds).
        self.traces = traces
        self.tangent_uv_maps = tangent_uv_maps
        self.material_pass_index = material_pass_index
        self._compilers = COMPILERS if compilers is None else compilers
        self.ops: list[Op] = []
        self._memo: dict = {}          # (node, groups) -> op index, or a dict of folded outputs
        self._visiting: set = set()

    def program(self) -> Program:
        return Program(tuple(self.ops))

    # ---------------------------------------------------------------- inputs
    def input(self, socket, groups: tuple, want: str | None = None):
        """What feeds an input socket: a Ref into the program, or a constant tuple (1 or 3 floats)."""
        return run_nested(self.read(socket, groups, want))

    def read(self, socket, groups: tuple, want: str | None = None):
        """input() as a step for compilers (engine/export/graph.py): `value = yield builder.read(...)`."""
        want = want or _TYPES.get(socket.type, "VALUE")
        source = source_of(socket, groups)
        if source.node is None:
            if socket_has_nan(source.socket):
                node = source.socket.node
                self.issues.append(f"{node.bl_label} '{node.name}' {source.socket.name} is not a number, read as 0")
            return socket_constant(source.socket, want)
        return (yield from self._output(source, socket, want))

    def _output(self, source, consumer, want: str):
        """A node output (sockets.Source) as the consumer reads it: a Ref, or a folded constant."""
        node, groups = source.node, source.groups
        key = (node.as_pointer(), tuple(g.as_pointer() for g in groups))
        if key in self._visiting:
            self.issues.append(f"{node.bl_label} '{node.name}' is part of a cycle in the node tree; "
                               f"{consumer.name} uses its own value")
            return socket_constant(consumer, want)
        if key not in self._memo:
            self._visiting.add(key)
            try:
                self._memo[key] = yield self._compile(node, groups, consumer)
            finally:
                self._visiting.discard(key)
        compiled = self._memo[key]
        if compiled is None:  # not supported (warned): the consumer's own value
            return socket_constant(consumer, want)
        return self.result(compiled, source.socket.identifier, _TYPES.get(source.socket.type, "VALUE"), want)

    @staticmethod
    def result(compiled, output: str, have: str, want: str):
        """An output of what add() returned (an op index or folded constants) as a consumer reads it."""
        if isinstance(compiled, dict):  # folded
            if f"{output}:{want}" in compiled:   # a folded output as a consumer of that type reads it
                return compiled[f"{output}:{want}"]
            return fold_convert(compiled[output], have, want)
        return Ref(compiled, output, have, want)

    def vector_op(self, operation: str, a, b):
        """Vector Math `operation` of two inputs (Refs or constants; colours are read as vectors, SCALE
        takes a float b): its Vector output, read as a colour."""
        second = "Scale" if operation == "SCALE" else "Vector_001"
        inputs = {"Vector": _reading(a, "VECTOR"), second: _reading(b, "VALUE" if operation == "SCALE" else "VECTOR")}
        return self.result(self.add("ShaderNodeVectorMath", inputs, {"operation": operation}), "Vector", "VECTOR",
                           "RGBA")

    def mix(self, factor, a, b):
        """(1 - f) a + f b of two colours, the factor clamped to [0, 1] (a Mix Shader's weights)."""
        inputs = {"Factor_Float": _reading(factor, "VALUE"), "A_Vector": _reading(a, "VECTOR"),
                  "B_Vector": _reading(b, "VECTOR")}
        options = {"data_type": "VECTOR", "factor_mode": "UNIFORM", "clamp_factor": True}
        return self.result(self.add("ShaderNodeMix", inputs, options), "Result_Vector", "VECTOR", "RGBA")

    def add(self, kind: str, inputs: dict, options: dict | None = None, outputs=None):
        """Add an op (or fold it): returns its op index, or a dict of constant outputs when folded."""
        options = dict(options or {})
        if outputs is not None:
            options["outputs"] = tuple(outputs)
        op = Op(kind, tuple(inputs.items()), tuple(sorted(options.items())))
        if kind in PURE_OPS and not any(isinstance(v, Ref) for v in inputs.values()):
            folded = fold(op)
            if folded is not None:
                return folded
        self.ops.append(op)
        return len(self.ops) - 1

    def _compile(self, node, groups, consumer):
        """The node's compiler: its result, or the step that computes it."""
        compiler = self._compilers.get(node.bl_idname)
        if compiler is None:
            self.issues.append(f"{node.bl_label} node '{node.name}' feeding {consumer.name} is not supported, "
                               f"used {consumer.name}'s own value")
            return None
        return compiler(self, node, groups)

    # ---------------------------------------------------------------- helpers for compilers
    def node_inputs(self, node, groups, *, vector_default: str | None = None):
        """Step: every enabled input of a node by identifier (a dict). An unlinked Vector reads the
        coordinate Cycles gives it (vector_default: 'Generated' or 'UV'), a Normal the shading normal
        (left out)."""
        out = {}
        for s in node.inputs:
            if not s.enabled or s.type not in _TYPES:
                continue
            linked = source_of(s, groups).node is not None
            if not linked and s.identifier == "Vector" and vector_default:
                out[s.identifier] = self.coordinate(vector_default)
            elif not linked and s.identifier == "Normal" and s.hide_value:
                continue
            else:
                out[s.identifier] = yield self.read(s, groups)
        return out

    def coordinate(self, name: str) -> Ref:
        """A Texture Coordinate output (Generated, UV, ...) of the hits, shared by all its readers."""
        key = ("coordinate", name)
        if key not in self._memo:
            self._memo[key] = self.add("ShaderNodeTexCoord", {}, {"object_from_world": None}, outputs=(name,))
        return Ref(self._memo[key], name, "VECTOR", "VECTOR")


def _reading(value, want: str):
    """A Ref or constant as a consumer of type `want` reads it."""
    if isinstance(value, Ref):
        return Ref(value.op, value.output, value.type, want)
    return fold_convert(tuple(value), "VALUE" if len(value) == 1 else "VECTOR", want)


def node_options(node) -> dict:
    """A node's own settings (enums, booleans, numbers, strings) by RNA identifier."""
    import bpy
    base = {p.identifier for p in bpy.types.ShaderNode.bl_rna.properties}
    out = {}
    for prop in node.bl_rna.properties:
        if prop.identifier in base or prop.type not in _OPTION_TYPES:
            continue
        value = getattr(node, prop.identifier)
        if prop.type in ("INT", "FLOAT") and getattr(prop, "array_length", 0):
            value = tuple(value)
        out[prop.identifier] = value
    return out


def socket_constant(socket, want: str) -> tuple:
    """An unlinked socket's value as a constant of the wanted type."""
    value = getattr(socket, "default_value", 0.0)
    values = np.atleast_1d(np.nan_to_num(np.asarray(value[:] if hasattr(value, "__len__") else value, np.float64)))
    if socket.type == "VECTOR" and len(values) < 3:     # a 2D vector (Radial Tiling's): z is 0
        values = np.concatenate([values, np.zeros(3 - len(values))])
    have = "RGBA" if socket.type == "RGBA" else "VECTOR" if len(values) >= 3 else "VALUE"
    values = values[:3] if have != "VALUE" else values[:1]
    return fold_convert(tuple(float(v) for v in values), have, want)


def fold_convert(value: tuple, have: str, want: str) -> tuple:
    """A constant between socket types, as the kernel converts arrays (program.convert)."""
    out = convert(np.asarray(value, F32)[None] if len(value) == 3 else np.asarray(value, F32), have, want, 1)
    return tuple(float(v) for v in np.ravel(out))


class _OneHit:
    """The hits of a folded op: one, and it reads nothing else."""
    n = 1


def fold(op: Op) -> dict | None:
    """Run a pure op on constants: {output: constant tuple}, or None when it cannot be folded."""
    inputs = {}
    for name, value in op.inputs:
        c = constant(value)
        inputs[name] = np.array([c], F32) if isinstance(c, float) else np.asarray(c, F32)[None]
    try:
        with np.errstate(all="ignore"):
            outputs = OPS[op.kind](_OneHit(), inputs, op)  # pure ops read only hits.n
    except Exception:  # noqa: BLE001 - not foldable after all: it runs per hit instead
        return None
    folded = {}
    for name, value in outputs.items():
        a = np.asarray(value, F32).reshape(-1)
        if a.size not in (1, 3):
            return None
        folded[name] = tuple(float(v) for v in a)
    return folded


# ---------------------------------------------------------------- node compilers
# compiler(builder, node, groups) -> op index, a dict of constant outputs, or None (warned); a compiler
# that reads inputs is a step (engine/export/graph.py): `value = yield builder.read(socket, groups)`, or
# `inputs = yield builder.node_inputs(node, groups)`, then returns its result.

def _linked_outputs(node) -> tuple:
    return tuple(o.identifier for o in node.outputs if o.is_linked) or tuple(o.identifier for o in node.outputs)


def _value(builder, node, groups):
    return {"Value": (float(node.outputs[0].default_value),)}


def _rgb(builder, node, groups):
    return {"Color": tuple(float(v) for v in node.outputs[0].default_value[:3])}


def _tex_coord(builder, node, groups):
    matrix = None
    if node.object is not None and "Object" in _linked_outputs(node):
        inverse = np.linalg.inv(np.array(node.object.matrix_world, np.float64))
        matrix = tuple(float(v) for v in inverse[:3, :4].ravel())
    return builder.add(node.bl_idname, {}, {"object_from_world": matrix}, outputs=_linked_outputs(node))


def _uv_map(builder, node, groups):
    if node.uv_map:
        builder.attributes.add("uv:" + node.uv_map)
    return builder.add(node.bl_idname, {}, {"uv_map": node.uv_map})


# The Geometry outputs that are mesh attributes made at export (engine/export/mesh_topology.py), as Cycles' sync
# makes ATTR_STD_POINTINESS and ATTR_STD_RANDOM_PER_ISLAND only for meshes whose shaders read them.
TOPOLOGY_ATTRIBUTES = {"Pointiness": "geom:pointiness", "Random Per Island": "geom:random_per_island"}


def _geometry(builder, node, groups):
    outputs = _linked_outputs(node)
    for name in outputs:
        if name in TOPOLOGY_ATTRIBUTES:
            builder.attributes.add(TOPOLOGY_ATTRIBUTES[name])
    return builder.add(node.bl_idname, {}, outputs=outputs)


# The Curves Info and Point Info outputs that are attributes the export makes (engine/export/curves.py,
# points.py), as Cycles' sync makes ATTR_STD_CURVE_INTERCEPT, _LENGTH, _RANDOM and ATTR_STD_POINT_RANDOM only for
# curves and points whose shaders read them.
SHAPE_ATTRIBUTES = {"ShaderNodeHairInfo": {"Intercept": "std:intercept", "Length": "std:length",
                                           "Random": "std:curve_random"},
                    "ShaderNodePointInfo": {"Random": "std:point_random"}}


def _shape_info(builder, node, groups):
    """Curves Info and Point Info (kernels/shading/shape_ops.py)."""
    outputs = _linked_outputs(node)
    for name in outputs:
        made = SHAPE_ATTRIBUTES[node.bl_idname].get(name)
        if made is not None:
            builder.attributes.add(made)
    return builder.add(node.bl_idname, {}, outputs=outputs)


def _object_info(builder, node, groups):
    return builder.add(node.bl_idname, {}, {"material_index": float(builder.material_pass_index)})


def _attribute(builder, node, groups):
    """Geometry attributes are the mesh's, Object and Instancer ones the object table's (read at export per
    instance, engine/export/rgba_attributes.py); View Layer ones are looked up now and folded into constants, as
    Cycles' resolve_view_layer_attributes does (intern/cycles/blender/shader.cpp)."""
    kind = node.attribute_type
    if kind == "VIEW_LAYER":
        return _view_layer_attribute(builder, node)
    prefix = {"OBJECT": "object:", "INSTANCER": "instancer:"}.get(kind, "attr:")
    name = prefix + node.attribute_name
    builder.attributes.add(name)
    return builder.add("ATTRIBUTE", {}, {"name": name})


def _particle_info(builder, node, groups):
    """Particle Info: each output read at export per instance, as an object attribute (particle_attribute_name,
    engine/export/rgba_attributes.py particle_values)."""
    outputs = _linked_outputs(node)
    for identifier in outputs:
        builder.attributes.add(particle_attribute_name(identifier))
    return builder.add("PARTICLE_INFO", {}, outputs=outputs)


def _view_layer_attribute(builder, node) -> dict:
    """A View Layer attribute's outputs as constants. Cycles folds every output as its consumer reads it:
    a float consumer of Color or Vector gets the average of r, g, b (not the colour-to-float conversion);
    the ":VALUE" entries say so (ProgramBuilder.result)."""
    lookup = builder.layer_attribute
    if lookup is None:
        builder.issues.append(f"Attribute '{node.name}': no view layer to read '{node.attribute_name}' from, "
                              f"reads zero")
        r = g = b = a = 0.0
    else:
        r, g, b, a = (float(v) for v in lookup(node.attribute_name))
    f32 = np.float32
    average = float((f32(r) + f32(g) + f32(b)) / f32(3.0))
    return {"Color": (r, g, b), "Vector": (r, g, b), "Fac": (average,), "Alpha": (a,),
            "Color:VALUE": (average,), "Vector:VALUE": (average,)}


def _volume_info(builder, node, groups):
    """Volume Info: the grids named color, density, flame and temperature at a point of a volume (zero
    elsewhere, as in Cycles)."""
    return builder.add("VOLUME_INFO", {})


def _vertex_color(builder, node, groups):
    name = "color:" + node.layer_name
    builder.attributes.add(name)
    return builder.add("ATTRIBUTE", {}, {"name": name})


def _plain(builder, node, groups):
    """A node read with all its inputs and options as they are."""
    inputs = yield builder.node_inputs(node, groups)
    return builder.add(node.bl_idname, inputs, node_options(node), outputs=_linked_outputs(node))


def _radial_tiling(builder, node, groups):
    """Radial Tiling (kernels/shading/radial_tiling.py), rounded as this Blender's Cycles. An unlinked Vector is
    the socket's own (x, y), not a coordinate. When every input is a constant, Blender evaluates the node itself
    (probed: constants from Value or Math nodes too) and Cycles renders that value: the op folds here, rounded
    as Blender does (option "constant")."""
    inputs = yield builder.node_inputs(node, groups)
    constant = not any(isinstance(value, Ref) for value in inputs.values())
    options = dict(node_options(node), cycles_version=blender_version(), constant=constant)
    return builder.add(node.bl_idname, inputs, options, outputs=_linked_outputs(node))


def _light_path(builder, node, groups):
    outputs = _linked_outputs(node)
    return builder.add(node.bl_idname, {}, outputs=outputs)


def _normal_map(builder, node, groups):
    if node.space == "TANGENT":
        builder.tangent_uv_maps.append(node.uv_map)
    inputs = {"Color": (yield builder.read(node.inputs["Color"], groups, "RGBA")),
              "Strength": (yield builder.read(node.inputs["Strength"], groups, "VALUE"))}
    # Blender 5.1 added the DirectX convention; its Base option (the displaced or undisplaced surface's
    # normal under "Displacement and Bump") is not read.
    options = {"space": node.space, "convention": getattr(node, "convention", "OPENGL"),
               "object_frame": blender_version() >= NORMAL_MAP_OBJECT_FRAME_FROM}
    return builder.add(node.bl_idname, inputs, options)


def _image(builder, node, groups):
    image = node.image
    texture, tiles = -1, None
    if image is None:
        builder.issues.append(f"Image Texture '{node.name}' has no image, rendered magenta")
    elif image.source == "TILED":
        # UDIM: each tile a texture of its own, picked per lookup by its tile number (image_ops.image).
        tiles = builder.images.tiles(image)
        texture = tiles[0][1] if tiles else -1
    else:
        index = builder.images.index(image, node.image_user)
        texture = -1 if index is None else index
    unassociate = (node.outputs["Alpha"].is_linked and image is not None and not image.colorspace_settings.is_data
                   and image.alpha_mode not in ("CHANNEL_PACKED", "NONE"))
    options = {"texture": texture, "interpolation": node.interpolation, "extension": node.extension,
               "projection": node.projection, "projection_blend": float(node.projection_blend),
               "unassociate": bool(unassociate)}
    if tiles is not None:
        options["tiles"] = tiles
    inputs = _mapped(builder, node, (yield builder.node_inputs(node, groups, vector_default="UV")))
    return builder.add(node.bl_idname, inputs, options)


def _texture(builder, node, groups):
    """A procedural texture: an unlinked Vector reads Generated coordinates."""
    inputs = yield builder.node_inputs(node, groups, vector_default="Generated")
    if any(s.identifier == "Vector" and not s.enabled for s in node.inputs):
        inputs.setdefault("Vector", (0.0, 0.0, 0.0))   # 1D modes have no Vector (not even by name): W alone is read
    else:
        inputs = _mapped(builder, node, inputs)
    options = dict(node_options(node), cycles_version=blender_version())
    return builder.add(node.bl_idname, inputs, options, outputs=_linked_outputs(node))


# Blender's TexMapping axis enums, Cycles' TextureMapping::Mapping: NONE, X, Y, Z.
_AXES = {"NONE": 0, "X": 1, "Y": 2, "Z": 3}


def texture_mapping_matrix(mapping):
    """(3, 4) float64 of a texture node's Texture Mapping panel as Cycles' TextureMapping::compute_transform applies
    it to the Vector (Blender's sync reads location, rotation, scale, type and the axes, not Min and Max): the axes
    picked first, then scale, rotation (XYZ Euler) and location for a Point, their inverse for a Texture, no
    location for a Vector, the inverse transpose for a Normal (then normalized). None where it changes nothing."""
    import mathutils
    translation, rotation, scale = (np.array(tuple(v), np.float64) for v in
                                    (mapping.translation, mapping.rotation, mapping.scale))
    axes = [_AXES[a] for a in (mapping.mapping_x, mapping.mapping_y, mapping.mapping_z)]
    if not translation.any() and not rotation.any() and (scale == 1).all() and axes == [1, 2, 3]:
        return None
    pick = np.zeros((4, 4))
    pick[3, 3] = 1.0
    for row, axis in enumerate(axes):
        if axis:
            pick[row, axis - 1] = 1.0
    kind = mapping.vector_type
    if kind in ("TEXTURE", "NORMAL"):   # kept invertible, as Cycles keeps it
        scale = np.where(np.abs(scale) < 1e-5, np.where(scale < 0, -1e-5, 1e-5), scale)
    s, r, t = np.diag([*scale, 1.0]), np.eye(4), np.eye(4)
    r[:3, :3] = np.array(mathutils.Euler(tuple(rotation), "XYZ").to_matrix())
    t[:3, 3] = translation
    if kind == "TEXTURE":
        matrix = np.linalg.inv(t @ r @ s)
    elif kind == "POINT":
        matrix = t @ r @ s
    elif kind == "VECTOR":
        matrix = r @ s
    else:
        matrix = np.linalg.inv(r @ s).T
    return (matrix @ pick)[:3]


def _mapped(builder, node, inputs: dict) -> dict:
    """The node's inputs, its Vector moved by its Texture Mapping panel (texture_mapping_matrix) where that does
    anything, as Cycles' TextureMapping::compile_begin moves it before the texture reads it."""
    mapping = getattr(node, "texture_mapping", None)
    matrix = None if mapping is None or "Vector" not in inputs else texture_mapping_matrix(mapping)
    if matrix is None:
        return inputs
    moved = builder.add("TEXTURE_MAPPING", {"Vector": _reading(inputs["Vector"], "VECTOR")},
                        {"matrix": tuple(float(v) for v in matrix.ravel()),
                         "normalize": mapping.vector_type == "NORMAL"})
    return {**inputs, "Vector": Ref(moved, "Vector", "VECTOR", "VECTOR")}


def _color_ramp(builder, node, groups):
    table, interpolate = node_tables.color_ramp_table(node.color_ramp)
    inputs = yield builder.node_inputs(node, groups)
    return builder.add(node.bl_idname, inputs, {"table": table, "interpolate": interpolate})


def _curves(baker):
    def compile_curves(builder, node, groups):
        table, lo, hi, extrapolate = baker(node.mapping)
        inputs = yield builder.node_inputs(node, groups)
        return builder.add(node.bl_idname, inputs, {"table": table, "min_x": lo, "max_x": hi, "extrapolate": extrapolate})
    return compile_curves


def _environment(builder, node, groups):
    texture = -1
    if node.image is None:
        builder.issues.append(f"Environment Texture '{node.name}' has no image, rendered magenta")
    else:
        index = builder.images.index(node.image, node.image_user)
        texture = -1 if index is None else index
    options = {"texture": texture, "interpolation": node.interpolation, "projection": node.projection,
               "extension": "REPEAT", "unassociate": False}
    inputs = _mapped(builder, node, (yield builder.node_inputs(node, groups, vector_default="Generated")))
    return builder.add(node.bl_idname, inputs, options)


def _sky(builder, node, groups):
    """The Sky Texture: its tables precomputed here; with the sun disc on, Blender disables the Vector and
    Cycles reads the default (Generated: the direction, in a world)."""
    if node.sky_type not in sky.SKY_TYPES:
        builder.issues.append(f"Sky Texture '{node.name}': the {node.sky_type.replace('_', ' ').title()} model "
                              f"is not supported, rendered black")
        return {"Color": (0.0, 0.0, 0.0)}
    accepted = inspect.signature(sky.precompute_sky).parameters
    settings = {k: v for k, v in node_options(node).items() if k in accepted}
    inputs = yield builder.node_inputs(node, groups, vector_default="Generated")
    inputs = _mapped(builder, node, {**inputs, "Vector": inputs.get("Vector", builder.coordinate("Generated"))})
    return builder.add(node.bl_idname, inputs, {"precomputed": sky.precompute_sky(**settings)})


def _ies(builder, node, groups):
    """The IES Texture: its profile read here (engine/export/ies.py) from the node's text or file, as Cycles'
    IESLightNode; an unlinked Vector reads the incoming direction in object space, as a normal (Cycles'
    LINK_TEXTURE_INCOMING: on a lamp, the direction from the lamp toward the point it lights)."""
    table, problem = _ies_profile(node)
    if problem:
        builder.issues.append(f"IES Texture '{node.name}': {problem}; it gives 100 x its Strength, as in Cycles")
    inputs = yield builder.node_inputs(node, groups)
    if table is None and not isinstance(inputs["Strength"], Ref):
        return {"Fac": (float(INVALID_PROFILE) * float(inputs["Strength"][0]),)}
    if source_of(node.inputs["Vector"], groups).node is None:
        incoming = builder.add("ShaderNodeNewGeometry", {}, outputs=("Incoming",))
        local = builder.add("ShaderNodeVectorTransform", {"Vector": Ref(incoming, "Incoming", "VECTOR", "VECTOR")},
                            {"vector_type": "NORMAL", "convert_from": "WORLD", "convert_to": "OBJECT"})
        inputs["Vector"] = Ref(local, "Vector", "VECTOR", "VECTOR")
    return builder.add(node.bl_idname, inputs, {"table": table})


def _ies_profile(node):
    """(IesTable or None, what went wrong or None) of an IES Texture node: its Text (Internal) or its file
    (External, relative to the .blend)."""
    import bpy
    if node.mode == "INTERNAL":
        if node.ies is None:
            return None, "it has no IES text"
        text, source = node.ies.as_string(), f"the text '{node.ies.name}'"
    else:
        path = bpy.path.abspath(node.filepath)
        if not node.filepath:
            return None, "it has no IES file"
        try:
            with open(path, encoding="latin-1") as f:
                text = f.read()
        except OSError as error:
            return None, f"its file {path} could not be read ({error.strerror})"
        source = f"the file {path}"
    table = ies.parse_ies(text)
    return (table, None) if table is not None else (None, f"{source} is not an IES file Cycles can read")


def _tangent(builder, node, groups):
    if node.direction_type == "UV_MAP":
        builder.tangent_uv_maps.append(node.uv_map)
    return builder.add(node.bl_idname, {}, {"direction_type": node.direction_type, "axis": node.axis})


def _vector_transform(builder, node, groups):
    """Light space (Blender 5.3) is not one of the spaces Cycles' SVM transforms between (World, Object,
    Camera): passed through."""
    if "LIGHT" in (node.convert_from, node.convert_to):
        builder.issues.append(f"Vector Transform '{node.name}': Light space is not supported, the vector is "
                              f"passed through")
    inputs = yield builder.node_inputs(node, groups)
    return builder.add(node.bl_idname, inputs, node_options(node), outputs=_linked_outputs(node))


def _normal(builder, node, groups):
    direction = tuple(float(v) for v in node.outputs["Normal"].default_value)
    inputs = yield builder.node_inputs(node, groups)
    return builder.add(node.bl_idname, inputs, {"direction": direction}, outputs=_linked_outputs(node))


def _ambient_occlusion(builder, node, groups):
    """Ambient Occlusion, traced at hits (kernels/shading/raytrace.py). An unlinked Distance of 0 reads the
    world's AO distance (Cycles' NODE_AO_GLOBAL_RADIUS, scene/shader_nodes.cpp). Where Cycles traces nothing
    (a world) AO is 1 and Color passes through."""
    inputs = yield builder.node_inputs(node, groups)
    if not builder.traces and not isinstance(inputs["Color"], Ref):
        return {"AO": (1.0,), "Color": tuple(inputs["Color"])}
    distance = node.inputs["Distance"]
    options = {"samples": int(node.samples), "inside": bool(node.inside), "only_local": bool(node.only_local),
               "world_distance": source_of(distance, groups).node is None and float(distance.default_value) == 0.0}
    return builder.add(node.bl_idname, inputs, options)


def _bevel(builder, node, groups):
    """Bevel, traced at hits (kernels/shading/raytrace.py)."""
    inputs = yield builder.node_inputs(node, groups)
    return builder.add(node.bl_idname, inputs, {"samples": int(node.samples)})


def _raycast(builder, node, groups):
    """Raycast (Blender 5.3), traced at hits (kernels/shading/raytrace.py): an unlinked Position is the hit's, an
    unlinked Direction its shading normal (Cycles' LINK_POSITION, LINK_NORMAL). Its sampled attributes are not
    read (zero, with a warning). Where Cycles traces nothing (a world, a lamp) it finds no hit."""
    inputs = yield builder.node_inputs(node, groups)
    for name in ("Position", "Direction"):
        if source_of(node.inputs[name], groups).node is None:
            inputs.pop(name, None)
    items = [item.name for item in getattr(node, "sample_attribute_items", ())]
    if items:
        builder.issues.append(f"Raycast '{node.name}': its sampled attributes ({', '.join(items)}) are not "
                              f"supported, they read zero")
    outputs = tuple(o.identifier for o in node.outputs if o.is_linked and o.identifier in _RAYCAST_OUTPUTS) \
        or _RAYCAST_OUTPUTS
    return builder.add(node.bl_idname, inputs, {"only_local": bool(node.only_local)}, outputs=outputs)


_RAYCAST_OUTPUTS = ("Is Hit", "Self Hit", "Hit Distance", "Hit Position", "Hit Normal")


def _bump(builder, node, groups):
    inputs = yield builder.node_inputs(node, groups)
    return builder.add(node.bl_idname, inputs, {"invert": bool(node.invert)})


def _displacement(builder, node, groups):
    """Displacement and Vector Displacement (kernels/shading/displace.py); tangent space reads the render UV
    map's tangents (Cycles' ATTR_STD_UV_TANGENT)."""
    inputs = yield builder.node_inputs(node, groups)
    if node.bl_idname == "ShaderNodeVectorDisplacement" and node.space == "TANGENT":
        builder.tangent_uv_maps.append("")
    return builder.add(node.bl_idname, inputs, {"space": node.space})


COMPILERS = {
    "ShaderNodeDisplacement": _displacement,
    "ShaderNodeVectorDisplacement": _displacement,
    "ShaderNodeVectorTransform": _vector_transform,
    "ShaderNodeNormal": _normal,
    "ShaderNodeCameraData": _plain,
    "ShaderNodeWireframe": _plain,
    "ShaderNodeLightFalloff": _plain,
    "ShaderNodeTexIES": _ies,
    "ShaderNodeParticleInfo": _particle_info,
    "ShaderNodeTangent": _tangent,
    "ShaderNodeTexEnvironment": _environment,
    "ShaderNodeTexSky": _sky,
    **{name: _texture for name in ("ShaderNodeTexNoise", "ShaderNodeTexWhiteNoise", "ShaderNodeTexWave",
                                   "ShaderNodeTexVoronoi", "ShaderNodeTexGabor", "ShaderNodeTexChecker",
                                   "ShaderNodeTexGradient", "ShaderNodeTexBrick", "ShaderNodeTexMagic")},
    **{name: _plain for name in ("ShaderNodeMath", "ShaderNodeVectorMath", "ShaderNodeMix", "ShaderNodeMixRGB",
                                 "ShaderNodeMapRange", "ShaderNodeClamp", "ShaderNodeSeparateColor",
                                 "ShaderNodeCombineColor", "ShaderNodeHueSaturation", "ShaderNodeBrightContrast",
                                 "ShaderNodeGamma", "ShaderNodeInvert", "ShaderNodeRGBToBW", "ShaderNodeBlackbody",
                                 "ShaderNodeWavelength", "ShaderNodeMapping", "ShaderNodeVectorRotate")},
    "ShaderNodeRadialTiling": _radial_tiling,
    "ShaderNodeValToRGB": _color_ramp,
    "ShaderNodeRGBCurve": _curves(node_tables.rgb_curves_table),
    "ShaderNodeVectorCurve": _curves(node_tables.vector_curves_table),
    "ShaderNodeFloatCurve": _curves(node_tables.float_curve_table),
    "ShaderNodeBump": _bump,
    "ShaderNodeAmbientOcclusion": _ambient_occlusion,
    "ShaderNodeBevel": _bevel,
    "ShaderNodeRaycast": _raycast,
    "ShaderNodeValue": _value,
    "ShaderNodeRGB": _rgb,
    "ShaderNodeTexCoord": _tex_coord,
    "ShaderNodeUVMap": _uv_map,
    "ShaderNodeNewGeometry": _geometry,
    "ShaderNodeObjectInfo": _object_info,
    "ShaderNodeHairInfo": _shape_info,
    "ShaderNodePointInfo": _shape_info,
    "ShaderNodeAttribute": _attribute,
    "ShaderNodeVolumeInfo": _volume_info,
    "ShaderNodeVertexColor": _vertex_color,
    "ShaderNodeLayerWeight": _plain,
    "ShaderNodeFresnel": _plain,
    "ShaderNodeLightPath": _light_path,
    "ShaderNodeSeparateXYZ": _plain,
    "ShaderNodeCombineXYZ": _plain,
    "ShaderNodeNormalMap": _normal_map,
    "ShaderNodeTexImage": _image,
}
