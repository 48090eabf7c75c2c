"""The camera: Blender's camera object and render settings -> kernels.Camera, plus the render region.

Blender's camera looks down its local -Z with +Y up, which is also the kernel's convention, so the
object's world matrix is used as it is (scale removed).
"""
from __future__ import annotations

import math

import numpy as np

from ...kernels import Camera


def render_resolution(scene) -> tuple[int, int]:
    """Full frame size in pixels after the resolution percentage, rounded down as Blender does."""
    render = scene.render
    percent = render.resolution_percentage
    return max(render.resolution_x * percent // 100, 1), max(render.resolution_y * percent // 100, 1)


def render_region(scene, width: int, height: int) -> tuple[int, int, int, int] | None:
    """The render border as pixels (x0, y0, x1, y1), half-open, row 0 at the TOP; None without a border.

    Blender stores the border from the bottom (border_min_y) and truncates it to whole pixels. With a
    border, Blender hands the engine a render result of just this region whether or not
    use_crop_to_border is on: cropping only decides whether the saved image is the region alone or the
    full frame with the rest left transparent.
    """
    render = scene.render
    if not render.use_border:
        return None
    x0, x1 = int(render.border_min_x * width), int(render.border_max_x * width)
    bottom0, bottom1 = int(render.border_min_y * height), int(render.border_max_y * height)
    return x0, height - bottom1, x1, height - bottom0


def export_camera(camera_ob, scene, width: int, height: int, warnings: list[str]) -> Camera:
    """kernels.Camera for an evaluated camera object; width, height : full frame in pixels."""
    render = scene.render
    frame = dict(world_from_camera=_rigid(camera_ob.matrix_world), width=int(width), height=int(height),
                 pixel_aspect=render.pixel_aspect_x / render.pixel_aspect_y)
    if camera_ob.type != "CAMERA":  # Blender lets any object be the scene camera
        warnings.append(f"Active camera '{camera_ob.name}' is not a camera object: rendered with a "
                        f"50 mm lens")
        return Camera(**frame)
    cam = camera_ob.data
    kind = cam.type
    if kind == "PANO":
        warnings.append(f"Camera '{camera_ob.name}': panoramic cameras are not supported, rendered as "
                        f"perspective")
        kind = "PERSP"
    if cam.dof.use_dof:
        warnings.append(f"Camera '{camera_ob.name}': depth of field is not supported")
    sensor = cam.sensor_height if cam.sensor_fit == "VERTICAL" else cam.sensor_width
    return Camera(kind=kind, fov_rad=2.0 * math.atan(sensor / (2.0 * cam.lens)), sensor_fit=cam.sensor_fit,
                  shift_x=cam.shift_x, shift_y=cam.shift_y, ortho_scale=cam.ortho_scale,
                  clip_start=cam.clip_start, clip_end=cam.clip_end, **frame)


def _rigid(matrix_world) -> np.ndarray:
    """(4, 4) float64 world matrix with the scale taken out of its rotation columns."""
    m = np.array(matrix_world, np.float64)
    lengths = np.linalg.norm(m[:3, :3], axis=0)
    m[:3, :3] /= np.where(lengths > 0, lengths, 1.0)
    return m
