"""The world: constant radiance, an equirectangular HDRI looked up in Cycles' convention, or a node program.

Cycles' equirectangular map: u = 0.5 - atan2(d.y, d.x) / (2 pi), v = 1 - acos(d.z) / pi, with the
image's row 0 at the bottom (v = 0 looks straight down). d is the world direction taken to the
map's frame by env_from_world.
"""
from __future__ import annotations

import numpy as np

from . import sampling
from .scene import World
from .textures import Texture, luminance

INV_2PI = np.float32(0.5 / np.pi)
INV_PI = np.float32(1.0 / np.pi)


def direction_to_equirect(dx, dy, dz):
    """World-frame unit direction components -> (u, v) in [0, 1]."""
    u = np.float32(0.5) - np.arctan2(dy, dx) * INV_2PI
    v = np.float32(1.0) - np.arccos(np.clip(dz, np.float32(-1.0), np.float32(1.0))) * INV_PI
    return u, v


def equirect_to_direction(u, v):
    """Inverse of direction_to_equirect. Returns dx, dy, dz and sin(theta)."""
    phi = (np.float32(0.5) - u) * np.float32(2.0 * np.pi)
    theta = (np.float32(1.0) - v) * np.float32(np.pi)
    sin_t = np.sin(theta)
    return np.cos(phi) * sin_t, np.sin(phi) * sin_t, np.cos(theta), sin_t


class Environment:
    """World radiance for escaped rays, and importance sampling of the world as a light.

    A constant world is sampled uniformly over the sphere. An HDRI is sampled from a piecewise-constant
    distribution over its pixels, proportional to their level x sin(theta) (the area of a pixel on the
    sphere), so the pdf per solid angle is pdf_uv / (2 pi^2 sin(theta)).
    """

    def __init__(self, world: World, shader=None):
        """shader: the world's node program (shading.world.WorldShader) when it has one; its radiance is
        evaluated per ray, and a bake of it at world.map_resolution is the sampling distribution."""
        self.world = world
        self.shader = shader
        self.texture = Texture(world.hdri) if world.hdri is not None and shader is None else None
        if shader is not None:
            self.strength = np.float32(1.0)
            self.rotation = np.eye(3, dtype=np.float32)
            width = int(world.map_resolution)
            self._distribution = _PixelDistribution(shader.bake(width, max(width // 2, 2)))
        else:
            self.strength = np.float32(world.strength)
            self.rotation = np.asarray(world.env_from_world, np.float32)
            self._distribution = _PixelDistribution(world.hdri) if world.hdri is not None else None
        self.constant = (np.asarray(world.color, np.float32) * self.strength)[:, None]

    def mean_luminance(self) -> float:
        """Radiance luminance averaged over the sphere of directions."""
        if self._distribution is None:
            return float(luminance(self.constant[:, 0]))
        # (1 / 4 pi) * sum(L sin(theta)) * (pi / H) * (2 pi / W) = (pi / 2) * mean(L sin(theta))
        return float(self._distribution.mean_weight * 0.5 * np.pi * self.strength)

    def sample_direction(self, u1, u2):
        """World directions with pdf per solid angle: (wx, wy, wz, pdf)."""
        if self._distribution is None:
            wx, wy, wz = sampling.sample_uniform_sphere(u1, u2)
            return wx, wy, wz, np.full(len(u1), sampling.UNIFORM_SPHERE_PDF)
        u, v, pdf_uv = self._distribution.sample(u1, u2)
        ex, ey, ez, sin_t = equirect_to_direction(u, v)
        with np.errstate(divide="ignore", invalid="ignore"):
            pdf = pdf_uv / (np.float32(2.0 * np.pi ** 2) * sin_t)
        pdf = np.where((sin_t > 0) & np.isfinite(pdf), pdf, np.float32(0.0)).astype(np.float32)
        wx, wy, wz = self.to_world(ex, ey, ez)
        return wx, wy, wz, pdf

    def direction_pdf(self, dx, dy, dz) -> np.ndarray:
        """pdf per solid angle with which sample_direction() yields world directions d."""
        if self._distribution is None:
            return np.full(len(dx), sampling.UNIFORM_SPHERE_PDF)
        ex, ey, ez = self.to_env(dx, dy, dz)
        u, v = direction_to_equirect(ex, ey, ez)
        sin_t = np.sqrt(np.maximum(np.float32(1.0) - ez * ez, np.float32(0.0)))
        with np.errstate(divide="ignore", invalid="ignore"):
            pdf = self._distribution.pdf(u, v) / (np.float32(2.0 * np.pi ** 2) * sin_t)
        return np.where((sin_t > 0) & np.isfinite(pdf), pdf, np.float32(0.0)).astype(np.float32)

    @property
    def is_constant(self) -> bool:
        return self._distribution is None

    def to_env(self, dx, dy, dz):
        r = self.rotation
        return (r[0, 0] * dx + r[0, 1] * dy + r[0, 2] * dz,
                r[1, 0] * dx + r[1, 1] * dy + r[1, 2] * dz,
                r[2, 0] * dx + r[2, 1] * dy + r[2, 2] * dz)

    def to_world(self, ex, ey, ez):
        r = self.rotation
        return (r[0, 0] * ex + r[1, 0] * ey + r[2, 0] * ez,
                r[0, 1] * ex + r[1, 1] * ey + r[2, 1] * ez,
                r[0, 2] * ex + r[1, 2] * ey + r[2, 2] * ez)

    def radiance(self, dx, dy, dz, ray=None) -> np.ndarray:
        """(3, N) float32 radiance arriving from world directions d (unit). ray: the escaped rays' path
        state (interaction.RayInfo) for a world program's Light Path node; None for light samples."""
        n = len(dx)
        if self.shader is not None:
            return self.shader.radiance(dx, dy, dz, ray)
        if self.texture is None:
            return np.broadcast_to(self.constant, (3, n))
        u, v = direction_to_equirect(*self.to_env(dx, dy, dz))
        return self.texture.lookup(u, v, wrap_v=False) * self.strength


def cell_means(values: np.ndarray) -> np.ndarray:
    """(H, W) means over each texel's cell of the bilinear interpolation of (H, W) texel values (texel
    centres at (i + 1/2) / W, u wrapping, v clamped at the poles, as the lookups read them): the
    separable filter (1/8, 3/4, 1/8). Sampling a cell in proportion to the texel alone gave a dark texel
    beside a small bright one a tiny pdf while half its cell reads the bright one: fireflies."""
    out = 0.75 * values + 0.125 * (np.roll(values, 1, axis=1) + np.roll(values, -1, axis=1))
    up = np.concatenate([out[1:], out[-1:]])
    down = np.concatenate([out[:1], out[:-1]])
    return 0.75 * out + 0.125 * (up + down)


class _PixelDistribution:
    """Piecewise-constant distribution over an (H, W) map's cells in (u, v), row 0 at v = 0.

    Weights are the mean of |R|, |G|, |B| x sin(theta) at the row's centre, averaged over the cell as the
    bilinear lookup reads it (cell_means; filtered=False: the texel's own); rows are drawn from the
    marginal, columns from the row's conditional, and the point is uniform inside the cell.
    """

    def __init__(self, image: np.ndarray, filtered: bool = True):
        h, w = image.shape[:2]
        rgb = image[:, :, :3] if image.shape[2] >= 3 else np.repeat(image[:, :, :1], 3, axis=2)
        theta = (1.0 - (np.arange(h) + 0.5) / h) * np.pi
        # Cycles weighs its map by the average of |R|, |G|, |B| (scene/light.cpp background_cdf), not the
        # luminance: on the interior HDRI that gave 10% less variance.
        level = np.abs(rgb.astype(np.float64)).mean(axis=2)
        if filtered:
            level = cell_means(level)
        weight = level * np.sin(theta)[:, None]
        self.height, self.width = h, w
        row_sum = weight.sum(axis=1)
        total = row_sum.sum()
        # The map's mean luminance x sin(theta), for the world's share in light selection.
        self.mean_weight = float((np.maximum(luminance(rgb).astype(np.float64), 0.0) *
                                  np.sin(theta)[:, None]).mean())
        if total <= 0:  # a black map: fall back to uniform cells
            weight = np.ones((h, w)) * np.sin(theta)[:, None]
            row_sum = weight.sum(axis=1)
            total = row_sum.sum()
        self.row_pmf = row_sum / total
        self.row_cdf = np.cumsum(self.row_pmf)
        self.row_cdf /= self.row_cdf[-1]
        safe = np.where(row_sum > 0, row_sum, 1.0)
        self.col_pmf = weight / safe[:, None]
        col_cdf = np.cumsum(self.col_pmf, axis=1)
        col_cdf[row_sum > 0] /= col_cdf[row_sum > 0, -1:]
        # Offsetting row r's cdf by r makes one flat sorted array: one search for all rows.
        self.flat_cdf = (col_cdf + np.arange(h)[:, None]).ravel()
        self._rows = sampling.GuidedCdf(self.row_cdf, buckets=4 * h)
        self._cols = sampling.GuidedCdf(self.flat_cdf, segments=h)
        # pdf per unit (u, v) area of each cell: pmf * cells.
        self.cell_pdf = (self.row_pmf[:, None] * self.col_pmf * (h * w)).astype(np.float32).ravel()

    def sample(self, u1, u2):
        h, w = self.height, self.width
        row = np.minimum(self._rows.search(0, u1), h - 1)
        flat = self._cols.search(row, u2)
        col = np.clip(flat - row * w, 0, w - 1)
        # The position inside the cell reuses the remainders of both draws (stratified, no new numbers).
        row_lo = np.where(row > 0, self.row_cdf[np.maximum(row - 1, 0)], 0.0)
        row_p = self.row_pmf[row]
        fv = np.clip((u1 - row_lo) / np.where(row_p > 0, row_p, 1.0), 0.0, 1.0 - 1e-7)
        cell = row * w + col
        col_lo = np.where(col > 0, self.flat_cdf[np.maximum(cell - 1, 0)] - row, 0.0)
        col_p = self.col_pmf.ravel()[cell]
        fu = np.clip((u2 - col_lo) / np.where(col_p > 0, col_p, 1.0), 0.0, 1.0 - 1e-7)
        u = ((col + fu) / w).astype(np.float32)
        v = ((row + fv) / h).astype(np.float32)
        return u, v, self.cell_pdf[cell]

    def pdf(self, u, v) -> np.ndarray:
        col = np.clip((np.mod(u, 1.0) * self.width).astype(np.int64), 0, self.width - 1)
        row = np.clip((v * self.height).astype(np.int64), 0, self.height - 1)
        return self.cell_pdf[row * self.width + col]
