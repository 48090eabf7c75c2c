"""Colour ramps and curve mappings baked into the tables the kernel samples, as Cycles' Blender sync bakes
them (`intern/cycles/blender/shader.cpp` and `util.h`, Blender 5.0); and the colour-space constants of the
OCIO config in use (kernels.shading.color_nodes and curve_nodes read all of these).

What Cycles does, and so what this module does:
- A Color Ramp becomes RAMP_TABLE_SIZE + 1 = 257 RGBA entries, entry i = the ramp evaluated at
  i / 256 (`BKE_colorband_evaluate`, which is Python's ColorRamp.evaluate: every interpolation, colour
  mode and hue interpolation is Blender's own). The kernel lerps neighbouring entries at
  fac * 256 (fac clamped to [0, 1]); a Constant ramp takes entry floor(fac * 256) instead.
- A curve mapping's x range is [min_x, max_x] = [least first point x, greatest last point x] over its
  curves (RGB Curves: R, G, B and C; Vector Curves: X, Y, Z; Float Curve: its one curve): the points'
  span, not the clipping rectangle. Entry i is the curve evaluated at min_x + i / 256 (max_x - min_x)
  (`BKE_curvemap_evaluateF`, which is Python's CurveMapping.evaluate, after `BKE_curvemapping_changed_all`
  = CurveMapping.update(): points sorted and clipped). RGB Curves store R(C(x)), G(C(x)), B(C(x)); the
  black/white levels and the tone option are not used by Cycles.
- The kernel looks a value up at (v - min_x) / (max_x - min_x); outside [0, 1] it extends the end
  segments' lines when the mapping extends "EXTRAPOLATED", else holds the end entries.
"""
from __future__ import annotations

import numpy as np

F32 = np.float32
RAMP_TABLE_SIZE = 256  # Cycles' kernel/types.h; the tables hold RAMP_TABLE_SIZE + 1 entries
_STEPS = np.arange(RAMP_TABLE_SIZE + 1, dtype=F32) / F32(RAMP_TABLE_SIZE)  # i / 256, exact in float32


def color_ramp_table(ramp) -> tuple[np.ndarray, bool]:
    """A ColorRamp (ShaderNodeValToRGB.color_ramp) -> ((257, 4) float32 RGBA table, interpolate)."""
    table = np.array([tuple(ramp.evaluate(float(x))) for x in _STEPS], F32)
    return table, ramp.interpolation != "CONSTANT"


def _span(mapping, count: int) -> tuple[float, float]:
    """[min_x, max_x]: the least first and the greatest last point x over the first `count` curves."""
    curves = list(mapping.curves)[:count]
    lo = min(F32(c.points[0].location[0]) for c in curves)
    hi = max(F32(c.points[len(c.points) - 1].location[0]) for c in curves)
    return F32(lo), F32(hi)


def _positions(lo, hi) -> np.ndarray:
    """min_x + i / 256 * (max_x - min_x) in float32, each operation rounded (not fused: probed)."""
    return _STEPS * F32(hi - lo) + F32(lo)


def _prepared(mapping, count: int) -> np.ndarray:
    """The table positions (from the span before the update, as Cycles takes them), then the update."""
    positions = _positions(*_span(mapping, count))
    mapping.update()
    return positions


def rgb_curves_table(mapping) -> tuple[np.ndarray, float, float, bool]:
    """An RGB Curves mapping -> ((257, 3) table of R(C(x)), G(C(x)), B(C(x)), min_x, max_x, extrapolate)."""
    positions = _prepared(mapping, 4)
    r, g, b, c = mapping.curves[0], mapping.curves[1], mapping.curves[2], mapping.curves[3]
    table = np.empty((len(positions), 3), F32)
    for i, x in enumerate(positions):
        xc = mapping.evaluate(c, float(x))
        table[i] = (mapping.evaluate(r, xc), mapping.evaluate(g, xc), mapping.evaluate(b, xc))
    lo, hi = _span(mapping, 4)
    return table, float(lo), float(hi), mapping.extend == "EXTRAPOLATED"


def vector_curves_table(mapping) -> tuple[np.ndarray, float, float, bool]:
    """A Vector Curves mapping -> ((257, 3) table of X(x), Y(x), Z(x), min_x, max_x, extrapolate)."""
    positions = _prepared(mapping, 3)
    curves = mapping.curves[0], mapping.curves[1], mapping.curves[2]
    table = np.array([[mapping.evaluate(c, float(x)) for c in curves] for x in positions], F32)
    lo, hi = _span(mapping, 3)
    return table, float(lo), float(hi), mapping.extend == "EXTRAPOLATED"


def float_curve_table(mapping) -> tuple[np.ndarray, float, float, bool]:
    """A Float Curve mapping -> ((257,) table, min_x, max_x, extrapolate)."""
    positions = _prepared(mapping, 1)
    curve = mapping.curves[0]
    table = np.array([mapping.evaluate(curve, float(x)) for x in positions], F32)
    lo, hi = _span(mapping, 1)
    return table, float(lo), float(hi), mapping.extend == "EXTRAPOLATED"


def color_constants() -> dict:
    """The scene-linear colour constants of the OCIO config in use, as Cycles derives them
    (scene/shader.cpp `init_xyz_transforms`): XYZ via the aces_interchange role and Cycles' ACES AP0 ->
    XYZ D65 matrix. Returns keyword arguments for color_nodes: rgb_to_y (3,), xyz_to_rgb (3, 3),
    rec709_to_rgb (3, 3), or None when scene linear is Rec.709 (within Cycles' 0.001).

    Computed in float64 from Blender's own conversions (mathutils.Color), so within ~1e-7 of the float32
    values Cycles computes (for Blender's default config, color_nodes.RGB_TO_Y holds Cycles' exact ones)."""
    from mathutils import Color

    def matrix(convert) -> np.ndarray:  # columns: the images of the unit colours
        return np.array([tuple(convert(Color(e))) for e in np.eye(3)], np.float64).T

    ap0_to_xyz = np.array([[0.938280, -0.004451, 0.016628],
                           [0.337369, 0.729522, -0.066890],
                           [0.001174, -0.003711, 1.091595]])
    xyz_to_rec709 = np.array([[3.2404542, -1.5371385, -0.4985314],
                              [-0.9692660, 1.8760108, 0.0415560],
                              [0.0556434, -0.2040259, 1.0572252]])
    rgb_to_xyz = ap0_to_xyz @ matrix(Color.from_scene_linear_to_aces)
    xyz_to_rgb = np.linalg.inv(rgb_to_xyz)
    rec709 = np.abs(xyz_to_rgb - xyz_to_rec709).max() <= 0.001
    rec709_to_rgb = None if rec709 else xyz_to_rgb @ np.linalg.inv(xyz_to_rec709)
    return {"rgb_to_y": rgb_to_xyz[1].astype(F32), "xyz_to_rgb": xyz_to_rgb.astype(F32),
            "rec709_to_rgb": None if rec709_to_rgb is None else rec709_to_rgb.astype(F32)}
