"""Cycles' Mix node (and the legacy MixRGB) over arrays of hits: the float and vector lerps, and the
colour blend modes (`kernel/svm/mix.h`, `color_util.h`, Blender 5.0).

Inputs, outputs and numerics follow the conventions of kernels.shading.cycles_math.
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, columns
from .color_nodes import hsv_to_rgb, rgb_to_hsv
from .cycles_math import as_float, as_vector, cycles_max, cycles_min, interp, safe_divide, saturate


# ---------------------------------------------------------------- Mix
def _per_channel_dodge(c1, c2, t):
    tmp = F32(1.0) - t * c2
    q = safe_divide(c1, tmp)
    out = np.where(tmp <= 0, F32(1.0), np.where(q > 1, F32(1.0), q))
    return np.where(c1 != 0, out, c1)


def _per_channel_burn(c1, c2, t, tm):
    tmp = tm + t * c2
    q = F32(1.0) - safe_divide(F32(1.0) - c1, tmp)
    return np.where(tmp <= 0, F32(0.0), np.where(q < 0, F32(0.0), np.where(q > 1, F32(1.0), q)))


def _blend_hue(t, c1, c2):
    hsv2 = rgb_to_hsv(c2)
    hsv = rgb_to_hsv(c1)
    hsv = np.stack(np.broadcast_arrays(hsv2[..., 0], hsv[..., 1], hsv[..., 2]), -1)
    return np.where(columns(hsv2[..., 1] != 0), interp(c1, hsv_to_rgb(hsv), t), c1)


def _blend_saturation(t, tm, c1, c2):
    hsv = rgb_to_hsv(c1)
    hsv2 = rgb_to_hsv(c2)
    s = tm[..., 0] * hsv[..., 1] + t[..., 0] * hsv2[..., 1]
    out = hsv_to_rgb(np.stack(np.broadcast_arrays(hsv[..., 0], s, hsv[..., 2]), -1))
    return np.where(columns(hsv[..., 1] != 0), out, c1)


def _blend_value(t, tm, c1, c2):
    hsv = rgb_to_hsv(c1)
    hsv2 = rgb_to_hsv(c2)
    v = tm[..., 0] * hsv[..., 2] + t[..., 0] * hsv2[..., 2]
    return hsv_to_rgb(np.stack(np.broadcast_arrays(hsv[..., 0], hsv[..., 1], v), -1))


def _blend_color(t, c1, c2):
    hsv2 = rgb_to_hsv(c2)
    hsv = rgb_to_hsv(c1)
    hsv = np.stack(np.broadcast_arrays(hsv2[..., 0], hsv2[..., 1], hsv[..., 2]), -1)
    return np.where(columns(hsv2[..., 1] != 0), interp(c1, hsv_to_rgb(hsv), t), c1)


def _blend_overlay(t, tm, c1, c2):
    low = c1 * (tm + F32(2.0) * t * c2)
    high = F32(1.0) - (tm + F32(2.0) * t * (F32(1.0) - c2)) * (F32(1.0) - c1)
    return np.where(c1 < 0.5, low, high)


def _blend_soft_light(t, tm, c1, c2):
    one = F32(1.0)
    scr = one - (one - c2) * (one - c1)
    return tm * c1 + t * ((one - c1) * c2 * c1 + c1 * scr)


_BLEND = {  # blend_type -> f(t, tm, c1, c2); t and tm are the factor and 1 - factor as columns()
    "MIX": lambda t, tm, a, b: interp(a, b, t),
    "ADD": lambda t, tm, a, b: interp(a, a + b, t),
    "MULTIPLY": lambda t, tm, a, b: interp(a, a * b, t),
    "SCREEN": lambda t, tm, a, b: F32(1.0) - (tm + t * (F32(1.0) - b)) * (F32(1.0) - a),
    "OVERLAY": _blend_overlay,
    "SUBTRACT": lambda t, tm, a, b: interp(a, a - b, t),
    "DIVIDE": lambda t, tm, a, b: np.where(b != 0, tm * a + t * safe_divide(a, b), a),
    "DIFFERENCE": lambda t, tm, a, b: interp(a, np.abs(a - b), t),
    "EXCLUSION": lambda t, tm, a, b: cycles_max(interp(a, a + b - F32(2.0) * a * b, t), F32(0.0)),
    "DARKEN": lambda t, tm, a, b: interp(a, cycles_min(a, b), t),
    "LIGHTEN": lambda t, tm, a, b: interp(a, cycles_max(a, b), t),
    "DODGE": lambda t, tm, a, b: _per_channel_dodge(a, b, t),
    "BURN": lambda t, tm, a, b: _per_channel_burn(a, b, t, tm),
    "HUE": lambda t, tm, a, b: _blend_hue(t, a, b),
    "SATURATION": _blend_saturation,
    "VALUE": _blend_value,
    "COLOR": lambda t, tm, a, b: _blend_color(t, a, b),
    "SOFT_LIGHT": _blend_soft_light,
    "LINEAR_LIGHT": lambda t, tm, a, b: a + t * (F32(2.0) * b + F32(-1.0)),
}
BLEND_TYPES = tuple(_BLEND)


def mix_color(factor, a, b, *, blend_type: str = "MIX", clamp_factor: bool = True,
              clamp_result: bool = False) -> np.ndarray:
    """Cycles' svm_mix over (N, 3) colours with an (N,) factor: (N, 3)."""
    t = as_float(factor)
    if clamp_factor:
        t = saturate(t)
    t = columns(t)
    c1, c2 = as_vector(a), as_vector(b)
    with np.errstate(all="ignore"):
        out = _BLEND[blend_type](t, F32(1.0) - t, c1, c2)
        out = np.broadcast_to(out, np.broadcast_shapes(out.shape, c1.shape, c2.shape, t.shape))
        if clamp_result:
            out = saturate(out)
    return out.astype(F32, copy=False)


def mix(factor=0.5, a=0.0, b=0.0, *, data_type: str = "FLOAT", factor_mode: str = "UNIFORM",
        blend_type: str = "MIX", clamp_factor: bool = True, clamp_result: bool = False) -> dict:
    """Mix node (ShaderNodeMix): {"Result": (N,) for FLOAT, (N, 3) for VECTOR and RGBA}.

    factor: Factor_Float, or Factor_Vector for VECTOR with factor_mode NON_UNIFORM; a, b: A_*/B_* of the
    data type. FLOAT and VECTOR lerp a (1 - t) + b t; RGBA blends by blend_type (`svm_mix`), clamp_result
    saturating the colour. clamp_factor clamps the factor to [0, 1] first."""
    if data_type == "RGBA":
        return {"Result": mix_color(factor, a, b, blend_type=blend_type, clamp_factor=clamp_factor,
                                    clamp_result=clamp_result)}
    if data_type == "VECTOR":
        t = as_vector(factor) if factor_mode == "NON_UNIFORM" else columns(as_float(factor))
        a, b = as_vector(a), as_vector(b)
    else:
        t, a, b = as_float(factor), as_float(a), as_float(b)
    if clamp_factor:
        t = saturate(t)
    return {"Result": (a * (F32(1.0) - t) + b * t).astype(F32, copy=False)}


def mix_rgb(fac=0.5, color1=0.5, color2=0.5, *, blend_type: str = "MIX", use_clamp: bool = False) -> dict:
    """Legacy MixRGB node: {"Color": (N, 3)}; its factor is always clamped, use_clamp saturates the result."""
    return {"Color": mix_color(fac, color1, color2, blend_type=blend_type, clamp_factor=True,
                               clamp_result=use_clamp)}
