"""Points rendered as spheres (Cycles' PointCloud: Point Cloud objects, geometry-nodes points such as Mesh to
Points), their checks and cleaning."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .checks import check_array, check_motion, require, usable_keys


@dataclass(frozen=True)
class Points:
    """Spheres in world space (SceneArrays.points) or in a prototype's object space (ShapeInstances).

    points : (P, 4) float32, each sphere's centre x, y, z and radius (Embree's RTC_GEOMETRY_TYPE_SPHERE_POINT
        vertex layout, read in place).
    material_ids : (P,) int32 rows of SceneArrays.materials.
    object_ids : (P,) int32 rows of SceneArrays.objects, or None (a prototype's points take their instance's).
    attributes : ((name, (P, C) float32), ...) per point, C in 1..4, the names node programs read
        ("attr:<name>", "color:<name>", "uv:<name>"; "std:point_random", Point Info's Random).
    motion : None, or (S, P, 4) float32 with S >= 2: the spheres at S times evenly spread over the shutter (motion
        blur: Embree's time steps, interpolated linearly at each ray's time). points stays the frame's.
    """
    points: np.ndarray
    material_ids: np.ndarray
    object_ids: np.ndarray | None = None
    attributes: tuple = ()
    motion: np.ndarray | None = None

    @property
    def count(self) -> int:
        return len(self.points)

    def validate(self, name: str, materials: int, objects: int | None) -> None:
        p = len(self.points) if hasattr(self.points, "__len__") else -1
        check_array(self.points, f"{name}.points", (p, 4), np.float32, finite=False)
        check_array(self.material_ids, f"{name}.material_ids", (p,), np.int32)
        if p:
            require(self.material_ids.min() >= 0 and self.material_ids.max() < materials, f"{name}.material_ids",
                    f"must be in [0, {materials})")
        if self.object_ids is not None:
            require(objects is not None, f"{name}.object_ids", "needs the object table")
            check_array(self.object_ids, f"{name}.object_ids", (p,), np.int32)
            if p:
                require(self.object_ids.min() >= 0 and self.object_ids.max() < objects, f"{name}.object_ids",
                        f"must be in [0, {objects})")
        check_motion(self.motion, f"{name}.motion", p)
        for key, values in self.attributes:
            check_array(values, f"{name}.attributes[{key!r}]", (p, values.shape[1] if values.ndim == 2 else -1),
                        np.float32)

    def cleaned(self) -> tuple["Points", int]:
        """The points without those Embree cannot take (a centre or radius not finite or beyond float32, a
        negative radius), and how many were dropped."""
        ok = usable_keys(self.points)
        if self.motion is not None:
            ok &= usable_keys(self.motion).all(axis=0)
        if ok.all():
            return self, 0
        return self.take(np.flatnonzero(ok)), int(np.count_nonzero(~ok))

    def take(self, idx: np.ndarray) -> "Points":
        return dataclasses.replace(
            self, points=np.ascontiguousarray(self.points[idx]),
            motion=None if self.motion is None else np.ascontiguousarray(self.motion[:, idx]), material_ids=self.material_ids[idx],
            object_ids=None if self.object_ids is None else self.object_ids[idx],
            attributes=tuple((name, np.ascontiguousarray(values[idx])) for name, values in self.attributes))
