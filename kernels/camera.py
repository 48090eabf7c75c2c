"""Camera rays: Blender's view plane (sensor fit, shift, pixel aspect, ortho scale) and clipping.

Pixel (row, col) with row 0 at the top of the full frame; a jitter (jx, jy) in [0, 1)^2 places the
sample inside the pixel; the camera's pixel filter warps it (kernels.pixel_filter), and a lens with depth
of field moves the ray's origin (kernels.lens).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from . import motion, pixel_filter
from .lens import sample_aperture
from .scene import Camera
from .vec import matmul


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


def generate_rays(camera: Camera, row: np.ndarray, col: np.ndarray, jx: np.ndarray, jy: np.ndarray,
                  lens: tuple | None = None, times: np.ndarray | None = None, spread: bool = False):
    """Rays through the given pixels. Returns origins (N, 3), directions (N, 3) unit, t_max (N,),
    all float32. Origins sit on the near clip plane; t_max reaches the far clip plane.

    (jx, jy) in [0, 1)^2 are warped by the camera's pixel filter into offsets from the pixel's corner;
    lens = (u, v) uniform numbers for the point on the lens when the camera has depth of field;
    times = (N,) path times in the shutter, which move a camera with motion blur (camera.motion).
    spread: then also each ray's differentials, (dp, dd) at its origin (differentials, or for panoramas
    panorama.panorama_differentials), None for orthographic cameras."""
    if camera.motion is not None and times is not None:
        # Built in the camera's own space, then moved by its transform at each ray's time (Cycles).
        still = dataclasses.replace(camera, world_from_camera=np.eye(4), motion=None)
        out = generate_rays(still, row, col, jx, jy, lens, times, spread)
        origins, dirs, t_max = out[:3]
        m = motion.interpolate(motion.decompose(np.asarray(camera.motion, np.float64)), times)
        origins = np.einsum("nij,nj->ni", m[:, :, :3], origins) + m[:, :, 3]
        dirs = np.einsum("nij,nj->ni", m[:, :, :3], dirs)
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        return (np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(dirs, np.float32), t_max) + out[3:]
    rays = _generate_rays(camera, row, col, jx, jy, lens, times)
    if not spread:
        return rays[:3]
    return rays[:3] + ((rays[3]() if rays[3] is not None else None),)


def differentials(camera: Camera, px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(dp, dd) (n,) float32 each: Cycles' compact differentials of perspective camera rays through the view-plane
    points (px, py) (the plane z = -1, before the lens) at their origins on the near clip plane. dd: the mean length
    of the change of the unit pinhole direction one pixel right and one pixel up (camera_sample_perspective,
    kernel/camera/camera.h: normalize(D + dx) - normalize(D), and dy; differential_make_compact); a pixel's angle
    shrinks away from the frame's centre (by 12% at the corners of a 50 mm 3:2 frame), and a footprint of the centre's
    everywhere widens a Bump's steps there. dp: dd times the distance from the eye to the origin (Cycles' rays
    start at the eye, dP 0, and their spread grows from there: differential_transfer_compact)."""
    xmin, xmax, ymin, ymax = view_plane(camera)
    hx = np.float32((xmax - xmin) / max(camera.width, 1))
    hy = np.float32((ymax - ymin) / max(camera.height, 1))
    one = np.float32(1.0)
    inv = one / np.sqrt(px * px + py * py + one)
    inv_x = one / np.sqrt((px + hx) * (px + hx) + py * py + one)
    inv_y = one / np.sqrt(px * px + (py + hy) * (py + hy) + one)
    step_x = np.sqrt(((px + hx) * inv_x - px * inv) ** 2 + (py * (inv_x - inv)) ** 2 + (inv_x - inv) ** 2)
    step_y = np.sqrt((px * (inv_y - inv)) ** 2 + ((py + hy) * inv_y - py * inv) ** 2 + (inv_y - inv) ** 2)
    dd = (np.float32(0.5) * (step_x + step_y)).astype(np.float32)
    return (dd * (np.float32(camera.clip_start) / inv)).astype(np.float32), dd


def _generate_rays(camera, row, col, jx, jy, lens, times):
    """generate_rays for a camera that does not move, with a function that gives the rays' differentials
    (None for orthographic cameras) as a fourth item."""
    jx = pixel_filter.offsets(camera.filter_type, camera.filter_width, jx)
    jy = pixel_filter.offsets(camera.filter_type, camera.filter_width, jy)
    if camera.kind == "PANO":
        from .panorama import panorama_differentials, panorama_rays
        # Cycles clips panoramic rays along the ray, from clip_start to clip_end. A pixel without a
        # direction (outside a fisheye's circle) gets t_max 0, Cycles' "no ray": it must stay black, alpha 1.
        points = sample_aperture(camera, *lens) if lens is not None and camera.aperture_radius > 0 else None
        start, local, valid = panorama_rays(camera, col.astype(np.float32) + jx, row.astype(np.float32) + jy,
                                            points)
        eye, rot = camera_frame(camera)
        rot32 = rot.astype(np.float32)
        dirs = matmul(local, rot32.T)
        origins = eye.astype(np.float32) + matmul(start, rot32.T) + dirs * np.float32(camera.clip_start)
        t_max = np.where(valid, np.float32(camera.clip_end - camera.clip_start), np.float32(0.0))
        sx, sy = col.astype(np.float32) + jx, row.astype(np.float32) + jy
        return (np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(dirs, np.float32),
                t_max.astype(np.float32), lambda: panorama_differentials(camera, sx, sy))
    xmin, xmax, ymin, ymax = view_plane(camera)
    sx = (col.astype(np.float32) + jx) / np.float32(camera.width)
    sy = np.float32(1.0) - (row.astype(np.float32) + jy) / np.float32(camera.height)
    px = np.float32(xmin) + sx * np.float32(xmax - xmin)
    py = np.float32(ymin) + sy * np.float32(ymax - ymin)
    if camera.fov_motion is not None and times is not None and camera.kind == "PERSP":
        # Cycles' perspective motion (kernel/camera/camera.h): the view-plane point lerps from the shutter's
        # start lens to the frame's in the first half, from the frame's to the end lens in the second.
        t = np.asarray(times, np.float32)
        early = t < np.float32(0.5)
        toward = np.where(early, np.float32(1) - 2 * t, 2 * t - np.float32(1))
        centre = np.tan(camera.fov_rad / 2.0)
        target = np.where(early, np.float32(np.tan(camera.fov_motion[0] / 2.0) / centre),
                          np.float32(np.tan(camera.fov_motion[1] / 2.0) / centre))
        zoom = np.float32(1) + toward * (target - np.float32(1))
        px, py = px * zoom, py * zoom
    eye, rot = camera_frame(camera)
    rot32 = rot.astype(np.float32)
    n = len(px)
    dof = lens is not None and camera.aperture_radius > 0
    if dof:
        lx, ly = sample_aperture(camera, *lens)
    if camera.kind == "ORTHO":
        if dof:  # Cycles: from the lens point toward the focus point straight ahead, cut at the near plane
            focus = np.float32(camera.focus_distance)
            inv = np.float32(1) / np.sqrt(lx * lx + ly * ly + focus * focus)
            local = np.stack([-lx * inv, -ly * inv, -focus * inv], 1)
            dirs = matmul(local, rot32.T)
            start = matmul(np.stack([px + lx, py + ly, np.zeros(n, np.float32)], 1), rot32.T)
            origins = eye.astype(np.float32) + start + dirs * (np.float32(camera.clip_start) / (focus * inv))[:, None]
        else:
            dirs = np.broadcast_to(-rot32[:, 2], (n, 3))
            origins = (eye.astype(np.float32) + matmul(np.stack([px, py, np.zeros(n, np.float32)], 1), rot32.T)
                       + dirs * np.float32(camera.clip_start))
        t_max = np.full(n, camera.clip_end - camera.clip_start, np.float32)
        return np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(dirs, np.float32), t_max, None
    inv_len = np.float32(1.0) / np.sqrt(px * px + py * py + np.float32(1.0))
    cos_axis = inv_len  # distance along the view axis per unit of the pinhole ray's length
    if dof:
        # Cycles: the pinhole ray meets the plane of focus at depth focus_distance; the ray leaves the lens
        # point toward it. Clipping keeps the pinhole ray's scale, as Cycles does.
        focus = np.float32(camera.focus_distance)
        fx, fy = px * focus - lx, py * focus - ly
        inv = np.float32(1.0) / np.sqrt(fx * fx + fy * fy + focus * focus)
        dirs = matmul(np.stack([fx * inv, fy * inv, -focus * inv], 1), rot32.T)
        start = matmul(np.stack([lx, ly, np.zeros(n, np.float32)], 1), rot32.T)
        origins = eye.astype(np.float32) + start + dirs * (np.float32(camera.clip_start) / cos_axis)[:, None]
    else:
        local = np.stack([px * inv_len, py * inv_len, -inv_len], 1)  # unit, z component is -cos
        dirs = matmul(local, rot32.T)
        origins = eye.astype(np.float32) + dirs * (np.float32(camera.clip_start) / cos_axis)[:, None]
    t_max = (np.float32(camera.clip_end - camera.clip_start) / cos_axis).astype(np.float32)
    return (np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(dirs, np.float32), t_max,
            lambda: differentials(camera, px, py))
