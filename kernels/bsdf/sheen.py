"""Cycles' Sheen BSDF (microfiber): Zeltner, Burley and Chiang 2022, "Practical Multiple-Scattering
Sheen Using Linearly Transformed Cosines", as `bsdf_sheen.h` in Cycles 5.0 has it.

This module owns the sheen lobe and its table. Contract as in the package docstring: local frame with
z along the lobe's normal, directions (x, y, z) tuples of (N,) float32 unit arrays, `wo` to the viewer,
`wi` to the light or the sampled direction.

The lobe is a linearly transformed cosine (LTC) in a frame whose x axis is `wo` projected on the
tangent plane. A direction with coordinates (x, y, z) in that frame has the density

    D(wi) = max(z, 0) a^2 / (pi L^2),   L = (a x + b z)^2 + (a y)^2 + z^2,

which integrates to 1 over the upper hemisphere (the transform keeps z, so the clamped cosine's
hemisphere maps onto itself). The lobe returns f_cos = albedo * D and pdf = D, so a sampled direction
has weight = albedo. (a, b, albedo) come from a 32 x 32 table over mu = wo.z (x, fastest) and the
roughness clamped to [1e-3, 1] (y), read with Cycles' bilinear `lookup_table_read_2D`. Cycles drops
the closure where |a| < 1e-5 or albedo < 1e-5; so do we (f_cos = pdf = weight = 0).

The table in data/sheen_ltc.npz is ours: tools/fit_sheen_table.py measures Cycles' lobe through bpy and
fits (a, b, albedo) per cell; Cycles' own numbers are not copied. The colour weight (Sheen Color,
Principled sheen weight times tint) is the caller's; the albedo is also what Cycles uses for layering
the closures below the sheen (see `sheen_albedo`).
"""
from __future__ import annotations

import functools
import os

import numpy as np

from ..sampling import sample_uniform_disk
from ..vec import F32, INV_PI, ONE, ZERO

TABLE_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "sheen_ltc.npz")
TABLE_SIZE = 32                 # cells per axis: mu = i / 31, roughness = j / 31
ROUGHNESS_MIN = F32(1e-3)       # `bsdf_sheen_setup` clamps the roughness to [1e-3, 1]
DROP_BELOW = F32(1e-5)          # |a| or albedo below this: Cycles skips the closure


@functools.lru_cache(maxsize=None)
def load_table(path: str = TABLE_PATH) -> np.ndarray:
    """The LTC table, (3, 32, 32) float32: [a, b, albedo] x roughness index j x mu index i."""
    with np.load(path) as data:
        table = np.asarray(data["ltc"], np.float32)
    assert table.shape == (3, TABLE_SIZE, TABLE_SIZE), table.shape
    return table


def _grid_coordinate(v, size: int):
    """Cycles' `lookup_table_read`: saturate, scale to [0, size-1], truncate; (index, next, t)."""
    x = np.clip(np.asarray(v, np.float32), ZERO, ONE) * F32(size - 1)
    index = np.minimum(x.astype(np.int32), size - 1)
    return index, np.minimum(index + 1, size - 1), (x - index.astype(np.float32)).astype(np.float32)


def lookup_table_2d(grid: np.ndarray, x, y) -> np.ndarray:
    """Bilinear read of grid (..., ny, nx) at x (fastest axis) and y in [0, 1], as Cycles does it.
    Returns (..., N) float32."""
    ny, nx = grid.shape[-2:]
    i0, i1, tx = _grid_coordinate(x, nx)
    j0, j1, ty = _grid_coordinate(y, ny)
    row0 = (ONE - tx) * grid[..., j0, i0] + tx * grid[..., j0, i1]
    row1 = (ONE - tx) * grid[..., j1, i0] + tx * grid[..., j1, i1]
    return ((ONE - ty) * row0 + ty * row1).astype(np.float32)


def ltc_parameters(cos_theta_o, roughness, table: np.ndarray | None = None):
    """(a, b, albedo), each (N,) float32, for mu = cos_theta_o and roughness as Cycles looks them up;
    albedo is set to 0 where Cycles would drop the closure."""
    table = load_table() if table is None else table
    r = np.clip(np.asarray(roughness, np.float32), ROUGHNESS_MIN, ONE)
    mu = np.asarray(cos_theta_o, np.float32)
    mu, r = np.broadcast_arrays(mu, r)
    a, b, albedo = lookup_table_2d(table, mu, r)
    dropped = (np.abs(a) < DROP_BELOW) | (albedo < DROP_BELOW)
    return a, b, np.where(dropped, ZERO, albedo).astype(np.float32)


def sheen_albedo(cos_theta_o, roughness, table: np.ndarray | None = None) -> np.ndarray:
    """Directional albedo of the sheen lobe (the tabulated value), (N,) float32: the factor Cycles
    multiplies into the sheen closure weight and uses in `closure_layering_weight`."""
    return ltc_parameters(cos_theta_o, roughness, table)[2]


def _ltc_frame(wo):
    """cos and sin of the azimuth of wo: the LTC frame's x axis is wo projected on the tangent plane.
    At normal incidence Cycles falls back to an arbitrary world-space frame; the local x axis is ours
    (the tabulated b is ~0 there, so the lobe hardly depends on it)."""
    p2 = wo[0] * wo[0] + wo[1] * wo[1]
    ok = p2 > F32(1e-30)
    inv_p = np.where(ok, ONE / np.sqrt(np.where(ok, p2, ONE)), ZERO)
    return np.where(ok, wo[0] * inv_p, ONE), np.where(ok, wo[1] * inv_p, ZERO)


def ltc_density(x, y, z, a, b):
    """D = max(z, 0) a^2 / (pi L^2) for (x, y, z) in the LTC frame; 0 for the degenerate direction."""
    ax_bz = a * x + b * z
    ay = a * y
    length_sqr = ax_bz * ax_bz + ay * ay + z * z
    ok = length_sqr > 0
    ratio = a / np.where(ok, length_sqr, ONE)
    return np.where(ok, INV_PI * np.maximum(z, ZERO) * ratio * ratio, ZERO).astype(np.float32)


def sheen_eval(wo, wi, roughness, table: np.ndarray | None = None):
    """Sheen lobe for viewer wo and light wi; roughness (N,) or scalar. Returns (f_cos, pdf), (N,)
    float32 each: f_cos = albedo * D, pdf = D (0 where Cycles drops the closure)."""
    a, b, alb = ltc_parameters(wo[2], roughness, table)
    c, s = _ltc_frame(wo)
    x = wi[0] * c + wi[1] * s
    y = wi[1] * c - wi[0] * s
    pdf = np.where(alb > 0, ltc_density(x, y, wi[2], a, b), ZERO).astype(np.float32)
    return (alb * pdf).astype(np.float32), pdf


def sheen_sample(wo, roughness, u1, u2, table: np.ndarray | None = None):
    """Sample the LTC: a uniform disk point d lifted to the hemisphere, h = sqrt(1 - |d|^2), is a
    cosine-distributed direction; M maps it to normalize(d.x - b h, d.y, a h). Returns
    (wi, weight, pdf), weight = albedo, all (N,) float32; 0 where dropped or below the surface.

    Cycles uses the concentric disk map and we use sampling.py's polar one: the same distribution
    (both uniform on the disk), a different stratification."""
    a, b, alb = ltc_parameters(wo[2], roughness, table)
    dx, dy = sample_uniform_disk(u1, u2)
    h = np.sqrt(np.maximum(ONE - dx * dx - dy * dy, ZERO))
    x, y, z = dx - b * h, dy, a * h
    norm = np.sqrt(x * x + y * y + z * z)
    inv = np.where(norm > 0, ONE / np.where(norm > 0, norm, ONE), ZERO)
    x, y, z = x * inv, y * inv, z * inv
    c, s = _ltc_frame(wo)
    wi = ((x * c - y * s).astype(np.float32), (x * s + y * c).astype(np.float32), z.astype(np.float32))
    ok = (alb > 0) & (z > 0)
    pdf = np.where(ok, ltc_density(x, y, z, a, b), ZERO)
    ok &= pdf > 0
    return wi, np.where(ok, alb, ZERO).astype(np.float32), np.where(ok, pdf, ZERO).astype(np.float32)
