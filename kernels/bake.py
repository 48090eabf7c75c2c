"""Baking: the texels of an object's image (or the corners of its colour attribute) as the starts of paths, and
what each bake type records of them, as Cycles bakes.

Blender rasterises the object's UV map and hands the engine each texel's triangle and barycentric
coordinates (object_bake_api.cc, engine.cc's render_result_from_bake); as Cycles does
(kernel/integrator/init_from_bake.h), a texel becomes a path that starts on the surface, seen from above it or
from the camera (kernels/bake_texels.py), and goes on as a camera path would from its first hit. What each bake
type keeps is the pass Cycles' Blender session names "Combined" for it (intern/cycles/blender/session.cpp,
bake_setup_pass):

- POSITION, NORMAL, UV, ROUGHNESS: the first hit's position, the closures' average normal (the smooth normal
  where no closure has another), the render UV map's (u, v, 1) and the closures' average roughness
  (kernel/film/data_passes.h, kernel/integrator/surface_shader.h), averaged over the samples.
- EMIT: the first hit's emission. ENVIRONMENT: the world seen along normalize(P) from the origin.
- AO: an ambient occlusion ray per sample from the first hit, cosine-distributed about the diffuse closures'
  normal, as far as the world's AO distance, through transparent surfaces (integrate_surface_ao).
- COMBINED, DIFFUSE, GLOSSY, TRANSMISSION: whole paths (kernels/integrator.py) with Cycles' bake switches
  (scene/integrator.cpp's filter_closures): the first hit keeps only the closure classes asked for
  (glass goes only with both glossy and transmission), transparent closures there become holdout (the
  bake sees the object itself, not what is behind it); without Direct light the first hit takes no light
  sample and its rays do not see lamps or the world; without Indirect light the paths end after one bounce;
  without Emit no surface emits. DIFFUSE, GLOSSY and TRANSMISSION read their light passes, divided by their
  Color pass unless Color is asked for (Cycles' include_albedo), or the Color pass alone.
- SHADOW: Cycles' shadow catcher pass with the object as the catcher: what reaches it with everything, over
  what reaches it where only the object itself is there (kernel/film/read.h,
  film_calculate_shadow_catcher), channel by channel, 1 where nothing reaches it.

For a denoiser (engine/bake.py denoises Combined and Shadow bakes, as Cycles does), the whole-path bakes also
record each texel's Denoising Albedo and Normal, where its paths meet their first hit that is not mostly specular
(kernels/passes.py write_denoising_features, as Cycles' bake paths write their denoising features).

Cycles sums its Position bake over the samples instead of averaging it (the pass is not divided when it is
read); Ember averages it, which is the same at one sample.
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import threading
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from . import integrator
from .ao_pass import DIFFUSE_CLOSURES as _DIFFUSE   # Cycles' CLOSURE_IS_BSDF_DIFFUSE, for the bake switches
from .ao_pass import ambient_occlusion
from .bake_texels import BakePaths, BakeTexels, FirstHits, first_hits, object_triangles
from .bsdf.lobes import (BSSRDF, GLASS, GLOSSY_LOBES, MICROFACET_LOBES, OREN_NAYAR, PORTAL,
                         TRANSMISSION_LOBES, TRANSPARENT)
from .interaction import RayInfo, SurfaceHit
from .lights import LightSampler, nee
from .paths import ray_keys
from .samples import BSDF, Samples
from .scene.objects import ALL_RAYS
from .vec import F32

__all__ = ["GUIDES", "KINDS", "BakeJob", "BakeTexels", "bake", "object_triangles"]

# The bake types of Blender's bake operator (Cycles offers them all) and the passes they read.
KINDS = ("COMBINED", "AO", "SHADOW", "POSITION", "NORMAL", "UV", "ROUGHNESS", "EMIT", "ENVIRONMENT", "DIFFUSE",
         "GLOSSY", "TRANSMISSION")
LIGHT_KINDS = ("DIFFUSE", "GLOSSY", "TRANSMISSION")
# The bakes that trace whole paths, and the denoising passes they can record for a denoiser (bake's guides).
TRACED_KINDS = ("COMBINED", "SHADOW") + LIGHT_KINDS
GUIDES = ("denoising_albedo", "denoising_normal")
# Blender's pass filter bits (DNA_scene_types.h, eBakePassFilter), as RenderEngine.bake receives them.
FILTER_EMIT, FILTER_DIFFUSE, FILTER_GLOSSY, FILTER_TRANSMISSION = 1 << 1, 1 << 2, 1 << 3, 1 << 4
FILTER_DIRECT, FILTER_INDIRECT, FILTER_COLOR = 1 << 6, 1 << 7, 1 << 8
# How many paths a bake traces at once, at most (texels x samples).
CHUNK_PATHS = 1 << 17


@dataclass(frozen=True)
class BakeJob:
    """What to bake: kind (KINDS), Blender's pass_filter bits, and whether the surface is seen from the camera
    (Bake > View From > Active Camera) rather than from above it."""
    kind: str
    pass_filter: int = -1
    use_camera: bool = False

    def has(self, bit: int) -> bool:
        return bool(self.pass_filter & bit)

    @property
    def exposed(self) -> bool:
        """Whether Film > Exposure scales the bake, as it scales the pass Cycles bakes from (scene/pass.cpp
        use_exposure): Combined, Emit, Environment and light, not a colour alone nor data."""
        if self.kind in LIGHT_KINDS:
            return self.has(FILTER_DIRECT) or self.has(FILTER_INDIRECT)
        return self.kind in ("COMBINED", "EMIT", "ENVIRONMENT")


def _shade_first(tables, state, first: FirstHits, split):
    """The SurfaceHit and SurfaceShading of the first hits, as the integrator's first vertex shades them."""
    hits, d = first.hits, first.rays.dirs
    n = len(hits.prim)
    hit = SurfaceHit(tables.triangles, hits.prim, hits.u, hits.v, (d[:, 0], d[:, 1], d[:, 2]), tables.shading.needs_uv)
    hit.ray = RayInfo(state.bounce, state.transparent, hits.t, dp=first.dp, lobes=state.lobes, portal=state.portal)
    if tables.shading.traces:
        hit.ray.keys = ray_keys(state, np.arange(n))
        hit.ray.time, hit.ray.min_ray_pdf, hit.ray.split = None, state.min_ray_pdf, split
    return hit, tables.shading.surface(hit)


# ---------------------------------------------------------------- whole paths: Cycles' bake switches
class BakeRun:
    """The integrator's view of a bake (integrator.trace's bake): where its paths start, and what Cycles' bake
    switches leave out of them (scene/integrator.cpp, kernel/integrator/surface_shader.h)."""

    def __init__(self, image: BakeTexels, job: BakeJob, kind: str, all_light: bool = False):
        self.image, self.use_camera = image, job.use_camera
        every = all_light or kind != "COMBINED" and kind not in LIGHT_KINDS
        self.direct = every or job.has(FILTER_DIRECT)
        if every:
            keep = (True, True, True)
        elif kind == "COMBINED":
            keep = (job.has(FILTER_DIFFUSE), job.has(FILTER_GLOSSY), job.has(FILTER_TRANSMISSION))
        else:
            keep = (kind == "DIFFUSE", kind == "GLOSSY", kind == "TRANSMISSION")
        dropped = (_DIFFUSE if not keep[0] else ()) + (GLOSSY_LOBES if not keep[1] else ()) + \
            (TRANSMISSION_LOBES if not keep[2] else ()) + ((GLASS,) if not (keep[1] or keep[2]) else ())
        self.dropped = np.array(dropped, np.int8)

    def start(self, tables, wave, paths, start: int, end: int, last: int):
        """The first vertex of the paths [start, end) (integrator.trace's start of a batch)."""
        texel, sample, rng, strata = paths.batch(start, end)
        settings = wave.settings
        samples = Samples(rng, strata if settings.mode == "NEE_MIS" else None, settings.seed, wave.nee,
                          lobes=tables.shading.mixes_lobes or nee.termination_scale(tables, settings) > 0)
        jx, jy = samples.camera()
        first = first_hits(tables, self.image, texel, jx, jy, self.use_camera)
        state = integrator.new_paths(tables, wave, end - start, samples, start)
        state.dp = first.dp
        wave.spread_dd = F32(0.0)   # a bake's rays spread no further (Cycles: dD = 0), but by rough bounces
        if state.dd is not None:
            state.dd[:] = 0.0
        return integrator.first_vertex(tables, wave, state, first.rays, first.hits, last)

    def first_hit(self, wave, state, hit, shading) -> None:
        """The first hit's closures as the bake keeps them: the classes asked for; transparent ones cut a hole
        in alpha instead (Cycles' FILTER_CLOSURE_TRANSPARENT turns them into holdout)."""
        cs = shading.closures
        if not len(cs):
            return
        transparent = cs.lobe == TRANSPARENT
        if transparent.any():
            share = np.bincount(cs.hit[transparent], cs.weight[:, transparent].mean(axis=0), minlength=len(hit))
            wave.alpha[state.path] -= share * state.throughput.mean(axis=0)
        drop = transparent | np.isin(cs.lobe, self.dropped)
        if drop.any():
            shading.closures = cs.without(drop, hit.ns)

    def sees_lights(self, bounce: np.ndarray) -> np.ndarray:
        """(n,) bool: rays at these bounces see lamps and the world (not the first hit's without direct
        light, which took no light sample either: integrator_intersect_skip_lights)."""
        return (bounce != 1) | self.direct


def _path_settings(settings, job: BakeJob, kind: str, guides: tuple = ()):
    """The render settings of a bake's paths: one bounce without Indirect, no adaptive sampling; guides: the
    denoising passes they record besides their light (GUIDES)."""
    indirect = kind in ("SHADOW",) or job.has(FILTER_INDIRECT)
    return dataclasses.replace(settings, adaptive_threshold=0.0,
                               max_bounces=settings.max_bounces if indirect else 0,
                               passes=_light_passes(kind) + tuple(guides), cryptomatte=())


def _light_passes(kind: str) -> tuple:
    if kind not in LIGHT_KINDS:
        return ()
    cls = kind.lower()
    return (f"{cls}_direct", f"{cls}_indirect", f"{cls}_color")


# ---------------------------------------------------------------- a chunk of texels
def _trace_chunk(tables, image, job, settings, texels, spp, split, all_light=False):
    """Whole paths of texels, spp each: ((C, m) per-texel sums of the pass, (m,) alpha sums, {guide: (3, m)
    per-texel sums} of the GUIDES the settings' passes name)."""
    kind = job.kind
    paths = BakePaths(image, texels, 0, spp, settings)
    aux = {name: np.zeros((3, len(paths)), F32) for name in settings.passes} or None
    run = BakeRun(image, job, kind, all_light)
    radiance, alpha = integrator.trace(tables, paths, settings, split, aux=aux,
                                       live=tables.live_paths(settings), bake=run)
    bad = ~np.isfinite(radiance).all(axis=0)
    radiance[:, bad] = 0.0
    m = len(texels)

    def per_texel(values):
        return values.astype(np.float64).reshape(len(values), m, spp).sum(axis=2)

    guides = {name: per_texel(np.where(bad, 0.0, aux[name])) for name in GUIDES if name in settings.passes}
    if kind in LIGHT_KINDS:
        cls = kind.lower()
        for name in aux:
            aux[name][:, bad] = 0.0
        light = per_texel(aux[f"{cls}_direct"]) * job.has(FILTER_DIRECT) + \
            per_texel(aux[f"{cls}_indirect"]) * job.has(FILTER_INDIRECT)
        colour = per_texel(aux[f"{cls}_color"])
        if not (job.has(FILTER_DIRECT) or job.has(FILTER_INDIRECT)):
            value = colour
        elif job.has(FILTER_COLOR):
            value = light
        else:   # light over colour, as Cycles reads a light pass without its albedo
            with np.errstate(divide="ignore", invalid="ignore"):
                value = np.where(colour != 0, light / np.where(colour != 0, colour, 1.0), 0.0) * spp
        return value, per_texel(alpha[None])[0], guides
    return per_texel(radiance), per_texel(alpha[None])[0], guides


def _first_hit_chunk(tables, image, job, settings, texels, spp, split):
    """What the first hits of texels record (the data passes, Emit, Environment, AO): (C, m) sums."""
    kind = job.kind
    paths = BakePaths(image, texels, 0, spp, settings)
    texel, sample, rng, strata = paths.batch(0, len(paths))
    nee_on = settings.mode == "NEE_MIS"
    samples = Samples(rng, strata if nee_on else None, settings.seed, nee_on, lobes=tables.shading.mixes_lobes)
    jx, jy = samples.camera()
    first = first_hits(tables, image, texel, jx, jy, job.use_camera)
    n = len(texel)
    if kind == "ENVIRONMENT":
        d = first.p / np.maximum(np.linalg.norm(first.p, axis=1, keepdims=True), F32(1e-30))
        ray = RayInfo(np.zeros(n, np.int32), np.zeros(n, np.int32), emission=True) \
            if tables.environment.shader else None
        value = tables.environment.radiance(d[:, 0], d[:, 1], d[:, 2], ray)
    elif kind == "POSITION":
        value = first.p.T
    elif kind == "NORMAL":
        # Only where a closure's normal may differ from the smooth normal (Cycles' SD_HAS_BUMP) is the material
        # run: elsewhere the smooth normal is the closures' average.
        value = first.normal.T.copy()
        bumped = np.flatnonzero(np.take(_bumped_materials(tables), tables.triangles.materials(first.hits.prim)))
        if len(bumped):
            some = first.take(bumped)
            wave = SimpleNamespace(settings=settings, split=split, nee=nee_on, aux=None, only_catchers=None,
                                   spread_dd=F32(0.0))
            state = integrator.new_paths(tables, wave, len(bumped), samples.take(bumped), 0)
            hit, shading = _shade_first(tables, state, some, split)
            value[:, bumped] = average_normal(shading.closures, len(bumped), hit.ns)
    else:
        wave = SimpleNamespace(settings=settings, split=split, nee=nee_on, aux=None, only_catchers=None,
                               spread_dd=F32(0.0))
        state = integrator.new_paths(tables, wave, n, samples, 0)
        hit, shading = _shade_first(tables, state, first, split)
        cs = shading.closures
        if kind == "EMIT":
            value = shading.emission
        elif kind == "UV":
            u, v = hit.uv_at(np.arange(n))
            value = np.stack([u, v, np.ones(n, F32)])
        elif kind == "ROUGHNESS":
            value = np.broadcast_to(average_roughness(cs, n), (3, n))
        else:
            value = ambient_occlusion(tables, wave, hit, cs, state.samples.bounce(0)[BSDF], np.arange(n))
    return np.asarray(value, np.float64).reshape(3, len(texels), spp).sum(axis=2), None, {}


def _bumped_materials(tables) -> np.ndarray:
    """(M,) bool: materials with a closure whose Normal input is linked (a bump, a normal map, displacement's bump),
    Cycles' SD_HAS_BUMP."""
    return np.array([any(c.input("Normal") is not None for c in shader.closures)
                     for shader in tables.scene.materials.shaders], bool)


def _weights(cs, rows):
    return np.abs(cs.weight[:, rows].mean(axis=0))


def average_normal(cs, n: int, fallback) -> np.ndarray:
    """(3, n) Cycles' surface_shader_average_normal: the BSDF and BSSRDF closures' normals weighted by |their
    mean weight|, normalised; the shading normal where there are none (transparent ones are holdout here)."""
    out = np.stack([np.asarray(c, F32) for c in fallback]).copy()
    rows = np.flatnonzero(cs.lobe != TRANSPARENT) if len(cs) else np.zeros(0, np.int64)
    if not len(rows):
        return out
    w = _weights(cs, rows)
    summed = np.stack([np.bincount(cs.hit[rows], cs.normal[k, rows] * w, minlength=n) for k in range(3)])
    length = np.sqrt((summed * summed).sum(axis=0))
    ok = length > 0
    out[:, ok] = (summed[:, ok] / length[ok]).astype(F32)
    return out


def average_roughness(cs, n: int) -> np.ndarray:
    """(n,) Cycles' surface_shader_average_roughness: per BSDF closure (bsdf_get_roughness_pass_squared, its
    root twice) Oren-Nayar's roughness, a microfacet's sqrt of its alphas' geometric mean, 0 for singular ones,
    1 for the rest; other diffuse ones left out; weighted by |mean weight|; 1 where none counts."""
    out = np.ones(n, F32)
    if not len(cs):
        return out
    lobe = cs.lobe
    counted = ~np.isin(lobe, _DIFFUSE) | (lobe == OREN_NAYAR)
    counted &= (lobe != TRANSPARENT) & (lobe != BSSRDF)
    rows = np.flatnonzero(counted)
    if not len(rows):
        return out
    ax, ay = np.broadcast_to(cs.ax, lobe.shape)[rows], np.broadcast_to(cs.ay, lobe.shape)[rows]
    value = np.where(np.isin(lobe[rows], MICROFACET_LOBES), np.sqrt(np.sqrt(np.maximum(ax * ay, 0.0))), 1.0)
    value = np.where(lobe[rows] == OREN_NAYAR, np.broadcast_to(cs.rough, lobe.shape)[rows], value)
    value = np.where(np.isin(lobe[rows], (PORTAL,)) | cs.delta[rows] & ~np.isin(lobe[rows], MICROFACET_LOBES),
                     0.0, value)
    w = _weights(cs, rows)
    total = np.bincount(cs.hit[rows], w, minlength=n)
    summed = np.bincount(cs.hit[rows], w * value, minlength=n)
    return np.where(total > 0, summed / np.where(total > 0, total, 1.0), 1.0).astype(F32)


# ---------------------------------------------------------------- the bake
def bake(tables, image: BakeTexels, job: BakeJob, settings, should_stop=None, on_progress=None,
         guides: dict | None = None) -> np.ndarray:
    """(P, 4) float32 the bake of every texel (RGB and alpha; zero where prim is -1), the mean of
    settings.samples samples. tables: a kernels.Renderer of the scene. should_stop() is polled between chunks of
    texels (CHUNK_PATHS paths), on this thread; on_progress(fraction done) is called there after each.
    guides: a dict whose keys name GUIDES, for the bakes that trace whole paths (COMBINED, SHADOW and the light
    bakes): each is set to the (P, 3) float32 mean of that pass over the texel's paths (zero where prim is -1),
    as Cycles' bake paths record their denoising features (the film's Denoising Albedo and Normal, written at
    the first hit that is not mostly specular: the baked surface's own unless it is a mirror)."""
    if job.kind not in KINDS:
        raise ValueError(f"cannot bake {job.kind!r}: Ember bakes {', '.join(KINDS)}")
    spp = max(1, int(settings.samples))
    texels = np.flatnonzero(image.prim >= 0)
    out = np.zeros((len(image.prim), 4), F32)
    out[:, 3] = 1.0
    if not len(texels):
        return out
    wanted = tuple(name for name in GUIDES if guides is not None and name in guides)
    if guides is not None:
        for name in guides:
            if name not in GUIDES:
                raise ValueError(f"guides: {name!r} is none of {GUIDES}")
            guides[name] = np.zeros((len(image.prim), 3), F32)
    paths_settings = _path_settings(settings, job, job.kind, wanted if job.kind in TRACED_KINDS else ())
    step = max(1, CHUNK_PATHS // spp)
    chunks = [texels[i:i + step] for i in range(0, len(texels), step)]
    pool = getattr(tables.crew, "pool", None) if len(chunks) > 1 else None
    split = pool is None
    stop = threading.Event()
    done = [0, len(chunks) * (2 if job.kind == "SHADOW" else 1)]

    def each(work):
        def one(chunk):
            if stop.is_set():
                return None
            with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
                return work(tables, image, job, paths_settings, chunk, spp, split)
        results = []
        for result in (pool.map(one, chunks) if pool is not None else map(one, chunks)):
            results.append(result)
            done[0] += 1
            if should_stop is not None and should_stop():
                stop.set()   # the chunks not started yet are skipped
            elif on_progress is not None:
                on_progress(done[0] / done[1])
        return results

    kind = job.kind
    if kind == "SHADOW":
        results = _shadow(tables, image, spp, each)
    elif kind == "COMBINED" or kind in LIGHT_KINDS:
        with _surface_emission(tables, kind != "COMBINED" or job.has(FILTER_EMIT)):
            results = each(_trace_chunk)
    else:
        results = each(_first_hit_chunk)
    for chunk, result in zip(chunks, results):
        if result is None:
            continue
        value, alpha, sums = result
        out[chunk, :3] = (value / spp).T
        for name, total in sums.items():
            guides[name][chunk] = (total / spp).T
        if kind == "COMBINED":
            out[chunk, 3] = alpha / spp
    if job.exposed and float(settings.exposure) != 1.0:
        out[:, :3] *= F32(settings.exposure)
    return out


@contextlib.contextmanager
def _surface_emission(tables, on: bool):
    """Without Emit no surface emits, whether a ray meets it or a light sample picks it (Cycles bakes so: its mesh
    lights add nothing then); lamps and the world still light the scene."""
    if on or not tables.emissive:
        yield
        return
    lights, emissive = tables.lights, tables.emissive
    tables.lights = LightSampler(tables.scene, tables.environment, _NoEmitters(len(tables.shading.emissive)),
                                 tables.shading.data)
    tables.emissive = False
    try:
        yield
    finally:
        tables.lights, tables.emissive = lights, emissive


class _NoEmitters:
    """The light sampler's view of materials of which none emits (LightSampler's triangle_emission)."""

    def __init__(self, materials: int):
        self.emissive = self.varies = np.zeros(materials, bool)

    def __call__(self, tri, b1=None, b2=None, toward=None, dist=None):
        return np.zeros((3, len(tri)), F32)


def _shadow(tables, image, spp: int, each) -> list:
    """Cycles' shadow catcher pass with the baked object as the catcher: the light reaching it with everything
    over the light reaching it where no other object is there (its split path sees the catchers alone), per
    channel, 1 where none reaches it; over white by the object's alpha (film_calculate_shadow_catcher)."""
    everything = each(functools.partial(_trace_chunk, all_light=True))
    own = np.unique(tables.triangles.object_rows(image.prim[image.prim >= 0][:1]))
    seen = tables.visibility
    alone = np.zeros(len(tables.scene.objects), np.uint8)
    alone[own] = ALL_RAYS if seen is None else seen[own]
    tables.visibility = alone
    try:
        catcher = each(functools.partial(_trace_chunk, all_light=True))
    finally:
        tables.visibility = seen
    out = []
    for full, by_itself in zip(everything, catcher):
        if full is None or by_itself is None:
            out.append(None)
            continue
        (value, alpha, guides), (own_value, _, _) = full, by_itself
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(own_value != 0, value / np.where(own_value != 0, own_value, 1.0), 1.0)
        a = np.clip(alpha / spp, 0.0, 1.0)
        out.append((((1.0 - a) + a * ratio) * spp, None, guides))
    return out
