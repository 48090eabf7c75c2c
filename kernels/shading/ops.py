"""The ops a node program runs (OPS): one function per shader node kind, over the hits of one material.

Every op is `op(hits, inputs, op) -> {output name: array}`: hits a program.HitInputs, inputs a dict of
the node's input values by name ((n,) or (n, 3) float32 arrays; a folded constant is a Python float or a
(3,) array), op the kernels.programs.Op (its options). Numerics follow Cycles' SVM nodes
(`kernel/svm/*.h`). The ops that read the hits are in input_ops.py, the image lookups in image_ops.py;
the texture, colour and math nodes live in their own modules and are wrapped here (node_op). One exception:
the Bump op (bump.py) is `op(run, op)`, a program.ProgramRun, for it evaluates its Height at other points too.
"""
from __future__ import annotations

import inspect

import numpy as np

from ..vec import F32, matmul, normalize_rows_einsum
from . import color_nodes, curve_nodes, math_nodes, mix_nodes, vector_nodes
from . import gabor as gb
from . import noise as ns
from . import patterns as pt
from . import radial_tiling as rt
from . import sky as sk
from . import voronoi as vr
from .bump import bump_node
from .displace import displacement_node, vector_displacement_node
from .ies import ies_node
from .image_ops import environment, image
from .input_ops import attribute, camera_data, combine_xyz, fresnel_node, geometry, layer_weight, light_falloff, \
    light_path, normal_map, normal_node, object_info, particle_info, separate_xyz, tangent_node, tex_coord, uv_map, \
    vector_transform, volume_info, wireframe
from .program import full
from .raytrace import ambient_occlusion_node, bevel_node, raycast_node
from .shape_ops import curves_info, point_info


# ---------------------------------------------------------------- the Sky Texture, its tables precomputed at export
def sky(hits, inputs, op):
    """The Sky Texture node (sky.py), its tables precomputed at export (option "precomputed")."""
    return sk.sky_texture(full(inputs["Vector"], hits.n, 3), precomputed=op.option("precomputed"))


# ---------------------------------------------------------------- a texture node's Texture Mapping panel
def texture_mapping(hits, inputs, op):
    """Cycles' svm_node_texture_mapping: the Vector through the panel's (3, 4) transform (option "matrix",
    engine/export/nodes.py texture_mapping_matrix), normalized for the Normal type."""
    v = np.asarray(full(inputs["Vector"], hits.n, 3), F32)
    m = np.asarray(op.option("matrix"), F32).reshape(3, 4)
    out = (matmul(v, m[:, :3].T) + m[:, 3]).astype(F32)
    return {"Vector": normalize_rows_einsum(out) if op.option("normalize") else out}


# ---------------------------------------------------------------- the table
OPS = {
    "ShaderNodeTexCoord": tex_coord,
    "ShaderNodeUVMap": uv_map,
    "ShaderNodeNewGeometry": geometry,
    "ShaderNodeObjectInfo": object_info,
    "ShaderNodeHairInfo": curves_info,
    "ShaderNodePointInfo": point_info,
    "ATTRIBUTE": attribute,
    "VOLUME_INFO": volume_info,
    "PARTICLE_INFO": particle_info,
    "TEXTURE_MAPPING": texture_mapping,
    "ShaderNodeLayerWeight": layer_weight,
    "ShaderNodeFresnel": fresnel_node,
    "ShaderNodeLightPath": light_path,
    "ShaderNodeLightFalloff": light_falloff,
    "ShaderNodeTexIES": ies_node,
    "ShaderNodeSeparateXYZ": separate_xyz,
    "ShaderNodeCombineXYZ": combine_xyz,
    "ShaderNodeNormalMap": normal_map,
    "ShaderNodeTexImage": image,
    "ShaderNodeTexEnvironment": environment,
    "ShaderNodeTangent": tangent_node,
    "ShaderNodeVectorTransform": vector_transform,
    "ShaderNodeNormal": normal_node,
    "ShaderNodeCameraData": camera_data,
    "ShaderNodeWireframe": wireframe,
    "ShaderNodeTexSky": sky,
    "ShaderNodeAmbientOcclusion": ambient_occlusion_node,
    "ShaderNodeBevel": bevel_node,
    "ShaderNodeRaycast": raycast_node,
    "ShaderNodeDisplacement": displacement_node,
    "ShaderNodeVectorDisplacement": vector_displacement_node,
    "ShaderNodeBump": bump_node,   # takes the run, not the hits (program.ProgramRun._run)
}
# Ops that read nothing of the hits besides their inputs: folded at export when those are constants.
PURE_OPS = {"ShaderNodeSeparateXYZ", "ShaderNodeCombineXYZ", "TEXTURE_MAPPING"}


# ---------------------------------------------------------------- texture, colour and math nodes
# The node functions of noise.py, voronoi.py, gabor.py, patterns.py, math_nodes.py, color_nodes.py,
# mix_nodes.py, vector_nodes.py, radial_tiling.py and curve_nodes.py take snake_case keywords named after the node's sockets
# and options; these adapters pass what the program holds.


def _snake(identifier: str) -> str:
    return identifier.lower().replace(" ", "_")


def node_op(fn, inputs=None, options=None, outputs=None, result_key=None):
    """An op calling fn with the node's inputs (by socket identifier, snake_case, or renamed by `inputs`)
    and options (by RNA name, or renamed by `options`); outputs renamed by `outputs`, or by
    result_key(op) for the one output of a node whose identifier depends on its data type."""
    params = inspect.signature(fn).parameters
    inputs, options, outputs = inputs or {}, options or {}, outputs or {}

    def op_fn(hits, values, op):
        kwargs = {}
        for ident, value in values.items():
            key = inputs.get(ident, _snake(ident))
            if key in params:
                kwargs[key] = value
        for name, value in op.options:
            key = options.get(name, name)
            if key in params and key not in kwargs and value is not None:
                kwargs[key] = value
        result = fn(**kwargs)
        if result_key is not None:
            (value,) = result.values()
            return {result_key(op): value}
        return {outputs.get(k, k): v for k, v in result.items()}
    return op_fn


def _mix_result(op):
    return {"FLOAT": "Result_Float", "VECTOR": "Result_Vector", "RGBA": "Result_Color"}[op.option("data_type")]


_MIX_INPUTS = {"Factor_Float": "factor", "Factor_Vector": "factor", "A_Float": "a", "B_Float": "b",
               "A_Vector": "a", "B_Vector": "b", "A_Color": "a", "B_Color": "b"}
_TEXTURES = {
    "ShaderNodeTexNoise": node_op(ns.noise_texture, options={"noise_dimensions": "dimensions"}),
    "ShaderNodeTexWhiteNoise": node_op(ns.white_noise_texture, options={"noise_dimensions": "dimensions"}),
    "ShaderNodeTexWave": node_op(ns.wave_texture),
    "ShaderNodeTexVoronoi": node_op(vr.voronoi_texture, options={"voronoi_dimensions": "dimensions"}),
    "ShaderNodeTexGabor": node_op(gb.gabor_texture),
    "ShaderNodeTexChecker": node_op(pt.checker),
    "ShaderNodeTexGradient": node_op(pt.gradient),
    "ShaderNodeTexBrick": node_op(pt.brick),
    "ShaderNodeTexMagic": node_op(pt.magic),
}
_CONVERTERS = {
    "ShaderNodeMath": node_op(math_nodes.math),
    "ShaderNodeVectorMath": node_op(math_nodes.vector_math),
    "ShaderNodeMix": node_op(mix_nodes.mix, inputs=_MIX_INPUTS, result_key=_mix_result),
    "ShaderNodeMixRGB": node_op(mix_nodes.mix_rgb, inputs={"Fac": "fac", "Color1": "color1", "Color2": "color2"}),
    "ShaderNodeMapRange": node_op(math_nodes.map_range, inputs={"Value": "value", "From Min": "from_min",
                                                                "From Max": "from_max", "To Min": "to_min",
                                                                "To Max": "to_max", "Steps": "steps",
                                                                "Vector": "value", "From_Min_FLOAT3": "from_min",
                                                                "From_Max_FLOAT3": "from_max",
                                                                "To_Min_FLOAT3": "to_min", "To_Max_FLOAT3": "to_max",
                                                                "Steps_FLOAT3": "steps"}),
    "ShaderNodeClamp": node_op(math_nodes.clamp),
    "ShaderNodeSeparateColor": node_op(color_nodes.separate_color),
    "ShaderNodeCombineColor": node_op(color_nodes.combine_color),
    "ShaderNodeHueSaturation": node_op(color_nodes.hue_saturation),
    "ShaderNodeBrightContrast": node_op(color_nodes.bright_contrast),
    "ShaderNodeGamma": node_op(color_nodes.gamma),
    "ShaderNodeInvert": node_op(color_nodes.invert),
    "ShaderNodeRGBToBW": node_op(color_nodes.rgb_to_bw),
    "ShaderNodeBlackbody": node_op(color_nodes.blackbody),
    "ShaderNodeWavelength": node_op(color_nodes.wavelength),
    "ShaderNodeMapping": node_op(vector_nodes.mapping),
    "ShaderNodeVectorRotate": node_op(vector_nodes.vector_rotate),
    "ShaderNodeRadialTiling": node_op(rt.radial_tiling),
    "ShaderNodeValToRGB": node_op(curve_nodes.color_ramp),
    "ShaderNodeRGBCurve": node_op(curve_nodes.rgb_curves),
    "ShaderNodeVectorCurve": node_op(curve_nodes.vector_curves),
    "ShaderNodeFloatCurve": node_op(curve_nodes.float_curve),
}
OPS.update(_TEXTURES)
OPS.update(_CONVERTERS)
PURE_OPS |= set(_TEXTURES) | set(_CONVERTERS)
