"""The closure mixture of a wave's hits: every BSDF closure of every hit in one flat table, evaluated and
sampled as one weighted sum per hit, the way Cycles does (`kernel/integrator/surface_shader.h`).

A hit's material makes a few closures, each with an RGB weight and a scalar sample weight (the mean of
its weight, times an albedo estimate for microfacet lobes). Then, per hit:

    f(wi)   = sum_j weight_j * f_j(wi) |cos|                (delta lobes contribute nothing)
    pdf(wi) = sum_j sample_weight_j * pdf_j(wi) / sum_j sample_weight_j

Sampling picks one closure in proportion to its sample weight. A delta closure (a mirror, smooth glass,
transparency) gives its own direction with weight weight_j * w_j / P(j) and pdf = inf (nothing else can
find that direction). Otherwise the chosen lobe proposes the direction and the whole mixture is evaluated
there: weight = f / pdf, one-sample MIS over the lobes (balance heuristic), as Cycles does; the lobe that
sampled enters that sum with its sampler's own value where the two differ (lobes.SELF_EVALUATED: toon, hair), as
Cycles keeps the sampling closure's eval. A Ray Portal is a delta closure whose sample also moves the ray's
start (BsdfSample.origin).

The table is sorted by hit; lobes of one kind are evaluated together, in their local frames (z along the
closure's own normal: shading, coat or bump-mapped; x along its tangent for anisotropic lobes).

A closure whose normal is not the hit's shading normal (a normal map, the specular tilt of Bump Map
Correction) is also weighed by Cycles' `bump_shadowing_term` (`kernel/closure/bsdf.h`): evaluated, it is
zero where the light and the closure's normal sit on different sides of the shading normal's plane, and
diffuse closures are softened by a GGX shadowing term of the normal's deviation (Chiang et al., "Taming
the Shadow Terminator"); sampled, only diffuse reflection takes the term, as in Cycles.
"""
from __future__ import annotations

import numpy as np

from .. import sampling
from ..vec import F32, INV_PI, ONE, ZERO
from . import fresnel, frames
from .lobes import (ANY_SIDE_LOBES, ASHIKHMIN_SHIRLEY, DIFFUSE_LOBES, GLASS, GLOSSY_LOBES, LAMBERT, MICROFACET_LOBES,
                    PORTAL, REFLECTION, REFRACTION, SELF_EVALUATED, SINGULAR_LOBES, TRANSMISSION_LOBES, TRANSPARENT)
from .registry import LOBES

# Cycles drops closures whose sample weight is below this (`CLOSURE_WEIGHT_CUTOFF`).
WEIGHT_CUTOFF = np.float32(1e-5)

# Per-closure parameter columns and their defaults: scalars (C,) and colours (3, C).
# soften: 1 where a diffuse closure on another normal takes the shadowing term's softening (Cycles skips
# it when the material turns Bump Map Correction off). dist: a microfacet lobe's distribution (0 GGX,
# 1 Beckmann: microfacet.GGX / BECKMANN). size, smooth: a toon closure's angles (toon.toon_angles).
# origin, direction: where a Ray Portal sends the ray on, world space (origin NaN: from the hit itself).
# r1, r2, offset, hair_t: a hair closure's roughnesses, highlight shift and unit tangent (world space).
_SCALARS = {"ax": 0.0, "ay": 0.0, "eta": 1.0, "rough": 0.0, "eval_scale": 1.0, "fresnel": 0.0, "soften": 1.0,
            "dist": 0.0, "size": 0.0, "smooth": 0.0, "r1": 1.0, "r2": 1.0, "offset": 0.0}
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
        self._bumped = None  # (C,) closures whose normal is not the shading normal, None if there are none
        if any(ch["n"] is not None for ch in chunks):
            normal = cat([ch["n"] if ch["n"] is not None else np.stack([np.take(a, ch["hit"]) for a in ns])
                          for ch in chunks])
            shading = np.stack([np.take(a, self.hit) for a in ns])
            bumped = np.any(normal != shading, axis=0)
            if bumped.any():
                self._bumped, self._shading = bumped, shading.astype(F32)
                self._cos_d = np.einsum("ij,ij->j", shading, normal).astype(F32)
                self._diffuse = np.isin(self.lobe, DIFFUSE_LOBES)
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
        self._wo_world = wo
        self._frame = self._wo = None
        self.kinds = sorted({int(ch["lobe"]) for ch in chunks})
        self.self_evaluated = any(k in SELF_EVALUATED for k in self.kinds)
        self.delta = self._delta_mask()
        # Lambert alone is evaluated in world space, without frames (the common case of diffuse scenes).
        self.lambert_only = self.kinds == [LAMBERT] and self._bumped is None

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
                reflect[:, missing] = _weight_albedo(self.weight[:, missing], self.sw[missing])
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
            self._wo = frames.to_local(self.frame, tuple(np.take(a, self.hit) for a in self._wo_world))
        return self._wo

    def blur(self, roughness: np.ndarray) -> None:
        """Cycles' Filter Glossy (bsdf_blur): every microfacet and Ashikhmin-Shirley closure's alphas raised
        to at least `roughness` (n_hits,) of its hit; what was set up from the old alphas (Fresnel, energy
        compensation) stays, as in Cycles. A sharp closure made rough is no longer delta."""
        micro = np.isin(self.lobe, (REFLECTION, REFRACTION, GLASS, ASHIKHMIN_SHIRLEY))
        if not micro.any():
            return
        r = np.take(roughness, self.hit)
        self.ax = np.where(micro, np.maximum(self.ax, r), self.ax).astype(F32)
        self.ay = np.where(micro, np.maximum(self.ay, r), self.ay).astype(F32)
        self.delta = self._delta_mask()

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

    # ---------------------------------------------------------------- evaluation
    def _eval_closures(self, wi_world, idx, bump: bool = True):
        """f |cos| (3, n) times the closure weight, and pdf (n,), of closures idx at wi_world (n,); with
        the bump shadowing term of an evaluation unless bump is False."""
        f, pdf = self._eval_unshadowed(wi_world, idx)
        bumped = self._bump_rows(idx, wi_world) if bump else None
        if bumped is not None:  # the term is 1 elsewhere: only the bumped closures change
            sel, term = bumped
            sampling.scale_columns(f, sel, term)
            pdf[sel] = np.where(term > 0, pdf[sel], ZERO)
        return f, pdf

    def _bump_term(self, rows, wi_world):
        """(n,) Cycles' bump_shadowing_term of closures rows evaluated toward wi_world (module docstring),
        None when none of them needs it."""
        bumped = self._bump_rows(rows, wi_world)
        if bumped is None:
            return None
        term = np.ones(len(rows), F32)
        term[bumped[0]] = bumped[1]
        return term

    def _bump_rows(self, rows, wi_world):
        """(sel, term): the entries of rows whose closure is on another normal than the shading normal,
        and their bump shadowing term; None when there are none (the term is 1 at every other entry)."""
        if self._bumped is None:
            return None
        sel = np.flatnonzero(self._bumped[rows])
        if not len(sel):
            return None
        rows = rows[sel]
        wx, wy, wz = (np.take(c, sel) for c in wi_world)
        diffuse = self._diffuse[rows]
        ns = np.take(self._shading, rows, axis=1)
        cos_si = wx * ns[0] + wy * ns[1] + wz * ns[2]
        n = np.take(self.normal, rows, axis=1)
        cos_ni = wx * n[0] + wy * n[1] + wz * n[2]
        cos_d = self._cos_d[rows]
        reject = cos_si * cos_d * cos_ni < 0
        term = np.where(reject, ZERO, ONE)
        soft = diffuse & ~reject & (self.soften[rows] > 0)
        if soft.any():
            ci, cd = np.abs(cos_si), np.abs(cos_d)
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                alpha2 = np.clip(F32(0.125) * (ONE / (cd * cd) - ONE), 0.0, 1.0)
                tan2 = np.maximum(ONE / (ci * ci) - ONE, ZERO)
                g = F32(2.0) / (ONE + np.sqrt(ONE + alpha2 * tan2))
            g = np.where(ci < F32(1e-6), ZERO, g)
            term = np.where(soft & (cd < ONE) & (ci < ONE), g, term)
        return sel, term.astype(F32)

    def _eval_unshadowed(self, wi_world, idx):
        """_eval_closures without the bump shadowing term."""
        if self.lambert_only:
            n = self.normal
            cos = wi_world[0] * n[0, idx] + wi_world[1] * n[1, idx] + wi_world[2] * n[2, idx]
            pdf = np.maximum(cos, ZERO) * INV_PI
            return np.take(self.weight, idx, axis=1) * pdf, pdf
        wi = frames.to_local(tuple(np.take(c, idx, axis=1) for c in self.frame), wi_world)
        if len(self.kinds) == 1:
            return self._eval_lobe(self.kinds[0], idx, wi)
        f = np.zeros((3, len(idx)), F32)
        pdf = np.zeros(len(idx), F32)
        lobe = self.lobe[idx]
        for k in self.kinds:
            sel = np.flatnonzero(lobe == k)
            if len(sel):
                f_k, pdf[sel] = self._eval_lobe(k, idx[sel], _pick(wi, sel))
                sampling.put_columns(f, sel, f_k)
        return f, pdf

    def _eval_lobe(self, k, rows, wi):
        if k in SINGULAR_LOBES:
            return np.zeros((3, len(rows)), F32), np.zeros(len(rows), F32)
        value, pdf = LOBES[k].eval(self, rows, _pick(self.wo, rows), wi)
        f = value * np.take(self.weight, rows, axis=1)
        if k in MICROFACET_LOBES:
            live = ~self.delta[rows]
            f, pdf = np.where(live, f, ZERO), np.where(live, pdf, ZERO)
        return f, pdf

    # ---------------------------------------------------------------- sampling
    def choose(self, u: np.ndarray) -> np.ndarray:
        """One closure per hit, in proportion to the sample weights: (N,) row, -1 where a hit has none."""
        return self._pick(u, rescale=False)[0]

    def choose_rescaled(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """choose(u), and u stretched back to [0, 1) over the chosen closure's share of the interval, as Cycles
        picks a closure with a number of the direction's own stratified sequence and rescales it: the number
        then samples the closure's direction, and (closure, direction) are stratified together instead of
        by two independent sequences (a Principled BSDF's diffuse and specular pair under a grey sky: a fifth
        of the per-sample variance)."""
        return self._pick(u, rescale=True)

    def _pick(self, u: np.ndarray, rescale: bool):
        """(row per hit, -1 where none; u rescaled within the chosen closure's share, or u when not asked)."""
        if self.single:
            return np.where(self.total_sw > 0, self.row_of_hit, -1), u
        cum = np.cumsum(self.sw, dtype=np.float64)
        if not len(cum):
            return np.full(self.n_hits, -1, np.int64), u
        before = np.where(self.start > 0, cum[np.maximum(self.start - 1, 0)], 0.0)
        target = before + u.astype(np.float64) * self.total_sw
        row = np.clip(np.searchsorted(cum, target, side="right"), self.start, self.start + self.count - 1)
        row = np.where((self.count > 0) & (self.total_sw > 0), row, -1)
        if not rescale:
            return row, u
        r = np.maximum(row, 0)
        lo = np.where(r > 0, cum[np.maximum(r - 1, 0)], 0.0)
        width = np.take(self.sw, r).astype(np.float64)
        stretched = np.clip((target - lo) / np.where(width > 0, width, 1.0), 0.0, 1.0 - 2.0 ** -24)
        return row, np.where(row >= 0, stretched, u).astype(np.float32)

    def sample(self, u_lobe, u1, u2, uc, warp=None) -> "BsdfSample":
        """Pick a closure per hit by u_lobe and sample the mixture (module docstring); uc is the glass
        lobes' reflect-or-refract number. u_lobe None: the closure is picked by u1, rescaled
        (choose_rescaled).

        warp(hits, u1, u2) -> (wi world, pdf): the reference estimators' direction sampler (LECTURE and
        COSINE). With it, only delta closures are sampled by their lobe; when a non-delta closure is
        picked the warp proposes the direction and the weight is the non-delta mixture / (pdf x the
        probability of having picked a non-delta closure)."""
        n = self.n_hits
        out = BsdfSample(n)
        if u_lobe is None:
            row, u1 = self.choose_rescaled(u1)
        else:
            row = self.choose(u_lobe)
        out.row = row
        has = np.flatnonzero(row >= 0)
        if not len(has):
            return out
        rows = row[has]
        if self.lambert_only and warp is None:
            self._sample_lambert(out, has, rows, u1, u2)
            return out
        if warp is not None:
            picked = self.delta[rows]
            self._sample_lobes(out, has[picked], rows[picked], u1, u2, uc)
            self._sample_warp(out, has[~picked], warp, u1, u2)
        else:
            self._sample_lobes(out, has, rows, u1, u2, uc)
            out.delta[has] = self.delta[rows] | np.isinf(out.pdf[has])
            # Otherwise: the whole (non-delta) mixture at the sampled direction.
            s = np.flatnonzero(~out.delta & (out.pdf > 0))
            if len(s):
                own = (out.weight[:, s] * out.pdf[s], out.pdf[s].copy()) if self.self_evaluated else None
                f, pdf = self.eval_at(s, tuple(c[s] for c in out.wi))
                self._sampled_bump(s, row[s], out, f, pdf)
                if own is not None:
                    self._sampled_self(s, row[s], out, f, pdf, own)
                good = pdf > 0
                sampling.put_columns(out.weight, s, np.where(good, f / np.where(good, pdf, ONE), ZERO))
                out.pdf[s] = pdf
        # Delta: the chosen closure alone, divided by the probability of choosing it.
        d = np.flatnonzero(out.delta & (out.pdf > 0))
        if len(d):
            r = row[d]
            sampling.scale_columns(out.weight, d, np.take(self.weight, r, axis=1) * (self.total_sw[d] / self.sw[r]))
            out.pdf[d] = np.inf
        sampling.put_columns(out.weight, np.flatnonzero(~(out.pdf > 0)), ZERO)
        return out

    def _sampled_bump(self, s, rows, out, f, pdf):
        """Cycles weighs the closure that sampled a direction by the term of a sample, not of an
        evaluation: no rejection for non-diffuse ones, no term at all for transmission. Put back into the
        mixture (f, pdf at hits s, in place) what eval_at's evaluation term took from them."""
        if self._bumped is None:
            return
        fix = np.flatnonzero(self._bumped[rows] & (~self._diffuse[rows] | out.transmit[s]))
        if not len(fix):
            return
        r = rows[fix]
        wi = tuple(c[s[fix]] for c in out.wi)
        lost = ONE - self._bump_term(r, wi)
        f_c, pdf_c = self._eval_closures(wi, r, bump=False)
        f[:, fix] += f_c * lost
        pdf[fix] += (pdf_c * lost * self.sw[r] / self.total_sw[s[fix]]).astype(F32)

    def _sampled_self(self, s, rows, out, f, pdf, own):
        """For closures of SELF_EVALUATED lobes that sampled, put their sampler's (f |cos|, pdf) own (lobe
        values at hits s) in the mixture (f, pdf, in place) in place of eval_at's evaluation of them: Cycles
        keeps the sampling closure's own eval. The bump term is that of a sample (_sampled_bump)."""
        fix = np.flatnonzero(np.isin(self.lobe[rows], SELF_EVALUATED))
        if not len(fix):
            return
        r, h = rows[fix], s[fix]
        wi = tuple(c[h] for c in out.wi)
        f_c, pdf_c = self._eval_closures(wi, r, bump=False)
        term = self._bump_term(r, wi) if self._bumped is not None else None
        term = np.ones(len(r), F32) if term is None else np.where(self._diffuse[r], term, ONE)
        f_own = own[0][:, fix] * np.take(self.weight, r, axis=1)
        f[:, fix] += (f_own - f_c) * term
        pdf[fix] += ((own[1][fix] - pdf_c) * (term > 0) * self.sw[r] / self.total_sw[h]).astype(F32)

    def _sample_lambert(self, out, hits, rows, u1, u2):
        """Only Lambert closures, all on the shading normal: a cosine sample about it. Every closure of
        the hit has the same pdf, so the mixture's f cos / pdf is the sum of the hit's closure weights
        (one closure's weight when it has one)."""
        # Every hit has its closure, in hit order (a diffuse scene): no gathers or scatters.
        whole = len(hits) == self.n_hits and self.single and len(rows) == len(self.hit) and \
            bool((rows == np.arange(len(rows))).all())
        if whole:
            lx, ly, lz = sampling.sample_cosine_hemisphere(u1, u2)
            n = self.normal
        else:
            lx, ly, lz = sampling.sample_cosine_hemisphere(u1[hits], u2[hits])
            n = np.take(self.normal, rows, axis=1)
        world = sampling.local_to_world(lx, ly, lz, n[0], n[1], n[2])
        pdf = sampling.cosine_hemisphere_pdf(lz)
        good = pdf > 0
        if self.single:
            weight = self.weight if whole else np.take(self.weight, rows, axis=1)
        else:  # a Mix or Add of Diffuse BSDFs
            weight = np.stack([np.bincount(self.hit, self.weight[k], minlength=self.n_hits)[hits]
                               for k in range(3)]).astype(F32)
        if whole:
            out.wi = tuple(world)
            out.weight = np.where(good, weight, ZERO)
            out.pdf = pdf
            return
        for axis in range(3):
            out.wi[axis][hits] = world[axis]
        sampling.put_columns(out.weight, hits, np.where(good, weight, ZERO))
        out.pdf[hits] = pdf

    def is_diffuse(self, rows: np.ndarray) -> np.ndarray:
        """Whether closure rows are diffuse lobes (Cycles' LABEL_DIFFUSE: Lambert, Oren-Nayar, Translucent,
        Sheen); the others are glossy, or singular when delta."""
        return np.isin(self.lobe[rows], DIFFUSE_LOBES)

    def _sample_lobes(self, out, hits, rows, u1, u2, uc):
        """Each hit's chosen closure samples its own lobe: direction, lobe weight, lobe pdf."""
        lobe = self.lobe[rows]
        for k in np.unique(lobe):
            sel = np.flatnonzero(lobe == k)
            r, h = rows[sel], hits[sel]
            if k == PORTAL:
                self._sample_portals(out, h, r)
                continue
            wi, weight, pdf, transmit = LOBES[k].sample(self, r, _pick(self.wo, r), u1[h], u2[h], uc[h])
            world = frames.to_world(tuple(np.take(c, r, axis=1) for c in self.frame), wi)
            for axis in range(3):
                out.wi[axis][h] = world[axis]
            sampling.put_columns(out.weight, h, weight)
            out.pdf[h] = pdf
            out.transmit[h] = transmit
            out.delta[h] = self.delta[r] | np.isinf(pdf)
            out.transparent[h] = k == TRANSPARENT
            out.any_side[h] = k in ANY_SIDE_LOBES

    def _sample_portals(self, out, hits, rows):
        """Ray Portal closures rows at hits send the ray on from their origin along their direction (world
        space), weight 1 and pdf inf: a pass-through like transparency, Cycles' integrate_surface_ray_portal.
        Which side of the surface that is, the integrator sees (it has the geometric normal)."""
        for axis in range(3):
            out.wi[axis][hits] = self.direction[axis, rows]
        sampling.put_columns(out.weight, hits, ONE)
        out.pdf[hits] = np.inf
        for mask in (out.delta, out.transparent, out.portal, out.any_side, out.transmit):
            mask[hits] = True
        origin = np.take(self.origin, rows, axis=1)
        moved = np.flatnonzero(np.isfinite(origin[0]))
        if len(moved):
            if out.origin is None:
                out.origin = np.full((3, len(out.pdf)), np.nan, F32)
            out.origin[:, hits[moved]] = origin[:, moved]

    def _sample_warp(self, out, hits, warp, u1, u2):
        if not len(hits):
            return
        wi, pdf = warp(hits, u1[hits], u2[hits])
        f, _ = self.eval_at(hits, wi)
        if self.single:
            share = np.ones(len(hits), F32)
        else:
            smooth = np.bincount(self.hit, self.sw * ~self.delta, minlength=self.n_hits)[hits]
            share = (smooth / self.total_sw[hits]).astype(F32)
        good = (pdf > 0) & (share > 0)
        denom = np.where(good, pdf * share, ONE)
        for axis in range(3):
            out.wi[axis][hits] = wi[axis]
        sampling.put_columns(out.weight, hits, np.where(good, f / denom, ZERO))
        out.pdf[hits] = np.where(good, pdf, ZERO)

    def eval_at(self, hits: np.ndarray, wi) -> tuple[np.ndarray, np.ndarray]:
        """The mixture of the hits `hits` (ascending, unique) at their world directions wi (n,).
        Returns f |cos| (3, n) and pdf (n,)."""
        if self.single:
            rows = self.row_of_hit[hits]
            have = rows >= 0
            if have.all():
                return self._eval_closures(wi, rows)
            f, pdf = np.zeros((3, len(hits)), F32), np.zeros(len(hits), F32)
            sel = np.flatnonzero(have)
            f[:, sel], pdf[sel] = self._eval_closures(tuple(c[sel] for c in wi), rows[sel])
            return f, pdf
        count = self.count[hits]
        idx = np.repeat(self.start[hits], count) + _ranges(count)
        local = np.repeat(np.arange(len(hits)), count)
        f_c, pdf_c = self._eval_closures(tuple(np.take(c, local) for c in wi), idx)
        f = np.stack([np.bincount(local, f_c[k], minlength=len(hits)) for k in range(3)]).astype(F32)
        total = self.total_sw[hits]
        with np.errstate(divide="ignore", invalid="ignore"):
            pdf = np.bincount(local, pdf_c * self.sw[idx], minlength=len(hits)) / total
        return f, np.where(total > 0, pdf, 0.0).astype(F32)

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


# glossy_axes: the lobes that gather light about one direction (a mirror's or a refraction's, blurred by
# roughness) are reflection, refraction, glass and Ashikhmin-Shirley.
MAX_AXIS_RADIUS = F32(1.0)    # radians: a lobe wider than this gathers from too much of the sphere to focus on
MIN_AXIS_RADIUS = F32(0.02)
MIN_AXIS_SHARE = F32(0.2)     # a lobe with less of its hit's sampling weight is not worth focusing on
AXIS_TILT = F32(2.0)          # microfacet normals within atan(2 alpha) of the macro normal: 80% of GGX's


def glossy_axes(cs):
    """Each hit's main glossy lobe: (hits, (dx, dy, dz), radius, share) for the hits that have one, where d is
    the world direction about which the lobe gathers light, radius (radians) holds most of it and share is
    its part of the hit's sampling weight (at least MIN_AXIS_SHARE); a rough microfacet lobe narrower than
    MAX_AXIS_RADIUS qualifies. d is the mirror direction about the closure's normal, or the refracted one
    (glass: the branch that Fresnel favours at the macro normal, with its probability in the share). The
    radius is how far d moves when the microfacet normal tilts by atan(2 alpha): twice the tilt for
    reflection, |1 - cos_i / (eta cos_t)| times it for refraction (Snell's law differentiated)."""
    lobe = cs.lobe
    cand = ((lobe == REFLECTION) | (lobe == REFRACTION) | (lobe == GLASS) | (lobe == ASHIKHMIN_SHIRLEY)) & \
        ~cs.delta & (cs.sw >= MIN_AXIS_SHARE * np.take(cs.total_sw, cs.hit))
    rows = np.flatnonzero(cand)
    empty = np.zeros(0, F32)
    if not len(rows):
        return np.zeros(0, np.int64), (empty, empty, empty), empty, empty
    h = cs.hit[rows]
    nx, ny, nz = np.take(cs.normal, rows, axis=1)
    wx, wy, wz = (np.take(a, h) for a in cs._wo_world)
    cos = wx * nx + wy * ny + wz * nz
    flip = np.where(cos < 0, F32(-1.0), ONE)
    nx, ny, nz, c = nx * flip, ny * flip, nz * flip, np.abs(cos)
    lobe = lobe[rows]
    tilt = np.arctan(AXIS_TILT * np.maximum(cs.ax[rows], cs.ay[rows]))
    branch = np.ones(len(rows), F32)
    k, scale, spread = F32(2.0) * c, np.ones(len(rows), F32), np.full(len(rows), F32(2.0))
    dielectric = np.flatnonzero((lobe == REFRACTION) | (lobe == GLASS))
    if len(dielectric):
        eta = cs.eta[rows[dielectric]]
        cd = c[dielectric]
        f, cos_t = fresnel.dielectric(cd, eta)
        glass = lobe[dielectric] == GLASS
        refract = (~glass | (f < F32(0.5))) & (cos_t > 0)
        branch[dielectric] = np.where(glass, np.where(refract, ONE - f, f), (cos_t > 0).astype(F32))
        inv_eta = ONE / eta
        k[dielectric] = np.where(refract, inv_eta * cd - cos_t, k[dielectric])
        scale[dielectric] = np.where(refract, inv_eta, ONE)
        with np.errstate(divide="ignore", invalid="ignore"):
            spread[dielectric] = np.where(refract, np.abs(ONE - cd / (eta * cos_t)), F32(2.0))
    radius = np.maximum(spread * tilt, MIN_AXIS_RADIUS)
    share = np.where(np.isfinite(radius) & (radius <= MAX_AXIS_RADIUS),
                     cs.sw[rows] * branch / np.take(cs.total_sw, h), F32(0.0))
    if len(h) > 1 and not np.all(h[1:] != h[:-1]):
        # Several candidates at a hit (rows are in hit order): keep the heaviest, the last in (hit, share) order.
        order = np.lexsort((share, h))
        hs = h[order]
        best = order[np.append(hs[1:] != hs[:-1], True)]
    else:
        best = np.arange(len(h))
    dx, dy, dz = (k * n - scale * w for n, w in ((nx, wx), (ny, wy), (nz, wz)))
    norm = np.sqrt(dx * dx + dy * dy + dz * dz)
    best = best[(share[best] >= MIN_AXIS_SHARE) & (norm[best] > 0)]   # > 0 is False for a NaN normal too
    norm = norm[best]
    return h[best], (dx[best] / norm, dy[best] / norm, dz[best] / norm), radius[best], share[best]


def pass_classes(cs, idx, wi):
    """(diffuse, glossy) (n,) bool of closures idx toward world directions wi (n,), as Cycles' bsdf_eval_accum
    sorts them for its light passes (anything else is transmission)."""
    lobe = cs.lobe[idx]
    diffuse = np.isin(lobe, DIFFUSE_LOBES)
    glossy = np.isin(lobe, GLOSSY_LOBES)
    if GLASS in cs.kinds:
        n = np.take(cs.normal, idx, axis=1)
        glossy |= (lobe == GLASS) & (wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2] > 0)
    return diffuse, glossy


def eval_split(cs, hits: np.ndarray, wi):
    """ClosureSet.eval_at with its diffuse and glossy parts: (f (3, n), f_diffuse (3, n), f_glossy (3, n))."""
    if cs.single:
        rows = cs.row_of_hit[hits]
        have = np.flatnonzero(rows >= 0)
        out = [np.zeros((3, len(hits)), F32) for _ in range(3)]
        if len(have):
            w = tuple(c[have] for c in wi)
            f, _ = cs._eval_closures(w, rows[have])
            diffuse, glossy = pass_classes(cs, rows[have], w)
            out[0][:, have], out[1][:, have], out[2][:, have] = f, f * diffuse, f * glossy
        return tuple(out)
    count = cs.count[hits]
    idx = np.repeat(cs.start[hits], count) + _ranges(count)
    local = np.repeat(np.arange(len(hits)), count)
    w = tuple(np.take(c, local) for c in wi)
    f_c, _ = cs._eval_closures(w, idx)
    diffuse, glossy = pass_classes(cs, idx, w)
    return tuple(np.stack([np.bincount(local, part[k], minlength=len(hits)) for k in range(3)]).astype(F32)
                 for part in (f_c, f_c * diffuse, f_c * glossy))


def _weight_albedo(weight, sw) -> np.ndarray:
    """(3, C) the weight times the sample weight over the weight's mean: the albedo of a closure whose
    colour is all in its weight (its sample weight is the mean weight times the lobe's estimated albedo)."""
    weight = np.asarray(weight, F32)
    mean = weight.mean(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (weight * np.where(mean > 0, np.asarray(sw, F32) / mean, 0.0)).astype(F32)


def closure_albedos(cs) -> np.ndarray:
    """(3, C) each closure's albedo estimate, Cycles' bsdf_albedo (reflection and transmission): the one
    the closure gave (a metal's Fresnel colour, glass's tints), else its weight times its sample weight
    over its mean weight."""
    if cs.albedo is not None:
        return (cs.albedo[0] + cs.albedo[1]).astype(F32)
    return _weight_albedo(cs.weight, cs.sw)


def class_albedo(cs, n_hits: int):
    """(diffuse, glossy, transmission) (3, n) colours of the hits' closures (Cycles' surface_shader_diffuse,
    _glossy, _transmission): each closure's albedo (closure_albedos) summed in its class; glass gives its
    reflection to glossy and its transmission to transmission, as Cycles' bsdf_albedo(reflection,
    transmission) splits them."""
    out = [np.zeros((3, n_hits), F32) for _ in range(3)]
    if not len(cs):
        return tuple(out)
    lobe = cs.lobe
    reflect, transmit = cs.albedo if cs.albedo is not None else (_weight_albedo(cs.weight, cs.sw), ZERO)
    total = reflect + transmit
    glass = lobe == GLASS
    parts = (total * np.isin(lobe, DIFFUSE_LOBES),
             total * np.isin(lobe, GLOSSY_LOBES) + reflect * glass,
             total * np.isin(lobe, TRANSMISSION_LOBES) + transmit * glass)
    for o, part in zip(out, parts):
        for k in range(3):
            o[k] = np.bincount(cs.hit, part[k], minlength=n_hits)
    return tuple(out)


class BsdfSample:
    """Per hit: direction wi (world), throughput weight (3, N), pdf (N,) for MIS (inf for delta),
    delta, transmit (the lobe transmits: Cycles' LABEL_TRANSMIT), transparent (a pass-through: a Transparent
    closure or a Ray Portal, which counts no bounce), portal (a Ray Portal) and any_side (ANY_SIDE_LOBES: no
    side test) masks, and row, the closure table row that was picked (-1: none), whose lobe says diffuse or
    glossy (Light Path). origin: None, or (3, N) float32 where a Ray Portal moves the ray's start (NaN
    elsewhere: the ray leaves from the hit). through: None, or (N,) where the ray leaves below the surface
    when that is not what transmit says (the integrator sets it for any_side samples)."""
    __slots__ = ("wi", "weight", "pdf", "delta", "transmit", "transparent", "portal", "any_side", "origin",
                 "through", "row")

    def __init__(self, n: int):
        self.wi = (np.zeros(n, F32), np.zeros(n, F32), np.ones(n, F32))
        self.weight = np.zeros((3, n), F32)
        self.pdf = np.zeros(n, F32)
        self.delta = np.zeros(n, bool)
        self.transmit = np.zeros(n, bool)
        self.transparent = np.zeros(n, bool)
        self.portal = np.zeros(n, bool)
        self.any_side = np.zeros(n, bool)
        self.origin = self.through = None
        self.row = np.full(n, -1, np.int64)


# ---------------------------------------------------------------- frames
def _is_singular(ax, ay):
    """Cycles treats a microfacet lobe with alpha_x * alpha_y <= 2e-10 as perfectly smooth."""
    return ax * ay <= F32(2e-10)


def _pick(w, idx):
    return tuple(np.take(c, idx) for c in w)


def _concat(parts, order):
    axis = parts[0].ndim - 1
    joined = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=axis)
    return joined if order is None else np.take(joined, order, axis=axis)


def _ranges(count: np.ndarray) -> np.ndarray:
    """0..count[i]-1 for every i, concatenated."""
    total = int(count.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    offsets = np.repeat(np.cumsum(count) - count, count)
    return np.arange(total) - offsets
