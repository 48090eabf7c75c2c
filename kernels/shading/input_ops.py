"""The ops of the nodes that read the hits: coordinates and spaces (Texture Coordinate, UV Map, Vector
Transform, Tangent, Normal, Camera Data), Geometry, Object Info, Attribute, Layer Weight, Fresnel, Light
Path, Wireframe, Separate/Combine XYZ and Normal Map.

Each is an op as kernels.shading.ops describes it, `op(hits, inputs, op) -> {output name: array}`, and
follows Cycles' SVM node (`kernel/svm/*.h`).
"""
from __future__ import annotations

import numpy as np

from ..paths import DIFFUSE, GLOSSY, REFLECT, SINGULAR, TRANSMIT, VOLUME_SCATTER
from ..scene import OBJ_COLOR, OBJ_FROM_WORLD, OBJ_LOCATION, OBJ_PASS_INDEX, OBJ_RANDOM, OBJ_TEXSPACE_LOC, \
    OBJ_TEXSPACE_SIZE, OBJ_WORLD_LINEAR
from ..vec import F32, HALF, ONE, ZERO, columns, dot_rows_einsum, matmul, normalize_rows_einsum
from . import normals, shape_ops
from .program import full, make_orthonormals


# ---------------------------------------------------------------- coordinates and spaces
# Per-corner attributes (kernels.scene.SceneArrays.attributes, object space) of a mesh before true displacement
# moved it, stored for meshes whose material displaces with "Displacement and Bump" (kernels/shading/bump.py):
# the position as (x, y, z, 1) (the 1 marks the meshes that have it) and the normal Cycles bumps from.
UNDISPLACED_POSITION, UNDISPLACED_NORMAL = "geom:undisplaced_position", "geom:undisplaced_normal"
# The mesh's positions before its deforming modifiers (Blender's ORCO layer, which a render's depsgraph always
# computes; Cycles' ATTR_STD_GENERATED is made from it), per corner with a 1; only where they differ.
UNDEFORMED_POSITION = "geom:undeformed_position"


def object_point(hits, p: np.ndarray) -> np.ndarray:
    """(n, 3) world points into the hits' object spaces."""
    rows = hits.objects()
    m = rows[:, OBJ_FROM_WORLD:OBJ_FROM_WORLD + 12].reshape(-1, 3, 4)
    return np.einsum("nij,nj->ni", m[:, :, :3], p) + m[:, :, 3]


def generated(hits) -> np.ndarray:
    """Blender's Generated coordinates: the object-space point in the mesh's texture space, [0, 1]^3 over
    its bounding box (Cycles' ATTR_STD_GENERATED: from the mesh before its deforming modifiers where the mesh
    keeps that, UNDEFORMED_POSITION; else the evaluated one, before true displacement where the mesh keeps that:
    UNDISPLACED_POSITION). In a world: the ray direction. On a lamp, which has no such attribute: the
    object-space position (svm_node_attr's fallback)."""
    if getattr(hits, "world", False):
        return hits.P
    if getattr(hits, "lamp", False):
        return object_point(hits, hits.P)
    def make():
        local = _undisplaced_point(hits)
        return shape_ops.shape_generated(hits, _texture_space(hits, local), local, _texture_space)
    return hits.memo("generated", make)


def _undisplaced_point(hits) -> np.ndarray:
    # Cycles' Generated is an attribute: at a bump's offsets it follows the barycentrics (P_bary), not P.
    p = object_point(hits, getattr(hits, "P_bary", hits.P))
    for name in (UNDISPLACED_POSITION, UNDEFORMED_POSITION):
        kept = hits.attribute(name) if hasattr(hits, "attribute") else None
        if kept is not None:
            p = np.where(columns(kept[:, 3] > HALF), kept[:, :3], p).astype(F32)
    return p


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


# ---------------------------------------------------------------- the hit: geometry, object, attributes
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
            out[name] = shape_ops.shape_tangent(hits, radial_tangent(hits, "Z"))
        elif name == "Pointiness":         # a vertex attribute, interpolated (Cycles' ATTR_STD_POINTINESS)
            out[name] = _float_attribute(hits, "geom:pointiness", True)
        elif name == "Random Per Island":  # a face attribute, not interpolated (ATTR_STD_RANDOM_PER_ISLAND)
            out[name] = _float_attribute(hits, "geom:random_per_island", False)
    return out


def _float_attribute(hits, name: str, interpolate: bool) -> np.ndarray:
    """(n,) a one-channel attribute made at export (engine/export/mesh_topology.py); 0 where the scene has
    none, as Cycles' attribute lookup gives."""
    values = hits.attribute(name, interpolate)
    return np.zeros(hits.n, F32) if values is None else np.ascontiguousarray(values[:, 0], F32)


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


# Particle Info's outputs and whether each is a vector; the export reads each per instance as the object attribute
# particle_attribute_name(output) (engine/export/rgba_attributes.py particle_values).
PARTICLE_OUTPUTS = {"Index": False, "Random": False, "Age": False, "Lifetime": False, "Location": True,
                    "Size": False, "Velocity": True, "Angular Velocity": True}


def particle_attribute_name(output: str) -> str:
    return "particle:" + output.lower().replace(" ", "_")


def particle_info(hits, inputs, op):
    """Particle Info (svm_node_particle_info): the outputs the export read per instance (object attributes,
    particle_attribute_name); zero where none was read (a world, a lamp)."""
    out = {}
    for name in op.option("outputs", ()):
        values = hits.attribute(particle_attribute_name(name))
        vector = PARTICLE_OUTPUTS[name]
        if values is None:
            out[name] = np.zeros((hits.n, 3) if vector else hits.n, F32)
        else:
            out[name] = np.ascontiguousarray(values[:, :3] if vector else values[:, 0], F32)
    return out


def volume_info(hits, inputs, op):
    """Volume Info: the grids Blender names color, density, flame and temperature (Cycles' standard volume
    attributes), zero where the point has none (a mesh's volume, a surface)."""
    n = hits.n
    out = {}
    for socket, name, channels in (("Color", "color", 3), ("Density", "density", 1), ("Flame", "flame", 1),
                                   ("Temperature", "temperature", 1)):
        values = hits.attribute("attr:" + name)
        if values is None:
            out[socket] = np.zeros((n, 3) if channels == 3 else n, F32)
        elif channels == 3:
            out[socket] = np.ascontiguousarray(np.repeat(values[:, :1], 3, axis=1) if values.shape[1] == 1
                                               else values[:, :3], F32)
        else:
            out[socket] = np.ascontiguousarray(values[:, 0] if values.shape[1] == 1 else values[:, :3].mean(axis=1),
                                               F32)
    return out


# ---------------------------------------------------------------- facing: Layer Weight, Fresnel
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


# ---------------------------------------------------------------- Light Path
# Light Path outputs read from the path's last bounce (PathState.lobes): (row, label bit or None).
LOBE_OUTPUTS = {"Is Diffuse Ray": (0, DIFFUSE), "Is Glossy Ray": (0, GLOSSY), "Is Singular Ray": (0, SINGULAR),
                "Is Reflection Ray": (0, REFLECT), "Is Transmission Ray": (0, TRANSMIT),
                "Is Volume Scatter Ray": (0, VOLUME_SCATTER),
                "Diffuse Depth": (1, None), "Glossy Depth": (2, None), "Transmission Depth": (3, None)}


def reads_lobes(program) -> bool:
    """Whether a program's Light Path nodes read the last bounce's lobe (the integrator then tracks it)."""
    return any(op.kind == "ShaderNodeLightPath" and set(op.option("outputs", ())) & set(LOBE_OUTPUTS)
               for op in program.ops)


def _ray_length(hits, ray, take):
    """Light Path's Ray Length: the path state's, Cycles' FLT_MAX for the world and for suns (an infinite ray,
    shader_setup_from_background and distant lights' t), 0 where there is none."""
    if getattr(hits, "world", False):
        return np.full(hits.n, np.finfo(F32).max, F32)
    if ray is None or ray.length is None:
        return np.zeros(hits.n, F32)
    length = take(ray.length)
    return np.where(np.isinf(length), np.finfo(F32).max, length).astype(F32)


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
           "Ray Length": _ray_length(hits, ray, take),
           # Shadow rays, the world and lights are one bounce further (Cycles adds 1 for them).
           "Ray Depth": depth + F32(1.0 if further else 0.0),
           "Transparent Depth": take(ray.transparent) if ray is not None else zero,
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


def light_falloff(hits, inputs, op):
    """Cycles' Light Falloff (svm_node_light_falloff): Strength times the ray length to the power 0 (Quadratic),
    1 (Linear) or 2 (Constant), times t^2 / (Smooth + t^2) where Smooth > 0; Strength itself for an infinite
    ray (a sun's, the world's), whose powers would overflow. The ray length is the path state's (the surface's
    distance from the ray's origin, a light's from the point it lights); 0 where there is none."""
    ray = hits.hit.ray
    n = hits.n
    strength = np.array(full(inputs["Strength"], n), F32)
    smooth = np.array(full(inputs["Smooth"], n), F32)
    if getattr(hits, "world", False):   # Cycles' background shading point has an infinite ray length
        t = np.full(n, F32(np.inf))
    elif ray is not None and ray.length is not None:
        t = np.take(ray.length, hits.idx).astype(F32)
    else:
        t = np.zeros(n, F32)
    far = ~np.isfinite(t)
    t = np.where(far, F32(0.0), t)
    t2 = t * t
    with np.errstate(divide="ignore", invalid="ignore"):
        soft = np.where(smooth > 0, t2 / (smooth + t2), F32(1.0)).astype(F32)
    soft = np.where(np.isfinite(soft), soft, F32(0.0))
    out = {}
    for name, power in (("Quadratic", F32(1.0)), ("Linear", t), ("Constant", t2)):
        out[name] = np.where(far, strength, strength * power * soft).astype(F32)
    return out


# ---------------------------------------------------------------- vectors
def separate_xyz(hits, inputs, op):
    v = full(inputs["Vector"], hits.n, 3)
    return {"X": v[:, 0], "Y": v[:, 1], "Z": v[:, 2]}


def combine_xyz(hits, inputs, op):
    n = hits.n
    return {"Vector": np.stack([full(inputs[k], n) for k in ("X", "Y", "Z")], axis=1)}


def normal_map(hits, inputs, op):
    """The Normal Map node (tangent, object, world, Blender object or Blender world space) over program inputs."""
    n = hits.n
    color = full(inputs["Color"], n, 3).T
    strength = full(inputs["Strength"], n)
    space = op.option("space", "TANGENT")
    ns = tuple(hits.N[:, k] for k in range(3))
    frame = hits.hit.tangent_frame(hits.idx) if space == "TANGENT" else None
    has_object = not getattr(hits, "world", False)
    object_frame = bool(op.option("object_frame", False))
    uneven = getattr(hits.scene, "uneven_linear", None) if frame is not None and has_object else None
    out = normals.normal_map(color, strength, space, ns, hits.backfacing, frame,
                             op.option("convention", "OPENGL") == "DIRECTX",
                             (lambda v: to_world(hits, v, "NORMAL")) if has_object else None,
                             None if uneven is None else uneven(hits.prim), object_frame)
    return {"Normal": np.stack(out, axis=1)}
