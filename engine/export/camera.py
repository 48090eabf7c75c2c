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
                 pixel_aspect=render.pixel_aspect_x / render.pixel_aspect_y, **pixel_filter(scene))
    if camera_ob.type != "CAMERA":  # Blender lets any object be the scene camera
        warnings.append(f"Active camera '{camera_ob.name}' is not a camera object: rendered with a "
                        f"50 mm lens")
        return Camera(**frame)
    cam = camera_ob.data
    kind = cam.type
    if kind == "PANO":
        from .panorama import export_panorama
        panorama_type, panorama = export_panorama(camera_ob, scene, width, height, warnings)
        frame.update(panorama_type=panorama_type, panorama=panorama)
    if cam.dof.use_dof:
        frame.update(depth_of_field(camera_ob, kind))
    sensor = cam.sensor_height if cam.sensor_fit == "VERTICAL" else cam.sensor_width
    return Camera(kind=kind, fov_rad=2.0 * math.atan(sensor / (2.0 * cam.lens)), sensor_fit=cam.sensor_fit,
                  shift_x=cam.shift_x, shift_y=cam.shift_y, ortho_scale=cam.ortho_scale,
                  clip_start=cam.clip_start, clip_end=cam.clip_end, **frame)


def pixel_filter(scene) -> dict:
    """The film's pixel filter from Ember's Film panel (Cycles': Box is one pixel wide)."""
    settings = getattr(scene, "ember", None)
    if settings is None:
        return {}
    kind = settings.pixel_filter_type
    return dict(filter_type=kind, filter_width=1.0 if kind == "BOX" else float(settings.filter_width))


DOF_FIELDS = ("aperture_radius", "aperture_blades", "aperture_rotation", "aperture_ratio", "focus_distance")


def depth_of_field(camera_ob, kind: str) -> dict:
    """Camera fields of Blender's Depth of Field panel, as Cycles' Blender layer reads them: the aperture
    radius is focal length / (2 f-stop) with the focal length in metres (orthographic: 1 / (2 f-stop)); the
    focus distance is the field's, or the focus object's (or bone's) depth along the camera's view axis."""
    cam = camera_ob.data
    dof = cam.dof
    fstop = max(float(dof.aperture_fstop), 1e-5)
    radius = 1.0 / (2.0 * fstop) if kind == "ORTHO" else cam.lens * 1e-3 / (2.0 * fstop)
    return dict(aperture_radius=radius, aperture_blades=int(dof.aperture_blades),
                aperture_rotation=float(dof.aperture_rotation), aperture_ratio=float(dof.aperture_ratio),
                focus_distance=max(focus_distance(camera_ob), 1e-5))


def focus_distance(camera_ob) -> float:
    dof = camera_ob.data.dof
    target = dof.focus_object
    if target is None:
        return float(dof.focus_distance)
    m = np.array(target.matrix_world, np.float64)
    bone = target.pose.bones.get(dof.focus_subtarget) if target.pose and dof.focus_subtarget else None
    if bone is not None:
        m = m @ np.array(bone.matrix, np.float64)
    cam = _rigid(camera_ob.matrix_world)
    axis = cam[:3, 2] / np.linalg.norm(cam[:3, 2])
    return float(abs(axis @ (cam[:3, 3] - m[:3, 3])))


def _rigid(matrix_world) -> np.ndarray:
    """(4, 4) float64 world matrix with the scale taken out of its rotation columns."""
    m = np.array(matrix_world, np.float64)
    lengths = np.linalg.norm(m[:3, :3], axis=0)
    m[:3, :3] /= np.where(lengths > 0, lengths, 1.0)
    return m
