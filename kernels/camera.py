"""Camera rays: Blender's view plane (sensor fit, shift, pixel aspect, ortho scale) and clipping.

Pixel (row, col) with row 0 at the top of the full frame; a jitter (jx, jy) in [0, 1)^2 places the
sample inside the pixel (a box filter of one pixel, like Cycles with filter width 1 box).
"""
from __future__ import annotations

import numpy as np

from .scene import Camera


def view_plane(camera: Camera) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) of the frame on the plane z = -1 (perspective) or z = 0 (ortho),
    in camera units. Follows Blender's BKE_camera_params_compute_viewplane."""
    w, h = float(camera.width), float(camera.height)
    ycor = 1.0 / camera.pixel_aspect  # Blender's aspect_y / aspect_x
    fit = camera.sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if w >= ycor * h else "VERTICAL"
    viewfac = w if fit == "HORIZONTAL" else ycor * h
    extent = camera.ortho_scale if camera.kind == "ORTHO" else 2.0 * np.tan(camera.fov_rad / 2.0)
    pixsize = extent / viewfac
    dx = camera.shift_x * viewfac
    dy = camera.shift_y * viewfac
    return ((-0.5 * w + dx) * pixsize, (0.5 * w + dx) * pixsize,
            (-0.5 * ycor * h + dy) * pixsize, (0.5 * ycor * h + dy) * pixsize)


def camera_frame(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(eye (3,), rotation (3, 3)) float64 of world_from_camera with any scale dropped: columns are the
    camera's x (right), y (up) and z (back) axes in world space."""
    m = np.asarray(camera.world_from_camera, np.float64)
    return m[:3, 3], m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0)


def generate_rays(camera: Camera, row: np.ndarray, col: np.ndarray, jx: np.ndarray, jy: np.ndarray):
    """Rays through the given pixels. Returns origins (N, 3), directions (N, 3) unit, t_max (N,),
    all float32. Origins sit on the near clip plane; t_max reaches the far clip plane."""
    xmin, xmax, ymin, ymax = view_plane(camera)
    sx = (col.astype(np.float32) + jx) / np.float32(camera.width)
    sy = np.float32(1.0) - (row.astype(np.float32) + jy) / np.float32(camera.height)
    px = np.float32(xmin) + sx * np.float32(xmax - xmin)
    py = np.float32(ymin) + sy * np.float32(ymax - ymin)
    eye, rot = camera_frame(camera)
    rot32 = rot.astype(np.float32)
    n = len(px)
    if camera.kind == "ORTHO":
        lx, ly, lz = px, py, np.zeros(n, np.float32)
        dirs = np.broadcast_to(-rot32[:, 2], (n, 3))
        origins = (eye.astype(np.float32) + np.stack([lx, ly, lz], 1) @ rot32.T
                   + dirs * np.float32(camera.clip_start))
        t_max = np.full(n, camera.clip_end - camera.clip_start, np.float32)
        return np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(dirs, np.float32), t_max
    inv_len = np.float32(1.0) / np.sqrt(px * px + py * py + np.float32(1.0))
    local = np.stack([px * inv_len, py * inv_len, -inv_len], 1)  # unit, z component is -cos
    dirs = local @ rot32.T
    cos_axis = inv_len  # distance along the view axis per unit of ray length
    origins = eye.astype(np.float32) + dirs * (np.float32(camera.clip_start) / cos_axis)[:, None]
    t_max = (np.float32(camera.clip_end - camera.clip_start) / cos_axis).astype(np.float32)
    return np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(dirs, np.float32), t_max
