"""The camera: the one place that builds kernels.Camera, for final renders and for the viewport.

    export_camera   from a camera object and the render settings (final renders)
    view_camera     from a 3D view, free or through a camera, placed as Blender's BKE_camera_params_from_view3d
                    and BKE_camera_params_compute_viewplane place it (region_camera: from bpy's view structs)

Both read a camera's lens, sensor, shift, clipping and depth of field (_lens), the pixel filter and the
panorama alike. Blender's camera looks down its local -Z with +Y up, as the kernel's, so world matrices are
used as they are (scale removed). A camera whose focal length, sensor size or orthographic scale is zero
or not a number sees nothing of the scene, as in Cycles: it renders the world along its view axis, with a
warning. Also here: the render resolution and the render region.
"""
from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np

from ...kernels import Camera
from ...kernels.camera import view_plane

# Blender's DNA defaults (DNA_camera_defaults.h): the 3D view has no sensor of its own and uses these.
DEFAULT_SENSOR_WIDTH = 36.0
DEFAULT_SENSOR_HEIGHT = 24.0
# BKE_camera.h: CameraParams.zoom for a free 3D view. The view shows twice the field of a camera with
# the same lens, i.e. a 72 mm wide sensor.
CAMERA_PARAM_ZOOM_INIT_PERSP = 2.0
# BKE_camera_params_from_object: objects other than cameras and lights get this lens as the camera.
NON_CAMERA_LENS = 35.0


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


# ====================================================================== final renders
def export_camera(camera_ob, scene, width: int, height: int, warnings: list[str]) -> Camera:
    """kernels.Camera for an evaluated camera object; width, height : full frame in pixels."""
    render = scene.render
    frame = dict(world_from_camera=rigid_transform(camera_ob.matrix_world), width=int(width), height=int(height),
                 pixel_aspect=render.pixel_aspect_x / render.pixel_aspect_y, **pixel_filter(scene))
    axes = frame["world_from_camera"][:3, :3]
    if not abs(np.linalg.det(axes)) > 1e-9:
        # A scale of zero on an axis (or axes scaled into one plane) leaves no direction to look in: Cycles'
        # rays then have no direction and each pixel shows the world (transform_clear_scale keeps a zero axis).
        axes[:] = np.eye(3)
        scale = ", ".join(f"{v:g}" for v in np.linalg.norm(np.array(camera_ob.matrix_world, np.float64)[:3, :3], axis=0))
        warnings.append(f"Camera '{camera_ob.name}' is scaled to nothing along an axis (its world scale {scale}), so it "
                        f"sees nothing of the scene (as in Cycles): rendered the world along the world's -Z axis")
        return blind_camera(**frame)
    if camera_ob.type != "CAMERA":  # Blender lets any object be the scene camera
        warnings.append(f"Active camera '{camera_ob.name}' is not a camera object: rendered with a "
                        f"50 mm lens")
        return Camera(**frame)
    lens, sensor, fields = _lens(camera_ob)
    problem = degenerate_view(fields["kind"], lens, sensor, fields["ortho_scale"], camera_ob.data.sensor_fit)
    if problem is not None:
        warnings.append(f"Camera '{camera_ob.name}': {problem}, so it sees nothing of the scene (as in Cycles): "
                        f"rendered the world along its view axis")
        return blind_camera(**frame)
    if fields["kind"] == "PANO":
        from .panorama import export_panorama
        panorama_type, panorama = export_panorama(camera_ob, scene, width, height, warnings)
        frame.update(panorama_type=panorama_type, panorama=panorama)
    return Camera(fov_rad=2.0 * math.atan(sensor / (2.0 * lens)), **fields, **frame)


def _lens(camera_ob) -> tuple[float, float, dict]:
    """(focal length in mm, sensor size along the fit axis in mm, kernels.Camera's kind, sensor fit, shift,
    ortho scale, clipping and depth of field) of a camera object, as BKE_camera_params_from_object reads it."""
    cam = camera_ob.data
    fields = dict(kind=cam.type, sensor_fit=cam.sensor_fit, shift_x=cam.shift_x, shift_y=cam.shift_y,
                  ortho_scale=cam.ortho_scale, clip_start=cam.clip_start, clip_end=cam.clip_end)
    if cam.dof.use_dof:
        fields.update(depth_of_field(camera_ob, cam.type))
    sensor = cam.sensor_height if cam.sensor_fit == "VERTICAL" else cam.sensor_width
    return cam.lens, sensor, fields


def perspective_fov(lens: float, sensor: float) -> float | None:
    """The field of view 2 atan(sensor / (2 lens)) of a perspective lens, radians; None when it is not in
    (0, pi): a focal length or sensor size of zero, negative or not a number (Blender's interface stops
    at 1 mm, but a script can set NaN and a file can hold anything)."""
    with np.errstate(all="ignore"):
        fov = float(2.0 * np.arctan(np.float64(sensor) / (2.0 * np.float64(lens))))
    return fov if 0.0 < fov < math.pi and lens > 0 and sensor > 0 else None


def degenerate_view(kind: str, lens: float, sensor: float, ortho_scale: float, sensor_fit: str) -> str | None:
    """What makes a camera's projection degenerate (its rays all start at one point or leave along the
    image plane, or are not numbers: Cycles' camera then sees no geometry), or None."""
    if kind == "ORTHO":
        return None if 0.0 < ortho_scale < math.inf else f"its orthographic scale is {ortho_scale:g}"
    if kind != "PERSP" or perspective_fov(lens, sensor) is not None:
        return None
    side = "height" if sensor_fit == "VERTICAL" else "width"
    return f"its focal length is {lens:g} mm with a sensor {side} of {sensor:g} mm"


def blind_camera(**frame) -> Camera:
    """A camera seeing no geometry: every ray starts at the camera and ends at once, so each pixel shows
    the world along the view axis (what a degenerate Cycles camera shows of a constant world)."""
    return Camera(kind="ORTHO", ortho_scale=float(np.finfo(np.float32).tiny), clip_start=0.0,
                  clip_end=float(np.finfo(np.float32).tiny), **frame)


def pixel_filter(scene) -> dict:
    """The film's pixel filter from Ember's Film panel (Cycles': Box is one pixel wide)."""
    settings = getattr(scene, "ember", None)
    if settings is None:
        return {}
    kind = settings.pixel_filter_type
    return dict(filter_type=kind, filter_width=1.0 if kind == "BOX" else float(settings.filter_width))


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
    cam = rigid_transform(camera_ob.matrix_world)
    axis = cam[:3, 2] / np.linalg.norm(cam[:3, 2])
    return float(abs(axis @ (cam[:3, 3] - m[:3, 3])))


def rigid_transform(matrix_world) -> np.ndarray:
    """(4, 4) float64 world matrix with the scale taken out of its rotation columns."""
    m = np.array(matrix_world, np.float64)
    lengths = np.linalg.norm(m[:3, :3], axis=0)
    m[:3, :3] /= np.where(lengths > 0, lengths, 1.0)
    return m


def stand_in_camera(**data) -> SimpleNamespace:
    """A camera object with Blender's default camera data (`data` overrides fields of it), carrying only
    what export_camera and view_camera read: the viewport exports a scene without camera with it."""
    data = SimpleNamespace(**{**dict(type="PERSP", dof=SimpleNamespace(use_dof=False), sensor_fit="AUTO",
                                     sensor_width=DEFAULT_SENSOR_WIDTH, sensor_height=DEFAULT_SENSOR_HEIGHT,
                                     lens=50.0, shift_x=0.0, shift_y=0.0, ortho_scale=6.0, clip_start=0.1,
                                     clip_end=100.0), **data})
    stand_in = SimpleNamespace(name="Viewport", type="CAMERA", data=data, matrix_world=np.eye(4))
    stand_in.evaluated_get = lambda depsgraph: stand_in
    return stand_in


# ====================================================================== the viewport
def region_camera(space, region_data, width: int, height: int, camera_ob=None, scene=None) -> Camera:
    """view_camera of a SpaceView3D and its RegionView3D; camera_ob is the evaluated object the view looks
    through (view_camera_object; used only when view_perspective is 'CAMERA'); the scene gives the pixel
    filter and a panoramic camera's frame."""
    return view_camera(region_data.view_matrix, width, height, region_data.view_perspective, space.lens,
                       space.clip_start, space.clip_end, region_data.view_distance, camera_ob,
                       region_data.view_camera_zoom, tuple(region_data.view_camera_offset), scene)


def view_camera(view_matrix, width: int, height: int, perspective: str, lens: float, clip_start: float,
                clip_end: float, view_distance: float, camera_ob=None, camera_zoom: float = 0.0,
                camera_offset=(0.0, 0.0), scene=None) -> Camera:
    """What a 3D view shows, as Blender projects it (BKE_camera_params_from_view3d, then
    BKE_camera_params_compute_viewplane with the region's size and square pixels).

    view_matrix : camera_from_world, RegionView3D.view_matrix.
    width, height : the film's size in pixels.
    perspective : RegionView3D.view_perspective, 'PERSP', 'ORTHO' or 'CAMERA'.
    lens, clip_start, clip_end : SpaceView3D's; view_distance : RegionView3D.view_distance.
    camera_ob : the evaluated object a 'CAMERA' view looks through (None: the view's own lens).
    camera_zoom, camera_offset : RegionView3D.view_camera_zoom / view_camera_offset ('CAMERA').
    scene : gives the pixel filter, and the frame of a panoramic camera (None: a one-pixel box, no panorama).
    """
    world_from_camera = np.linalg.inv(np.asarray(view_matrix, np.float64).reshape(4, 4))
    film = dict(width=int(width), height=int(height), **(pixel_filter(scene) if scene is not None else {}))
    if perspective == "CAMERA":
        return _through_camera(world_from_camera, film, camera_ob, scene, camera_zoom, camera_offset,
                               lens, clip_start, clip_end)
    zoom = CAMERA_PARAM_ZOOM_INIT_PERSP
    if perspective == "ORTHO":
        # Blender clips an ortho view to [-clip_end / 2, clip_end / 2] around the view point. The
        # kernel starts rays at clip_start >= 0, so the eye moves back by clip_end / 2 instead.
        world_from_camera[:3, 3] += world_from_camera[:3, 2] * (0.5 * clip_end)
        ortho_scale = view_distance * DEFAULT_SENSOR_WIDTH / lens  # ED_view3d_radius_to_dist_ortho
        return Camera(world_from_camera=world_from_camera, kind="ORTHO", ortho_scale=ortho_scale * zoom,
                      clip_start=0.0, clip_end=float(clip_end), **film)
    return Camera(world_from_camera=world_from_camera, kind="PERSP",
                  fov_rad=2.0 * math.atan(zoom * DEFAULT_SENSOR_WIDTH / (2.0 * lens)),
                  clip_start=float(clip_start), clip_end=float(clip_end), **film)


def camera_zoom_factor(view_camera_zoom: float) -> float:
    """BKE_screen_view3d_zoom_to_fac: how much of the camera frame a camera view shows (0.5 at zoom 0,
    where the frame fills half of the region)."""
    return (math.sqrt(2.0) + view_camera_zoom / 50.0) ** 2 / 4.0


def view_camera_object(space, scene):
    """The object a camera view looks through: the view's own camera when it is unlocked from the
    scene's (Cycles does the same)."""
    return space.camera if space.use_local_camera else scene.camera


def _through_camera(world_from_camera, film: dict, camera_ob, scene, camera_zoom: float, camera_offset,
                    view_lens: float, clip_start: float, clip_end: float) -> Camera:
    """A camera view: the region is the image, whatever the render resolution; only the fit axis comes
    from the camera. As in Blender, an object that is not a camera keeps the view's clipping and the
    default sensor, with a 35 mm lens (a light: the lens whose field matches its spot size); no object at
    all keeps the view's lens. A panoramic camera shows its panorama (_panorama_window)."""
    if camera_ob is not None and camera_ob.type == "CAMERA":
        lens, sensor, fields = _lens(camera_ob)
        fields["kind"] = "ORTHO" if fields["kind"] == "ORTHO" else "PERSP"
    else:
        lens, sensor = view_lens, DEFAULT_SENSOR_WIDTH
        if camera_ob is not None:
            lens = NON_CAMERA_LENS
            if camera_ob.type == "LIGHT":
                # Every light stores a spot size (45 degrees unless it is a spot light).
                spot = float(getattr(camera_ob.data, "spot_size", math.radians(45.0)))
                lens = 16.0 / math.tan(spot / 2.0) or NON_CAMERA_LENS
        lens = float(lens)
        fields = dict(kind="PERSP", sensor_fit="AUTO", shift_x=0.0, shift_y=0.0, ortho_scale=6.0,
                      clip_start=float(clip_start), clip_end=float(clip_end))
    if degenerate_view(fields["kind"], lens, sensor, fields["ortho_scale"], fields["sensor_fit"]) is not None:
        return blind_camera(world_from_camera=world_from_camera, **film)
    width, height = film["width"], film["height"]
    fac = camera_zoom_factor(camera_zoom)
    fit = fields["sensor_fit"]
    if fit == "AUTO":
        fit = "HORIZONTAL" if width >= height else "VERTICAL"
    viewfac = width if fit == "HORIZONTAL" else height
    # Blender scales the lens shift by fac and adds the pan offset; the kernel's shift is in units of the
    # (zoomed) fitted extent, hence the extra factor fac.
    fields.update(shift_x=fac * (fields["shift_x"] + 2.0 * camera_offset[0] * width / viewfac),
                  shift_y=fac * (fields["shift_y"] + 2.0 * camera_offset[1] * height / viewfac),
                  ortho_scale=fields["ortho_scale"] / fac)
    camera = Camera(world_from_camera=world_from_camera, fov_rad=2.0 * math.atan(sensor / (2.0 * lens * fac)),
                    **fields, **film)
    if scene is not None and camera_ob is not None and camera_ob.type == "CAMERA" and camera_ob.data.type == "PANO":
        return _panorama_window(camera, camera_ob, scene)
    return camera


def _panorama_window(view: Camera, camera_ob, scene) -> Camera:
    """A camera view through a panoramic camera: the final render's panorama, showing the part of the
    camera's frame the region shows (its zoomed, panned border, as the perspective view plane of the
    camera view places it), as Cycles' viewport does."""
    final = export_camera(camera_ob, scene, *render_resolution(scene), [])
    fx0, fx1, fy0, fy1 = view_plane(dataclasses.replace(final, kind="PERSP"))
    x0, x1, y0, y1 = view_plane(view)
    window = ((x0 - fx0) / (fx1 - fx0), (x1 - fx0) / (fx1 - fx0), (y0 - fy0) / (fy1 - fy0), (y1 - fy0) / (fy1 - fy0))
    return dataclasses.replace(view, kind="PANO", panorama_type=final.panorama_type, panorama=final.panorama,
                               panorama_window=window, shift_x=final.shift_x, shift_y=final.shift_y)
