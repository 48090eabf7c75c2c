"""The dicing camera: how long a pixel is in world units at a point, as Cycles' Camera::world_to_raster_size
(scene/camera.cpp), which DiagSplit divides edge lengths by.

- Perspective: as if the point were straight ahead of the camera, its distance times the angle one pixel
  spans at the centre of the frame (the shorter of a pixel's width and height).
- Orthographic: a pixel's width or height, the shorter.
- Panoramic: the distance times Cycles' compact differential of the centre pixel's ray.
- Off screen (perspective and orthographic), Offscreen Scale s > 1 coarsens: the size grows by the distance
  to the view frustum (perspective: the greatest distance outside its side planes, or to the eye when behind
  it; the pixel's angle times that) times (s - 1); orthographic: by the pixel size times the distance to the
  view box over its half diagonal, times (s - 1).
"""
from __future__ import annotations

import math

import numpy as np

from ....kernels import Camera
from ....kernels.camera import camera_frame, view_plane
from ....kernels.panorama import pixel_spread


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


class DicingCamera:
    """A kernels.Camera (its resolution is the frame's) and Offscreen Scale."""

    def __init__(self, camera: Camera, offscreen_scale: float = 1.0):
        self.kind = camera.kind
        self.offscreen = float(offscreen_scale)
        eye, rotation = camera_frame(camera)
        self.eye = eye
        # Camera coordinates as Cycles': x right, y up, z ahead (Blender's camera looks down its -Z).
        self.to_camera = rotation.T * np.array([1.0, 1.0, -1.0])[:, None]
        if self.kind == "PANO":
            self.angle = pixel_spread(camera)
            return
        xmin, xmax, ymin, ymax = view_plane(camera)
        self.xmin, self.xmax, self.ymin, self.ymax = xmin, xmax, ymin, ymax
        dx = np.array([(xmax - xmin) / camera.width, 0.0, 0.0])
        dy = np.array([0.0, (ymax - ymin) / camera.height, 0.0])
        step = dx if dx @ dx < dy @ dy else dy
        if self.kind == "ORTHO":
            self.pixel = float(np.sqrt(step @ step))
            return
        ahead = np.array([0.5 * (xmin + xmax), 0.5 * (ymin + ymax), 1.0])
        d = _unit(ahead)
        turn = _unit(ahead + step) - d
        self.angle = float(np.linalg.norm(turn - (turn @ d) * d))
        self.planes = np.stack([_unit(np.array([1.0, 0.0, -xmax])), _unit(np.array([-1.0, 0.0, xmin])),
                                _unit(np.array([0.0, 1.0, -ymax])), _unit(np.array([0.0, -1.0, ymin]))])
        # Along each side plane, away from the eye (Cycles' along_right, along_left, along_top, along_bottom).
        r, left, t, b = self.planes
        self.along = np.stack([[-r[2], 0.0, r[0]], [left[2], 0.0, -left[0]], [0.0, -t[2], t[1]],
                               [0.0, b[2], -b[1]]])

    def pixel_size_at(self, point) -> float:
        """pixel_size of one point (DiagSplit's many single queries), in plain floats."""
        x, y, z = (float(c) for c in self.to_camera @ (np.asarray(point, np.float64) - self.eye))
        if self.kind == "ORTHO":
            size = self.pixel
            if self.offscreen > 1.0:
                dx = x - min(max(x, self.xmin), self.xmax)
                dy = y - min(max(y, self.ymin), self.ymax)
                dz = z - max(z, 0.0)
                half = math.sqrt((self.xmax ** 2 + self.ymax ** 2) * 0.5)
                size += size * math.sqrt(dx * dx + dy * dy + dz * dz) / half * (self.offscreen - 1.0)
            return size
        length = math.sqrt(x * x + y * y + z * z)
        size = length * self.angle
        if self.kind == "PERSP" and self.offscreen > 1.0:
            d = [a * x + b * y + c * z for a, b, c in self.planes]
            if any(k > 0 for k in d):
                if all(k > 0 for k in d):
                    outside = length
                else:
                    ahead = [a * x + b * y + c * z >= 0 for a, b, c in self.along]
                    outside = max([k for k, up in zip(d, ahead) if k > 0 and up], default=0.0)
                    if any(k > 0 and not up for k, up in zip(d, ahead)):
                        outside = min(outside, length) if outside > 0 else length
                size += self.angle * outside * (self.offscreen - 1.0)
        return size

    def pixel_size(self, points: np.ndarray) -> np.ndarray:
        """(N,) world length of a pixel at (N, 3) world points."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        p = (points - self.eye) @ self.to_camera.T
        if self.kind == "ORTHO":
            size = np.full(len(p), self.pixel)
            if self.offscreen > 1.0:
                c = np.stack([np.clip(p[:, 0], self.xmin, self.xmax), np.clip(p[:, 1], self.ymin, self.ymax),
                              np.maximum(p[:, 2], 0.0)], axis=1)
                half = np.sqrt((self.xmax ** 2 + self.ymax ** 2) * 0.5)
                size += size * np.linalg.norm(p - c, axis=1) / half * (self.offscreen - 1.0)
            return size
        distance = np.linalg.norm(p, axis=1)
        size = distance * self.angle
        if self.kind == "PERSP" and self.offscreen > 1.0:
            size += self.angle * self._outside(p) * (self.offscreen - 1.0)
        return size

    def _outside(self, p: np.ndarray) -> np.ndarray:
        """Cycles' rough distance to the perspective frustum: 0 inside, the eye's distance behind it."""
        d = p @ self.planes.T                                       # (N, 4): right, left, top, bottom
        length = np.linalg.norm(p, axis=1)
        inside = (d <= 0).all(axis=1)
        behind = (d > 0).all(axis=1)
        ahead = (p @ self.along.T) >= 0
        candidate = np.where((d > 0) & ahead, d, 0.0).max(axis=1)
        far_side = ((d > 0) & ~ahead).any(axis=1)
        mixed = np.where(far_side, np.where(candidate > 0, np.minimum(candidate, length), length), candidate)
        return np.where(inside, 0.0, np.where(behind, length, mixed))
