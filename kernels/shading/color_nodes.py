"""Cycles' colour nodes over arrays of hits (Blender 5.0, `kernel/svm/*.h`): Separate/Combine Color,
Hue/Saturation/Value, Bright/Contrast, Gamma, Invert, RGB to BW, Blackbody, Wavelength; the colour models
they use (HSV, HSL: `util/color.h`); and the conversions Cycles inserts on links (colour -> float by
luminance, vector -> float by the average).

Inputs, outputs and numerics follow the conventions of kernels.shading.cycles_math. The colour-space
constants (luminance weights, XYZ -> RGB, Rec.709 -> RGB) are kernels.colorspace's, named here too.
"""
from __future__ import annotations

import numpy as np

from ..colorspace import REC709_TO_RGB, RGB_TO_Y, XYZ_TO_RGB  # noqa: F401  (re-exported)
from ..vec import F32, columns, dot_rows, fma
from .cycles_math import INT_MIN, as_float, as_vector, cycles_max, cycles_min, fract, interp, safe_divide, saturate


# ---------------------------------------------------------------- Cycles' tables (kernel/tables.h)
# Blackbody: 800 K..12000 K piecewise fit, R, G = a/t + b t + c, B = ((a t + b) t + c) t + d, Rec.709.
_BLACKBODY_EDGES = np.array([965.0, 1167.0, 1449.0, 1902.0, 3315.0, 6365.0], F32)
_BLACKBODY_R = np.array([
    [1.61919106e+03, -2.05010916e-03, 5.02995757e+00],
    [2.48845471e+03, -1.11330907e-03, 3.22621544e+00],
    [3.34143193e+03, -4.86551192e-04, 1.76486769e+00],
    [4.09461742e+03, -1.27446582e-04, 7.25731635e-01],
    [4.67028036e+03, 2.91258199e-05, 1.26703442e-01],
    [4.59509185e+03, 2.87495649e-05, 1.50345020e-01],
    [3.78717450e+03, 9.35907826e-06, 3.99075871e-01]], F32)
_BLACKBODY_G = np.array([
    [-4.88999748e+02, 6.04330754e-04, -7.55807526e-02],
    [-7.55994277e+02, 3.16730098e-04, 4.78306139e-01],
    [-1.02363977e+03, 1.20223470e-04, 9.36662319e-01],
    [-1.26571316e+03, 4.87340896e-06, 1.27054498e+00],
    [-1.42529332e+03, -4.01150431e-05, 1.43972784e+00],
    [-1.17554822e+03, -2.16378048e-05, 1.30408023e+00],
    [-5.00799571e+02, -4.59832026e-06, 1.09098763e+00]], F32)
_BLACKBODY_B = np.array([
    [5.96945309e-11, -4.85742887e-08, -9.70622247e-05, -4.07936148e-03],
    [2.40430366e-11, 5.55021075e-08, -1.98503712e-04, 2.89312858e-02],
    [-1.40949732e-11, 1.89878968e-07, -3.56632824e-04, 9.10767778e-02],
    [-3.61460868e-11, 2.84822009e-07, -4.93211319e-04, 1.56723440e-01],
    [-1.97075738e-11, 1.75359352e-07, -2.50542825e-04, -2.22783266e-02],
    [-1.61997957e-13, -1.64216008e-08, 3.86216271e-04, -7.38077418e-01],
    [6.72650283e-13, -2.73078809e-08, 4.24098264e-04, -7.52335691e-01]], F32)
_BLACKBODY_HOT = np.array([0.8262954810464208, 0.9945080501520986, 1.566307710274283], F32)    # t >= 12000 K
_BLACKBODY_COLD = np.array([5.413294490189271, -0.20319390035873933, -0.0822535242887164], F32)  # t < 800 K

# CIE 1931 colour matching functions, 380..780 nm in 5 nm steps (81 rows of x, y, z).
_CIE_XYZ = np.array([
    [0.0014, 0.0000, 0.0065], [0.0022, 0.0001, 0.0105], [0.0042, 0.0001, 0.0201],
    [0.0076, 0.0002, 0.0362], [0.0143, 0.0004, 0.0679], [0.0232, 0.0006, 0.1102],
    [0.0435, 0.0012, 0.2074], [0.0776, 0.0022, 0.3713], [0.1344, 0.0040, 0.6456],
    [0.2148, 0.0073, 1.0391], [0.2839, 0.0116, 1.3856], [0.3285, 0.0168, 1.6230],
    [0.3483, 0.0230, 1.7471], [0.3481, 0.0298, 1.7826], [0.3362, 0.0380, 1.7721],
    [0.3187, 0.0480, 1.7441], [0.2908, 0.0600, 1.6692], [0.2511, 0.0739, 1.5281],
    [0.1954, 0.0910, 1.2876], [0.1421, 0.1126, 1.0419], [0.0956, 0.1390, 0.8130],
    [0.0580, 0.1693, 0.6162], [0.0320, 0.2080, 0.4652], [0.0147, 0.2586, 0.3533],
    [0.0049, 0.3230, 0.2720], [0.0024, 0.4073, 0.2123], [0.0093, 0.5030, 0.1582],
    [0.0291, 0.6082, 0.1117], [0.0633, 0.7100, 0.0782], [0.1096, 0.7932, 0.0573],
    [0.1655, 0.8620, 0.0422], [0.2257, 0.9149, 0.0298], [0.2904, 0.9540, 0.0203],
    [0.3597, 0.9803, 0.0134], [0.4334, 0.9950, 0.0087], [0.5121, 1.0000, 0.0057],
    [0.5945, 0.9950, 0.0039], [0.6784, 0.9786, 0.0027], [0.7621, 0.9520, 0.0021],
    [0.8425, 0.9154, 0.0018], [0.9163, 0.8700, 0.0017], [0.9786, 0.8163, 0.0014],
    [1.0263, 0.7570, 0.0011], [1.0567, 0.6949, 0.0010], [1.0622, 0.6310, 0.0008],
    [1.0456, 0.5668, 0.0006], [1.0026, 0.5030, 0.0003], [0.9384, 0.4412, 0.0002],
    [0.8544, 0.3810, 0.0002], [0.7514, 0.3210, 0.0001], [0.6424, 0.2650, 0.0000],
    [0.5419, 0.2170, 0.0000], [0.4479, 0.1750, 0.0000], [0.3608, 0.1382, 0.0000],
    [0.2835, 0.1070, 0.0000], [0.2187, 0.0816, 0.0000], [0.1649, 0.0610, 0.0000],
    [0.1212, 0.0446, 0.0000], [0.0874, 0.0320, 0.0000], [0.0636, 0.0232, 0.0000],
    [0.0468, 0.0170, 0.0000], [0.0329, 0.0119, 0.0000], [0.0227, 0.0082, 0.0000],
    [0.0158, 0.0057, 0.0000], [0.0114, 0.0041, 0.0000], [0.0081, 0.0029, 0.0000],
    [0.0058, 0.0021, 0.0000], [0.0041, 0.0015, 0.0000], [0.0029, 0.0010, 0.0000],
    [0.0020, 0.0007, 0.0000], [0.0014, 0.0005, 0.0000], [0.0010, 0.0004, 0.0000],
    [0.0007, 0.0002, 0.0000], [0.0005, 0.0002, 0.0000], [0.0003, 0.0001, 0.0000],
    [0.0002, 0.0001, 0.0000], [0.0002, 0.0001, 0.0000], [0.0001, 0.0000, 0.0000],
    [0.0001, 0.0000, 0.0000], [0.0001, 0.0000, 0.0000], [0.0000, 0.0000, 0.0000]], F32)


# ---------------------------------------------------------------- colour models (util/color.h)
_HSV_PICK = np.array([  # hsv_to_rgb's sextants (i = 0..4, anything else): which of (v, p, q, t) per channel
    [0, 2, 1, 1, 3, 0],       # r: v q p p t v
    [3, 0, 0, 2, 1, 1],       # g: t v v q p p
    [1, 1, 3, 0, 0, 2]],      # b: p p t v v q
    np.intp)


def _channels(rgb: np.ndarray):
    return rgb[..., 0], rgb[..., 1], rgb[..., 2]


def rgb_to_hsv(rgb: np.ndarray) -> np.ndarray:
    """(N, 3) RGB -> HSV as Cycles' rgb_to_hsv (hue in [0, 1), no clamping of negative colours)."""
    r, g, b = _channels(rgb)
    cmax = np.fmax(r, np.fmax(g, b))
    delta = cmax - cycles_min(r, cycles_min(g, b))
    s = safe_divide(delta, cmax)
    cr, cg, cb = (safe_divide(cmax - c, delta) for c in (r, g, b))
    h = np.where(r == cmax, cb - cg, np.where(g == cmax, (F32(2.0) + cr) - cb, (F32(4.0) + cg) - cr))
    h *= F32(1.0 / 6.0)  # h /= 6.0f under -freciprocal-math
    h = np.where(h < 0, h + F32(1.0), h)
    return np.stack(np.broadcast_arrays(np.where(s != 0, h, F32(0.0)), s, cmax), -1)


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """(N, 3) HSV -> RGB as Cycles' hsv_to_rgb (hue 1 -> 0; a hue outside [0, 1) takes the last sextant)."""
    h, s, v = _channels(hsv)
    h = np.where(h == 1, F32(0.0), h) * F32(6.0)
    i = np.floor(h)
    # Saturation 0 is grey, (v, v, v): with f = 0, p = q = t = v exactly, whatever the hue.
    f = np.where(s != 0, h - i, F32(0.0))
    p = v * (F32(1.0) - s)
    q = v * (F32(1.0) - s * f)
    t = v * (F32(1.0) - s * (F32(1.0) - f))
    sextant = np.where((i >= 0) & (i <= 4), i, F32(5.0)).astype(np.intp)
    cols = np.stack(np.broadcast_arrays(v, p, q, t), -1)
    flat = cols.reshape(-1)
    base = np.arange(0, flat.size, 4, dtype=np.intp).reshape(cols.shape[:-1])
    return np.stack([np.take(flat, base + np.take(_HSV_PICK[k], sextant)) for k in range(3)], -1)


def rgb_to_hsl(rgb: np.ndarray) -> np.ndarray:
    """(N, 3) RGB -> HSL as Cycles' rgb_to_hsl."""
    r, g, b = _channels(rgb)
    cmax = np.fmax(r, np.fmax(g, b))
    cmin = cycles_min(r, cycles_min(g, b))
    l = cycles_min(F32(1.0), (cmax + cmin) * F32(0.5))
    delta = cmax - cmin
    grey = cmax == cmin
    s = np.where(l > 0.5, safe_divide(delta, F32(2.0) - cmax - cmin), safe_divide(delta, cmax + cmin))
    h = np.where(cmax == r, safe_divide(g - b, delta) + np.where(g < b, F32(6.0), F32(0.0)),
                 np.where(cmax == g, safe_divide(b - r, delta) + F32(2.0), safe_divide(r - g, delta) + F32(4.0)))
    h = np.where(grey, F32(0.0), h) * F32(1.0 / 6.0)
    return np.stack(np.broadcast_arrays(h, np.where(grey, F32(0.0), s), l), -1)


def hsl_to_rgb(hsl: np.ndarray) -> np.ndarray:
    """(N, 3) HSL -> RGB as Cycles' hsl_to_rgb."""
    h, s, l = _channels(hsl)
    h6 = h * F32(6.0)
    nr = saturate(np.abs(h6 - F32(3.0)) - F32(1.0))
    ng = saturate(F32(2.0) - np.abs(h6 - F32(2.0)))
    nb = saturate(F32(2.0) - np.abs(h6 - F32(4.0)))
    chroma = (F32(1.0) - np.abs(F32(2.0) * l - F32(1.0))) * s
    return np.stack(np.broadcast_arrays((nr - F32(0.5)) * chroma + l, (ng - F32(0.5)) * chroma + l,
                                        (nb - F32(0.5)) * chroma + l), -1)


# ---------------------------------------------------------------- colour nodes
def separate_color(color=0.8, *, mode: str = "RGB") -> dict:
    """Separate Color node: {"Red", "Green", "Blue": (N,)} (H, S, V or H, S, L for those modes)."""
    c = as_vector(color)
    with np.errstate(all="ignore"):
        c = rgb_to_hsv(c) if mode == "HSV" else rgb_to_hsl(c) if mode == "HSL" else c
    return {"Red": c[..., 0].copy(), "Green": c[..., 1].copy(), "Blue": c[..., 2].copy()}


def combine_color(red=0.0, green=0.0, blue=0.0, *, mode: str = "RGB") -> dict:
    """Combine Color node: {"Color": (N, 3)}."""
    c = np.stack(np.broadcast_arrays(as_float(red), as_float(green), as_float(blue)), -1)
    with np.errstate(all="ignore"):
        c = hsv_to_rgb(c) if mode == "HSV" else hsl_to_rgb(c) if mode == "HSL" else c
    return {"Color": c.astype(F32, copy=False)}


def hue_saturation(hue=0.5, saturation=1.0, value=1.0, fac=1.0, color=0.8) -> dict:
    """Hue/Saturation/Value node (`svm_node_hsv`): {"Color": (N, 3)}: hue shifted by Hue - 1/2 and wrapped,
    saturation scaled and clamped to [0, 1], value scaled, mixed with the input by Fac, negatives -> 0."""
    c = as_vector(color)
    fac = columns(as_float(fac))
    with np.errstate(all="ignore"):
        hsv = rgb_to_hsv(c)
        h = fract(hsv[..., 0] + as_float(hue) + F32(0.5))
        s = saturate(hsv[..., 1] * as_float(saturation))
        v = hsv[..., 2] * as_float(value)
        out = hsv_to_rgb(np.stack(np.broadcast_arrays(h, s, v), -1))
        out = fac * out + (F32(1.0) - fac) * c
    return {"Color": cycles_max(out, F32(0.0)).astype(F32, copy=False)}


def bright_contrast(color=1.0, bright=0.0, contrast=0.0) -> dict:
    """Bright/Contrast node: {"Color": max((1 + contrast) c + bright - contrast / 2, 0)}."""
    c = as_vector(color)
    contrast = as_float(contrast)
    a = columns(F32(1.0) + contrast)
    b = columns(as_float(bright) - contrast * F32(0.5))
    return {"Color": cycles_max(fma(a, c, b), F32(0.0))}


def gamma(color=1.0, gamma=1.0) -> dict:  # noqa: A002
    """Gamma node: {"Color": c ** gamma for positive channels (others kept); all 1 when gamma == 0}."""
    c = as_vector(color)
    g = columns(as_float(gamma))
    with np.errstate(all="ignore"):
        out = np.where(c > 0, np.power(np.where(c > 0, c, F32(1.0)), g), c)
    return {"Color": np.where(g == 0, F32(1.0), out).astype(F32, copy=False)}


def invert(fac=1.0, color=0.0) -> dict:
    """Invert node: {"Color": fac (1 - c) + (1 - fac) c}."""
    c = as_vector(color)
    f = columns(as_float(fac))
    return {"Color": (f * (F32(1.0) - c) + (F32(1.0) - f) * c).astype(F32, copy=False)}


def color_to_float(color, rgb_to_y=RGB_TO_Y) -> np.ndarray:
    """Colour -> float as Cycles converts on a link and RGB to BW computes: luminance, (N,)."""
    return dot_rows(as_vector(color), np.asarray(rgb_to_y, F32))


def vector_to_float(vector) -> np.ndarray:
    """Vector -> float as Cycles converts on a link: the average of the components, (N,)."""
    v = as_vector(vector)
    return (v[..., 0] + v[..., 1] + v[..., 2]) * F32(1.0 / 3.0)


def rgb_to_bw(color=0.5, *, rgb_to_y=RGB_TO_Y) -> dict:
    """RGB to BW node: {"Val": (N,)} the scene-linear luminance (RGB_TO_Y)."""
    return {"Val": color_to_float(color, rgb_to_y)}


def blackbody(temperature=6500.0, *, rec709_to_rgb=REC709_TO_RGB) -> dict:
    """Blackbody node: {"Color": (N, 3)}: Cycles' piecewise fit (800..12000 K, constant beyond), in
    Rec.709 then scene linear (rec709_to_rgb, a 3x3 matrix; None = identity), negatives -> 0."""
    t = as_float(temperature)
    with np.errstate(all="ignore"):
        i = np.searchsorted(_BLACKBODY_EDGES, t, side="right")
        r, g, b = _BLACKBODY_R[i], _BLACKBODY_G[i], _BLACKBODY_B[i]
        t_inv = safe_divide(F32(1.0), t)
        red = fma(r[..., 0], t_inv, r[..., 1] * t) + r[..., 2]
        green = fma(g[..., 0], t_inv, g[..., 1] * t) + g[..., 2]
        blue = fma(fma(fma(b[..., 0], t, b[..., 1]), t, b[..., 2]), t, b[..., 3])
        rgb = np.stack([red, green, blue], -1)
        rgb = np.where(columns(t >= 12000), _BLACKBODY_HOT, np.where(columns(t < 800), _BLACKBODY_COLD, rgb))
        if rec709_to_rgb is not None:
            m = np.asarray(rec709_to_rgb, F32)
            rgb = np.stack([dot_rows(rgb, m[k]) for k in range(3)], -1)
    return {"Color": cycles_max(rgb, F32(0.0)).astype(F32, copy=False)}


def wavelength(wavelength=500.0, *, xyz_to_rgb=XYZ_TO_RGB) -> dict:  # noqa: A002
    """Wavelength node: {"Color": (N, 3)}: the CIE table lerped at (nm - 380) / 5 (C's truncating index,
    so 375..380 nm extrapolate the first interval), black outside, XYZ -> scene linear, / 2.52, negatives
    -> 0."""
    lam = as_float(wavelength)
    with np.errstate(all="ignore"):
        ii = (lam - F32(380.0)) * F32(1.0 / 5.0)
        small = np.abs(ii) < F32(2147483648.0)
        i = np.where(small, np.trunc(np.where(small, ii, F32(0.0))), INT_MIN)
        valid = (i >= 0) & (i < 80)
        k = np.where(valid, i, F32(0.0)).astype(np.intp)
        frac = columns(ii - np.where(valid, i, F32(0.0)))
        xyz = interp(_CIE_XYZ[k], _CIE_XYZ[k + 1], frac)
        m = np.asarray(xyz_to_rgb, F32)
        rgb = np.stack([dot_rows(xyz, m[c]) for c in range(3)], -1) * F32(1.0 / 2.52)
        rgb = np.where(columns(valid), rgb, F32(0.0))
    return {"Color": cycles_max(rgb, F32(0.0)).astype(F32, copy=False)}
