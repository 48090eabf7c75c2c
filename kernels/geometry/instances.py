"""Instances: prototypes (meshes stored once, in object space) placed by transforms, as Embree's two-level
BVH holds them; their boxes and the scene's extent, the emissive triangles of instances, their normal matrices,
and the flattened copy of an instanced scene (tests and benchmarks compare the two)."""
from __future__ import annotations


import numpy as np

from ..scene import CornerRows, SceneArrays, corner_values
from ..scene.objects import BSDF_RAYS



def normal_matrices(linear: np.ndarray) -> np.ndarray:
    """(K, 3, 3) float32 inverse-transpose of each (K, 3, 3) linear part, up to a positive factor.

    Computed as the cofactor matrix (det x inverse-transpose) with the determinant's sign: it exists for
    singular matrices too (their triangles are degenerate and dropped later). Scaled to magnitude 1 so
    huge or tiny object scales stay well inside float32.
    """
    # The cofactors of a matrix scaled by s are scaled by s^2: scale each matrix to entries of at most 1
    # first, so that object scales of 1e30 or 1e-30 neither overflow nor underflow on the way.
    linear = np.asarray(linear, np.float64)
    size = np.abs(linear).max(axis=(1, 2)) if len(linear) else np.zeros(0)
    finite = np.isfinite(size) & (size > 0)
    linear = np.where(finite[:, None, None], linear, 0.0) / np.where(finite, size, 1.0)[:, None, None]
    c0, c1, c2 = linear[:, :, 0], linear[:, :, 1], linear[:, :, 2]
    cofactor = np.stack([np.cross(c1, c2), np.cross(c2, c0), np.cross(c0, c1)], axis=2)
    det = np.einsum("ki,ki->k", c0, cofactor[:, :, 0])
    largest = np.abs(cofactor).max(axis=(1, 2)) if len(linear) else np.zeros(0)
    scale = np.copysign(1.0, det) / np.where(largest > 0, largest, 1.0)
    return (cofactor * scale[:, None, None]).astype(np.float32)


def prototype_boxes(scene: SceneArrays) -> list:
    """(lo, hi) float64 (3,) object-space box of each of the scene's prototypes (kernels.scene.Instances)."""
    inst = scene.instances
    return [] if inst is None else [extent(p.positions) for p in inst.prototypes]


def instance_boxes(scene: SceneArrays, local: list | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (K, 3) float64 world boxes of the scene's instances; local: prototype_boxes(scene), when
    known already (the prototypes do not change when instances move)."""
    inst = scene.instances
    if inst is None or not inst.count:
        return np.zeros((0, 3)), np.zeros((0, 3))
    local = prototype_boxes(scene) if local is None else local
    lo = np.array([b[0] for b in local])[inst.prototype]
    hi = np.array([b[1] for b in local])[inst.prototype]
    corners = np.stack([np.where(np.array(bits, bool), hi, lo)
                        for bits in np.ndindex(2, 2, 2)], axis=1)            # (K, 8, 3)
    m = inst.world_from_object
    world = np.einsum("kij,kcj->kci", m[:, :3, :3], corners) + m[:, None, :3, 3]
    return world.min(axis=1), world.max(axis=1)


def scene_extent(scene: SceneArrays, local: list | None = None):
    """(lo, hi) float64 (3,) corners of the box around all triangles, plain and instanced (local: see
    instance_boxes), and the curves and points."""
    lo, hi = extent(scene.positions)
    ilo, ihi = instance_boxes(scene, local)
    if len(ilo):
        if len(scene.positions):
            lo, hi = np.minimum(lo, ilo.min(axis=0)), np.maximum(hi, ihi.max(axis=0))
        else:
            lo, hi = ilo.min(axis=0), ihi.max(axis=0)
    if scene.has_shapes:
        slo, shi = shape_boxes(scene)
        if len(slo):
            empty = not len(scene.positions) and not len(ilo)
            lo = slo.min(axis=0) if empty else np.minimum(lo, slo.min(axis=0))
            hi = shi.max(axis=0) if empty else np.maximum(hi, shi.max(axis=0))
    return lo, hi


def shape_boxes(scene: SceneArrays) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (B, 3) float64 world boxes of the scene's curves and points (kernels.scene.Curves, Points): one per
    world-space record and one per shape instance, radii included."""
    def box(values):
        if not len(values):
            return None
        r = values[:, 3]   # column by column: a strided float32 pass each, no (n, 3) float64 copies
        return (np.array([float((values[:, k] - r).min()) for k in range(3)]),
                np.array([float((values[:, k] + r).max()) for k in range(3)]))
    boxes = [box(r.keys) for r in scene.curves] + ([box(scene.points.points)] if scene.points is not None else [])
    placed = scene.shape_instances
    if placed is not None and placed.count:
        local = [box(p.keys if hasattr(p, "keys") else p.points) for p in placed.prototypes]
        for k, p in enumerate(placed.prototype):
            if local[p] is None:
                continue
            corners = np.array([np.where(np.array(bits, bool), local[p][1], local[p][0]) for bits in np.ndindex(2, 2, 2)])
            m = placed.world_from_object[k]
            world = corners @ m[:3, :3].T + m[:3, 3]
            boxes.append((world.min(axis=0), world.max(axis=0)))
    boxes = [b for b in boxes if b is not None]
    if not boxes:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.array([b[0] for b in boxes]), np.array([b[1] for b in boxes])


def lights_of(scene: SceneArrays) -> np.ndarray | None:
    """(K,) bool per object row: its emissive triangles are lights for the light sampler, as Cycles'
    Object::usable_as_light: some BSDF ray sees the object (Ray Visibility); None when all are."""
    vis = scene.object_visibility
    if vis is None:
        return None
    return (vis & BSDF_RAYS) != 0


def emissive_instanced(scene: SceneArrays, emits: np.ndarray):
    """The instanced triangles whose material emits, of objects that are lights (lights_of): (scene triangle numbers (E,) int64 ascending,
    world-space corners (E, 3, 3) float64, material rows (E,) int32)."""
    inst = scene.instances
    ids, corners, mats = [], [], []
    if inst is not None and inst.count:
        bases = inst.bases(len(scene.positions))
        local = [np.flatnonzero(emits[p.material_ids]) for p in inst.prototypes]
        lit = lights_of(scene)
        for k in range(inst.count):
            proto = inst.prototype[k]
            tri = local[proto]
            if not len(tri) or (lit is not None and not lit[inst.object_ids[k]]):
                continue
            m = inst.world_from_object[k]
            p = inst.prototypes[proto].positions[tri].astype(np.float64)
            ids.append(bases[k] + tri)
            corners.append(p @ m[:3, :3].T + m[:3, 3])
            mats.append(inst.prototypes[proto].material_ids[tri])
    if not ids:
        return np.zeros(0, np.int64), np.zeros((0, 3, 3)), np.zeros(0, np.int32)
    return np.concatenate(ids), np.concatenate(corners), np.concatenate(mats)


def flatten_instances(scene: SceneArrays) -> SceneArrays:
    """The scene with every instance copied into plain world-space triangles (what a one-level BVH
    holds): the reference the instanced scene must render like. A mirrored copy's front is its object
    row's to say (SceneArrays.positions); in a scene without an object table its corners are put in the
    other order instead."""
    import dataclasses
    inst = scene.instances
    if inst is None or not inst.count:
        return dataclasses.replace(scene, instances=None)
    parts = {"positions": [corner_values(scene.positions)], "normals": [corner_values(scene.normals)], "uvs": [scene.uvs],
             "material_ids": [scene.material_ids]}
    tangents = [scene.tangents] if scene.tangents is not None else None
    want_tangents = scene.tangents is not None or any(p.tangents is not None for p in inst.prototypes)
    if want_tangents:
        tangents = [scene.tangents if scene.tangents is not None else np.zeros((len(scene.positions), 3, 4), np.float32)]
    names = dict.fromkeys(name for part in (scene, *inst.prototypes) for name, _ in part.attributes)
    attributes = {name: [] for name in names}
    object_ids = [scene.object_ids] if scene.object_ids is not None else None
    normal = normal_matrices(inst.world_from_object[:, :3, :3])
    turned = (np.linalg.det(inst.world_from_object[:, :3, :3]) < 0) & (scene.objects is None)
    for k in range(inst.count):
        proto = inst.prototypes[inst.prototype[k]]
        if turned[k]:
            proto = _other_winding(proto)
        m = inst.world_from_object[k]
        linear = m[:3, :3].astype(np.float32)
        parts["positions"].append((proto.positions @ linear.T + m[:3, 3].astype(np.float32)).astype(np.float32))
        parts["normals"].append((proto.normals @ normal[k].T).astype(np.float32))
        parts["uvs"].append(proto.uvs)
        parts["material_ids"].append(proto.material_ids)
        if want_tangents:
            if proto.tangents is None:
                tangents.append(np.zeros((proto.triangle_count, 3, 4), np.float32))
            else:
                t = proto.tangents[..., :3].astype(np.float64) @ m[:3, :3].T
                length = np.linalg.norm(t, axis=-1, keepdims=True)
                t = np.where(length > 0, t / np.where(length > 0, length, 1), 0)
                sign = proto.tangents[..., 3:] * np.sign(np.linalg.det(m[:3, :3]))
                tangents.append(np.concatenate([t, sign], axis=-1).astype(np.float32))
        own = dict(proto.attributes)
        for name in names:
            attributes[name].append(own.get(name))
        if object_ids is not None:
            object_ids.append(np.full(proto.triangle_count, inst.object_ids[k], np.int32))
    counts = [len(p) for p in parts["positions"]]
    plain_attributes = dict(scene.attributes)
    flat_attributes = []
    for name in names:
        values = [plain_attributes.get(name)] + attributes[name]
        c = max(v.shape[2] for v in values if v is not None)
        filled = []
        for v, n in zip(values, counts):
            block = np.zeros((n, 3, c), np.float32)
            if v is not None:
                block[..., :v.shape[2]] = v
            filled.append(block)
        flat_attributes.append((name, np.concatenate(filled)))
    return dataclasses.replace(
        scene, instances=None, bvh_vertices=None, bvh_indices=None,
        **{key: np.ascontiguousarray(np.concatenate(v)) for key, v in parts.items()},
        tangents=None if not want_tangents else np.concatenate(tangents), attributes=tuple(flat_attributes),
        object_ids=None if object_ids is None else np.concatenate(object_ids))


def _other_winding(proto):
    """The prototype with each triangle's corners 1 and 2 swapped, with everything kept per corner."""
    import dataclasses
    order = [0, 2, 1]
    return dataclasses.replace(
        proto, positions=proto.positions[:, order], normals=proto.normals[:, order], uvs=proto.uvs[:, order],
        tangents=None if proto.tangents is None else proto.tangents[:, order],
        attributes=tuple((name, v[:, order]) for name, v in proto.attributes))


def apply_matrices(matrices: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """(m, 3) float32: each (3, 3) matrix times its vector."""
    return np.einsum("mij,mj->mi", matrices, vectors).astype(np.float32, copy=False)


def extent(positions: np.ndarray):
    """(lo, hi) corners of the geometry's bounding box, float64 (3,) each."""
    if not len(positions):
        return np.zeros(3), np.zeros(3)
    if isinstance(positions, CornerRows):
        lo, hi = positions.bounds()
        return lo.astype(np.float64), hi.astype(np.float64)
    lo = np.array([positions[:, :, k].min() for k in range(3)], np.float64)
    hi = np.array([positions[:, :, k].max() for k in range(3)], np.float64)
    return lo, hi


def uniform_scales(matrices: np.ndarray) -> np.ndarray:
    """(n,) bool: which (n, 3, 4) or (n, 4, 4) transforms are a rotation times a uniform scale (Cycles'
    transform_uniform_scale: every row's and column's squared length within 1e-6 of the first row's), those
    Cycles applies to curves and points (scene/object.cpp apply_static_transforms)."""
    m = np.asarray(matrices, np.float64)[:, :3, :3]
    lengths = np.concatenate([np.sum(m * m, axis=2), np.sum(m * m, axis=1)], axis=1)
    return np.all(np.abs(lengths - lengths[:, :1]) < 1e-6, axis=1)
