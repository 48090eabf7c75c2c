"""Cycles' pattern textures over arrays of hits: Checker, Gradient, Brick and Magic.

Each node is one function with Blender's input sockets as arguments (snake_case) and its options as
keywords (Blender's RNA names and enum identifiers); it returns {"Color": (N, 3), "Fac": (N,)} in
float32, as Cycles computes them (`kernel/svm/checker.h`, `gradient.h`, `brick.h`, `magic.h`). A float
input is (N,) or a constant (Python float, 0-d or length-1 array); a vector or colour input is (N, 3)
or a constant ((3,), (1, 3), or a scalar for all three components; RGBA drops its alpha). The Vector
input is what the node reads (the runner supplies Generated coordinates when it is unlinked); Scale
multiplies it inside the node, as in Cycles.

Cycles' arithmetic is float32 and so is this; its float -> int casts truncate, its `%` keeps the sign of
the dividend (numpy's fmod on int32 does the same), and its brick noise wraps in uint32. Cycles' x86-64
kernel for AVX2 CPUs is compiled with -ffp-contract=fast: some multiply-adds become one fused
instruction, rounded once. Where it does so (found by comparing against the kernel) this rounds the same
way (`fma`), and with glibc's sines (kernels.shading.libm) the results are bit-identical to that
kernel's - except the Radial gradient, whose atan2f is within an ulp of glibc's.
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, F64, HALF, I32, ONE, TWO_PI, U32, ZERO, fma
from .libm import cosf, sinf

_INT_MIN = I32(-2 ** 31)


# ---- inputs -------------------------------------------------------------------------------------

def _scalar(x) -> np.ndarray:
    """A float socket: (N,) float32, or a 0-d float32 array for a constant."""
    a = np.asarray(x, F32)
    return a.reshape(()) if a.size == 1 else a


def _vector(v) -> np.ndarray:
    """A vector/colour socket: (N, 3) float32, or (1, 3) for a constant (an RGBA colour drops alpha, as
    Cycles' colour sockets do)."""
    a = np.asarray(v, F32)
    if a.ndim == 0 or a.size == 1:
        return np.full((1, 3), a.reshape(()), F32)
    if a.shape[-1] == 4:
        a = a[..., :3]
    return a.reshape(-1, 3)


def _count(*arrays) -> int:
    """The number of hits N implied by the inputs (1 if they are all constants)."""
    n = 1
    for a in arrays:
        if a.ndim and a.shape[0] != 1:
            n = a.shape[0]
    return n


def _floor_to_int(x: np.ndarray) -> np.ndarray:
    """Cycles' floor_to_int: floorf, then C's (int) cast, which gives INT_MIN out of range on x86."""
    f = np.floor(x)
    inside = (f >= F32(-2.0 ** 31)) & (f < F32(2.0 ** 31))
    return np.where(inside, np.where(inside, f, ZERO).astype(I32), _INT_MIN)


def _smoothstep(f: np.ndarray) -> np.ndarray:
    """Cycles' smoothstepf: 3f^2 - 2f^3 on [0, 1] (3f^2 fused into the subtraction), clamped outside."""
    ff = f * f
    s = fma(F32(3.0), ff, -(F32(2.0) * ff * f))
    return np.where(f <= ZERO, ZERO, np.where(f >= ONE, ONE, s)).astype(F32, copy=False)


def _color_fac(color: np.ndarray, fac: np.ndarray) -> dict:
    return {"Color": color, "Fac": fac}


# ---- Checker ------------------------------------------------------------------------------------

def checker(vector, color1=(0.8, 0.8, 0.8), color2=(0.2, 0.2, 0.2), scale=5.0) -> dict:
    """Checker Texture: Fac 1 (Color1) where the parities of floor(x), floor(y), floor(z) sum to odd.

    The point is nudged by (p + 1e-6) * 0.999999 so that integer coordinates fall on a defined side.
    Cycles takes |int(floor(x))| % 2; floats beyond 2^24 are even, as are its out-of-range int casts
    (INT_MIN), so the parity f - 2 floor(f / 2) of the float floor f is Cycles' everywhere.
    """
    p = _vector(vector) * _scalar(scale)[..., None]
    p = (p + F32(1e-6)) * F32(0.999999)
    f = np.floor(p)
    parity = f - F32(2.0) * np.floor(f * HALF)          # 0 or 1 per axis
    # NaN and inf coordinates cast to INT_MIN in Cycles, which is even.
    parity = np.where(np.isfinite(parity), parity, ZERO)
    total = parity[:, 0] + parity[:, 1] + parity[:, 2]
    fac = total - F32(2.0) * np.floor(total * HALF)
    c1, c2 = _vector(color1), _vector(color2)
    if len(c1) == 1 and len(c2) == 1:
        color = np.take(np.concatenate([c2, c1]), fac.astype(np.intp), axis=0)
    else:
        color = np.where(fac[:, None] == ONE, c1, c2)
    return _color_fac(color, fac)


# ---- Gradient -----------------------------------------------------------------------------------

GRADIENT_TYPES = ("LINEAR", "QUADRATIC", "EASING", "DIAGONAL", "SPHERICAL", "QUADRATIC_SPHERE", "RADIAL")


def gradient(vector, *, gradient_type: str = "LINEAR") -> dict:
    """Gradient Texture of the given type, clamped to [0, 1] (Fac and grey Color)."""
    p = _vector(vector)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    if gradient_type == "LINEAR":
        f = x
    elif gradient_type == "QUADRATIC":
        r = np.maximum(x, ZERO)
        f = r * r
    elif gradient_type == "EASING":
        r = np.clip(x, ZERO, ONE)
        t = r * r
        f = fma(F32(3.0), t, -(F32(2.0) * t * r))
    elif gradient_type == "DIAGONAL":
        f = (x + y) * HALF
    elif gradient_type == "RADIAL":
        # The kernel multiplies by 1/(2pi) and fuses the + 1/2; atan2f is within an ulp of glibc's.
        f = fma(np.arctan2(y.astype(F64), x).astype(F32), ONE / TWO_PI, HALF)
    elif gradient_type in ("SPHERICAL", "QUADRATIC_SPHERE"):
        # 0.999999 rather than 1 makes unit vectors give exactly 0.
        r = np.maximum(F32(0.999999) - np.sqrt(fma(z, z, fma(x, x, y * y))), ZERO)
        f = r if gradient_type == "SPHERICAL" else r * r
    else:
        raise ValueError(f"unknown gradient_type {gradient_type!r}")
    fac = np.clip(f, ZERO, ONE).astype(F32, copy=False)
    return _color_fac(np.repeat(fac[:, None], 3, axis=1), fac)


# ---- Brick --------------------------------------------------------------------------------------

def brick_noise(n: np.ndarray) -> np.ndarray:
    """Cycles' fast integer noise of a uint32 word -> [0, 1) float32."""
    n = (np.asarray(n, U32) + U32(1013)) & U32(0x7FFFFFFF)
    n = (n >> U32(13)) ^ n
    nn = (n * (n * n * U32(60493) + U32(19990303)) + U32(1376312589)) & U32(0x7FFFFFFF)
    return HALF * (nn.astype(F32) / F32(1073741824.0))


def brick(vector, color1=(0.8, 0.8, 0.8), color2=(0.2, 0.2, 0.2), mortar=(0.0, 0.0, 0.0), scale=5.0,
          mortar_size=0.02, mortar_smooth=0.1, bias=0.0, brick_width=0.5, row_height=0.25, *,
          offset: float = 0.5, offset_frequency: int = 2, squash: float = 1.0,
          squash_frequency: int = 2) -> dict:
    """Brick Texture: Fac is the mortar mask, Color the brick's tint of Color1/Color2 under the mortar.

    Every `offset_frequency`-th row (counting from row 0) is shifted by offset * brick width and every
    `squash_frequency`-th row has its bricks `squash` times as wide. Each brick's tint is the integer
    noise of (row << 16) + (brick & 0xFFFF), plus Bias, clamped.
    """
    p = _vector(vector) * _scalar(scale)[..., None]
    px, py = p[:, 0], p[:, 1]
    width = _scalar(brick_width)
    height = _scalar(row_height)
    size = _scalar(mortar_size)
    smooth = _scalar(mortar_smooth)

    row = _floor_to_int(py / height)
    shift = ZERO
    if offset_frequency and squash_frequency:
        # C's % keeps the dividend's sign; only "is it zero" matters here.
        width = np.where(np.fmod(row, I32(squash_frequency)) != 0, width, width * F32(squash))
        shift = np.where(np.fmod(row, I32(offset_frequency)) != 0, ZERO, width * F32(offset))
    xs = px + shift
    column = _floor_to_int(xs / width)
    x = xs - width * column.astype(F32)
    y = py - height * row.astype(F32)

    word = (row.astype(U32) << U32(16)) + (column.astype(U32) & U32(0xFFFF))
    tint = np.clip(brick_noise(word) + _scalar(bias), ZERO, ONE)

    dist = np.minimum(np.minimum(x, y), np.minimum(width - x, height - y))
    with np.errstate(divide="ignore", invalid="ignore"):
        soft = _smoothstep((ONE - dist / size) / smooth)
    fac = np.where(dist >= size, ZERO, np.where(smooth == ZERO, ONE, soft)).astype(F32, copy=False)

    n = _count(p, fac)
    c1, c2, c3 = _vector(color1), _vector(color2), _vector(mortar)
    in_brick = fac != ONE
    color = np.empty((n, 3), F32)
    for i in range(3):          # per channel: contiguous (N,) arrays are much faster than (N, 3) broadcasts
        # The kernel fuses one product of each sum into its addition.
        brick_color = np.where(in_brick, fma(tint, c2[:, i], (ONE - tint) * c1[:, i]), c1[:, i])
        color[:, i] = fma(c3[:, i], fac, brick_color * (ONE - fac))
    return _color_fac(color, np.broadcast_to(fac, (n,)))


# ---- Magic --------------------------------------------------------------------------------------

# Blender 5.2's Cycles scales the point before wrapping it to (-2pi, 2pi), as OSL and EEVEE do (Cycles
# commit ae48bccc9); 5.0 and 5.1 wrapped the unscaled point and scaled the sines' arguments.
MAGIC_SCALE_FIRST_FROM = (5, 2)


def magic(vector, scale=5.0, distortion=1.0, *, turbulence_depth: int = 2, cycles_version=None) -> dict:
    """Magic Texture: nested sines and cosines of the point's coordinates (wrapped to (-2pi, 2pi) by C's
    fmod first), `turbulence_depth` (0..10) rounds deep; Fac is the mean of the colour. cycles_version:
    the Blender whose Cycles is followed (MAGIC_SCALE_FIRST_FROM); None: 5.0's.

    Each round feeds the last one's values times Distortion into the next sine, so differences grow by
    about 3 * Distortion per round: this uses glibc's sinf/cosf and rounds as Cycles' compiled kernel
    does (one fused multiply-add in the first round, a reciprocal for the final division), which makes
    it bit-exact rather than merely close.
    """
    s = _scalar(scale)
    d = _scalar(distortion)
    five = F32(5.0)
    scale_first = cycles_version is not None and tuple(cycles_version[:2]) >= MAGIC_SCALE_FIRST_FROM
    if scale_first:
        p = np.fmod(_vector(vector) * (s[:, None] if np.ndim(s) else s), TWO_PI)
        s = ONE
    else:
        p = np.fmod(_vector(vector), TWO_PI)
    px, py, pz = p[:, 0], p[:, 1], p[:, 2]
    x = sinf((px + py + pz) * five * s)
    y = cosf((-px + py - pz) * five * s)
    z = -cosf((-px - py + pz) * five * s)
    n = int(turbulence_depth)
    if n > 0:
        x = x * d
        z = z * d
        # Blender 5.0's compiler fuses y * d into the subtraction (y * d has no other use); 5.3's does not.
        y = -cosf((x - y * d if scale_first else fma(-y, d, x)) + z) * d
    if n > 1:
        x = cosf(x - y - z) * d
    if n > 2:
        z = sinf(-x - y - z) * d
    if n > 3:
        x = -cosf(-x + y - z) * d
    if n > 4:
        y = -sinf(-x + y + z) * d
    if n > 5:
        y = -cosf(-x + y + z) * d
    if n > 6:
        x = cosf(x + y + z) * d
    if n > 7:
        z = sinf(x + y - z) * d
    if n > 8:
        x = -cosf(-x - y + z) * d
    if n > 9:
        y = -sinf(x - y + z) * d
    # Cycles divides by 2 * distortion unless the distortion is 0 (as one reciprocal, times three).
    twice = d * F32(2.0)
    inv = np.where(twice != ZERO, ONE / np.where(twice != ZERO, twice, ONE), ONE).astype(F32, copy=False)
    color = np.stack(np.broadcast_arrays(HALF - x * inv, HALF - y * inv, HALF - z * inv), axis=1)
    fac = (color[:, 0] + color[:, 1] + color[:, 2]) * F32(1.0 / 3.0)
    return _color_fac(color, fac)
