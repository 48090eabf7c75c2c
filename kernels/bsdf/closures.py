"""The closure mixture of a wave's hits: every BSDF closure of every hit in one flat table, evaluated and
sampled as one weighted sum per hit, the way Cycles does (`kernel/integrator/surface_shader.h`).

A hit's material makes a few closures, each with an RGB weight and a scalar sample weight (the mean of
its weight, times an albedo estimate for microfacet lobes). Then, per hit:

    f(wi)   = sum_j weight_j * f_j(wi) |cos|                (delta lobes contribute nothing)
    pdf(wi) = sum_j sample_weight_j * pdf_j(wi) / sum_j sample_weight_j

This module builds the table (ClosureBuilder, ClosureSet) and answers what is asked of it as a whole; the
mixture is evaluated in mixture_eval, sampled in mixture_sample (one closure picked by its sample weight,
one-sample MIS over the lobes), and a closure on another normal than its hit's shading normal takes the
bump shadowing term of bump.py. light_passes and focus read the table for the passes and for world focus
sampling.

The table is sorted by hit; lobes of one kind are evaluated together, in their local frames (z along the
closure's own normal: shading, coat or bump-mapped; x along its tangent for anisotropic lobes).
"""
from __future__ import annotations

import numpy as np

from .. import sampling
from ..vec import F32
from . import frames
from .bump import BumpShadowing
from .light_passes import weight_albedo
from .lobes import (ASHIKHMIN_SHIRLEY, DIFFUSE_LABEL_LOBES, GLASS, HAIR_CHIANG, HAIR_HUANG, LAMBERT, MICROFACET_LOBES,
                    REFLECTION, REFRACTION, SELF_EVALUATED, SINGULAR_LOBES, TRANSMITTING_LOBES, TRANSPARENT)
from .mixture_eval import average_roughness_squared, eval_at
from .mixture_sample import BsdfSample, pick_closures, sample
from .registry import LOBES

# Cycles drops closures whose sample weight is below this (`CLOSURE_WEIGHT_CUTOFF`).
WEIGHT_CUTOFF = np.float32(1e-5)

# Per-closure parameter columns and their defaults: scalars (C,) and colours (3, C).
# soften: 1 where a diffuse closure on another normal takes the shadowing term's softening (Cycles skips
# it when the material turns Bump Map Correction off). dist: a microfacet lobe's distribution (0 GGX,
# 1 Beckmann: microfacet.GGX / BECKMANN). size, smooth: a toon closure's angles (toon.toon_angles).
# origin, direction: where a Ray Portal sends the ray on, world space (origin NaN: from the hit itself).
# r1, r2, offset, hair_t: a hair closure's roughnesses, highlight shift and unit tangent (world space).
# film_t, film_ior: a microfacet closure's thin film, thickness in nm and IOR (0: none).
# hair_v, hair_s, hair_m0, hair_h, aspect, coverage: a Principled Hair closure's longitudinal variance, logistic
# scale, R variance, offset across the strand, aspect ratio and pixel coverage (hair_chiang, hair_huang).
# on_curve: 1 for a closure of a hit on a curve, which takes no bump shadowing term (Cycles' bump_shadowing_term).
_SCALARS = {"ax": 0.0, "ay": 0.0, "eta": 1.0, "rough": 0.0, "eval_scale": 1.0, "fresnel": 0.0, "soften": 1.0,
            "dist": 0.0, "size": 0.0, "smooth": 0.0, "r1": 1.0, "r2": 1.0, "offset": 0.0, "film_t": 0.0,
            "film_ior": 0.0, "hair_v": 1.0, "hair_s": 1.0, "hair_m0": 1.0, "hair_h": 0.0, "aspect": 1.0,
            "coverage": 1.0, "on_curve": 0.0}
_COLOURS = {"c0": 0.0, "c1": 0.0, "c2": 0.0, "origin": np.nan, "direction": 0.0, "hair_t": 0.0}


class ClosureBuilder:
    """Collects the closures of a wave's hits; finish() makes the ClosureSet."""

    def __init__(self, n_hits: int, ns, wo):
        self.n_hits = n_hits
        self.ns = ns   # the hits' shading normals, the default closure normal
        self.wo = wo   # toward the viewer, per hit
        self._chunks: list[dict] = []

    def add(self, lobe: int, hits: np.ndarray, weight: np.ndarray, sample_weight=None, normal=None,
            tangent=None, albedo=None, **params) -> None:
        """Closures of one lobe at hits (n,) int with weight (3, n). sample_weight defaults to the
        mean of the weight; normal to the shading normal; tangent to an arbitrary one. albedo: (reflection,
        transmission) (3, n) each, Cycles' bsdf_albedo (the weight times the lobe's estimated albedo, in
        colour) for closures whose colour is not all in their weight (a metal's Fresnel, glass's tints);
        by default the weight times the sample weight over the weight's mean, all reflection. params: the
        scalar and colour columns above, arrays of (n,) / (3, n) or constants."""
        n = len(hits)
        if n == 0:
            return
        unknown = set(params) - set(_SCALARS) - set(_COLOURS)
        if unknown:
            raise TypeError(f"unknown closure parameters {sorted(unknown)}")
        weight = np.broadcast_to(np.asarray(weight, F32), (3, n))
        sw = np.abs(sampling.channel_mean(weight)) if sample_weight is None else np.broadcast_to(
            np.asarray(sample_weight, F32), (n,))
        keep = sw >= WEIGHT_CUTOFF
        if keep.all():
            keep = slice(None)
        elif not keep.any():
            return
        else:
            keep = np.flatnonzero(keep)
        chunk = {"hit": np.asarray(hits)[keep], "lobe": lobe, "weight": weight[:, keep],
                 "sw": np.asarray(sw[keep], F32)}
        chunk["n"] = None if normal is None else np.stack([np.broadcast_to(c, (n,))[keep] for c in normal])
        chunk["t"] = None if tangent is None else np.stack([np.broadcast_to(c, (n,))[keep] for c in tangent])
        for name, value in params.items():
            shape = (3, n) if name in _COLOURS else (n,)
            chunk[name] = np.broadcast_to(np.asarray(value, F32), shape)[..., keep]
        if albedo is not None:
            chunk["albedo"] = tuple(np.broadcast_to(np.asarray(a, F32), (3, n))[:, keep] for a in albedo)
        self._chunks.append(chunk)

    def finish(self) -> "ClosureSet":
        return ClosureSet(self.n_hits, self._chunks, self.ns, self.wo)


class ClosureSet:
    """C closures over N hits. See the module docstring for the mixture.

    When every hit has exactly one closure (a diffuse scene, a single BSDF node per material) the table
    stays in build order and row_of_hit maps hits to rows; otherwise it is sorted by hit, and start
    gives each hit's first row."""

    def __init__(self, n_hits: int, chunks: list[dict], ns, wo):
        self.n_hits = n_hits
        hit = np.concatenate([c["hit"] for c in chunks]) if chunks else np.zeros(0, np.int64)
        c = len(hit)
        # Every add() is over distinct hits: one chunk is one closure per hit at most.
        count = None if len(chunks) <= 1 else np.bincount(hit, minlength=n_hits)
        self.single = count is None or (c == n_hits and (c == 0 or count.max() == 1))
        order = None if self.single else np.argsort(hit, kind="stable")
        cat = (lambda parts: _concat(parts, order))  # noqa: E731
        self.hit = hit if order is None else hit[order]
        self.lobe = cat([np.full(len(ch["hit"]), ch["lobe"], np.int8) for ch in chunks]) if chunks else \
            np.zeros(0, np.int8)
        self.weight = cat([ch["weight"] for ch in chunks]) if chunks else np.zeros((3, 0), F32)
        self.sw = cat([ch["sw"] for ch in chunks]) if chunks else np.zeros(0, F32)
        # The closures' own colour albedos, made when the passes ask (the albedo property).
        self._given_albedo = ([(ch.get("albedo"), len(ch["hit"])) for ch in chunks], order) \
            if any("albedo" in ch for ch in chunks) else None
        self._albedo = None
        for name, default in (*_SCALARS.items(), *_COLOURS.items()):
            shape = (3,) if name in _COLOURS else ()
            if any(name in ch for ch in chunks):
                parts = [ch[name] if name in ch else
                         np.full(shape + (len(ch["hit"]),), default, F32) for ch in chunks]
                setattr(self, name, cat(parts))
            else:
                setattr(self, name, np.broadcast_to(F32(default), shape + (c,)))
        # (N,) float32 per hit, Cycles' shadow terminator frequency multiplier 1 / (1 - shading offset / 2) of the
        # hit's object (mixture_eval.terminator_shift), or None when no hit's object has a Shading Offset.
        self.terminator = None
        self.bump = None  # BumpShadowing when some closure's normal is not its hit's shading normal
        if any(ch["n"] is not None for ch in chunks):
            normal = cat([ch["n"] if ch["n"] is not None else np.stack([np.take(a, ch["hit"]) for a in ns])
                          for ch in chunks])
            shading = np.stack([np.take(a, self.hit) for a in ns])
            self.bump = BumpShadowing.of(normal, shading, self.lobe, self.on_curve > 0)
        else:
            normal = np.stack([np.take(a, self.hit) for a in ns]) if c else np.zeros((3, 0), F32)
        tangent = cat([ch["t"] if ch["t"] is not None else np.full((3, len(ch["hit"])), np.nan, F32)
                       for ch in chunks]) if any(ch["t"] is not None for ch in chunks) else None
        if self.single:
            self.total_sw = np.zeros(n_hits, F32)
            self.total_sw[self.hit] = self.sw
            self.row_of_hit = np.full(n_hits, -1, np.int64)
            self.row_of_hit[self.hit] = np.arange(c)
        else:
            self.total_sw = np.bincount(self.hit, self.sw, minlength=n_hits).astype(F32)
            self.start = np.searchsorted(self.hit, np.arange(n_hits))
            self.count = count
        self.normal = normal.astype(F32, copy=False)
        self._tangent = tangent
        self.wo_world = wo   # toward the viewer, per hit, world space
        self._frame = self._wo = None
        self.kinds = sorted({int(ch["lobe"]) for ch in chunks})
        self.self_evaluated = any(k in SELF_EVALUATED for k in self.kinds)
        self.delta = self._delta_mask()
        # Lambert alone is evaluated in world space, without frames (the common case of diffuse scenes).
        self.lambert_only = self.kinds == [LAMBERT] and self.bump is None

    def __len__(self) -> int:
        return len(self.hit)

    @property
    def albedo(self):
        """(reflection, transmission) (3, C) colour albedos, where some closure gave its own (add(albedo=)),
        the others' from their weight and sample weight (all reflection); None when none gave one (the
        weights then carry every closure's colour). Made on first use: only passes read it."""
        if self._given_albedo is None:
            return None
        if self._albedo is None:
            parts, order = self._given_albedo
            reflect = _concat([g[0] if g is not None else np.full((3, n), np.nan, F32) for g, n in parts], order)
            transmit = _concat([g[1] if g is not None else np.zeros((3, n), F32) for g, n in parts], order)
            missing = np.flatnonzero(np.isnan(reflect[0]))
            if len(missing):
                reflect[:, missing] = weight_albedo(self.weight[:, missing], self.sw[missing])
            self._albedo = (reflect, transmit)
        return self._albedo

    @property
    def frame(self):
        """(tangent, bitangent, normal) rows of every closure, each (3, C), made on first use."""
        if self._frame is None:
            self._frame = frames.frames(self.normal, self._tangent)
        return self._frame

    @property
    def wo(self):
        """The viewer direction in every closure's local frame."""
        if self._wo is None:
            self._wo = frames.to_local(self.frame, tuple(np.take(a, self.hit) for a in self.wo_world))
        return self._wo

    def blur(self, roughness: np.ndarray) -> None:
        """Cycles' Filter Glossy (bsdf_blur): every microfacet and Ashikhmin-Shirley closure's alphas raised
        to at least `roughness` (n_hits,) of its hit; what was set up from the old alphas (Fresnel, energy
        compensation) stays, as in Cycles. A sharp closure made rough is no longer delta."""
        micro = np.isin(self.lobe, (REFLECTION, REFRACTION, GLASS, ASHIKHMIN_SHIRLEY))
        if HAIR_CHIANG in self.kinds or HAIR_HUANG in self.kinds:
            self._blur_hair(np.take(roughness, self.hit))
        if not micro.any():
            return
        r = np.take(roughness, self.hit)
        self.ax = np.where(micro, np.maximum(self.ax, r), self.ax).astype(F32)
        self.ay = np.where(micro, np.maximum(self.ay, r), self.ay).astype(F32)
        self.delta = self._delta_mask()

    def _blur_hair(self, r: np.ndarray) -> None:
        """Cycles' bsdf_hair_chiang_blur and bsdf_hair_huang_blur: the mapped variances and scale (Chiang) or the
        roughness (Huang) raised to at least r."""
        chiang, huang = self.lobe == HAIR_CHIANG, self.lobe == HAIR_HUANG
        for name in ("hair_v", "hair_s", "hair_m0"):
            setattr(self, name, np.where(chiang, np.maximum(getattr(self, name), r), getattr(self, name)).astype(F32))
        self.rough = np.where(huang, np.maximum(self.rough, r), self.rough).astype(F32)

    def without(self, drop: np.ndarray, ns) -> "ClosureSet":
        """A new set of the closures not in the (C,) mask drop, columns and all (ns: the hits' shading normals,
        as the builder had them); what a bake leaves out of its first hits (kernels/bake.py)."""
        keep = np.flatnonzero(~np.asarray(drop, bool))
        albedo = self.albedo
        chunks = []
        for lobe in np.unique(self.lobe[keep]):
            rows = keep[self.lobe[keep] == lobe]
            chunk = {"hit": self.hit[rows], "lobe": int(lobe), "weight": self.weight[:, rows], "sw": self.sw[rows],
                     "n": self.normal[:, rows], "t": None if self._tangent is None else self._tangent[:, rows]}
            for name in _SCALARS:
                chunk[name] = np.broadcast_to(getattr(self, name), self.lobe.shape)[rows]
            for name in _COLOURS:
                chunk[name] = np.broadcast_to(getattr(self, name), (3,) + self.lobe.shape)[:, rows]
            if albedo is not None:
                chunk["albedo"] = (albedo[0][:, rows], albedo[1][:, rows])
            chunks.append(chunk)
        out = ClosureSet(self.n_hits, chunks, ns, self.wo_world)
        out.terminator = self.terminator
        return out

    def transparent_only(self, rows: np.ndarray, ns) -> tuple["ClosureSet", np.ndarray]:
        """(the set with only the Transparent closures left at the hits rows (N,) bool, every other hit as it is;
        (3, N) float32 the weights of each hit's Transparent closures): what a holdout object keeps of its material
        (Cycles' surface_shader_apply_holdout). ns: the hits' shading normals."""
        kept = self.lobe == TRANSPARENT
        passed = np.zeros((3, self.n_hits), F32)
        np.add.at(passed, (slice(None), self.hit[kept]), self.weight[:, kept])
        return self.without(np.take(rows, self.hit) & ~kept, ns), passed

    def evaluable(self) -> np.ndarray:
        """(N,) bool: hits with a closure that eval_at can find non-zero, one that is not singular (delta,
        transparent included). eval_at is zero at every other hit (none, or singular closures only), so
        next-event estimation skips them, as Cycles skips light sampling at a shader without
        SD_BSDF_HAS_EVAL. Call after blur(), which can make singular closures rough."""
        live = ~self.delta
        if self.single:
            return (self.row_of_hit >= 0) & np.take(live, np.maximum(self.row_of_hit, 0)) if len(live) else \
                np.zeros(self.n_hits, bool)
        return np.bincount(self.hit, live, minlength=self.n_hits) > 0

    def transmits(self) -> np.ndarray:
        """(N,) bool: hits with a closure that takes light from behind the surface (Cycles'
        SD_BSDF_HAS_TRANSMISSION)."""
        through = np.isin(self.lobe, TRANSMITTING_LOBES)
        if self.single:
            return (self.row_of_hit >= 0) & np.take(through, np.maximum(self.row_of_hit, 0)) if len(through) else \
                np.zeros(self.n_hits, bool)
        return np.bincount(self.hit, through, minlength=self.n_hits) > 0

    def _delta_mask(self) -> np.ndarray:
        delta = np.isin(self.lobe, SINGULAR_LOBES)
        singular = [k for k in (REFLECTION, REFRACTION, GLASS) if k in self.kinds]
        if singular:
            micro = np.isin(self.lobe, singular)
            delta |= micro & _is_singular(self.ax, self.ay)
        if ASHIKHMIN_SHIRLEY in self.kinds:
            # Cycles' Ashikhmin-Shirley is a mirror at max(alpha) <= 1e-4 (its setup clamps alpha there).
            delta |= (self.lobe == ASHIKHMIN_SHIRLEY) & (np.maximum(self.ax, self.ay) <= F32(1e-4))
        return delta

    # ---------------------------------------------------------------- the mixture (mixture_eval, mixture_sample)
    def eval_at(self, hits: np.ndarray, wi) -> tuple[np.ndarray, np.ndarray]:
        """The mixture of the hits `hits` (ascending, unique) at their world directions wi (n,): f |cos| (3, n)
        and pdf (n,) (mixture_eval.eval_at)."""
        return eval_at(self, hits, wi)

    def choose(self, u: np.ndarray) -> np.ndarray:
        """One closure per hit, in proportion to the sample weights: (N,) row, -1 where a hit has none."""
        return pick_closures(self, u, rescale=False)[0]

    def choose_rescaled(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """choose(u), and u stretched back to [0, 1) over the chosen closure's share of the interval, as Cycles
        picks a closure with a number of the direction's own stratified sequence and rescales it: the number
        then samples the closure's direction, and (closure, direction) are stratified together instead of
        by two independent sequences (a Principled BSDF's diffuse and specular pair under a grey sky: a fifth
        of the per-sample variance)."""
        return pick_closures(self, u, rescale=True)

    def sample(self, u_lobe, u1, u2, uc, warp=None) -> BsdfSample:
        """A direction per hit from the mixture: mixture_sample.sample, which says what the arguments are."""
        return sample(self, u_lobe, u1, u2, uc, warp)

    def average_roughness_squared(self, hits: np.ndarray, wi) -> np.ndarray:
        """(n,) float32 the roughness squared of the hits `hits` (ascending, unique) toward world directions wi, their
        closures' specular_roughness_squared averaged with weights pdf x sample weight (Cycles 5.2's
        _surface_shader_bsdf_eval_mis r_avg_roughness_squared, which bsdf_widen_dD reads); 0 where no pdf is."""
        return average_roughness_squared(self, hits, wi)

    def specular_roughness_squared(self, rows: np.ndarray) -> np.ndarray:
        """(n,) float32 Cycles' bsdf_get_specular_roughness_squared of closure rows: 0 for a singular closure (a
        delta one included), alpha_x alpha_y for microfacets, 1 for the others."""
        micro = np.isin(self.lobe[rows], MICROFACET_LOBES)
        value = np.where(micro, np.take(np.broadcast_to(self.ax, self.lobe.shape), rows)
                         * np.take(np.broadcast_to(self.ay, self.lobe.shape), rows), F32(1.0))
        return np.where(self.delta[rows] | np.isin(self.lobe[rows], SINGULAR_LOBES), F32(0.0), value).astype(F32)

    def is_diffuse(self, rows: np.ndarray) -> np.ndarray:
        """Whether closure rows sample diffuse directions (Cycles' LABEL_DIFFUSE: Lambert, Oren-Nayar, Translucent,
        Sheen, velvet); the others are glossy, or singular when delta."""
        return np.isin(self.lobe[rows], DIFFUSE_LABEL_LOBES)

    # ---------------------------------------------------------------- two-branched singular lobes
    @property
    def branches(self) -> bool:
        """Whether a closure of the set may be two-branched (registry.Lobe.other_branch: smooth glass)."""
        return any(k in _TWO_BRANCHED for k in self.kinds)

    def two_branched(self, rows: np.ndarray) -> np.ndarray:
        """(n,) bool: the closure rows that are singular now and of a two-branched lobe."""
        return np.isin(self.lobe[rows], _TWO_BRANCHED) & self.delta[rows]

    def other_branch(self, hits: np.ndarray, rows: np.ndarray, transmitted: np.ndarray):
        """The branch the two-branched closures `rows` (of the hits `hits`, which sampled them, taking the
        transmitted branch where `transmitted`) did not take, by their lobe's registry.Lobe.other_branch:
        (world directions, weight (3, n), transmit (n,), probability of the branch taken (n,), ok (n,))."""
        kinds = np.unique(self.lobe[rows])
        if len(kinds) == 1:
            return LOBES[int(kinds[0])].other_branch(self, hits, rows, transmitted)
        n = len(rows)
        wi, weight = tuple(np.zeros(n, F32) for _ in range(3)), np.zeros((3, n), F32)
        transmit, p_taken, ok = np.zeros(n, bool), np.ones(n, F32), np.zeros(n, bool)
        for k in kinds:
            s = np.flatnonzero(self.lobe[rows] == k)
            w_s, weight[:, s], transmit[s], p_taken[s], ok[s] = LOBES[int(k)].other_branch(
                self, hits[s], rows[s], transmitted[s])
            for axis in range(3):
                wi[axis][s] = w_s[axis]
        return wi, weight, transmit, p_taken, ok


# Lobes with two singular branches, whose branch not taken a path may look along (registry.Lobe.other_branch).
_TWO_BRANCHED = tuple(k for k, lobe in sorted(LOBES.items()) if lobe.other_branch is not None)


def _is_singular(ax, ay):
    """Cycles treats a microfacet lobe with alpha_x * alpha_y <= 2e-10 as perfectly smooth."""
    return ax * ay <= F32(2e-10)


def _concat(parts, order):
    axis = parts[0].ndim - 1
    joined = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=axis)
    return joined if order is None else np.take(joined, order, axis=axis)
