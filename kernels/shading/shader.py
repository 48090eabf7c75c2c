"""Evaluating materials over a wave's hits: inputs as arrays, then each closure node's closures."""
from __future__ import annotations

import numpy as np

from ..bsdf.closures import ClosureBuilder, ClosureSet
from ..scene import Closure, Materials, Param
from ..textures import Texture, finite_uv, luminance
from . import nodes

F32 = np.float32


class SurfaceShading:
    """What the materials make of N hits.

    closures : the BSDF mixture (None when only emission was asked for).
    emission : (3, N) float32 radiance emitted toward the viewer (both sides, as in Cycles).
    holdout : (N,) float32 weight of Holdout closures (the share of the hit that cuts a hole in alpha).
    """
    __slots__ = ("closures", "emission", "holdout")

    def __init__(self, closures: ClosureSet | None, emission: np.ndarray, holdout: np.ndarray):
        self.closures, self.emission, self.holdout = closures, emission, holdout


class Shading:
    """The scene's shaders, ready to be evaluated at hits."""

    def __init__(self, materials: Materials, textures: list[Texture]):
        self.shaders = materials.shaders
        self.textures = textures
        self.emissive = np.array([_may_emit(s.closures) for s in self.shaders], bool)
        # Emission that depends on more than the material: a texture, or layers above it (Principled).
        self.emission_varies = np.array([_emission_varies(s.closures) for s in self.shaders], bool)
        self.transparent = np.array([any(nodes.may_be_transparent(c) for c in s.closures) for s in self.shaders],
                                    bool)
        self.has_holdout = any(c.kind == "HOLDOUT" for s in self.shaders for c in s.closures)
        # Whether any hit has more than one lobe to choose from (a Principled BSDF, a Mix, a delta lobe).
        self.mixes_lobes = any(_mixes_lobes(s.closures) for s in self.shaders)
        self.needs_uv = any(p.texture >= 0 for s in self.shaders for c in s.closures for p in c.params())
        # Per texture: mean R, G, B and alpha over the image (alpha 1 for images without one).
        self._texture_means = [np.append(t.channels.mean(axis=1), t.alpha.mean() if t.alpha is not None else 1.0)
                               .astype(F32) for t in textures]

    # ---------------------------------------------------------------- per wave
    def surface(self, hit, closures: bool = True) -> SurfaceShading:
        """Evaluate every hit's material (hit: interaction.SurfaceHit)."""
        n = len(hit)
        wo = tuple(-c for c in hit.d)
        builder = ClosureBuilder(n, hit.ns, wo) if closures else None
        emission = np.zeros((3, n), F32)
        holdout = np.zeros(n, F32)
        for m, idx in _by_material(hit.mat):
            ctx = nodes.Context(self, hit, idx, wo)
            for closure in self.shaders[m].closures:
                weight = self._mix_weight(closure, ctx)
                out = nodes.build(closure, ctx, weight, builder)
                if out.emission is not None:
                    emission[:, idx] += out.emission
                if out.holdout is not None:
                    holdout[idx] += out.holdout
        return SurfaceShading(builder.finish() if closures else None, emission, holdout)

    def transparency(self, hit) -> np.ndarray:
        """(3, N) float32: the share of light that passes straight through each hit (transparent
        shadows): the sum of its Transparent closures, Principled alpha included."""
        n = len(hit)
        wo = tuple(-c for c in hit.d)
        out = np.zeros((3, n), F32)
        for m, idx in _by_material(hit.mat):
            if not self.transparent[m]:
                continue
            ctx = nodes.Context(self, hit, idx, wo)
            for closure in self.shaders[m].closures:
                if nodes.may_be_transparent(closure):
                    out[:, idx] += nodes.transparency(closure, ctx, self._mix_weight(closure, ctx))
        return out

    def mean_emission(self, mat: np.ndarray) -> np.ndarray:
        """(3, n) emitted radiance of materials mat, textures averaged over the image and layers taken
        at normal incidence: an estimate of an emitter's power, for light selection."""
        out = np.zeros((3, len(mat)), F32)
        for m, idx in _by_material(mat):
            for closure in self.shaders[m].closures:
                value = nodes.mean_emission(closure, self._mean_param)
                if value is not None:
                    out[:, idx] += np.asarray(value, F32)[:, None] * self._mean_factor(closure)
        return out

    # ---------------------------------------------------------------- inputs
    def param(self, p: Param, ctx, channels: int) -> np.ndarray:
        """A Param at the context's hits: (n,) for channels 1, (3, n) for 3. A colour feeding a float
        input becomes its luminance; a float feeding a colour input is grey, as Blender converts them."""
        n = len(ctx.idx)
        value = _as_channels(np.asarray(p.value, F32), channels)[:, None]
        if p.texture >= 0:
            tex = self.textures[p.texture]
            u, v = finite_uv(ctx.take(ctx.hit.u), ctx.take(ctx.hit.v))
            looked = tex.lookup_alpha(u, v)[None] if p.alpha else tex.lookup(u, v, unassociate=p.unassociate)
            value = value * _as_channels(looked, channels)
        else:
            value = np.broadcast_to(value, (channels, n))
        return np.ascontiguousarray(value[0] if channels == 1 else value, F32)

    def _mean_param(self, p: Param, channels: int) -> np.ndarray:
        """A Param's value averaged over its texture: (channels,)."""
        value = _as_channels(np.asarray(p.value, F32), channels)
        if p.texture >= 0:
            mean = self._texture_means[p.texture]
            value = value * _as_channels(mean[3:4] if p.alpha else mean[:3], channels)
        return value

    def _mix_weight(self, closure: Closure, ctx) -> np.ndarray:
        """(n,) product of the Mix Shader factors above the closure."""
        weight = np.ones(len(ctx.idx), F32)
        for p, second in closure.factors:
            fac = np.clip(self.param(p, ctx, 1), 0.0, 1.0)
            weight = weight * (fac if second else F32(1.0) - fac)
        return weight

    def _mean_factor(self, closure: Closure) -> float:
        weight = 1.0
        for p, second in closure.factors:
            fac = float(np.clip(self._mean_param(p, 1)[0], 0.0, 1.0))
            weight *= fac if second else 1.0 - fac
        return weight


def _by_material(mat: np.ndarray):
    """(material, hit indices) for every material present, indices ascending."""
    if len(mat) == 0:
        return
    order = np.argsort(mat, kind="stable")
    sorted_mat = mat[order]
    cuts = np.flatnonzero(np.diff(sorted_mat)) + 1
    for chunk in np.split(order, cuts):
        yield int(mat[chunk[0]]), chunk


def _as_channels(value: np.ndarray, channels: int) -> np.ndarray:
    """(1 or 3, ...) values as `channels` rows: luminance for colour -> float, grey for float -> colour."""
    if len(value) == channels:
        return value
    if channels == 1:
        return luminance(np.moveaxis(value, 0, -1))[None].astype(F32)
    return np.repeat(value[:1], 3, axis=0)


def _mixes_lobes(closures) -> bool:
    bsdfs = [c for c in closures if c.kind not in ("EMISSION", "HOLDOUT")]
    return len(bsdfs) > 1 or any(c.kind != "DIFFUSE" for c in bsdfs)


def _may_emit(closures) -> bool:
    return any(nodes.may_emit(c) for c in closures)


def _emission_varies(closures) -> bool:
    return any(nodes.may_emit(c) and nodes.emission_varies(c) for c in closures)
