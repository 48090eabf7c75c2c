"""Instancing: Prototype (a mesh stored once, in object space), Instances (where each copy is placed), their
validation and cleaning (bad prototype triangles and unusable placements dropped)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .checks import MAX_TIME_STEPS, check_array, require
from .triangles import check_triangles, clean_triangles, same_triangles


@dataclass(frozen=True)
class Prototype:
    """One mesh placed by several instances (SceneArrays.instances), in its object space: each field means
    what the SceneArrays field of the same name means, for the prototype's own t triangles."""
    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    material_ids: np.ndarray
    tangents: np.ndarray | None = None
    attributes: tuple = ()

    @property
    def triangle_count(self) -> int:
        return len(self.positions)

    def mirrored_triangles(self) -> None:
        """None: a prototype's triangles are in object space; whether an instance mirrors them is its
        transform's business (the SceneArrays method of this name)."""
        return None


@dataclass(frozen=True)
class Instances:
    """Meshes stored once and placed many times, traced through a two-level BVH as Cycles and Embree do:
    memory grows with the unique meshes, not with the number of instances.

    prototypes : tuple of Prototype.
    prototype : (K,) int32, each instance's prototype.
    world_from_object : (K, 4, 4) float64.
    object_ids : (K,) int32, each instance's row of SceneArrays.objects (None when the scene has none).

    Scene triangle numbers (what ray hits report) go on after the T plain triangles: triangle j of
    instance k is number bases(T)[k] + j.
    """
    prototypes: tuple
    prototype: np.ndarray
    world_from_object: np.ndarray
    object_ids: np.ndarray | None = None

    @property
    def count(self) -> int:
        return len(self.prototype)

    def triangle_counts(self) -> np.ndarray:
        """(K,) int64 triangles of each instance."""
        sizes = np.array([p.triangle_count for p in self.prototypes], np.int64)
        return sizes[self.prototype] if len(sizes) else np.zeros(0, np.int64)

    def bases(self, plain_count: int) -> np.ndarray:
        """(K,) int64 scene number of each instance's first triangle."""
        counts = self.triangle_counts()
        return plain_count + np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64) if len(counts) \
            else np.zeros(0, np.int64)

    @property
    def triangle_total(self) -> int:
        """Triangles of all instances together (what a flattened copy would hold)."""
        return int(self.triangle_counts().sum())

    def validate(self, materials: int, objects: int | None) -> None:
        k = len(self.prototype)
        check_array(self.prototype, "instances.prototype", (k,), np.int32)
        check_array(self.world_from_object, "instances.world_from_object", (k, 4, 4), np.float64, finite=False)
        if k:
            require(self.prototype.min() >= 0 and self.prototype.max() < len(self.prototypes),
                    "instances.prototype", f"must be in [0, {len(self.prototypes)})")
        require((objects is None) == (self.object_ids is None), "instances.object_ids",
                "given exactly when the scene has objects")
        if self.object_ids is not None:
            check_array(self.object_ids, "instances.object_ids", (k,), np.int32)
            if k:
                require(self.object_ids.min() >= 0 and self.object_ids.max() < objects, "instances.object_ids",
                        f"must be in [0, {objects})")
        for i, proto in enumerate(self.prototypes):
            check_triangles(proto, f"instances.prototypes[{i}].", materials)


def clean_instances(instances: Instances, clean: Instances | None = None) -> tuple[Instances, int, int, int]:
    """Each prototype cleaned once (not those equal to clean's, known clean); instances whose transform is
    not finite or flattens them dropped (their triangles counted as dropped, as a flattened copy's would be,
    and as non-finite where the transform is)."""
    dropped = repaired = nonfinite = 0
    prototypes = []
    known = clean.prototypes if clean is not None else ()
    for i, proto in enumerate(instances.prototypes):
        if i < len(known) and same_triangles(proto, known[i]):
            prototypes.append(proto)
            continue
        changes, d, r, f = clean_triangles(proto)
        prototypes.append(dataclasses.replace(proto, **changes) if changes else proto)
        # Every instance drops the prototype's bad triangles, as its flattened copy would.
        uses = int(np.count_nonzero(instances.prototype == len(prototypes) - 1))
        dropped += d * uses
        repaired += r * uses
        nonfinite += f * uses
    m = instances.world_from_object
    usable = usable_placements(m)
    counts = np.array([p.triangle_count for p in prototypes], np.int64)
    dropped += int(counts[instances.prototype[~usable]].sum()) if len(counts) else 0
    unbounded = ~(np.isfinite(m).all(axis=(1, 2)) & (np.abs(np.nan_to_num(m[:, :3, :])) < 3e38).all(axis=(1, 2)))
    nonfinite += int(counts[instances.prototype[unbounded]].sum()) if len(counts) else 0
    kept = Instances(tuple(prototypes), np.ascontiguousarray(instances.prototype[usable]),
                     np.ascontiguousarray(m[usable]),
                     None if instances.object_ids is None else np.ascontiguousarray(instances.object_ids[usable]))
    return kept, dropped, repaired, nonfinite


def usable_placements(world_from_object: np.ndarray) -> np.ndarray:
    """(K,) bool: which (K, 4, 4) instance transforms place their mesh somewhere (finite, within float32,
    not flattening it); validate() drops the instances of the others."""
    m = world_from_object
    linear = np.nan_to_num(m[:, :3, :3])
    with np.errstate(over="ignore", invalid="ignore"):
        det = np.linalg.det(linear) if len(m) else np.zeros(0)
    return np.isfinite(m).all(axis=(1, 2)) & np.isfinite(det) & (np.abs(det) > 0) \
        & (np.abs(m[:, :3, :]) < 3e38).all(axis=(1, 2))


@dataclass(frozen=True)
class ShapeInstances:
    """Curves and points stored once in object space and placed by transforms (SceneArrays.shape_instances), as
    Instances places meshes: each prototype (a kernels.scene.Curves or Points with object_ids None) is one
    bottom-level Embree scene that every instance of it shares.

    prototypes : tuple of Curves or Points.
    prototype : (K,) int32, each instance's prototype.
    world_from_object : (K, 4, 4) float64.
    object_ids : (K,) int32, each instance's row of SceneArrays.objects.
    motion : ((S, 4, 4) float64, ...) world_from_object at S >= 2 motion steps evenly spread over the shutter, one
        entry per moving instance (motion blur: Embree's instance time steps, interpolated as Cycles interpolates
        object motion, kernels.motion); motion_ids : (K,) int32 or None, each instance's entry, -1 when still.
    """
    prototypes: tuple
    prototype: np.ndarray
    world_from_object: np.ndarray
    object_ids: np.ndarray
    motion: tuple = ()
    motion_ids: np.ndarray | None = None

    @property
    def moves(self) -> bool:
        """Some instance has motion steps."""
        return self.motion_ids is not None and bool((self.motion_ids >= 0).any())

    @property
    def count(self) -> int:
        return len(self.prototype)

    def validate(self, materials: int, objects: int | None) -> None:
        k = len(self.prototype)
        check_array(self.prototype, "shape_instances.prototype", (k,), np.int32)
        check_array(self.world_from_object, "shape_instances.world_from_object", (k, 4, 4), np.float64)
        require(objects is not None, "shape_instances.object_ids", "needs the object table")
        check_array(self.object_ids, "shape_instances.object_ids", (k,), np.int32)
        if k:
            require(self.prototype.min() >= 0 and self.prototype.max() < len(self.prototypes),
                    "shape_instances.prototype", f"must be in [0, {len(self.prototypes)})")
            require(self.object_ids.min() >= 0 and self.object_ids.max() < objects, "shape_instances.object_ids",
                    f"must be in [0, {objects})")
        if self.motion_ids is not None:
            check_array(self.motion_ids, "shape_instances.motion_ids", (k,), np.int32)
            if k:
                require(self.motion_ids.min() >= -1 and self.motion_ids.max() < len(self.motion),
                        "shape_instances.motion_ids", f"must be in [-1, {len(self.motion)})")
        for i, keys in enumerate(self.motion):
            check_array(keys, f"shape_instances.motion[{i}]", (-1, 4, 4), np.float64)
            require(2 <= len(keys) <= MAX_TIME_STEPS, f"shape_instances.motion[{i}]",
                    f"needs 2 to {MAX_TIME_STEPS} steps, got {len(keys)}")
        for i, proto in enumerate(self.prototypes):
            require(proto.object_ids is None, f"shape_instances.prototypes[{i}].object_ids",
                    "must be None (an instance gives its row)")
            proto.validate(f"shape_instances.prototypes[{i}]", materials, None)

    def cleaned(self) -> tuple["ShapeInstances", int]:
        """Each prototype cleaned (kernels.scene.Curves.cleaned, Points.cleaned), the instances whose transform
        is unusable dropped; and how many curves and points all that dropped, counted per instance."""
        dropped = 0
        prototypes = []
        for i, proto in enumerate(self.prototypes):
            kept, d = proto.cleaned()
            prototypes.append(kept)
            dropped += d * int(np.count_nonzero(self.prototype == i))
        usable = usable_placements(self.world_from_object)
        for i, keys in enumerate(self.motion):   # a moving instance is usable at every step or not at all
            if self.motion_ids is not None:
                usable &= (self.motion_ids != i) | usable_placements(keys).all()
        counts = np.array([p.count for p in prototypes], np.int64)
        if len(counts):
            dropped += int(counts[self.prototype[~usable]].sum())
        return ShapeInstances(tuple(prototypes), np.ascontiguousarray(self.prototype[usable]),
                              np.ascontiguousarray(self.world_from_object[usable]),
                              np.ascontiguousarray(self.object_ids[usable]), self.motion,
                              None if self.motion_ids is None else np.ascontiguousarray(self.motion_ids[usable])), \
            dropped
