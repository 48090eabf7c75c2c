"""The world: constant radiance, an equirectangular HDRI looked up in Cycles' convention, or a node program.

Cycles' equirectangular map: u = 0.5 - atan2(d.y, d.x) / (2 pi), v = 1 - acos(d.z) / pi, with the
image's row 0 at the bottom (v = 0 looks straight down). d is the world direction taken to the
map's frame by env_from_world.
"""
from __future__ import annotations

import numpy as np

from . import sampling
from .scene import World
from .textures import BLOCK_TEXELS, Texture, luminance, sample_texture, srgb_to_linear
from .vec import F32, INV_2PI, INV_PI, ONE, PI, TWO_PI


def direction_to_equirect(dx, dy, dz):
    """World-frame unit direction components -> (u, v) in [0, 1]."""
    u = np.float32(0.5) - np.arctan2(dy, dx) * INV_2PI
    v = np.float32(1.0) - np.arccos(np.clip(dz, np.float32(-1.0), np.float32(1.0))) * INV_PI
    return u, v


def equirect_to_direction(u, v):
    """Inverse of direction_to_equirect. Returns dx, dy, dz and sin(theta)."""
    phi = (np.float32(0.5) - u) * TWO_PI
    theta = (np.float32(1.0) - v) * PI
    sin_t = np.sin(theta)
    return np.cos(phi) * sin_t, np.sin(phi) * sin_t, np.cos(theta), sin_t


class Environment:
    """World radiance for escaped rays, and importance sampling of the world as a light.

    A constant world is sampled uniformly over the sphere. An HDRI is sampled from a piecewise-constant
    distribution over its pixels, proportional to their level x sin(theta) (the area of a pixel on the
    sphere), so the pdf per solid angle is pdf_uv / (2 pi^2 sin(theta)).

    MIS compensation (Karlik et al. 2019, "MIS Compensation: Optimizing Sampling Techniques in Multiple
    Importance Sampling"): the map's levels are lowered by their mean over the sphere before the
    distribution is built, so light samples go only where the world is brighter than average and leave
    the rest to BSDF samples, which find a smooth world well. Every shading point that samples the world
    also sends a BSDF ray weighted against this same pdf, so the estimate stays unbiased; per sample it
    halved the variance of a matte room under interior.exr. Light samples of a compensated world and the BSDF
    rays that find it are weighted by the balance heuristic, which the method is derived for (mis_balance);
    the power heuristic otherwise. Cycles builds its map from the plain levels.
    Not for a world program with a Light Path node: its light samples and BSDF rays may see different
    radiance, and each technique must then keep the directions it had.
    """

    def __init__(self, world: World, shader=None):
        """shader: the world's node program (shading.world.WorldShader) when it has one; its radiance is
        evaluated per ray, and a bake of it at world.map_resolution is the sampling distribution."""
        self.world = world
        self.shader = shader
        # Whether the radiance depends on the ray that finds it (a world program with a Light Path node).
        self.varies_with_ray = shader is not None and any(op.kind == "ShaderNodeLightPath" for op in world.program.ops)
        self.texture = Texture(world.hdri, bool(world.hdri_srgb)) if world.hdri is not None and shader is None \
            else None
        if shader is not None:
            self.strength = np.float32(1.0)
            self.rotation = np.eye(3, dtype=np.float32)
            width = int(world.map_resolution)
            self._distribution = _BilinearDistribution(shader.bake(width, max(width // 2, 2)),
                                                       world.mis_compensation and not self.varies_with_ray)
        else:
            self.strength = np.float32(world.strength)
            self.rotation = np.asarray(world.env_from_world, np.float32)
            self._distribution = _BilinearDistribution(world.hdri, world.mis_compensation, bool(world.hdri_srgb)) \
                if world.hdri is not None else None
        self.constant = (np.asarray(world.color, np.float32) * self.strength)[:, None]
        # The MIS heuristic between light samples of the world and BSDF rays: the balance heuristic with a
        # compensated distribution (what compensation is derived for), else the power heuristic, as Cycles.
        self.mis_balance = self._distribution is not None and self._distribution.compensated

    def mean_luminance(self) -> float:
        """Radiance luminance averaged over the sphere of directions."""
        if self._distribution is None:
            return float(luminance(self.constant[:, 0]))
        # (1 / 4 pi) * sum(L sin(theta)) * (pi / H) * (2 pi / W) = (pi / 2) * mean(L sin(theta))
        return float(self._distribution.mean_weight * 0.5 * np.pi * self.strength)

    def cycles_average_radiance(self) -> float:
        """Cycles' average radiance of its background light's map (scene/light.cpp: cdf_total x pi / 2, the mean of
        the texels' average |R|, |G|, |B| x sin(theta)), for its light tree's measure of the world."""
        if self._distribution is None:
            return float(np.abs(self.constant[:, 0]).mean())
        return float(self._distribution.mean_average * 0.5 * np.pi * self.strength)

    @property
    def focuses(self) -> bool:
        """Whether light samples of the world can be focused on the shading points' glossy lobes (focus()). Not
        for a world program with a Light Path node: as with compensation, its light samples and BSDF rays may
        see different worlds, so the image depends on the MIS weights, which must stay Cycles'."""
        return self._distribution is not None and self.world.focus and not self.varies_with_ray

    def focus(self, dx, dy, dz, radius, share) -> "WorldFocus":
        """Blocks of the map around world directions d (unit, (n,) each): the patch rows and columns that
        hold the cone of angular radius `radius` (radians, below pi / 2) about d. A light sample of the world
        is then drawn from the block with probability `share` (0 where the block holds none of the
        distribution), else from the whole map (sample_direction, direction_pdf)."""
        dist = self._distribution
        h, w = dist.height, dist.width
        ex, ey, ez = self.to_env(dx, dy, dz)
        u, v = direction_to_equirect(ex, ey, ez)
        radius = np.asarray(radius, F32)
        dv = radius * INV_PI
        r0 = np.clip(np.floor((v - dv) * F32(h) + F32(0.5)), 0, h).astype(np.int64)
        r1 = np.clip(np.floor((v + dv) * F32(h) + F32(0.5)), 0, h).astype(np.int64) + 1
        # The cone's widest azimuth, asin(sin(radius) / sin(theta)) about its axis; all of it around a pole.
        sin_axis = np.sqrt(np.maximum(ONE - ez * ez, F32(0.0)))
        ratio = np.sin(radius) / np.maximum(sin_axis, F32(1e-6))
        du = np.arcsin(np.minimum(ratio, ONE)) * INV_2PI
        ca = np.floor((u - du) * F32(w) - F32(0.5)).astype(np.int64)
        nc = np.floor((u + du) * F32(w) - F32(0.5)).astype(np.int64) - ca + 1
        full = (ratio >= 1) | (nc >= w)
        c0 = np.where(full, 0, np.mod(ca, w))
        nc = np.where(full, w, nc)
        mass = dist.block_mass(r0, r1, c0, nc)
        live = mass > 1e-12
        p = np.where(live, np.asarray(share, F32), F32(0.0))
        inv_mass = np.where(live, 1.0 / np.where(live, mass, 1.0), 0.0)
        return WorldFocus(np.stack([r0, r1, c0, nc, p, inv_mass]).astype(F32))

    def sample_direction(self, u1, u2, focus: "WorldFocus | None" = None):
        """World directions with pdf per solid angle: (wx, wy, wz, pdf). focus (focus(), one per number):
        from its block with its probability, the pdf then that of the mixture."""
        if self._distribution is None:
            wx, wy, wz = sampling.sample_uniform_sphere(u1, u2)
            return wx, wy, wz, np.full(len(u1), sampling.UNIFORM_SPHERE_PDF)
        if focus is None:
            u, v, pdf_uv = self._distribution.sample(u1, u2)
        else:
            # u1 < p picks the block, and both halves are stretched back to [0, 1): no new number, and the
            # first vertex's stratification holds. Where p is 0 this is sample() bit for bit.
            p = focus.p
            block = np.flatnonzero(u1 < p)
            rest = np.flatnonzero(u1 >= p)
            u, v, pdf_uv = (np.empty(len(u1), F32) for _ in range(3))
            if len(rest):
                q = p[rest]
                ur = np.minimum((u1[rest] - q) / (ONE - q), F32(1.0 - 1e-7))
                u[rest], v[rest], pdf_uv[rest] = self._distribution.sample(ur, u2[rest])
            if len(block):
                f = focus.take(block)
                ub = np.minimum(u1[block] / f.p, F32(1.0 - 1e-7))
                u[block], v[block], pdf_uv[block] = self._distribution.sample_block(*f.block(), ub, u2[block])
            pdf_uv = pdf_uv * self._focus_factor(focus, u, v)
        ex, ey, ez, sin_t = equirect_to_direction(u, v)
        with np.errstate(divide="ignore", invalid="ignore"):
            pdf = pdf_uv / (np.float32(2.0 * np.pi ** 2) * sin_t)
        pdf = np.where((sin_t > 0) & np.isfinite(pdf), pdf, np.float32(0.0)).astype(np.float32)
        wx, wy, wz = self.to_world(ex, ey, ez)
        return wx, wy, wz, pdf

    def direction_pdf(self, dx, dy, dz, focus: "WorldFocus | None" = None) -> np.ndarray:
        """pdf per solid angle with which sample_direction() yields world directions d (with the same focus)."""
        if self._distribution is None:
            return np.full(len(dx), sampling.UNIFORM_SPHERE_PDF)
        ex, ey, ez = self.to_env(dx, dy, dz)
        u, v = direction_to_equirect(ex, ey, ez)
        sin_t = np.sqrt(np.maximum(np.float32(1.0) - ez * ez, np.float32(0.0)))
        pdf_uv = self._distribution.pdf(u, v)
        if focus is not None:
            pdf_uv = pdf_uv * self._focus_factor(focus, u, v)
        with np.errstate(divide="ignore", invalid="ignore"):
            pdf = pdf_uv / (np.float32(2.0 * np.pi ** 2) * sin_t)
        return np.where((sin_t > 0) & np.isfinite(pdf), pdf, np.float32(0.0)).astype(np.float32)

    def _focus_factor(self, focus: "WorldFocus", u, v) -> np.ndarray:
        """The mixture's pdf over the map's at (u, v): (1 - p) + p / mass inside the block, 1 - p outside."""
        factor = np.ones(len(u), F32)
        live = np.flatnonzero(focus.p > 0)
        if len(live):
            f = focus.take(live)
            r, c = self._distribution.patch_of(u[live], v[live])
            r0, r1, c0, nc = f.block()
            inside = (r >= r0) & (r < r1) & (np.mod(c - c0, self._distribution.width) < nc)
            factor[live] = (ONE - f.p) + f.p * np.where(inside, f.inv_mass, F32(0.0))
        return factor

    @property
    def is_constant(self) -> bool:
        return self._distribution is None

    @property
    def varies(self) -> bool:
        """Whether the radiance changes with direction (an HDRI, a program whose bake is not one colour)."""
        return self._distribution is not None and not self._distribution.uniform

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
        # As Cycles' Environment Texture: the node's interpolation, repeating in both directions, decoded after
        # filtering (svm_node_tex_environment, EnvironmentTextureNode::image_params).
        if self.world.hdri_interpolation == "Linear":   # Texture.lookup: the same taps, a fifth quicker
            return self.texture.lookup(u, v, wrap_v=True) * self.strength
        color = sample_texture(self.texture, u, v, self.world.hdri_interpolation, "REPEAT")
        if self.texture.srgb:
            color = srgb_to_linear(color)
        return color * self.strength


class WorldFocus:
    """Per shading point, a block of the world's map (patch rows [r0, r1), columns c0 .. c0 + nc - 1,
    wrapping) from which a light sample of the world is drawn with probability p, in proportion to the
    map's distribution there (inv_mass: 1 / the block's share of it); Environment.focus makes them. One
    (6, n) float32 array (the block's bounds are exact in it), so that paths take and compact it at once."""
    __slots__ = ("data",)

    def __init__(self, data: np.ndarray):
        self.data = data

    @classmethod
    def none(cls, n: int) -> "WorldFocus":
        return cls(np.zeros((6, n), F32))

    @property
    def p(self) -> np.ndarray:
        return self.data[4]

    @property
    def inv_mass(self) -> np.ndarray:
        return self.data[5]

    def block(self):
        """(r0, r1, c0, nc) int64 arrays."""
        return tuple(self.data[i].astype(np.int64) for i in range(4))

    def take(self, idx) -> "WorldFocus":
        return WorldFocus(np.take(self.data, idx, axis=1))

    def put(self, idx, other: "WorldFocus") -> None:
        self.data[:, idx] = other.data

    @staticmethod
    def concat(a: "WorldFocus", b: "WorldFocus") -> "WorldFocus":
        return WorldFocus(np.concatenate([a.data, b.data], axis=1))


def sample_linear(u: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x in [0, 1) with density proportional to (1 - x) a + x b (a, b >= 0), by inverting its cdf
    a x + (b - a) x^2 / 2 in the form that stays exact as a and b meet; u where both are 0."""
    root = np.sqrt((ONE - u) * a * a + u * b * b)
    den = a + root
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(den > 0, u * (a + b) / np.where(den > 0, den, ONE), u)
    return np.clip(x, F32(0.0), F32(1.0 - 1e-7))


class _BilinearDistribution:
    """An HDRI (or a world program's bake at texel centres) sampled in proportion to its bilinear lookup of
    linear texels (texel centres at (i + 1/2) / W, u wrapping, v clamped at the poles) x sin(theta) at the
    patch row's centre. Escaped rays read the Environment Texture as Cycles does (Environment.radiance: the
    node's interpolation, v repeating at the poles, an 8-bit sRGB image decoded after filtering), which the
    bilinear lookup of linear texels follows closely but not exactly: the pdf is still positive wherever that
    radiance is, so both estimates stay unbiased.

    The lookup is bilinear between neighbouring texel centres: the map splits into W x (H + 1) patches,
    with half-height rows at the poles where the lookup is constant in v. A patch is chosen in proportion
    to its integral (the mean of its four corners x its area x sin(theta)), through a marginal over patch
    rows and a conditional per row with guide tables; the point inside it is drawn from the bilinear
    density itself (marginal in v, then conditional in u, each linear and inverted exactly). So the pdf is
    the lookup's level x sin(theta_row) / total, proportional to what escaped rays read at every point.

    Cycles instead point-samples its map on a grid of at least 4096 x 2048 cells (scene/light.cpp). One
    cell per texel, uniform inside, weighted by the lookup's mean over it, left the floor under
    interior.exr's small bright windows 5x as noisy per sample as Cycles (a cell beside a window reads it
    bright on one side and dark on the other); this distribution is 0.9x Cycles' there.

    compensate: the levels less their mean over the sphere (weighted by sin(theta)), floored at 0, are the
    ones sampled (MIS compensation, Environment's docstring); a map with nothing above its mean (a
    constant one) keeps its levels.
    """

    def __init__(self, image: np.ndarray, compensate: bool = False, srgb: bool = False):
        """image: (H, W, C) float32 linear values, or a stored 8- or 16-bit image (kernels.textures.Texture; srgb:
        sRGB-encoded), decoded here a block of rows at a time."""
        h, w = image.shape[:2]
        theta = (1.0 - (np.arange(h) + 0.5) / h) * np.pi
        texture = Texture(image, srgb)
        level = np.empty((h, w), np.float32)
        lum_sum, first, self.uniform = 0.0, None, True
        rows = max(1, BLOCK_TEXELS // w)
        for y0 in range(0, h, rows):
            y1 = min(h, y0 + rows)
            rgb = texture.gather(np.arange(y0 * w, y1 * w))[:3]
            if texture.srgb:
                rgb = srgb_to_linear(rgb)
            rgb = rgb.reshape(3, y1 - y0, w)
            # The map's mean luminance x sin(theta), for the world's share in light selection.
            lum_sum += float((np.maximum(luminance(np.moveaxis(rgb, 0, -1)).astype(np.float64), 0.0)
                              * np.sin(theta[y0:y1])[:, None]).sum())
            # One colour in every direction: nothing for light samples to find that BSDF rays miss.
            first = rgb[:, :1, :1] if first is None else first
            self.uniform = self.uniform and bool((rgb == first).all())
            # Cycles weighs its map by the average of |R|, |G|, |B| (scene/light.cpp background_cdf).
            level[y0:y1] = np.abs(rgb).mean(axis=0)
        self.mean_weight = lum_sum / (h * w)
        # The map's mean of that average x sin(theta): Cycles' cdf_total (scene/light.cpp), for its light tree.
        self.mean_average = float((level.astype(np.float64) * np.sin(theta)[:, None]).sum() / (h * w))
        if not np.any(level > 0):  # a black map: sample uniformly in (u, v), weighted by sin(theta)
            level = np.ones((h, w), np.float32)
        self.compensated = False  # whether the levels were lowered (compensate, and something above the mean)
        if compensate:
            sin_theta = np.sin(theta)
            mean = float((level.astype(np.float64).sum(axis=1) * sin_theta).sum() / (sin_theta.sum() * w))
            lowered = np.maximum(level - np.float32(mean), np.float32(0.0))
            if np.any(lowered > 0):
                level, self.compensated = lowered, True
        self.height, self.width = h, w
        # Patch rows r = 0..H span v in [max(r - 1/2, 0), min(r + 1/2, H)] / H between texel rows
        # clip(r - 1, 0, H - 1) and clip(r, 0, H - 1); patch columns c span u in [c + 1/2, c + 3/2] / W.
        r = np.arange(h + 1)
        v0, v1 = np.maximum(r - 0.5, 0.0) / h, np.minimum(r + 0.5, h) / h
        sin_row = np.sin((1.0 - (v0 + v1) / 2) * np.pi)
        lo, hi = np.clip(r - 1, 0, h - 1), np.clip(r, 0, h - 1)
        lv = level.astype(np.float64)
        corners = lv[lo] + np.roll(lv[lo], -1, axis=1) + lv[hi] + np.roll(lv[hi], -1, axis=1)
        weight = corners * (0.25 * (v1 - v0) / w * sin_row)[:, None]   # (H + 1, W)
        row_sum = weight.sum(axis=1)
        total = row_sum.sum()
        self.row_pmf = row_sum / total
        self.row_cdf = np.cumsum(self.row_pmf)
        self.row_cdf /= self.row_cdf[-1]
        cdf = np.cumsum(weight, axis=1)
        live = row_sum > 0
        cdf[live] /= cdf[live, -1:]
        cdf += np.arange(h + 1, dtype=np.float64)[:, None]
        self.flat_cdf = cdf.ravel()
        self._rows = sampling.GuidedCdf(self.row_cdf, buckets=4 * (h + 1))
        self._cols = sampling.GuidedCdf(self.flat_cdf, segments=h + 1)
        # Per patch row: the flat offsets of its two texel rows, its v range, sin(theta) / total.
        self._lv = np.ascontiguousarray(level, np.float32).ravel()
        self._base_lo, self._base_hi = lo * w, hi * w
        self._v0, self._dv = v0.astype(F32), (v1 - v0).astype(F32)
        self._scale = (sin_row / total).astype(F32)
        # Sums of the patch weights over the rows before r and the columns before c, over the total:
        # the mass of any block of patches from four lookups.
        sat = np.zeros((h + 2, w + 1))
        sat[1:, 1:] = np.cumsum(np.cumsum(weight, axis=0), axis=1) / total
        self._sat = sat.ravel()

    def _corners(self, r, c):
        """The four texel levels (float32) of patches (r, c)."""
        c1 = c + 1
        c1[c1 == self.width] = 0
        lo, hi = np.take(self._base_lo, r), np.take(self._base_hi, r)
        lv = self._lv
        return np.take(lv, lo + c), np.take(lv, lo + c1), np.take(lv, hi + c), np.take(lv, hi + c1)

    def sample(self, u1, u2):
        h, w = self.height, self.width
        r = np.minimum(self._rows.search(0, u1), h)
        flat = self._cols.search(r, u2)
        c = np.clip(flat - r * w, 0, w - 1)
        # The remainders of both draws place the point inside the patch (stratified, no new numbers).
        row_lo = np.where(r > 0, self.row_cdf[np.maximum(r - 1, 0)], 0.0)
        row_p = self.row_pmf[r]
        fv = np.clip((u1 - row_lo) / np.where(row_p > 0, row_p, 1.0), 0.0, 1.0 - 1e-7).astype(F32)
        cell = r * w + c
        col_lo = np.where(c > 0, self.flat_cdf[np.maximum(cell - 1, 0)] - r, 0.0)
        col_p = (self.flat_cdf[cell] - r) - col_lo
        fu = np.clip((u2 - col_lo) / np.where(col_p > 0, col_p, 1.0), 0.0, 1.0 - 1e-7).astype(F32)
        return self._place(r, c, fv, fu)

    def _place(self, r, c, fv, fu):
        """(u, v, pdf per unit (u, v) area) of points drawn inside patches (r, c) from the bilinear density,
        with the numbers fv, fu in [0, 1)."""
        w = self.width
        w00, w10, w01, w11 = self._corners(r, c)
        y = sample_linear(fv, w00 + w10, w01 + w11)
        left, right = w00 + (w01 - w00) * y, w10 + (w11 - w10) * y
        x = sample_linear(fu, left, right)
        u = (c + F32(0.5) + x) * F32(1.0 / w)
        u = np.where(u >= 1, u - F32(1.0), u).astype(F32)
        v = (np.take(self._v0, r) + y * np.take(self._dv, r)).astype(F32)
        return u, v, (left + (right - left) * x) * np.take(self._scale, r)

    # ---- blocks: a rectangle of patches, rows [r0, r1) and columns c0 .. c0 + nc - 1 (wrapping in u)
    def patch_of(self, u, v):
        """(patch row, patch column) holding (u, v), as pdf() finds them."""
        h, w = self.height, self.width
        c = np.floor(np.mod(np.asarray(u, F32), F32(1.0)) * F32(w) - F32(0.5)).astype(np.int64)
        c[c < 0] += w
        y = np.clip(np.asarray(v, F32), F32(0.0), F32(1.0)) * F32(h) - F32(0.5)
        return np.minimum(np.floor(y).astype(np.int64) + 1, h), np.minimum(c, w - 1)

    def block_mass(self, r0, r1, c0, nc):
        """The distribution's mass in the blocks (float64)."""
        cols = self._block_columns(c0, nc)
        return self._above(r1, cols) - self._above(r0, cols)

    def _block_columns(self, c0, nc):
        """Offsets in the sums' rows of a block's column span: its end (or the map's), its start, and its end
        past the wrap (0 when it does not wrap: column 0 of the sums is 0)."""
        end = c0 + nc
        return np.minimum(end, self.width), c0, np.maximum(end - self.width, 0)

    def _above(self, r, cols):
        """The mass in patch rows < r of a block's columns (_block_columns)."""
        base = r * (self.width + 1)
        end, start, wrapped = cols
        sat = self._sat
        return np.take(sat, base + end) - np.take(sat, base + start) + np.take(sat, base + wrapped)

    def sample_block(self, r0, r1, c0, nc, u1, u2):
        """Points drawn from the distribution restricted to the blocks (each with some of its mass): the
        patch row by bisection on the block's row masses, the column by the row's own cdf over the block's
        span, the point inside as sample() does. Returns u, v and the global pdf per unit (u, v) area there
        (the block's pdf is that over block_mass)."""
        w = self.width
        cols = self._block_columns(c0, nc)
        top = self._above(r0, cols)
        t = top + u1.astype(np.float64) * (self._above(r1, cols) - top)
        # The last row r with the mass above it <= t: lo keeps that property, hi the opposite.
        lo, hi = r0, r1
        for _ in range(int(np.max(r1 - r0)).bit_length()):
            mid = (lo + hi) >> 1
            below = self._above(mid, cols) <= t
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        r = lo
        before = self._above(r, cols)
        row_mass = self._above(r + 1, cols) - before
        fv = np.clip((t - before) / np.where(row_mass > 0, row_mass, 1.0), 0.0, 1.0 - 1e-7).astype(F32)
        # The row's own cdf (flat_cdf less r) over the block's columns, wrapping past the last one.
        cdf = self.flat_cdf
        base = r * w

        def row_cdf(c):  # the row's cdf just before column c, c in [0, w]
            return np.where(c > 0, np.take(cdf, base + np.maximum(c, 1) - 1) - r, 0.0)
        end = c0 + nc
        start = row_cdf(c0)
        span = row_cdf(np.minimum(end, w)) - start + np.where(end > w, row_cdf(np.maximum(end - w, 0)), 0.0)
        x = start + u2.astype(np.float64) * span
        x = np.where(x >= 1.0, x - 1.0, x)
        flat = self._cols.search(r, np.minimum(x, np.nextafter(1.0, 0.0)))
        c = np.clip(flat - base, 0, w - 1)
        col_lo = row_cdf(c)
        col_p = row_cdf(c + 1) - col_lo
        fu = np.clip((x - col_lo) / np.where(col_p > 0, col_p, 1.0), 0.0, 1.0 - 1e-7).astype(F32)
        return self._place(r, c, fv, fu)

    def pdf(self, u, v) -> np.ndarray:
        """pdf per unit (u, v) area: the bilinear level at (u, v) x sin(theta) of its patch row / total."""
        h, w = self.height, self.width
        x = np.mod(np.asarray(u, F32), F32(1.0)) * F32(w) - F32(0.5)
        x0 = np.floor(x)
        fx = x - x0
        c = x0.astype(np.int64)
        c[c < 0] += w
        y = np.clip(np.asarray(v, F32), F32(0.0), F32(1.0)) * F32(h) - F32(0.5)
        y0 = np.floor(y)
        fy = y - y0
        r = np.minimum(y0.astype(np.int64) + 1, h)   # patch row; at the poles both texel rows are the same
        w00, w10, w01, w11 = self._corners(r, c)
        top = w00 + (w10 - w00) * fx
        bottom = w01 + (w11 - w01) * fx
        return (top + (bottom - top) * fy) * np.take(self._scale, r)
