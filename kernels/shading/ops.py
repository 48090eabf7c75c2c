"""The ops a node program runs: one function per shader node kind, over the hits of one material.

Every op is `op(hits, inputs, op) -> {output name: array}`: hits a program.HitInputs, inputs a dict of
the node's input values by name ((n,) or (n, 3) float32 arrays; a folded constant is a Python float or a
(3,) array), op the kernels.programs.Op (its options). Numerics follow Cycles' SVM nodes
(`kernel/svm/*.h`); the texture, colour and math nodes live in their own modules and are wrapped here.
"""
from __future__ import annotations

import inspect

import numpy as np

from ..paths import DIFFUSE, GLOSSY, REFLECT, SINGULAR, TRANSMIT
from ..scene import OBJ_COLOR, OBJ_FROM_WORLD, OBJ_LOCATION, OBJ_PASS_INDEX, OBJ_RANDOM, OBJ_TEXSPACE_LOC, \
    OBJ_TEXSPACE_SIZE, OBJ_WORLD_LINEAR
from ..textures import srgb_to_linear
from ..vec import F32, HALF, INV_2PI, INV_PI, ONE, ZERO, dot_rows_einsum, matmul, normalize_rows_einsum
from . import color_nodes, curve_nodes, math_nodes, mix_nodes, vector_nodes
from . import gabor as gb
from . import noise as ns
from . import normals
from . import patterns as pt
from .program import make_orthonormals
from . import sky as sk
from . import voronoi as vr


def full(x, n: int, channels: int = 1) -> np.ndarray:
    """An input as a full (n,) or (n, 3) float32 array (constants broadcast, not copied)."""
    a = np.asarray(x, F32)
    return np.broadcast_to(a, (n,) if channels == 1 else (n, 3))


# ---------------------------------------------------------------- geometry and coordinates
def object_point(hits, p: np.ndarray) -> np.ndarray:
    """(n, 3) world points into the hits' object spaces."""
    rows = hits.objects()
    m = rows[:, OBJ_FROM_WORLD:OBJ_FROM_WORLD + 12].reshape(-1, 3, 4)
    return np.einsum("nij,nj->ni", m[:, :, :3], p) + m[:, :, 3]


def generated(hits) -> np.ndarray:
    """Blender's Generated coordinates: the object-space point in the mesh's texture space, [0, 1]^3 over
    its bounding box (Cycles' ATTR_STD_GENERATED from the undeformed mesh; here the evaluated one). In a
    world: the ray direction."""
    if getattr(hits, "world", False):
        return hits.P
    return hits.memo("generated", lambda: _texture_space(hits, object_point(hits, hits.P)))


def _texture_space(hits, local: np.ndarray) -> np.ndarray:
    rows = hits.objects()
    loc = rows[:, OBJ_TEXSPACE_LOC:OBJ_TEXSPACE_LOC + 3]
    size = rows[:, OBJ_TEXSPACE_SIZE:OBJ_TEXSPACE_SIZE + 3]
    # Blender sync: scale 0.5 / size (0 for a flat axis), offset loc * scale - 0.5.
    scale = np.where(size != 0, F32(0.5) / np.where(size != 0, size, ONE), ZERO)
    return (local * scale - (loc * scale - HALF)).astype(F32)


def object_normal(hits, n: np.ndarray) -> np.ndarray:
    """World normals into object space (Cycles' object_inverse_normal_transform): M^T n, normalized."""
    m = hits.objects()[:, OBJ_WORLD_LINEAR:OBJ_WORLD_LINEAR + 9].reshape(-1, 3, 3)
    return normalize_rows_einsum(np.einsum("nji,nj->ni", m, n))


def camera_point(hits, p: np.ndarray) -> np.ndarray:
    """Cycles' camera space: x right, y up, z ahead of the camera. In a world p is a direction (Cycles adds
    the camera position first, so only the rotation applies)."""
    local = matmul(p if getattr(hits, "world", False) else p - hits.scene.camera_eye, hits.scene.camera_rotation)
    return local * np.array([1.0, 1.0, -1.0], F32)


def window_point(hits, p: np.ndarray) -> np.ndarray:
    """The point's place in the camera's frame: [0, 1]^2 over the image, z = 0."""
    c = camera_point(hits, p)
    xmin, xmax, ymin, ymax = hits.scene.view_plane
    if hits.scene.camera_kind == "ORTHO":
        x, y = c[:, 0], c[:, 1]
    else:
        z = np.where(c[:, 2] != 0, c[:, 2], F32(1e-30))
        x, y = c[:, 0] / z, c[:, 1] / z
    return np.stack([(x - xmin) / F32(xmax - xmin), (y - ymin) / F32(ymax - ymin), np.zeros_like(x)], 1).astype(F32)


_FLIP_Z = np.array([1.0, 1.0, -1.0], F32)


def _object_linear(hits, column: int) -> np.ndarray:
    return hits.objects()[:, column:column + 12 if column == OBJ_FROM_WORLD else column + 9]


def to_object(hits, v: np.ndarray, kind: str) -> np.ndarray:
    """World -> object space of POINT, VECTOR or NORMAL values (Cycles' object_inverse_*_transform)."""
    if kind == "POINT":
        return object_point(hits, v)
    if kind == "NORMAL":
        return object_normal(hits, v)
    a = _object_linear(hits, OBJ_FROM_WORLD).reshape(-1, 3, 4)[:, :, :3]
    return np.einsum("nij,nj->ni", a, v).astype(F32)


def to_world(hits, v: np.ndarray, kind: str) -> np.ndarray:
    """Object -> world space (Cycles' object_*_transform)."""
    if kind == "NORMAL":  # by the inverse transpose: (object_from_world)^T n
        a = _object_linear(hits, OBJ_FROM_WORLD).reshape(-1, 3, 4)[:, :, :3]
        return normalize_rows_einsum(np.einsum("nji,nj->ni", a, v)).astype(F32)
    m = _object_linear(hits, OBJ_WORLD_LINEAR).reshape(-1, 3, 3)
    out = np.einsum("nij,nj->ni", m, v)
    if kind == "POINT":
        out = out + hits.objects()[:, OBJ_LOCATION:OBJ_LOCATION + 3]
    return out.astype(F32)


def camera_from_world(hits, v: np.ndarray, kind: str) -> np.ndarray:
    """World -> Cycles' camera space (z ahead) of points, vectors or normals (normalized)."""
    if kind == "POINT":
        return camera_point(hits, v)
    out = matmul(v, hits.scene.camera_rotation) * _FLIP_Z
    return normalize_rows_einsum(out) if kind == "NORMAL" else out.astype(F32)


def world_from_camera(hits, v: np.ndarray, kind: str) -> np.ndarray:
    out = matmul(v * _FLIP_Z, hits.scene.camera_rotation.T)
    if kind == "POINT":
        return (out + hits.scene.camera_eye).astype(F32)
    return normalize_rows_einsum(out) if kind == "NORMAL" else out.astype(F32)


def vector_transform(hits, inputs, op):
    """The Vector Transform node (svm_node_vector_transform): between World, Object and Camera space,
    as a point, a vector or a normal. In a world (no object) object space is world space."""
    v = np.array(full(inputs["Vector"], hits.n, 3), F32)
    kind = op.option("vector_type", "VECTOR")
    source, target = op.option("convert_from", "WORLD"), op.option("convert_to", "OBJECT")
    has_object = not getattr(hits, "world", False)
    if source == "CAMERA" and target in ("WORLD", "OBJECT"):
        v = world_from_camera(hits, v, kind)
        source = "WORLD"
    if source == "OBJECT" and target in ("WORLD", "CAMERA"):
        if has_object:
            v = to_world(hits, v, kind)
        source = "WORLD"
    if source == "WORLD" and target == "OBJECT" and has_object:
        v = to_object(hits, v, kind)
    elif source == "WORLD" and target == "CAMERA":
        v = camera_from_world(hits, v, kind)
    return {"Vector": v}


def normal_node(hits, inputs, op):
    """The Normal node: its own direction (normalized) and the dot product with the input normal."""
    direction = np.asarray(op.option("direction", (0.0, 0.0, 1.0)), F32)
    direction = direction / max(float(np.linalg.norm(direction)), 1e-30)
    normal = normalize_rows_einsum(np.array(full(inputs["Normal"], hits.n, 3), F32))
    return {"Normal": np.broadcast_to(direction, (hits.n, 3)), "Dot": matmul(normal, direction).astype(F32)}


def camera_data(hits, inputs, op):
    """The Camera Data node: the shading point in Cycles' camera space (View Vector normalized, its z as
    View Z Depth, its length as View Distance)."""
    c = camera_point(hits, hits.P)
    distance = np.sqrt(dot_rows_einsum(c, c))
    return {"View Vector": c / np.where(distance > 0, distance, ONE)[:, None], "View Z Depth": c[:, 2],
            "View Distance": distance.astype(F32)}


def wireframe(hits, inputs, op):
    """The Wireframe node (svm_node_wireframe): 1 within Size / 2 of a triangle edge, in world units or
    (Pixel Size) in pixels, a pixel being the ray's spread across the view direction."""
    n = hits.n
    size = full(inputs["Size"], n)
    width = np.ones(n, F32)
    if op.option("use_pixel_size", False):
        a, b = make_orthonormals(hits.Ng)
        wi, dp = hits.I, hits.dp[:, None]
        across = [d * dp for d in (a, b)]
        across = [d - dot_rows_einsum(d, wi)[:, None] * wi for d in across]
        width = F32(0.5) * (np.sqrt(dot_rows_einsum(across[0], across[0]))
                            + np.sqrt(dot_rows_einsum(across[1], across[1])))
    width = (width * HALF * size) ** 2
    corners = hits.hit.corners(hits.idx)
    near = np.zeros(n, bool)
    for i in range(3):
        edge = corners[i] - corners[i - 1]
        crs = np.cross(edge, hits.P - corners[i])
        near |= dot_rows_einsum(crs, crs) < dot_rows_einsum(edge, edge) * width
    return {"Fac": near.astype(F32)}


def radial_tangent(hits, axis: str = "Z") -> np.ndarray:
    """Cycles' radial tangent (svm_node_tangent, and the default of unlinked Tangent inputs about Z): around
    the object's axis through its texture space's centre, to world space as a normal, made orthogonal to
    the shading normal. (n, 3) float32."""
    g = generated(hits) - HALF
    zero = np.zeros(hits.n, F32)
    if axis == "X":
        t = np.stack([zero, -g[:, 2], g[:, 1]], 1)
    elif axis == "Y":
        t = np.stack([-g[:, 2], zero, g[:, 0]], 1)
    else:
        t = np.stack([-g[:, 1], g[:, 0], zero], 1)
    a = hits.objects()[:, OBJ_FROM_WORLD:OBJ_FROM_WORLD + 12].reshape(-1, 3, 4)[:, :, :3]
    t = np.einsum("nji,nj->ni", a, t)  # object_normal_transform: (object_from_world)^T t
    n = hits.N
    return np.cross(n, normalize_rows_einsum(np.cross(t, n))).astype(F32)


def tangent_node(hits, inputs, op):
    """The Tangent node: radial about an axis, or the UV map's (MikkTSpace) tangent; Cycles' last step
    N x normalize(T x N) for both."""
    if op.option("direction_type", "RADIAL") == "RADIAL":
        return {"Tangent": radial_tangent(hits, op.option("axis", "Z"))}
    frame = hits.hit.tangent_frame(hits.idx)
    if frame is None:
        return {"Tangent": np.zeros((hits.n, 3), F32)}
    t = np.stack(frame[0], axis=1)
    n = hits.N
    return {"Tangent": np.cross(n, normalize_rows_einsum(np.cross(t, n))).astype(F32)}


def tex_coord(hits, inputs, op):
    wanted = op.option("outputs", ("Generated", "Normal", "UV", "Object", "Camera", "Window", "Reflection"))
    out = {}
    for name in wanted:
        if name == "Generated":
            out[name] = generated(hits)
        elif name == "Normal":
            out[name] = object_normal(hits, hits.N)
        elif name == "UV":
            out[name] = hits.uv
        elif name == "Object":
            matrix = op.option("object_from_world")
            if matrix is None:
                out[name] = object_point(hits, hits.P)
            else:
                m = np.asarray(matrix, F32).reshape(3, 4)
                out[name] = matmul(hits.P, m[:, :3].T) + m[:, 3]
        elif name == "Camera":
            out[name] = camera_point(hits, hits.P)
        elif name == "Window":
            out[name] = window_point(hits, hits.P)
        elif name == "Reflection":
            i, n = hits.I, hits.N
            out[name] = (F32(2.0) * dot_rows_einsum(i, n)[:, None] * n - i).astype(F32)
    return out


def uv_map(hits, inputs, op):
    name = op.option("uv_map", "")
    return {"UV": _uv(hits, name)}


def _uv(hits, name: str) -> np.ndarray:
    if not name:
        return hits.uv
    values = hits.attribute("uv:" + name)
    if values is None:
        return np.zeros((hits.n, 3), F32)
    return np.concatenate([values[:, :2], np.zeros((hits.n, 1), F32)], axis=1)


def geometry(hits, inputs, op):
    wanted = op.option("outputs", ("Position", "Normal", "True Normal", "Incoming", "Parametric", "Backfacing"))
    out = {}
    for name in wanted:
        if name == "Position":
            out[name] = hits.P
        elif name == "Normal":
            out[name] = hits.N
        elif name == "True Normal":
            out[name] = hits.Ng
        elif name == "Incoming":
            out[name] = hits.I
        elif name == "Parametric":
            b1, b2 = hits.barycentrics()
            # Cycles' u and v are the weights of corners 1 and 2 of its triangle (ours: 1 and 2).
            out[name] = np.stack([ONE - b1 - b2, b1, np.zeros_like(b1)], 1).astype(F32)
        elif name == "Backfacing":
            out[name] = hits.backfacing.astype(F32)
        elif name == "Tangent":
            out[name] = radial_tangent(hits, "Z")
        else:  # Pointiness, Random Per Island: the export warned
            out[name] = np.zeros((hits.n,) if name in ("Pointiness", "Random Per Island") else (hits.n, 3), F32)
    return out


def object_info(hits, inputs, op):
    rows = hits.objects()
    return {"Location": rows[:, OBJ_LOCATION:OBJ_LOCATION + 3],
            "Color": rows[:, OBJ_COLOR:OBJ_COLOR + 3],
            "Alpha": rows[:, OBJ_COLOR + 3],
            "Object Index": rows[:, OBJ_PASS_INDEX],
            "Material Index": np.full(hits.n, op.option("material_index", 0.0), F32),
            "Random": rows[:, OBJ_RANDOM]}


def attribute(hits, inputs, op):
    """A per-corner attribute by its exported name (kernels.scene.SceneArrays.attributes): (n, C) with C
    of 1 (float), 2 (UV), 3 (vector) or 4 (colour with alpha). Missing: zeros, as in Cycles."""
    values = hits.attribute(op.option("name"))
    n = hits.n
    if values is None:
        zero = np.zeros(n, F32)
        return {"Color": np.zeros((n, 3), F32), "Vector": np.zeros((n, 3), F32), "Fac": zero, "Alpha": zero}
    c = values.shape[1]
    if c == 1:
        vec = np.repeat(values, 3, axis=1)
    elif c == 2:
        vec = np.concatenate([values, np.zeros((n, 1), F32)], axis=1)
    else:
        vec = values[:, :3]
    # Cycles: a float attribute's Fac is the value; a vector's is its average; a colour's its average too.
    fac = values[:, 0] if c == 1 else vec.mean(axis=1, dtype=F32)
    alpha = values[:, 3] if c == 4 else np.ones(n, F32)
    return {"Color": vec, "Vector": vec, "Fac": fac, "Alpha": alpha}


def layer_weight(hits, inputs, op):
    n = hits.n
    normal = _normal_input(hits, inputs)
    cos = dot_rows_einsum(hits.I, normal)
    blend = full(inputs["Blend"], n)
    eta = np.maximum(ONE - blend, F32(1e-5))
    eta = np.where(hits.backfacing, eta, ONE / eta)
    out = {"Fresnel": fresnel_dielectric_cos(cos, eta)}
    f = np.abs(cos)
    b = np.clip(blend, ZERO, F32(1.0 - 1e-5))
    exponent = np.where(b < HALF, F32(2.0) * b, HALF / (ONE - b))
    f = np.where(blend != HALF, np.power(f, exponent), f)
    out["Facing"] = (ONE - f).astype(F32)
    return out


def fresnel_node(hits, inputs, op):
    normal = _normal_input(hits, inputs)
    eta = np.maximum(full(inputs["IOR"], hits.n), F32(1e-5))
    eta = np.where(hits.backfacing, ONE / eta, eta)
    return {"Fac": fresnel_dielectric_cos(dot_rows_einsum(hits.I, normal), eta)}


def fresnel_dielectric_cos(cos_i, eta) -> np.ndarray:
    """Cycles' fresnel_dielectric_cos (the Fresnel and Layer Weight nodes' form, to its float rounding)."""
    c = np.abs(np.asarray(cos_i, F32))
    eta = np.asarray(eta, F32)
    g = eta * eta - ONE + c * c
    ok = g > 0
    g = np.sqrt(np.where(ok, g, ONE))
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (g - c) / (g + c)
        b = (c * (g + c) - ONE) / (c * (g - c) + ONE)
        f = HALF * a * a * (ONE + b * b)
    return np.where(ok, f, ONE).astype(F32)


def _normal_input(hits, inputs):
    normal = inputs.get("Normal")
    return hits.N if normal is None else full(normal, hits.n, 3)


# Light Path outputs read from the path's last bounce (PathState.lobes): (row, label bit or None).
LOBE_OUTPUTS = {"Is Diffuse Ray": (0, DIFFUSE), "Is Glossy Ray": (0, GLOSSY), "Is Singular Ray": (0, SINGULAR),
                "Is Reflection Ray": (0, REFLECT), "Is Transmission Ray": (0, TRANSMIT),
                "Diffuse Depth": (1, None), "Glossy Depth": (2, None), "Transmission Depth": (3, None)}


def reads_lobes(program) -> bool:
    """Whether a program's Light Path nodes read the last bounce's lobe (the integrator then tracks it)."""
    return any(op.kind == "ShaderNodeLightPath" and set(op.option("outputs", ())) & set(LOBE_OUTPUTS)
               for op in program.ops)


def light_path(hits, inputs, op):
    """Cycles' Light Path outputs (svm_node_light_path) from the path state the integrator attached."""
    ray = hits.hit.ray
    n = hits.n
    zero = np.zeros(n, F32)

    def take(a):
        return np.take(a, hits.idx).astype(F32) if a is not None else zero
    shadow = ray is not None and ray.shadow
    depth = take(ray.depth) if ray is not None else zero
    camera = ray is None or (ray.camera and not shadow)
    further = ray is not None and (shadow or ray.emission)
    out = {"Is Camera Ray": ((depth == 0) & camera).astype(F32),
           "Is Shadow Ray": np.full(n, F32(1.0 if shadow else 0.0)),
           "Ray Length": take(ray.length) if ray is not None else zero,
           # Shadow rays, the world and lights are one bounce further (Cycles adds 1 for them).
           "Ray Depth": depth + F32(1.0 if further else 0.0),
           "Transparent Depth": take(ray.transparent) if ray is not None else zero,
           "Is Volume Scatter Ray": zero,
           "Portal Depth": take(ray.portal) if ray is not None and ray.portal is not None else zero}
    lobes = None if ray is None or ray.lobes is None else np.take(ray.lobes, hits.idx, axis=1)
    for name, (row, bit) in LOBE_OUTPUTS.items():
        if lobes is None:
            out[name] = zero
        elif bit is None:
            out[name] = lobes[row].astype(F32)
        else:
            out[name] = ((lobes[row] & bit) != 0).astype(F32)
    return out


# ---------------------------------------------------------------- vectors
def separate_xyz(hits, inputs, op):
    v = full(inputs["Vector"], hits.n, 3)
    return {"X": v[:, 0], "Y": v[:, 1], "Z": v[:, 2]}


def combine_xyz(hits, inputs, op):
    n = hits.n
    return {"Vector": np.stack([full(inputs[k], n) for k in ("X", "Y", "Z")], axis=1)}


def normal_map(hits, inputs, op):
    """The Normal Map node (tangent, world or Blender world space) over program inputs."""
    n = hits.n
    color = full(inputs["Color"], n, 3).T
    strength = full(inputs["Strength"], n)
    space = op.option("space", "TANGENT")
    ns = tuple(hits.N[:, k] for k in range(3))
    frame = hits.hit.tangent_frame(hits.idx) if space == "TANGENT" else None
    out = normals.normal_map(color, strength, space, ns, hits.backfacing, frame,
                             op.option("convention", "OPENGL") == "DIRECTX")
    return {"Normal": np.stack(out, axis=1)}


# ---------------------------------------------------------------- images
def image(hits, inputs, op):
    """The Image Texture node (Cycles' svm_node_tex_image and svm_node_tex_image_box, with the lookups of
    kernel/device/cpu/image.h): Closest, Linear or Cubic (B-spline) interpolation; Repeat, Extend, Clip
    (texels outside read zero) or Mirror extension; Flat, Box (blended by the object-space normal),
    Sphere and Tube projection. 8-bit sRGB images are filtered encoded and decoded after."""
    n = hits.n
    texture = op.option("texture", -1)
    vector = inputs.get("Vector")
    p = hits.uv if vector is None else full(vector, n, 3)
    if texture < 0:  # missing image: Cycles' magenta
        return {"Color": np.broadcast_to(np.array([1.0, 0.0, 1.0], F32), (n, 3)), "Alpha": np.ones(n, F32)}
    tex = hits.scene.textures[texture]
    projection = op.option("projection", "FLAT")
    if projection == "BOX":
        color, alpha = _box(hits, tex, p, op)
    else:
        if projection in ("SPHERE", "TUBE"):  # from the [0, 1] box to [-1, 1] first
            p = (map_to_sphere if projection == "SPHERE" else map_to_tube)((p - HALF) * F32(2.0))
        color, alpha = _image_lookup(tex, p[:, 0], p[:, 1], op)
    return {"Color": np.ascontiguousarray(color.T, F32), "Alpha": alpha.astype(F32)}


def environment(hits, inputs, op):
    """The Environment Texture node (svm_node_tex_environment): the direction, normalized, looked up in an
    equirectangular map or a mirror ball."""
    n = hits.n
    texture = op.option("texture", -1)
    if texture < 0:
        return {"Color": np.broadcast_to(np.array([1.0, 0.0, 1.0], F32), (n, 3)), "Alpha": np.ones(n, F32)}
    d = full(inputs["Vector"], n, 3)
    length = np.sqrt(dot_rows_einsum(d, d))
    d = d / np.where(length > 0, length, ONE)[:, None]
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    if op.option("projection", "EQUIRECTANGULAR") == "EQUIRECTANGULAR":
        u = HALF - np.arctan2(y, x) * INV_2PI
        v = ONE - np.arccos(np.clip(z, -ONE, ONE)) * INV_PI
        zero = length == 0
        u, v = np.where(zero, ZERO, u), np.where(zero, ZERO, v)
    else:  # mirror ball: the inverse of Cycles' mirrorball_to_direction
        y = y - ONE
        div = F32(2.0) * np.sqrt(np.maximum(F32(-0.5) * y, ZERO))
        div = np.where(div > 0, div, ONE)
        u, v = HALF * (x / div + ONE), HALF * (z / div + ONE)
    color, alpha = _image_lookup(hits.scene.textures[texture], u, v, op)
    return {"Color": np.ascontiguousarray(color.T, F32), "Alpha": alpha.astype(F32)}


def sky(hits, inputs, op):
    """The Sky Texture node (sky.py), its tables precomputed at export (option "precomputed")."""
    return sk.sky_texture(full(inputs["Vector"], hits.n, 3), precomputed=op.option("precomputed"))


def _image_lookup(tex, u, v, op):
    """(colour (3, n), alpha (n,)) of one image lookup, unassociated and decoded as the node asks."""
    values = sample_texture(tex, u, v, op.option("interpolation", "Linear"), op.option("extension", "REPEAT"))
    color = values[:3]
    alpha = values[3] if tex.has_alpha else np.ones(len(u), F32)
    if op.option("unassociate", False) and tex.has_alpha:
        partial = (alpha != 0) & (alpha != 1)
        color = np.where(partial, color / np.where(partial, alpha, ONE), color)
    if tex.srgb:
        color = srgb_to_linear(color)
    return color, alpha


def _box(hits, tex, p, op):
    """Box projection: three planar lookups weighted by the object-space normal's share of each axis."""
    signed = object_normal(hits, hits.N)
    a = np.abs(signed)
    a = a / np.maximum(a.sum(axis=1, keepdims=True), F32(1e-30))
    weight = _box_weights(a[:, 0], a[:, 1], a[:, 2], F32(op.option("projection_blend", 0.0)))
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    planes = ((np.where(signed[:, 0] < 0, ONE - y, y), z), (np.where(signed[:, 1] > 0, ONE - x, x), z),
              (np.where(signed[:, 2] > 0, ONE - y, y), x))
    color = np.zeros((3, hits.n), F32)
    alpha = np.zeros(hits.n, F32)
    for k, (u, v) in enumerate(planes):
        sel = np.flatnonzero(weight[k] > 0)
        if len(sel):
            c, al = _image_lookup(tex, u[sel], v[sel], op)
            color[:, sel] += weight[k][sel] * c
            alpha[sel] += weight[k][sel] * al
    return color, alpha


def _box_weights(nx, ny, nz, blend):
    """(3, n) weights of the X, Y and Z projections (svm_node_tex_image_box's seven zones)."""
    limit = HALF * (ONE + blend)
    w = np.zeros((3, len(nx)), F32)
    only_x = (nx > limit * (nx + ny)) & (nx > limit * (nx + nz))
    only_y = ~only_x & (ny > limit * (nx + ny)) & (ny > limit * (ny + nz))
    only_z = ~only_x & ~only_y & (nz > limit * (nx + nz)) & (nz > limit * (ny + nz))
    rest = ~(only_x | only_y | only_z)
    w[0, only_x], w[1, only_y], w[2, only_z] = 1, 1, 1
    if not blend > 0:
        w[0, rest] = 1  # Cycles falls back to one side
        return w
    with np.errstate(invalid="ignore", divide="ignore"):
        def ramp(a, b):
            return np.clip((a / (a + b) - HALF * (ONE - blend)) / blend, ZERO, ONE)
        xy = rest & (nz < (ONE - limit) * (ny + nx))
        yz = rest & ~xy & (nx < (ONE - limit) * (ny + nz))
        xz = rest & ~xy & ~yz & (ny < (ONE - limit) * (nx + nz))
        three = rest & ~xy & ~yz & ~xz
        t = ramp(nx, ny)
        w[0] = np.where(xy, t, w[0])
        w[1] = np.where(xy, ONE - t, w[1])
        t = ramp(ny, nz)
        w[1] = np.where(yz, t, w[1])
        w[2] = np.where(yz, ONE - t, w[2])
        t = ramp(nx, nz)
        w[0] = np.where(xz, t, w[0])
        w[2] = np.where(xz, ONE - t, w[2])
        for k, c in enumerate((nx, ny, nz)):
            w[k] = np.where(three, ((F32(2.0) - limit) * c + (limit - ONE)) / (F32(2.0) * limit - ONE), w[k])
    return w


def map_to_sphere(p: np.ndarray) -> np.ndarray:
    """Cycles' map_to_sphere (util/math_float3.h) of (n, 3) points: (u, v, 0), float32."""
    p = np.asarray(p, F32)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    length2 = x * x + y * y + z * z
    u = np.where((x == 0) & (y == 0), ZERO, HALF - np.arctan2(x, y) * INV_2PI)
    with np.errstate(invalid="ignore", divide="ignore"):
        v = ONE - np.arccos(np.clip(z / np.sqrt(length2), -ONE, ONE)) * INV_PI
    some = length2 > 0
    return np.stack([np.where(some, u, ZERO), np.where(some, v, ZERO), np.zeros_like(u)], 1).astype(F32)


def map_to_tube(p: np.ndarray) -> np.ndarray:
    """Cycles' map_to_tube (util/math_float3.h) of (n, 3) points: (u, v, 0), float32."""
    p = np.asarray(p, F32)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    length = np.sqrt(x * x + y * y)
    some = length > 0
    safe = np.where(some, length, ONE)
    u = (ONE - np.arctan2(x / safe, y / safe) * INV_PI) * HALF
    v = (z + ONE) * HALF
    return np.stack([np.where(some, u, ZERO), np.where(some, v, ZERO), np.zeros_like(u)], 1).astype(F32)


def _wrap(i: np.ndarray, size: int, extension: str):
    """Texel indices under the extension mode, and which are inside (CLIP reads zero outside)."""
    if extension == "REPEAT":
        return np.mod(i, size), None
    if extension == "MIRROR":
        m = np.abs(i + (i < 0)) % (2 * size)
        return np.where(m >= size, 2 * size - m - 1, m), None
    inside = (i >= 0) & (i < size)
    return np.clip(i, 0, size - 1), (inside if extension == "CLIP" else None)


def _taps(x: np.ndarray, size: int, interpolation: str):
    """Per axis: texel indices (k, n) int64 and weights (k, n) float32 of the filter."""
    if interpolation == "Closest":
        return np.floor(x * F32(size)).astype(np.int64)[None], np.ones((1, len(x)), F32)
    s = x * F32(size) - HALF
    i = np.floor(s)
    t = (s - i).astype(F32)
    i = i.astype(np.int64)
    if interpolation in ("Cubic", "Smart"):
        t2, t3 = t * t, t * t * t
        w = np.stack([(ONE - t) ** 3 / F32(6.0), (F32(3.0) * t3 - F32(6.0) * t2 + F32(4.0)) / F32(6.0),
                      (F32(-3.0) * t3 + F32(3.0) * t2 + F32(3.0) * t + ONE) / F32(6.0), t3 / F32(6.0)])
        return np.stack([i - 1, i, i + 1, i + 2]), w.astype(F32)
    return np.stack([i, i + 1]), np.stack([ONE - t, t])


def sample_texture(tex, u, v, interpolation: str, extension: str):
    """(C, n) filtered values of a kernels.textures.Texture at (u, v): colour (3 rows) and, for RGBA
    textures, alpha. Each filter tap gathers just the n texels it reads (Texture.gather: as float32,
    associated), weighs and sums them; the texture itself is never copied or converted whole."""
    width, height = tex.width, tex.height
    u = np.nan_to_num(np.clip(u, -1e6, 1e6), nan=0.0).astype(F32)
    v = np.nan_to_num(np.clip(v, -1e6, 1e6), nan=0.0).astype(F32)
    xi, xw = _taps(u, width, interpolation)
    yi, yw = _taps(v, height, interpolation)
    xi, x_in = _wrap(xi, width, extension)
    yi, y_in = _wrap(yi, height, extension)
    if extension == "CLIP":
        xw = xw * x_in
        yw = yw * y_in
    out = np.zeros((4 if tex.has_alpha else 3, len(u)), F32)
    for a in range(len(yi)):
        row = yi[a] * width
        for b in range(len(xi)):
            out += tex.gather(row + xi[b]) * (yw[a] * xw[b])
    return out


OPS = {
    "ShaderNodeTexCoord": tex_coord,
    "ShaderNodeUVMap": uv_map,
    "ShaderNodeNewGeometry": geometry,
    "ShaderNodeObjectInfo": object_info,
    "ATTRIBUTE": attribute,
    "ShaderNodeLayerWeight": layer_weight,
    "ShaderNodeFresnel": fresnel_node,
    "ShaderNodeLightPath": light_path,
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
}
# Ops that read nothing of the hits besides their inputs: folded at export when those are constants.
PURE_OPS = {"ShaderNodeSeparateXYZ", "ShaderNodeCombineXYZ"}


# ---------------------------------------------------------------- texture, colour and math nodes
# The node functions of noise.py, voronoi.py, gabor.py, patterns.py, math_nodes.py, color_nodes.py,
# mix_nodes.py, vector_nodes.py and curve_nodes.py take snake_case keywords named after the node's sockets
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
    "ShaderNodeValToRGB": node_op(curve_nodes.color_ramp),
    "ShaderNodeRGBCurve": node_op(curve_nodes.rgb_curves),
    "ShaderNodeVectorCurve": node_op(curve_nodes.vector_curves),
    "ShaderNodeFloatCurve": node_op(curve_nodes.float_curve),
}
OPS.update(_TEXTURES)
OPS.update(_CONVERTERS)
PURE_OPS |= set(_TEXTURES) | set(_CONVERTERS)
