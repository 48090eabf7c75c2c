"""Depth of field: Cycles' thin lens (kernel/camera/camera.h, kernel/sample/mapping.h).

The lens is a disk, or a regular polygon inscribed in the unit circle (aperture blades), scaled by the
aperture radius; its x is divided by the anamorphic ratio. A camera ray leaves from a point of the lens
toward the point where the pinhole ray through the same raster position meets the plane of focus
(camera depth = focus distance), so that plane stays sharp and everything else blurs by the circle of
confusion: a point at depth d images to a disk of radius  aperture * |1/focus - 1/d|  on the
view plane at unit distance.
"""
from __future__ import annotations

import numpy as np

from .scene import Camera


def sample_disk_concentric(u: np.ndarray, v: np.ndarray):
    """Shirley-Chiu concentric map of [0,1)^2 onto the unit disk (Cycles' sample_uniform_disk)."""
    a = np.float32(2) * u - np.float32(1)
    b = np.float32(2) * v - np.float32(1)
    first = a * a > b * b
    r = np.where(first, a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(first, np.float32(np.pi / 4) * (b / a),
                       np.float32(np.pi / 2) - np.float32(np.pi / 4) * (a / b))
    phi = np.where((a == 0) & (b == 0), np.float32(0), phi).astype(np.float32)
    return r * np.cos(phi), r * np.sin(phi)


def sample_regular_polygon(corners: int, rotation: float, u: np.ndarray, v: np.ndarray):
    """Uniform point in the regular polygon of `corners` vertices on the unit circle, turned by rotation
    (radians): a corner's triangle is picked by u, reused, then a point uniform in that triangle."""
    corners_f = np.float32(corners)
    corner = np.floor(u * corners_f)
    u = u * corners_f - corner
    u = np.sqrt(u)
    v = v * u
    u = np.float32(1) - u
    angle = np.float32(np.pi) / corners_f
    px = (u + v) * np.cos(angle)
    py = (u - v) * np.sin(angle)
    # Each corner's turn, rotation + 2 k angle, from a table of its cosines and sines.
    turn = np.float32(rotation) + np.arange(corners, dtype=np.float32) * np.float32(2) * angle
    k = np.minimum(corner.astype(np.int32), corners - 1)
    cr, sr = np.take(np.cos(turn), k), np.take(np.sin(turn), k)
    return cr * px - sr * py, sr * px + cr * py


def sample_aperture(camera: Camera, u: np.ndarray, v: np.ndarray):
    """Lens points (x, y) in camera units for uniform numbers (u, v), float32."""
    if camera.aperture_blades >= 3:
        x, y = sample_regular_polygon(int(camera.aperture_blades), camera.aperture_rotation, u, v)
    else:
        x, y = sample_disk_concentric(u, v)
    radius = np.float32(camera.aperture_radius)
    return (x * (radius / np.float32(camera.aperture_ratio))).astype(np.float32), (y * radius).astype(np.float32)
