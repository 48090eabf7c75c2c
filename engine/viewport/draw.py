"""What the viewport shows: the Frames the session publishes, their pixels made displayable, the status line,
and the GPU drawing, the only code that needs a GPU (kept thin: headless tests run it against a recording
stand-in for the gpu module)."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

# The largest finite half float: the texture is RGBA16F and an inf there turns the viewport black.
HALF_MAX = 65504.0
# scene.ember.preview_samples = 0 means "until the view changes"; this is the property's own maximum.
UNLIMITED_SAMPLES = 1 << 24


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


class Display:
    """The GPU texture of the frame drawn last: uploaded once per new frame, drawn over the region through
    Blender's display transform."""

    def __init__(self):
        self._texture = None
        self._frame = None

    def draw(self, engine, scene, frame: Frame, region_width: int, region_height: int) -> None:
        import gpu
        from gpu_extras.presets import draw_texture_2d

        if frame is not self._frame:
            height, width = frame.image.shape[:2]
            pixels = gpu_pixels(frame.image)
            buffer = gpu.types.Buffer("FLOAT", pixels.size, pixels)
            self._texture = gpu.types.GPUTexture((width, height), format="RGBA16F", data=buffer)
            self._frame = frame
        gpu.state.blend_set("ALPHA_PREMULT")
        engine.bind_display_space_shader(scene)
        draw_texture_2d(self._texture, (0, 0), region_width, region_height)
        engine.unbind_display_space_shader()
        gpu.state.blend_set("NONE")

    def free(self) -> None:
        """Drop the GPU texture."""
        self._texture = None
        self._frame = None
