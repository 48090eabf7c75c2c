"""The camera: Camera (lens, sensor fit, depth of field, pixel filter, panorama, motion) and its validation."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ..panorama import PANORAMA_PARAMS, POSITIVE_PARAMS
from .checks import require, require_finite

CAMERA_KINDS = ("PERSP", "ORTHO", "PANO")
PIXEL_FILTERS = ("BOX", "GAUSSIAN", "BLACKMAN_HARRIS")
SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")


@dataclass(frozen=True, eq=False)
class Camera:
    """A Blender camera: looks down its local -Z with +Y up.

    world_from_camera : (4, 4) float64, rigid transform (scale is removed by validate()).
    fov_rad : full angle across the sensor-fit axis (perspective). 2 * atan(sensor / (2 * lens)).
    sensor_fit : AUTO fits the larger image axis, as Blender does.
    shift_x, shift_y : lens shift in units of the fitted image axis.
    pixel_aspect : pixel width / pixel height (Blender's pixel_aspect_x / pixel_aspect_y).
    ortho_scale : width of the view along the fitted axis (orthographic).
    width, height : full frame resolution in pixels (after the resolution percentage).

    Cameras compare and hash by key(), their fields as plain values: the viewport restarts when its
    camera differs from the last one.
    """
    world_from_camera: np.ndarray = field(default_factory=lambda: np.eye(4))
    kind: str = "PERSP"
    fov_rad: float = 2.0 * np.arctan(36.0 / (2.0 * 50.0))
    sensor_fit: str = "AUTO"
    shift_x: float = 0.0
    shift_y: float = 0.0
    pixel_aspect: float = 1.0
    ortho_scale: float = 6.0
    clip_start: float = 0.1
    clip_end: float = 1000.0
    width: int = 256
    height: int = 256
    # Depth of field, Cycles' thin lens (kernels.lens): aperture_radius 0 is a pinhole. The lens point lies
    # on a disk, or on a regular polygon of aperture_blades >= 3 sides turned by aperture_rotation (radians);
    # its x is divided by aperture_ratio (anamorphic). Sharp at camera depth focus_distance.
    aperture_radius: float = 0.0
    aperture_blades: int = 0
    aperture_rotation: float = 0.0
    aperture_ratio: float = 1.0
    focus_distance: float = 10.0
    # The film's pixel filter (kernels.pixel_filter), importance-sampled: every sample weighs 1 and lands
    # in its own pixel. BOX is one pixel wide whatever filter_width says, as in Cycles.
    filter_type: str = "BOX"
    filter_width: float = 1.0
    # Panoramic cameras (kind PANO): the projection and its parameters (kernels.panorama).
    panorama_type: str = "EQUIRECTANGULAR"
    panorama: dict = field(default_factory=dict)
    # The part of the camera frame the film shows, (u0, u1, v0, v1) in frame units (0..1 from the frame's
    # left and bottom edges), or None for the whole frame: a viewport looking through a panoramic camera
    # shows the frame zoomed and panned inside its region, as Cycles' viewport does.
    panorama_window: tuple | None = None
    # Motion blur: world_from_camera at motion steps evenly spaced over the shutter, (K, 4, 4) rigid,
    # K >= 2, or None for a still camera (world_from_camera is then used at every time).
    motion: np.ndarray | None = None
    # A perspective lens zooming during the shutter: (fov_rad at the shutter's start, at its end), or None.
    fov_motion: tuple | None = None

    def key(self) -> tuple:
        """Every field as hashable plain values (arrays as nested tuples, dicts as sorted items): cameras
        with equal keys render equal images."""
        return tuple(_plain(getattr(self, f.name)) for f in dataclasses.fields(self))

    def __eq__(self, other) -> bool:
        return self.key() == other.key() if isinstance(other, Camera) else NotImplemented

    def __hash__(self) -> int:
        return hash(self.key())

    def validate(self) -> None:
        m = np.asarray(self.world_from_camera)
        require(m.shape == (4, 4), "camera.world_from_camera", f"must be (4, 4), got {m.shape}")
        require_finite(m, "camera.world_from_camera")
        require(abs(np.linalg.det(m[:3, :3])) > 1e-12, "camera.world_from_camera", "is singular")
        require(self.kind in CAMERA_KINDS, "camera.kind", f"must be one of {CAMERA_KINDS}, got {self.kind!r}")
        require(self.sensor_fit in SENSOR_FITS, "camera.sensor_fit",
                f"must be one of {SENSOR_FITS}, got {self.sensor_fit!r}")
        for name in ("fov_rad", "shift_x", "shift_y", "pixel_aspect", "ortho_scale", "clip_start", "clip_end"):
            require(np.isfinite(getattr(self, name)), f"camera.{name}", "must be finite")
        require(0.0 < self.fov_rad < np.pi, "camera.fov_rad", f"must be in (0, pi), got {self.fov_rad}")
        require(self.pixel_aspect > 0, "camera.pixel_aspect", "must be positive")
        require(self.ortho_scale > 0, "camera.ortho_scale", "must be positive")
        require(0.0 <= self.clip_start < self.clip_end, "camera.clip_start",
                f"must satisfy 0 <= clip_start < clip_end, got {self.clip_start}, {self.clip_end}")
        require(int(self.width) >= 1 and int(self.height) >= 1, "camera.width",
                f"resolution must be at least 1x1, got {self.width}x{self.height}")
        for name in ("aperture_radius", "aperture_rotation", "aperture_ratio", "focus_distance", "filter_width"):
            require(np.isfinite(getattr(self, name)), f"camera.{name}", "must be finite")
        require(self.aperture_radius >= 0, "camera.aperture_radius", "must be non-negative")
        require(self.aperture_ratio > 0, "camera.aperture_ratio", "must be positive")
        require(self.focus_distance > 0, "camera.focus_distance", "must be positive")
        require(self.filter_type in PIXEL_FILTERS, "camera.filter_type",
                f"must be one of {PIXEL_FILTERS}, got {self.filter_type!r}")
        require(self.filter_width > 0, "camera.filter_width", "must be positive")
        require(self.panorama_type in PANORAMA_PARAMS, "camera.panorama_type",
                f"must be one of {tuple(PANORAMA_PARAMS)}, got {self.panorama_type!r}")
        if self.kind == "PANO":
            needed, given = PANORAMA_PARAMS[self.panorama_type], set(self.panorama)
            require(given == set(needed), "camera.panorama",
                    f"{self.panorama_type} takes exactly {needed}, got {tuple(sorted(given))}")
            for name in needed:
                value = self.panorama[name]
                require(isinstance(value, (int, float, np.integer, np.floating)) and np.isfinite(value), f"camera.panorama[{name!r}]",
                        f"must be a finite number, got {value!r}")
                require(name not in POSITIVE_PARAMS or value > 0, f"camera.panorama[{name!r}]",
                        f"must be positive, got {value}")
        if self.motion is not None:
            motion = np.asarray(self.motion)
            require(motion.ndim == 3 and motion.shape[0] >= 2 and motion.shape[1:] == (4, 4), "camera.motion",
                    f"must be (K >= 2, 4, 4), got {motion.shape}")
            require_finite(motion, "camera.motion")


def _plain(value):
    """A value as hashable plain Python: arrays and sequences as tuples, dicts as sorted (key, value) tuples."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return tuple(_plain(v) for v in value)
    if isinstance(value, dict):
        return tuple(sorted((k, _plain(v)) for k, v in value.items()))
    return value
