"""The viewport's rendered mode: a progressive render that starts over when the scene or the view changes.

Three layers, so that everything but the last few GPU calls runs headless in tests:

    ViewportCamera    the 3D view's projection (Blender's BKE_camera_params_from_view3d) as plain numbers
    ViewportSession   a worker thread that renders into a film and publishes Frames; no bpy anywhere
    ViewportRender    the RenderEngine's view_update / view_draw: reads bpy on the main thread, hands the
                      session arrays and numbers, and draws the latest Frame with the gpu module

Sync once, snapshot, let go (as in session.py): the worker sees only SceneArrays, RenderSettings and
ViewportCamera values. It never touches bpy, and bpy never waits for it except in stop().

Edits update incrementally, as Cycles' Blender sync tracks what changed: view_update sorts
depsgraph.updates into parts (update_part). A moved object re-reads only the instances' transforms and
object rows, and the worker moves its Renderer's instances (the top level of the BVH is recommitted, no
mesh BVH is rebuilt); a shader, image or world edit re-reads the materials and the world, and the
worker rebuilds shading, environment and light sampler; a light edit re-reads the lights, and the worker
rebuilds the light sampler. Anything else, or a partial read that no longer lines up with the last
export (engine/export/updates.py), is a full export and a new Renderer. To make moves cheap the viewport
exports every mesh as an instance of itself (export_scene(..., instance_everything=True)), as Cycles'
viewport does: its dynamic BVH type skips apply_static_transforms, so every object keeps its own BVH and
its transform; final renders copy single meshes into world space, which traces faster (about 20% here,
bench/viewport_updates.py). An update restarts from sample 0 and renders what a full export of the
edited scene would, bit for bit (tests/test_viewport_updates.py).
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import threading
import time
import weakref
from dataclasses import dataclass
from types import SimpleNamespace
from typing import NamedTuple

import numpy as np

from ..kernels import Camera, Renderer, RenderSettings, SceneArrays
from ..kernels.camera import view_plane
from .export import ExportError, export_scene
from .export.updates import export_instances, export_lights, export_shading
from .export.camera import DOF_FIELDS, depth_of_field, pixel_filter
from .session import PreviewDenoiser, render_settings, render_threads

# Blender's DNA defaults (DNA_camera_defaults.h): the 3D view has no sensor of its own and uses these.
DEFAULT_SENSOR_WIDTH = 36.0
DEFAULT_SENSOR_HEIGHT = 24.0
# BKE_camera.h: CameraParams.zoom for a free 3D view. The view shows twice the field of a camera with
# the same lens, i.e. a 72 mm wide sensor.
CAMERA_PARAM_ZOOM_INIT_PERSP = 2.0
# BKE_camera_params_from_object: objects other than cameras and lights get this lens as the camera.
NON_CAMERA_LENS = 35.0
# The largest finite half float: the texture is RGBA16F and an inf there turns the viewport black.
HALF_MAX = 65504.0
# scene.ember.preview_samples = 0 means "until the view changes"; this is the property's own maximum.
UNLIMITED_SAMPLES = 1 << 24
# A restart first renders one sample at a resolution with about this many pixels, so that orbiting
# the view answers at once even when a full-resolution sample takes seconds.
PREVIEW_PIXELS = 1 << 14
# The worker publishes a copy of the image at most this often (the first and the last always go out).
DISPLAY_INTERVAL_S = 0.1
# stop() waits this long for the worker; it finishes the waves in flight, which take milliseconds.
STOP_TIMEOUT_S = 10.0


# ====================================================================== the view's camera
def camera_zoom_factor(view_camera_zoom: float) -> float:
    """BKE_screen_view3d_zoom_to_fac: how much of the camera frame a camera view shows (0.5 at zoom 0,
    where the frame fills half of the region)."""
    return (math.sqrt(2.0) + view_camera_zoom / 50.0) ** 2 / 4.0


@dataclass(frozen=True)
class LensParams:
    """The scene camera's parameters, as BKE_camera_params_from_object reads them (camera view only)."""
    kind: str = "PERSP"            # 'PERSP' or 'ORTHO'
    lens: float = 50.0             # mm
    sensor_width: float = DEFAULT_SENSOR_WIDTH
    sensor_height: float = DEFAULT_SENSOR_HEIGHT
    sensor_fit: str = "AUTO"
    shift_x: float = 0.0
    shift_y: float = 0.0
    ortho_scale: float = 6.0
    clip_start: float = 0.1
    clip_end: float = 100.0
    dof: tuple = ()                # depth of field: kernels.Camera's aperture and focus fields (DOF_FIELDS)

    @classmethod
    def from_object(cls, ob, view_lens: float, clip_start: float, clip_end: float) -> "LensParams":
        """From the (evaluated) object a camera view looks through. As in Blender, an object that is
        not a camera keeps the view's clipping and the default sensor, with a 35 mm lens (a light: the
        lens whose field matches its spot size); no object at all keeps the view's lens."""
        if ob is not None and ob.type == "CAMERA":
            cam = ob.data
            kind = "ORTHO" if cam.type == "ORTHO" else "PERSP"
            dof = depth_of_field(ob, kind) if cam.dof.use_dof else {}
            return cls(kind=kind, lens=float(cam.lens), dof=tuple(dof[name] for name in DOF_FIELDS) if dof else (),
                       sensor_width=float(cam.sensor_width), sensor_height=float(cam.sensor_height),
                       sensor_fit=cam.sensor_fit, shift_x=float(cam.shift_x), shift_y=float(cam.shift_y),
                       ortho_scale=float(cam.ortho_scale), clip_start=float(cam.clip_start),
                       clip_end=float(cam.clip_end))
        lens = view_lens
        if ob is not None:
            lens = NON_CAMERA_LENS
            if ob.type == "LIGHT":
                # Every light stores a spot size (45 degrees unless it is a spot light).
                spot = float(getattr(ob.data, "spot_size", math.radians(45.0)))
                lens = 16.0 / math.tan(spot / 2.0) or NON_CAMERA_LENS
        return cls(lens=float(lens), clip_start=float(clip_start), clip_end=float(clip_end))

    @property
    def sensor(self) -> float:
        """BKE_camera_sensor_size: the sensor side the fit applies to."""
        return self.sensor_height if self.sensor_fit == "VERTICAL" else self.sensor_width


@dataclass(frozen=True)
class ViewportCamera:
    """What one 3D view sees, as comparable plain values: equal cameras render equal images.

    world_from_camera : 4x4 nested tuple (row-major), rigid; the camera looks down its local -Z.
    Other fields are kernels.Camera's; width, height are the film's size in pixels.
    """
    world_from_camera: tuple
    kind: str
    fov_rad: float
    sensor_fit: str
    shift_x: float
    shift_y: float
    ortho_scale: float
    clip_start: float
    clip_end: float
    width: int
    height: int
    dof: tuple = ()                        # the camera's depth of field (camera view only), DOF_FIELDS
    pixel_filter: tuple = ("BOX", 1.0)     # the film's (type, width)
    # Looking through a panoramic camera: (type, params as sorted items, window, (shift_x, shift_y)), see
    # panorama_view; () otherwise.
    panorama: tuple = ()

    @classmethod
    def from_view(cls, view_matrix, width: int, height: int, perspective: str, lens: float,
                  clip_start: float, clip_end: float, view_distance: float, camera: LensParams | None = None,
                  camera_zoom: float = 0.0, camera_offset=(0.0, 0.0)) -> "ViewportCamera":
        """Blender's viewport projection (BKE_camera_params_from_view3d, then
        BKE_camera_params_compute_viewplane with the region's size and square pixels).

        view_matrix : camera_from_world, RegionView3D.view_matrix.
        perspective : RegionView3D.view_perspective, 'PERSP', 'ORTHO' or 'CAMERA'.
        lens, clip_start, clip_end : SpaceView3D's; view_distance : RegionView3D.view_distance.
        camera : the scene camera's parameters, used for 'CAMERA' only.
        camera_zoom, camera_offset : RegionView3D.view_camera_zoom / view_camera_offset ('CAMERA').
        """
        world_from_camera = np.linalg.inv(np.asarray(view_matrix, np.float64).reshape(4, 4))
        if perspective == "CAMERA":
            camera = camera or LensParams(lens=lens, clip_start=clip_start, clip_end=clip_end)
            fac = camera_zoom_factor(camera_zoom)
            # The region is the image, whatever the render resolution; only the fit axis comes from the camera.
            fit = camera.sensor_fit
            if fit == "AUTO":
                fit = "HORIZONTAL" if width >= height else "VERTICAL"
            viewfac = width if fit == "HORIZONTAL" else height
            # Blender scales the lens shift by fac and adds the pan offset; the kernel's shift is in
            # units of the (zoomed) fitted extent, hence the extra factor fac.
            shift_x = fac * (camera.shift_x + 2.0 * camera_offset[0] * width / viewfac)
            shift_y = fac * (camera.shift_y + 2.0 * camera_offset[1] * height / viewfac)
            return cls(_tuple4(world_from_camera), camera.kind,
                       2.0 * math.atan(camera.sensor / (2.0 * camera.lens * fac)), camera.sensor_fit,
                       shift_x, shift_y, camera.ortho_scale / fac, camera.clip_start, camera.clip_end,
                       int(width), int(height), camera.dof)
        zoom = CAMERA_PARAM_ZOOM_INIT_PERSP
        if perspective == "ORTHO":
            # Blender clips an ortho view to [-clip_end / 2, clip_end / 2] around the view point. The
            # kernel starts rays at clip_start >= 0, so the eye moves back by clip_end / 2 instead.
            world_from_camera[:3, 3] += world_from_camera[:3, 2] * (0.5 * clip_end)
            ortho_scale = view_distance * DEFAULT_SENSOR_WIDTH / lens  # ED_view3d_radius_to_dist_ortho
            return cls(_tuple4(world_from_camera), "ORTHO", Camera.fov_rad, "AUTO", 0.0, 0.0,  # fov unused
                       ortho_scale * zoom, 0.0, float(clip_end), int(width), int(height))
        return cls(_tuple4(world_from_camera), "PERSP",
                   2.0 * math.atan(zoom * DEFAULT_SENSOR_WIDTH / (2.0 * lens)), "AUTO", 0.0, 0.0,
                   Camera.ortho_scale, float(clip_start), float(clip_end), int(width), int(height))

    @classmethod
    def from_blender(cls, space, region_data, width: int, height: int, camera_object=None,
                     scene=None) -> "ViewportCamera":
        """From a SpaceView3D and its RegionView3D; camera_object is the evaluated camera the view
        looks through (used only when view_perspective is 'CAMERA'); the scene gives the pixel filter."""
        perspective = region_data.view_perspective
        lens = None
        if perspective == "CAMERA":
            lens = LensParams.from_object(camera_object, space.lens, space.clip_start, space.clip_end)
        view = cls.from_view(region_data.view_matrix, width, height, perspective, space.lens, space.clip_start,
                             space.clip_end, region_data.view_distance, lens, region_data.view_camera_zoom,
                             tuple(region_data.view_camera_offset))
        film = pixel_filter(scene) if scene is not None else {}
        if film:
            view = dataclasses.replace(view, pixel_filter=(film["filter_type"], film["filter_width"]))
        if (perspective == "CAMERA" and scene is not None and camera_object is not None
                and camera_object.type == "CAMERA" and camera_object.data.type == "PANO"):
            view = dataclasses.replace(view, panorama=panorama_view(view, camera_object, scene, lens))
        return view

    def to_kernel(self, width: int | None = None, height: int | None = None) -> Camera:
        """kernels.Camera; another width and height keep the view (a preview at lower resolution)."""
        if self.panorama:
            kind, params, window, shift = self.panorama
            camera = dataclasses.replace(self, panorama=()).to_kernel(width, height)
            return dataclasses.replace(camera, kind="PANO", panorama_type=kind, panorama=dict(params),
                                       panorama_window=window, shift_x=shift[0], shift_y=shift[1])
        return Camera(world_from_camera=np.array(self.world_from_camera, np.float64), kind=self.kind,
                      fov_rad=self.fov_rad, sensor_fit=self.sensor_fit, shift_x=self.shift_x,
                      shift_y=self.shift_y, pixel_aspect=1.0, ortho_scale=self.ortho_scale,
                      clip_start=self.clip_start, clip_end=self.clip_end,
                      width=int(width or self.width), height=int(height or self.height),
                      filter_type=self.pixel_filter[0], filter_width=self.pixel_filter[1],
                      **dict(zip(DOF_FIELDS, self.dof)))


def panorama_view(view: ViewportCamera, camera_ob, scene, lens: LensParams) -> tuple:
    """ViewportCamera.panorama for a region looking through a panoramic camera: the part of the camera's
    frame the region shows (its zoomed, panned border, as the perspective view plane of the camera view
    places it) mapped through the camera's panorama, as Cycles' viewport does."""
    from .export.camera import render_resolution
    from .export.panorama import export_panorama
    res_x, res_y = render_resolution(scene)
    render = scene.render
    frame = Camera(fov_rad=2.0 * math.atan(lens.sensor / (2.0 * lens.lens)), sensor_fit=lens.sensor_fit,
                   shift_x=lens.shift_x, shift_y=lens.shift_y, width=res_x, height=res_y,
                   pixel_aspect=render.pixel_aspect_x / render.pixel_aspect_y)
    fx0, fx1, fy0, fy1 = view_plane(frame)
    x0, x1, y0, y1 = view_plane(view.to_kernel())
    window = ((x0 - fx0) / (fx1 - fx0), (x1 - fx0) / (fx1 - fx0), (y0 - fy0) / (fy1 - fy0), (y1 - fy0) / (fy1 - fy0))
    kind, params = export_panorama(camera_ob, scene, res_x, res_y, [])
    return kind, tuple(sorted(params.items())), window, (lens.shift_x, lens.shift_y)


def _tuple4(m: np.ndarray) -> tuple:
    return tuple(tuple(float(v) for v in row) for row in m)


def view_camera_object(space, scene):
    """The object a camera view looks through: the view's own camera when it is unlocked from the
    scene's (Cycles does the same)."""
    return space.camera if space.use_local_camera else scene.camera


# ====================================================================== what the depsgraph says changed
def is_content_update(update) -> bool:
    """True when a depsgraph update can change the rendered image.

    Cameras are invisible: moving or editing one matters only when the view looks through it, and
    view_draw sees that in the view itself. Updates without any flag (the scene after a selection,
    node trees next to their material) change nothing by themselves.
    """
    if not (update.is_updated_transform or update.is_updated_geometry or update.is_updated_shading):
        return False
    data = update.id
    if data.id_type == "CAMERA" or (data.id_type == "OBJECT" and data.type == "CAMERA"):
        return False
    return True


# What a depsgraph update asks of the viewport's scene, cheapest first: re-read the instances' transforms
# and object rows, the materials and world, or the lights (engine/export/updates.py); FULL is a new export.
INSTANCES, SHADING, LIGHTS, FULL = "instances", "shading", "lights", "full"
# Data-blocks whose edits reach the image only through shaders (images and textures through the
# materials and the world that read them).
SHADING_ID_TYPES = ("MATERIAL", "WORLD", "IMAGE", "TEXTURE")
# Object data Ember turns into triangles (curves, surfaces and text are CURVE): edited geometry is a new
# export; their other updates come along with their objects' (a material edit tags its meshes for shading).
GEOMETRY_ID_TYPES = ("MESH", "CURVE", "METABALL")


def update_part(update) -> str:
    """The part of the scene one content update (is_content_update) changes, as Cycles' Blender sync
    sorts them: an object's transform or object-level settings (INSTANCES; an object whose geometry was
    evaluated again is FULL), a shader, image or world (SHADING), a light object or light data (LIGHTS).
    Anything else (collections, the scene, geometry nodes trees, unknown data) is FULL: when unsure,
    export everything."""
    data = update.id
    kind = data.id_type
    if kind == "OBJECT":
        if data.type == "LIGHT":
            return LIGHTS
        return FULL if update.is_updated_geometry else INSTANCES
    if kind == "LIGHT":
        return LIGHTS
    if kind in SHADING_ID_TYPES or (kind == "NODETREE" and data.bl_idname == "ShaderNodeTree"):
        return SHADING
    if kind in GEOMETRY_ID_TYPES:
        return FULL if update.is_updated_geometry else INSTANCES
    return FULL


def scene_changes(updates) -> frozenset:
    """The parts of the scene that depsgraph.updates change (update_part of each content update); empty
    when nothing Ember renders changed."""
    return frozenset(update_part(update) for update in updates if is_content_update(update))


def scene_needs_export(updates) -> bool:
    """Whether any of depsgraph.updates changes what Ember renders (see is_content_update)."""
    return bool(scene_changes(updates))


def visibility_key(depsgraph) -> tuple:
    """What the export sees besides the updates: hiding an object in the view layer (the eye icon)
    reaches view_update as a bare scene update, so the set of visible objects is compared as well."""
    scene = depsgraph.scene_eval
    world = scene.world.name_full if scene.world is not None else ""
    return frozenset(ob.name_full for ob in depsgraph.objects), world


# ====================================================================== images for the display
class Frame(NamedTuple):
    """One published image. image : (H, W, 4) float32, read-only, row 0 at the top, finite and within
    the half-float range. samples_done counts full-resolution samples (0 for the quick preview)."""
    image: np.ndarray
    samples_done: int
    samples_total: int
    generation: int


def display_pixels(image: np.ndarray) -> np.ndarray:
    """A float32 copy that an RGBA16F texture can hold: NaN -> 0, everything clamped to +-HALF_MAX."""
    out = np.nan_to_num(np.asarray(image, np.float32), nan=0.0, posinf=HALF_MAX, neginf=-HALF_MAX)
    return np.clip(out, -HALF_MAX, HALF_MAX, out=out)


def gpu_pixels(image: np.ndarray) -> np.ndarray:
    """(H*W*4,) float32, contiguous, bottom row first: the order gpu.types.GPUTexture reads."""
    return np.ascontiguousarray(image[::-1], np.float32).reshape(-1)


def preview_size(width: int, height: int, pixels: int) -> tuple[int, int] | None:
    """Film size of the quick first pass (same aspect, about `pixels` pixels); None when the full
    resolution is already that small."""
    scale = math.sqrt(width * height / max(pixels, 1))
    if scale < 2.0:
        return None
    return max(1, round(width / scale)), max(1, round(height / scale))


def upsample(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """Nearest-neighbour resize of (h, w, C) to (height, width, C)."""
    rows = np.arange(height) * image.shape[0] // height
    cols = np.arange(width) * image.shape[1] // width
    return image[rows][:, cols]


def status_text(frame: Frame | None, busy: bool, error: str | None) -> str:
    """The line Blender shows in the viewport's corner, in Cycles' words."""
    if error:
        return f"Ember: {error}"
    if frame is None:
        return "Ember: preparing" if busy else ""
    if frame.samples_done == 0:
        return "Ember: preview"
    if frame.samples_total >= UNLIMITED_SAMPLES:
        return f"Sample {frame.samples_done}"
    return f"Sample {frame.samples_done}/{frame.samples_total}"


# ====================================================================== the worker
@dataclass(frozen=True)
class _Job:
    generation: int
    scene: SceneArrays
    scene_version: int
    settings: RenderSettings
    camera: ViewportCamera
    denoise: tuple | None = None   # (quality, prefilter) of the previews' denoiser, or None
    updates: tuple = ()            # ((part, arguments), ...) to apply to the renderer of scene_version


_live_sessions: "weakref.WeakSet[ViewportSession]" = weakref.WeakSet()


def stop_all_sessions() -> None:
    """Stop every viewport worker (add-on unregister: no thread may outlive the code it runs)."""
    for session in list(_live_sessions):
        session.stop()


class ViewportSession:
    """Renders the latest scene, settings and view progressively on a worker thread.

    Every change bumps a generation: the running render stops after the waves in flight (its
    should_stop compares generations) and the worker starts over from sample 0 with the newest
    state. Changes that arrive while the worker is busy coalesce, so dragging a slider costs one
    restart per wave at most, not one per event. One session per engine instance (quad view has four).

        session.update_scene(scene_arrays, settings)   # after an export: the worker builds a new Renderer
        session.update_instances(world_from_object, objects)   # objects moved: the built one is updated,
        session.update_materials(materials, textures, srgb, world)  # ... shaders edited
        session.update_lights(lights)                  # ... lights changed
        session.update_view(ViewportCamera...)        # every draw; restarts only when it differs
        frame = session.snapshot()                     # latest Frame or None, never blocks on the render
        session.stop()                                 # joins the worker

    The partial updates are queued (the newest of each part wins: each carries that whole part) and the
    worker applies them to its Renderer before the next render (Renderer.update_instances and friends);
    the session's scene takes them at once, so that a rebuild, whenever one is needed (no renderer yet,
    an update that does not fit it), renders the same scene.
    """

    def __init__(self, threads: int = 0, *, preview_pixels: int = PREVIEW_PIXELS,
                 display_interval_s: float = DISPLAY_INTERVAL_S):
        self._threads = threads
        self._preview_pixels = preview_pixels
        self._display_interval_s = display_interval_s
        self._cond = threading.Condition()
        # State shared with the worker; every access holds self._cond.
        self._scene: SceneArrays | None = None
        self._scene_version = 0       # bumped by update_scene only: the worker then builds a new Renderer
        self._pending: dict[str, tuple] = {}   # part -> the newest arguments of its Renderer.update_*
        self._settings: RenderSettings | None = None
        self._denoise: tuple | None = None
        self._camera: ViewportCamera | None = None
        self._generation = 0          # bumped by every restart; the worker compares it to its job's
        self._started = -1            # generation the worker last picked up
        self._busy = False            # the current generation is not finished yet
        self._stopping = False
        self._samples_done = 0
        self._frame: Frame | None = None
        self._taken: Frame | None = None   # the frame snapshot() last handed out
        self._error: str | None = None
        self._thread: threading.Thread | None = None
        _live_sessions.add(self)

    # ------------------------------------------------------------------ main thread
    def update_scene(self, scene: SceneArrays, settings: RenderSettings, denoise: tuple | None = None) -> bool:
        """A new export: always restarts (the arrays are new even when the edit changed nothing)."""
        with self._cond:
            self._scene = scene
            self._scene_version += 1
            self._pending.clear()
            self._settings, self._denoise = settings, denoise
            self._restart()
        return True

    def update_instances(self, world_from_object: np.ndarray, objects: np.ndarray) -> None:
        """Objects moved: (K, 4, 4) world_from_object of the scene's instances and its object table, both
        in the order of the last export (engine/export/updates.export_instances). Restarts."""
        def moved(scene: SceneArrays) -> SceneArrays:
            instances = scene.instances
            if instances is not None:
                instances = dataclasses.replace(instances, world_from_object=world_from_object)
            return dataclasses.replace(scene, instances=instances, objects=objects)
        self._queue("instances", (world_from_object, objects), moved)

    def update_materials(self, materials, textures: tuple, texture_srgb: tuple, world) -> None:
        """Shaders, images or the world edited: the scene's material table (same rows), textures and world
        (engine/export/updates.export_shading). Restarts."""
        self._queue("materials", (materials, textures, texture_srgb, world),
                    lambda scene: dataclasses.replace(scene, materials=materials, textures=tuple(textures),
                                                      texture_srgb=tuple(texture_srgb), world=world))

    def update_lights(self, lights) -> None:
        """Lights moved, edited, added or removed: the scene's whole light table. Restarts."""
        self._queue("lights", (lights,), lambda scene: dataclasses.replace(scene, lights=lights))

    def _queue(self, part: str, arguments: tuple, change) -> None:
        with self._cond:
            if self._scene is None:
                return   # nothing built to update (the export failed): the next export brings it all
            self._scene = change(self._scene)
            self._pending[part] = arguments
            self._restart()

    @contextlib.contextmanager
    def batch(self):
        """Hold the session while several changes are made: the worker starts once, with all of them."""
        with self._cond:
            yield self

    @property
    def scene(self) -> SceneArrays | None:
        """The scene the session renders, with every update so far."""
        with self._cond:
            return self._scene

    def update_settings(self, settings: RenderSettings, denoise: tuple | None = None) -> bool:
        """Restarts only when the settings (or the previews' denoiser: (quality, prefilter) or None)
        differ; returns whether it did."""
        with self._cond:
            if (settings, denoise) == (self._settings, self._denoise):
                return False
            self._settings, self._denoise = settings, denoise
            self._restart()
        return True

    def update_view(self, camera: ViewportCamera) -> bool:
        """Restarts only when the view differs (moved, zoomed, resized); returns whether it did."""
        with self._cond:
            if camera == self._camera:
                return False
            self._camera = camera
            self._restart()
        return True

    def fail(self, message: str) -> None:
        """The scene cannot be rendered (export failed): stop rendering and show `message`."""
        with self._cond:
            self._scene = None
            self._pending.clear()
            self._restart()
            self._frame = None
            self._error = message

    def snapshot(self) -> Frame | None:
        """The newest published frame (the same object until a newer one exists), or None."""
        with self._cond:
            self._taken = self._frame
            return self._frame

    @property
    def needs_redraw(self) -> bool:
        """True while the render refines or a frame has not been taken by snapshot() yet."""
        with self._cond:
            return self._busy or self._frame is not self._taken

    @property
    def busy(self) -> bool:
        with self._cond:
            return self._busy

    @property
    def samples_done(self) -> int:
        """Full-resolution samples of the current generation (0 right after a restart)."""
        with self._cond:
            return self._samples_done

    @property
    def generation(self) -> int:
        with self._cond:
            return self._generation

    @property
    def error(self) -> str | None:
        with self._cond:
            return self._error

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def stop(self, timeout: float = STOP_TIMEOUT_S) -> bool:
        """Cancel the render and join the worker. Returns True when the worker has ended."""
        with self._cond:
            self._stopping = True
            self._generation += 1
            self._busy = False
            self._cond.notify_all()
            thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout)
        _live_sessions.discard(self)
        return thread is None or not thread.is_alive()

    def _restart(self) -> None:
        """Called with the lock held: cancel the current render and queue the newest state."""
        self._generation += 1
        self._samples_done = 0
        self._error = None
        self._busy = self._ready()
        if self._busy and self._thread is None and not self._stopping:
            self._thread = threading.Thread(target=self._run, name="ember-viewport", daemon=True)
            self._thread.start()
        self._cond.notify_all()

    def _ready(self) -> bool:
        return self._scene is not None and self._settings is not None and self._camera is not None

    # ------------------------------------------------------------------ worker thread
    def _run(self) -> None:
        renderer, built_version = None, -1
        try:
            while True:
                with self._cond:
                    while not self._stopping and not (self._ready() and self._started != self._generation):
                        self._cond.wait()
                    if self._stopping:
                        return
                    job = _Job(self._generation, self._scene, self._scene_version, self._settings, self._camera,
                               self._denoise, tuple(self._pending.items()))
                    self._pending.clear()
                    self._started = job.generation
                try:
                    if job.updates and job.scene_version == built_version and not self._apply(renderer, job):
                        renderer.close()
                        renderer, built_version = None, -1
                    if job.scene_version != built_version:
                        if renderer is not None:
                            renderer.close()
                        renderer, built_version = None, -1
                        renderer = Renderer(job.scene, self._threads)
                        built_version = job.scene_version
                    self._render(renderer, job)
                except Exception as err:  # shown in the viewport; the worker waits for the next change
                    with self._cond:
                        if job.generation == self._generation:
                            self._error = f"{type(err).__name__}: {err}"
                            self._busy = False
        finally:
            if renderer is not None:
                renderer.close()

    @staticmethod
    def _apply(renderer: Renderer, job: _Job) -> bool:
        """Apply the job's queued updates to the renderer built for its scene version. False when one
        does not fit (the renderer is then half updated: the caller builds job.scene, which has them all)."""
        apply = {"instances": renderer.update_instances, "materials": renderer.update_materials,
                 "lights": renderer.update_lights}
        try:
            for part, arguments in job.updates:
                apply[part](*arguments)
        except Exception:  # any failure is answered by a rebuild, which reports its own errors
            return False
        return True

    def _cancelled(self, job: _Job) -> bool:
        # Read without the lock: an int compare, and a stale answer only delays the stop by one wave.
        return self._stopping or self._generation != job.generation

    def _render(self, renderer: Renderer, job: _Job) -> None:
        camera = job.camera
        width, height = camera.width, camera.height

        def should_stop() -> bool:
            return self._cancelled(job)

        display = self._first_display(height, width)
        small = preview_size(width, height, self._preview_pixels)
        if small is not None:
            renderer.set_camera(camera.to_kernel(*small))
            preview = renderer.render(dataclasses.replace(job.settings, samples=1, time_limit_s=0.0),
                                      should_stop=should_stop)
            if should_stop():
                return
            display = upsample(display_pixels(preview.image), height, width)
            self._publish(job, display, 0)
        renderer.set_camera(camera.to_kernel())
        last_publish = [0.0]
        denoiser = PreviewDenoiser(job.denoise, self._display_interval_s, self._threads) if job.denoise else None

        def on_tile(film, row0: int, row1: int) -> None:
            if should_stop():
                return
            display[row0:row1] = display_pixels(film.resolve(row0, row1))
            done = film.samples_done
            now = time.perf_counter()
            if not last_publish[0] or now - last_publish[0] >= self._display_interval_s:
                last_publish[0] = now
                shown = denoiser.display(film, now) if denoiser is not None and done > 0 else None
                self._publish(job, display if shown is None else display_pixels(shown), done)
                return
            with self._cond:
                if job.generation == self._generation:
                    self._samples_done = done

        settings = dataclasses.replace(job.settings, time_limit_s=0.0)
        result = renderer.render(settings, on_tile=on_tile, should_stop=should_stop)
        if result.stopped_early or should_stop():
            return
        shown = denoiser.display(result.film, None) if denoiser is not None else None
        self._publish(job, display if shown is None else display_pixels(shown), result.progress.samples_done,
                      finished=True)

    def _first_display(self, height: int, width: int) -> np.ndarray:
        """The image a restart refines: the last one while the size stays (no black flash between
        restarts), else black."""
        with self._cond:
            frame = self._frame
        if frame is not None and frame.image.shape[:2] == (height, width):
            return frame.image.copy()
        return np.zeros((height, width, 4), np.float32)

    def _publish(self, job: _Job, display: np.ndarray, samples_done: int, finished: bool = False) -> None:
        image = display.copy()
        image.flags.writeable = False
        with self._cond:
            if job.generation != self._generation:
                return
            self._frame = Frame(image, int(samples_done), int(job.settings.samples), job.generation)
            self._samples_done = int(samples_done)
            if finished:
                self._busy = False


# ====================================================================== the RenderEngine's side
def viewport_settings(scene) -> RenderSettings:
    """Kernel settings for the viewport: scene.ember as for F12, with the viewport's sample count (and the
    denoiser's passes when previews are denoised)."""
    samples = int(scene.ember.preview_samples) or UNLIMITED_SAMPLES
    settings = render_settings(scene, None, samples=samples, time_limit=0.0)
    if viewport_denoise(scene) is not None:
        inputs = scene.ember.denoising_input_passes
        names = ("denoising_albedo",) if inputs == "RGB_ALBEDO" else \
            ("denoising_albedo", "denoising_normal") if inputs == "RGB_ALBEDO_NORMAL" else ()
        settings = dataclasses.replace(settings, passes=names)
    return settings


def viewport_denoise(scene) -> tuple | None:
    """(quality, prefilter) when the viewport's previews are denoised, else None."""
    ember = scene.ember
    return (ember.denoising_quality, ember.denoising_prefilter) if ember.use_preview_denoising else None


def film_size(region_width: int, region_height: int, pixel_size: int) -> tuple[int, int]:
    """The film behind a region: one film pixel per pixel_size x pixel_size screen pixels
    (RenderEngine.get_preview_pixel_size: 2 on high-DPI screens with the Automatic setting)."""
    pixel_size = max(1, int(pixel_size))
    return max(1, round(region_width / pixel_size)), max(1, round(region_height / pixel_size))


def _no_camera_stand_in():
    """export_scene insists on a scene camera; the viewport needs none (it replaces the camera), so
    a scene without one is exported with this stand-in, which carries only what the export reads."""
    data = SimpleNamespace(type="PERSP", dof=SimpleNamespace(use_dof=False), sensor_fit="AUTO",
                           sensor_width=DEFAULT_SENSOR_WIDTH, sensor_height=DEFAULT_SENSOR_HEIGHT,
                           lens=50.0, shift_x=0.0, shift_y=0.0, ortho_scale=6.0, clip_start=0.1,
                           clip_end=100.0)
    stand_in = SimpleNamespace(name="Viewport", type="CAMERA", data=data, matrix_world=np.eye(4))
    stand_in.evaluated_get = lambda depsgraph: stand_in
    return stand_in


class ViewportRender:
    """One engine instance's viewport: view_update exports (the whole scene, or only the parts the
    depsgraph says changed), view_draw follows the view and draws.

    It holds no reference to the engine (the engine holds it): Blender frees the engine, the
    engine's __del__ calls free(), and the worker stops.
    """

    def __init__(self, threads: int = 0, **session_options):
        self.session = ViewportSession(threads, **session_options)
        # Should the engine's __del__ never run, the worker still stops when this object goes.
        weakref.finalize(self, self.session.stop)
        self._visibility = None
        self._index = None            # the last full export's ExportIndex (None: export everything next)
        self._texture = None
        self._texture_frame = None

    # ------------------------------------------------------------------ view_update
    def view_update(self, engine, context, depsgraph) -> None:
        """Main thread: export what changed (everything on the first call, when the visible objects
        changed, or when an update is more than a move, a shader or a light edit), then follow the view."""
        scene = depsgraph.scene
        settings = viewport_settings(scene)
        visibility = visibility_key(depsgraph)
        parts = scene_changes(depsgraph.updates)
        if self._visibility is None or visibility != self._visibility or FULL in parts \
                or (parts and not self._update(depsgraph, parts, settings)):
            self._export(engine, context, depsgraph, settings)
            self._visibility = visibility
        elif not parts:
            self.session.update_settings(settings, viewport_denoise(scene))
        self.session.update_view(self.view_camera(engine, context, depsgraph))

    def _export(self, engine, context, depsgraph, settings: RenderSettings) -> None:
        """The whole scene, every mesh instanced (so that moving objects later only moves instances)."""
        width, height = self._film_size(engine, context, depsgraph)
        override = None if depsgraph.scene_eval.camera is not None else _no_camera_stand_in()
        self._index = None
        try:
            exported = export_scene(depsgraph, override, width=width, height=height, instance_everything=True)
        except ExportError as err:
            self.session.fail(str(err))
            return
        self.session.update_scene(exported.scene, settings, viewport_denoise(depsgraph.scene))
        self._index = exported.index

    def _update(self, depsgraph, parts: frozenset, settings: RenderSettings) -> bool:
        """Read only the changed parts of the scene again (engine/export/updates.py) and hand them to the
        session, all in one restart. False, with nothing handed over, when a part no longer lines up with
        the last export: then only a full export will do."""
        current = self.session.scene
        if current is None or self._index is None:
            return False
        placed = shading = lights = None
        if INSTANCES in parts:
            placed = export_instances(depsgraph, self._index)
            if placed is None:
                return False
            if _same_placement(current, *placed):
                placed = None   # object-level updates that change nothing Ember reads (a material edit's)
        if SHADING in parts:
            shading = export_shading(depsgraph, self._index)
            if shading is None:
                return False
        if LIGHTS in parts:
            lights = export_lights(depsgraph, [])
        with self.session.batch():
            if placed is not None:
                self.session.update_instances(*placed)
            if shading is not None:
                self.session.update_materials(shading.materials, shading.textures, shading.texture_srgb,
                                              shading.world)
            if lights is not None:
                self.session.update_lights(lights)
            self.session.update_settings(settings, viewport_denoise(depsgraph.scene))
        return True

    # ------------------------------------------------------------------ view_draw
    def prepare_draw(self, engine, context, depsgraph) -> Frame | None:
        """Everything view_draw does but the GPU calls: follow settings and view, report, ask for
        the next draw while refining, and return the frame to show."""
        scene = depsgraph.scene
        # Editing scene.ember does not always reach view_update: compare here too (a few RNA reads).
        self.session.update_settings(viewport_settings(scene), viewport_denoise(scene))
        self.session.update_view(self.view_camera(engine, context, depsgraph))
        frame = self.session.snapshot()
        engine.update_stats("", status_text(frame, self.session.busy, self.session.error))
        if self.session.needs_redraw:
            engine.tag_redraw()
        return frame

    def view_draw(self, engine, context, depsgraph) -> None:
        frame = self.prepare_draw(engine, context, depsgraph)
        if frame is not None:
            self._draw(engine, depsgraph.scene, frame, context.region.width, context.region.height)

    def _draw(self, engine, scene, frame: Frame, region_width: int, region_height: int) -> None:
        """The only code that needs a GPU (headless tests run it against a recording stand-in for
        the gpu module): upload each new frame once, draw it over the region through Blender's
        display transform."""
        import gpu
        from gpu_extras.presets import draw_texture_2d

        if frame is not self._texture_frame:
            height, width = frame.image.shape[:2]
            pixels = gpu_pixels(frame.image)
            buffer = gpu.types.Buffer("FLOAT", pixels.size, pixels)
            self._texture = gpu.types.GPUTexture((width, height), format="RGBA16F", data=buffer)
            self._texture_frame = frame
        gpu.state.blend_set("ALPHA_PREMULT")
        engine.bind_display_space_shader(scene)
        draw_texture_2d(self._texture, (0, 0), region_width, region_height)
        engine.unbind_display_space_shader()
        gpu.state.blend_set("NONE")

    # ------------------------------------------------------------------ shared
    def view_camera(self, engine, context, depsgraph) -> ViewportCamera:
        width, height = self._film_size(engine, context, depsgraph)
        space, region_data = context.space_data, context.region_data
        camera_object = None
        if region_data.view_perspective == "CAMERA":
            camera_object = view_camera_object(space, depsgraph.scene)
            if camera_object is not None:
                camera_object = camera_object.evaluated_get(depsgraph)
        return ViewportCamera.from_blender(space, region_data, width, height, camera_object, depsgraph.scene)

    @staticmethod
    def _film_size(engine, context, depsgraph) -> tuple[int, int]:
        return film_size(context.region.width, context.region.height,
                         engine.get_preview_pixel_size(depsgraph.scene))

    def free(self) -> None:
        """Stop and join the worker; drop the GPU texture."""
        self.session.stop()
        self._texture = None
        self._texture_frame = None


def _same_placement(scene: SceneArrays, world_from_object: np.ndarray, objects: np.ndarray) -> bool:
    """Whether a scene's instances and object table already are these."""
    current = scene.instances.world_from_object if scene.instances is not None else np.zeros((0, 4, 4))
    table = scene.objects if scene.objects is not None else np.zeros((0, objects.shape[1]), np.float32)
    return np.array_equal(current, world_from_object) and np.array_equal(table, objects)


def new_viewport(scene) -> ViewportRender:
    """The viewport of one engine instance, with the scene's thread count."""
    return ViewportRender(render_threads(scene.render))
