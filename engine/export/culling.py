"""Simplify > Culling (Cycles' own settings: scene.cycles.use_camera_cull and use_distance_cull with their margins,
object.cycles.use_camera_cull and use_distance_cull), as Cycles' BlenderObjectCulling (intern/cycles/blender/
object_cull.cpp) leaves objects out of a render:

- only with Simplify on, a perspective or orthographic camera and no multi-view;
- an object with Camera Culling is left out when its bounding box (the evaluated object's, at the instance's
  transform) lies outside the camera's frame widened by the margin (in units of the frame), or wholly nearer
  than the clip start (worldtondc's depth below minus the margin);
- an object with Distance Culling is left out when its box's nearest point is farther than the margin from the
  camera (a margin of 0 turns it off);
- with both, it must be culled by both.

Lights are never culled; what is left out casts no shadow and shows in no reflection, as in Cycles.
"""
from __future__ import annotations

import numpy as np

from ...kernels.camera import view_plane


class Culling:
    """The culling of one render's camera (kernels.Camera `camera` placed by its world_from_camera)."""

    def __init__(self, scene, camera):
        cycles = getattr(scene, "cycles", None)
        supported = cycles is not None and scene.render.use_simplify and camera.kind in ("PERSP", "ORTHO") and \
            not scene.render.use_multiview
        self.camera_margin = float(getattr(cycles, "camera_cull_margin", 0.0))
        self.distance_margin = float(getattr(cycles, "distance_cull_margin", 0.0))
        self.use_camera = bool(supported and cycles.use_camera_cull)
        self.use_distance = bool(supported and cycles.use_distance_cull and self.distance_margin != 0.0)
        self.camera = camera
        m = np.asarray(camera.world_from_camera, np.float64)
        self.rotation = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0)
        self.eye = m[:3, 3]
        self.plane = view_plane(camera) if supported else None

    @property
    def active(self) -> bool:
        return self.use_camera or self.use_distance

    def culled(self, ob, matrix: np.ndarray) -> bool:
        """Whether the object (an evaluated object, its instance's world matrix (4, 4)) is left out."""
        settings = getattr(ob, "cycles", None)
        by_camera = self.use_camera and bool(getattr(settings, "use_camera_cull", False))
        by_distance = self.use_distance and bool(getattr(settings, "use_distance_cull", False))
        if not (by_camera or by_distance):
            return False
        local = np.array([tuple(c) for c in ob.bound_box], np.float64)     # (8, 3) object space
        corners = local @ np.asarray(matrix, np.float64)[:3, :3].T + np.asarray(matrix, np.float64)[:3, 3]
        out_of_view = by_camera and self._outside_frame(corners)
        far = by_distance and self._far(corners)
        return (out_of_view and far) or (out_of_view and not by_distance) or (far and not by_camera)

    def _outside_frame(self, corners: np.ndarray) -> bool:
        """Cycles' test_camera: the box's corners in normalised device coordinates (mirrored behind the
        camera), against the frame widened by the margin; or every corner nearer than the clip start."""
        cam = self.camera
        local = (corners - self.eye) @ self.rotation            # camera space, looking down -z
        depth = -local[:, 2]
        near, far = float(cam.clip_start), float(cam.clip_end)
        if cam.kind == "ORTHO":
            w = np.ones(len(depth))
            z = depth / (far - near)
        else:
            w = depth
            z = far * (depth - near) / (far - near)
        xmin, xmax, ymin, ymax = self.plane
        with np.errstate(divide="ignore", invalid="ignore"):
            x = (local[:, 0] / w - xmin) / (xmax - xmin)
            y = (local[:, 1] / w - ymin) / (ymax - ymin)
        behind = z < 0
        x, y = np.where(behind, 1.0 - x, x), np.where(behind, 1.0 - y, y)
        margin = self.camera_margin
        if np.all(z < -margin):
            return True
        return bool(x.min() >= 1.0 + margin or y.min() >= 1.0 + margin or x.max() <= -margin or y.max() <= -margin)

    def _far(self, corners: np.ndarray) -> bool:
        """Cycles' test_distance: the box's nearest point to the camera farther than the margin."""
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        nearest = np.maximum(np.minimum(hi, self.eye), lo)
        return float(((self.eye - nearest) ** 2).sum()) > self.distance_margin ** 2
