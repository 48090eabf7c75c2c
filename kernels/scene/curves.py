"""Curves with a radius along them (Cycles' Hair: particle hair, Curves objects), one shape per record, their
checks and cleaning."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .checks import check_array, check_motion, require, usable_keys

# The shapes Cycles traces curves as (intern/cycles/bvh/embree.cpp, add_curves): a round tube swept along a
# Catmull-Rom spline (3D Curves), a flat ribbon facing the ray along one (Rounded Ribbons), and round cones
# with spherical joints between the keys (Linear 3D Curves, and every curve of poly type).
CURVE_SHAPES = ("ROUND", "RIBBON", "LINEAR")


@dataclass(frozen=True)
class Curves:
    """C curves of K keys in all, in world space (SceneArrays.curves) or a prototype's object space
    (ShapeInstances).

    shape : one of CURVE_SHAPES.
    keys : (K, 4) float32, each key's x, y, z and radius.
    offsets : (C + 1,) int32, curve c's keys are keys[offsets[c]:offsets[c + 1]], at least 2 each; offsets[0] is 0.
    material_ids : (C,) int32 rows of SceneArrays.materials.
    object_ids : (C,) int32 rows of SceneArrays.objects, or None (a prototype's curves take their instance's).
    attributes : ((name, values), ...) float32, (K, C') per key (interpolated along a segment) or (C, C') per
        curve, C' in 1..4: the names node programs read ("attr:<name>", "color:<name>", "uv:<name>", "uv" the
        render UV; "std:intercept", "std:length", "std:curve_random" for Curves Info; "std:root", particle hair's
        roots, for its Generated coordinates).
    subdivisions : Cycles' Curves > Subdivisions (Embree's tessellation rate is 2^subdivisions + 1, at most 17).
    motion : None, or (S, K, 4) float32 with S >= 2: the keys (radius included) at S times evenly spread over the
        shutter (motion blur: Embree's time steps, interpolated linearly at each ray's time as Cycles'
        motion_keys, intern/cycles/scene/hair.cpp). keys stays the frame's.
    """
    shape: str
    keys: np.ndarray
    offsets: np.ndarray
    material_ids: np.ndarray
    object_ids: np.ndarray | None = None
    attributes: tuple = ()
    subdivisions: int = 2
    motion: np.ndarray | None = None

    @property
    def count(self) -> int:
        """Curves."""
        return len(self.offsets) - 1

    @property
    def segment_count(self) -> int:
        """Segments: one between each two keys of a curve."""
        return len(self.keys) - self.count

    def segment_offsets(self) -> np.ndarray:
        """(C + 1,) int64: curve c's segments are numbers [s[c], s[c + 1])."""
        return self.offsets.astype(np.int64) - np.arange(self.count + 1, dtype=np.int64)

    def per_key(self, values: np.ndarray) -> bool:
        """Whether an attribute's values are per key (else per curve)."""
        return len(values) == len(self.keys) and len(self.keys) != self.count

    def validate(self, name: str, materials: int, objects: int | None) -> None:
        require(self.shape in CURVE_SHAPES, f"{name}.shape", f"must be one of {CURVE_SHAPES}, got {self.shape!r}")
        k = len(self.keys) if hasattr(self.keys, "__len__") else -1
        check_array(self.keys, f"{name}.keys", (k, 4), np.float32, finite=False)
        check_array(self.offsets, f"{name}.offsets", (len(self.offsets),), np.int32)
        c = len(self.offsets) - 1
        require(c >= 0 and self.offsets[0] == 0 and self.offsets[-1] == k, f"{name}.offsets",
                f"must run from 0 to the {k} keys")
        if c:
            require((np.diff(self.offsets) >= 2).all(), f"{name}.offsets", "every curve needs at least 2 keys")
        check_array(self.material_ids, f"{name}.material_ids", (c,), np.int32)
        if c:
            require(self.material_ids.min() >= 0 and self.material_ids.max() < materials, f"{name}.material_ids",
                    f"must be in [0, {materials})")
        if self.object_ids is not None:
            require(objects is not None, f"{name}.object_ids", "needs the object table")
            check_array(self.object_ids, f"{name}.object_ids", (c,), np.int32)
            if c:
                require(self.object_ids.min() >= 0 and self.object_ids.max() < objects, f"{name}.object_ids",
                        f"must be in [0, {objects})")
        for key, values in self.attributes:
            require(isinstance(values, np.ndarray) and values.ndim == 2 and len(values) in (k, c),
                    f"{name}.attributes[{key!r}]", "must be (K, C) per key or (C, C) per curve")
            check_array(values, f"{name}.attributes[{key!r}]", values.shape, np.float32)
        check_motion(self.motion, f"{name}.motion", k)
        require(isinstance(self.subdivisions, int) and 0 <= self.subdivisions <= 24, f"{name}.subdivisions",
                "must be an int in [0, 24]")

    def cleaned(self) -> tuple["Curves", int]:
        """The curves without those Embree cannot take (a key or radius not finite or beyond float32, a negative
        radius), and how many were dropped."""
        if not self.count:
            return self, 0
        bad_key = ~usable_keys(self.keys)
        if self.motion is not None:
            bad_key |= ~usable_keys(self.motion).all(axis=0)
        if not bad_key.any():
            return self, 0
        curve_of_key = np.repeat(np.arange(self.count), np.diff(self.offsets))
        bad = np.zeros(self.count, bool)
        bad[curve_of_key[bad_key]] = True
        return self.take(np.flatnonzero(~bad)), int(np.count_nonzero(bad))

    def take(self, curves: np.ndarray) -> "Curves":
        """The curves numbered `curves` (ascending), their keys and attributes."""
        sizes = np.diff(self.offsets)[curves]
        starts = self.offsets[:-1][curves]
        keys = np.repeat(starts - np.concatenate([[0], np.cumsum(sizes)[:-1]]), sizes) + np.arange(sizes.sum())
        offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int32)
        attributes = tuple((name, np.ascontiguousarray(values[keys] if self.per_key(values) else values[curves]))
                           for name, values in self.attributes)
        motion = None if self.motion is None else np.ascontiguousarray(self.motion[:, keys])
        return dataclasses.replace(self, keys=np.ascontiguousarray(self.keys[keys]), offsets=offsets, motion=motion,
                                   material_ids=self.material_ids[curves],
                                   object_ids=None if self.object_ids is None else self.object_ids[curves],
                                   attributes=attributes)
