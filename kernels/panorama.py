"""Panoramic cameras: Cycles' mappings between the image and directions (kernel/camera/projection.h).

The image: a raster position (sx, sy) in full-frame pixels (x right from the left edge, y down from the
top edge) becomes (u, v) on Cycles' panorama view plane, [0, 1]^2 over the frame whatever its aspect,
offset by the lens shift (blender/camera.cpp: pano_viewplane; scene/camera.cpp: rastertocamera):

    u = sx / width + shift_x        v = 1 - sy / height + shift_y     (v from the bottom edge)

The projections map (u, v) to a direction in Cycles' panorama frame, which looks down +x with +z up
(+y to the left); the mirror ball's frame looks down -y. Both are the Blender camera frame (-Z forward,
+Y up) turned (blender_camera_matrix): to_ember below. Where a projection has no direction (outside a
fisheye's circle or the mirror ball) the pixel gets no ray: Cycles writes RGB 0 and alpha 1 there, with
or without a transparent film (init_from_camera returns before any path; the sample still counts).

Camera.panorama holds plain floats under Blender's property names; angles in radians, lengths in mm:

    EQUIRECTANGULAR           latitude_min, latitude_max, longitude_min, longitude_max
    EQUIANGULAR_CUBEMAP_FACE  -
    MIRRORBALL                -
    FISHEYE_EQUIDISTANT       fisheye_fov
    FISHEYE_EQUISOLID         fisheye_fov, fisheye_lens, sensor_width, sensor_height
    FISHEYE_LENS_POLYNOMIAL   fisheye_fov, fisheye_polynomial_k0 .. k4, sensor_width, sensor_height
    CENTRAL_CYLINDRICAL       central_cylindrical_range_u_min, _u_max, _v_min, _v_max, central_cylindrical_radius

sensor_width, sensor_height are the sensor as fitted to the frame (Cycles' sensorwidth/sensorheight).
Mappings run in float64 (Cycles' float32 agrees to about 1e-6); directions leave as float32.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .vec import length_xyz

if TYPE_CHECKING:
    from .scene import Camera

_POLYNOMIAL = tuple(f"fisheye_polynomial_k{i}" for i in range(5))
_CYLINDRICAL = ("central_cylindrical_range_u_min", "central_cylindrical_range_u_max",
                "central_cylindrical_range_v_min", "central_cylindrical_range_v_max", "central_cylindrical_radius")
# The parameters each projection reads (all required).
PANORAMA_PARAMS = {
    "EQUIRECTANGULAR": ("latitude_min", "latitude_max", "longitude_min", "longitude_max"),
    "EQUIANGULAR_CUBEMAP_FACE": (),
    "MIRRORBALL": (),
    "FISHEYE_EQUIDISTANT": ("fisheye_fov",),
    "FISHEYE_EQUISOLID": ("fisheye_fov", "fisheye_lens", "sensor_width", "sensor_height"),
    "FISHEYE_LENS_POLYNOMIAL": ("fisheye_fov",) + _POLYNOMIAL + ("sensor_width", "sensor_height"),
    "CENTRAL_CYLINDRICAL": _CYLINDRICAL,
}
PANORAMA_TYPES = tuple(PANORAMA_PARAMS)
# Parameters that must be positive (Blender's ranges keep them so; the mappings divide by them).
POSITIVE_PARAMS = ("fisheye_fov", "fisheye_lens", "sensor_width", "sensor_height", "central_cylindrical_radius")

_NEWTON_STEPS = 20  # Cycles' bound for inverting the lens polynomial


# ---------------------------------------------------------------- the whole camera
def panorama_uv(camera: Camera, sx, sy) -> tuple[np.ndarray, np.ndarray]:
    """Raster positions (N,) -> (u, v) (N,) float64 on the panorama view plane."""
    fx = np.asarray(sx, np.float64) / camera.width
    fy = 1.0 - np.asarray(sy, np.float64) / camera.height
    if camera.panorama_window is not None:  # a viewport region showing part of the frame
        u0, u1, v0, v1 = camera.panorama_window
        fx, fy = u0 + fx * (u1 - u0), v0 + fy * (v1 - v0)
    return fx + camera.shift_x, fy + camera.shift_y


def panorama_directions(camera: Camera, sx, sy) -> tuple[np.ndarray, np.ndarray]:
    """Directions of raster positions sx, sy (N,) (full-frame pixels, y down from the top).

    Returns dirs (N, 3) float32 unit in the camera frame (-Z forward, +Y up) and valid (N,) bool; a
    position without a direction (valid False) gets the forward axis."""
    _, local, valid = panorama_rays(camera, sx, sy)
    return local, valid


def panorama_rays(camera: Camera, sx, sy, lens=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera-frame rays of raster positions sx, sy (N,), with Cycles' thin lens for panoramas when lens =
    (lx, ly) (N,) lens points (kernels.lens.sample_aperture): the lens lies across each pinhole direction
    and the ray leaves it toward the pinhole ray's point at distance focus_distance (a sphere of focus).

    Returns origins (N, 3) float32 relative to the eye (zero without a lens), dirs (N, 3) float32 unit,
    valid (N,) bool, all in the camera frame; no clipping."""
    u, v = panorama_uv(camera, sx, sy)
    (x, y, z), valid = PROJECTIONS[camera.panorama_type](camera.panorama, u, v)
    d = np.stack([x, y, z], axis=1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    start = np.zeros_like(d)
    if lens is not None:
        lx, ly = (np.asarray(c, np.float64)[:, None] for c in lens)
        # The lens' axes: U is Cycles' panorama x made orthogonal to the ray, V = ray x U.
        across = np.array([1.0, 0.0, 0.0]) - d[:, :1] * d
        length = np.linalg.norm(across, axis=1, keepdims=True)
        # Along x itself Cycles' U is 0 / 0; any axis across the ray does there.
        across = np.where(length > 0, across / np.where(length > 0, length, 1.0), (0.0, 1.0, 0.0))
        start = lx * across + ly * np.cross(d, across)
        d = d * camera.focus_distance - start
        d /= np.linalg.norm(d, axis=1, keepdims=True)
    start = np.stack(to_ember(camera.panorama_type, *start.T), axis=1)
    local = np.stack(to_ember(camera.panorama_type, *d.T), axis=1)
    local[~valid], start[~valid] = (0.0, 0.0, -1.0), 0.0
    return start.astype(np.float32), local.astype(np.float32), valid


def panorama_raster(camera: Camera, dirs) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of panorama_directions: camera-frame directions (N, 3) -> raster sx, sy (N,) float64.
    Meaningful for directions the camera sees (an equirectangular map wraps its longitude at +-pi)."""
    d = np.asarray(dirs, np.float64)
    x, y, z = to_cycles(camera.panorama_type, d[:, 0], d[:, 1], d[:, 2])
    u, v = INVERSES[camera.panorama_type](camera.panorama, x, y, z)
    fx, fy = u - camera.shift_x, v - camera.shift_y
    if camera.panorama_window is not None:
        u0, u1, v0, v1 = camera.panorama_window
        fx, fy = (fx - u0) / (u1 - u0), (fy - v0) / (v1 - v0)
    return fx * camera.width, (1.0 - fy) * camera.height


def panorama_differentials(camera: Camera, sx, sy) -> tuple[np.ndarray, np.ndarray]:
    """(dp, dd) (n,) float32 Cycles' compact differentials of the rays through raster points (sx, sy) (y from the top)
    at their origins on the near clip plane (camera_sample_panorama, camera_sample_to_ray): dd the mean length of
    the direction's change one pixel right and one up, from the raster points without the lens; dp = Clip Start x
    dd. Where one neighbour has no direction (outside a fisheye's circle) the other's change is taken, 0 where
    neither has one."""
    d, _ = panorama_directions(camera, sx, sy)
    dx, ok_x = panorama_directions(camera, sx + 1.0, sy)
    dy, ok_y = panorama_directions(camera, sx, sy - 1.0)  # Cycles' raster y + 1 is one row up
    ex, ey = np.linalg.norm(dx - d, axis=1), np.linalg.norm(dy - d, axis=1)
    dd = np.where(ok_x & ok_y, 0.5 * (ex + ey), np.where(ok_x, ex, np.where(ok_y, ey, 0.0))).astype(np.float32)
    return (dd * np.float32(camera.clip_start)).astype(np.float32), dd


def pixel_spread(camera: Camera) -> float:
    """Radians per pixel of the camera's rays, for ray differentials: Cycles' compact differential (the
    mean length of the direction change to the next pixel in x and in y) at the frame's centre, or, where
    the centre has no direction, the median of it over a grid across the frame."""
    sx = np.concatenate([[0.5 * camera.width], np.repeat(np.linspace(0.5, camera.width - 1.5, 9), 9)])
    sy = np.concatenate([[0.5 * camera.height], np.tile(np.linspace(1.5, camera.height - 0.5, 9), 9)])
    d, ok = panorama_directions(camera, sx, sy)
    dx, ok_x = panorama_directions(camera, sx + 1.0, sy)
    dy, ok_y = panorama_directions(camera, sx, sy - 1.0)  # Cycles' raster y + 1 is one row up
    spread = 0.5 * (np.linalg.norm(dx - d, axis=1) + np.linalg.norm(dy - d, axis=1))
    ok &= ok_x & ok_y
    if ok[0]:
        return float(spread[0])
    return float(np.median(spread[ok])) if ok.any() else 0.0


# ---------------------------------------------------------------- frames
def to_ember(panorama_type: str, x, y, z):
    """Cycles' panorama frame -> the Blender camera frame (blender_camera_matrix)."""
    if panorama_type == "MIRRORBALL":
        return x, z, y
    return -y, z, -x


def to_cycles(panorama_type: str, x, y, z):
    """The Blender camera frame -> Cycles' panorama frame (inverse of to_ember)."""
    if panorama_type == "MIRRORBALL":
        return x, z, y
    return -z, -x, y


# ---------------------------------------------------------------- (u, v) -> direction, Cycles' frame
# Each takes the parameters and u, v (N,) float64; returns ((x, y, z), valid), the direction not
# necessarily unit.

def equirectangular(p, u, v):
    phi = (p["longitude_min"] - p["longitude_max"]) * u - p["longitude_min"]
    theta = (p["latitude_min"] - p["latitude_max"]) * v + (0.5 * np.pi - p["latitude_min"])
    sin_t = np.sin(theta)
    return (sin_t * np.cos(phi), sin_t * np.sin(phi), np.cos(theta)), np.ones(u.shape, bool)


def equiangular_cubemap_face(p, u, v):
    return (np.ones_like(u), np.tan((0.5 - u) * (0.5 * np.pi)), np.tan((v - 0.5) * (0.5 * np.pi))), \
        np.ones(u.shape, bool)


def mirrorball(p, u, v):
    """The reflection of a view along -y in a unit ball seen orthographically: x = 2u - 1, z = 2v - 1."""
    x, z = 2.0 * u - 1.0, 2.0 * v - 1.0
    r2 = x * x + z * z
    s = np.sqrt(np.maximum(1.0 - r2, 0.0))  # -y of the ball's normal
    return (2.0 * s * x, 1.0 - 2.0 * s * s, 2.0 * s * z), r2 <= 1.0


def fisheye_equidistant(p, u, v):
    a, b = (u - 0.5) * 2.0, (v - 0.5) * 2.0
    r = np.hypot(a, b)
    return _fisheye(r * (0.5 * p["fisheye_fov"]), a, b, r), r <= 1.0


def fisheye_equisolid(p, u, v):
    a, b = (u - 0.5) * p["sensor_width"], (v - 0.5) * p["sensor_height"]
    r = np.hypot(a, b)
    lens = p["fisheye_lens"]
    valid = r <= 2.0 * lens * np.sin(0.25 * p["fisheye_fov"])
    theta = 2.0 * np.arcsin(np.minimum(r / (2.0 * lens), 1.0))
    return _fisheye(theta, a, b, r), valid


def fisheye_lens_polynomial(p, u, v):
    a, b = (u - 0.5) * p["sensor_width"], (v - 0.5) * p["sensor_height"]
    r = np.hypot(a, b)
    theta = -_polynomial(p, r)
    return _fisheye(theta, a, b, r), np.abs(theta) <= 0.5 * p["fisheye_fov"]


def central_cylindrical(p, u, v):
    """A cylinder around z: u spans the angle from -u_min to -u_max, v the height (over the radius)."""
    u0, u1 = -p["central_cylindrical_range_u_min"], -p["central_cylindrical_range_u_max"]
    radius = p["central_cylindrical_radius"]
    v0, v1 = p["central_cylindrical_range_v_min"] / radius, p["central_cylindrical_range_v_max"] / radius
    angle = u0 + u * (u1 - u0)
    return (np.cos(angle), np.sin(angle), v0 + v * (v1 - v0)), np.ones(u.shape, bool)


def _fisheye(theta, a, b, r):
    """Cycles' fisheye_to_direction: theta from the +x axis, in the image direction (a, b) at radius r;
    at r = 0 the azimuth is the +b side, as Cycles' safe_divide makes it."""
    cos_phi = np.clip(np.divide(a, r, out=np.zeros_like(a), where=r > 0), -1.0, 1.0)
    sin_phi = np.sqrt(1.0 - cos_phi * cos_phi) * np.where(b < 0, -1.0, 1.0)
    sin_t = np.sin(theta)
    return np.cos(theta), -cos_phi * sin_t, sin_phi * sin_t


def _polynomial(p, r):
    k = [p[name] for name in _POLYNOMIAL]
    return k[0] + r * (k[1] + r * (k[2] + r * (k[3] + r * k[4])))


PROJECTIONS = {
    "EQUIRECTANGULAR": equirectangular,
    "EQUIANGULAR_CUBEMAP_FACE": equiangular_cubemap_face,
    "MIRRORBALL": mirrorball,
    "FISHEYE_EQUIDISTANT": fisheye_equidistant,
    "FISHEYE_EQUISOLID": fisheye_equisolid,
    "FISHEYE_LENS_POLYNOMIAL": fisheye_lens_polynomial,
    "CENTRAL_CYLINDRICAL": central_cylindrical,
}


# ---------------------------------------------------------------- direction -> (u, v), Cycles' frame
# Each takes the parameters and a direction x, y, z (N,) float64 (any length); returns u, v.

def equirectangular_inverse(p, x, y, z):
    phi, theta = np.arctan2(y, x), np.arccos(np.clip(z / length_xyz((x, y, z)), -1.0, 1.0))
    return ((phi + p["longitude_min"]) / (p["longitude_min"] - p["longitude_max"]),
            (theta - (0.5 * np.pi - p["latitude_min"])) / (p["latitude_min"] - p["latitude_max"]))


def equiangular_cubemap_face_inverse(p, x, y, z):
    return 0.5 - np.arctan2(y, x) * (2.0 / np.pi), np.arctan2(z, x) * (2.0 / np.pi) + 0.5


def mirrorball_inverse(p, x, y, z):
    n = length_xyz((x, y, z))
    x, y, z = x / n, y / n - 1.0, z / n  # the ball's normal is the half vector of the view and d
    scale = 2.0 * np.sqrt(np.maximum(-0.5 * y, 0.0))
    scale = np.where(scale > 0, scale, 1.0)
    return 0.5 * (x / scale + 1.0), 0.5 * (z / scale + 1.0)


def fisheye_equidistant_inverse(p, x, y, z):
    radius = np.arctan2(np.hypot(y, z), x) / p["fisheye_fov"]
    a, b = _azimuth(y, z)
    return 0.5 - radius * a, 0.5 + radius * b


def fisheye_equisolid_inverse(p, x, y, z):
    theta = np.arccos(np.clip(x / length_xyz((x, y, z)), -1.0, 1.0))
    radius = 2.0 * p["fisheye_lens"] * np.sin(0.5 * theta)
    a, b = _azimuth(y, z)
    return 0.5 - radius * a / p["sensor_width"], 0.5 + radius * b / p["sensor_height"]


def fisheye_lens_polynomial_inverse(p, x, y, z):
    """Newton's method on theta = polynomial(r), from the linear term's root, as Cycles does."""
    theta = -np.arccos(np.clip(x / length_xyz((x, y, z)), -1.0, 1.0))
    k = [p[name] for name in _POLYNOMIAL]
    radius = (theta - k[0]) / k[1]
    for _ in range(_NEWTON_STEPS):
        slope = k[1] + radius * (2.0 * k[2] + radius * (3.0 * k[3] + radius * 4.0 * k[4]))
        radius = radius + (theta - _polynomial(p, radius)) / slope
    a, b = _azimuth(y, z)
    return 0.5 - radius * a / p["sensor_width"], 0.5 + radius * b / p["sensor_height"]


def central_cylindrical_inverse(p, x, y, z):
    u0, u1 = -p["central_cylindrical_range_u_min"], -p["central_cylindrical_range_u_max"]
    radius = p["central_cylindrical_radius"]
    v0, v1 = p["central_cylindrical_range_v_min"] / radius, p["central_cylindrical_range_v_max"] / radius
    return (np.arctan2(y, x) - u0) / (u1 - u0), (z / np.hypot(x, y) - v0) / (v1 - v0)


def _azimuth(y, z):
    """(y, z) normalised, zero where both are (Cycles' safe_normalize)."""
    n = np.hypot(y, z)
    safe = np.where(n > 0, n, 1.0)
    return y / safe, z / safe


INVERSES = {
    "EQUIRECTANGULAR": equirectangular_inverse,
    "EQUIANGULAR_CUBEMAP_FACE": equiangular_cubemap_face_inverse,
    "MIRRORBALL": mirrorball_inverse,
    "FISHEYE_EQUIDISTANT": fisheye_equidistant_inverse,
    "FISHEYE_EQUISOLID": fisheye_equisolid_inverse,
    "FISHEYE_LENS_POLYNOMIAL": fisheye_lens_polynomial_inverse,
    "CENTRAL_CYLINDRICAL": central_cylindrical_inverse,
}
