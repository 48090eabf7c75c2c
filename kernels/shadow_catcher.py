"""Shadow catchers (Object > Visibility > Shadow Catcher), as Cycles renders them: objects taken to be in the
footage already, which show only the shadows and reflections that the synthetic objects (all the others) add
to them, for compositing a render onto the footage.

What Cycles does, and where (blender/cycles at v5.0.0; bpy 5.0.1 and 5.3.0 render the same):
- kernel/integrator/shadow_catcher.h (kernel_shadow_catcher_is_path_split_bounce) and intersect_closest.h
  (integrator_split_shadow_catcher): a path still on its camera ray (PATH_RAY_TRANSPARENT_BACKGROUND: only
  transparent surfaces passed, here bounce 0) that meets a shadow catcher which is no holdout splits, once
  (PATH_RAY_SHADOW_CATCHER_HIT on both halves). The path goes on as before, the catcher an ordinary object;
  its copy (PATH_RAY_SHADOW_CATCHER_PASS) shades the same hit with the same random numbers and sees shadow
  catchers only: its rays and shadow rays pass every other object (kernel/types.h,
  SHADOW_CATCHER_PATH_VISIBILITY), and it takes no light from lights whose object is no shadow catcher
  (scene/light.cpp light_object_shader_flags, kernel/light/light.h light_sample and lights_intersect: Blender
  makes lights shadow catchers by default) nor from emitting objects that are none; the world lights it.
- kernel/film/light_passes.h: the copy's light goes to the catcher pass alone (film_write_shadow_catcher);
  light of paths that never split goes to Combined and to the matte; at the split the matte counts the path's
  mean throughput as transparency (film_write_shadow_catcher_bounce_data) and the split's sample count goes up
  by one; split paths write no light pass (Diffuse Direct, ...). The copy's transparency (a camera ray through a
  transparent catcher to the world on a transparent film) goes to Combined's alpha (film_write_transparent).
- kernel/film/read.h, film_calculate_shadow_catcher: Shadow Catcher pass = (Combined - matte) / catcher per
  channel (1 where the catcher is 0, and where no sample split), alpha-overed on white with Combined's alpha;
  film_calculate_shadow_catcher_matte_with_shadow: the "approximate" Combined, the matte over the shadow, alpha
  (1 - a)(1 - clamp(mean(catcher pass))) + a with a the matte's; on an opaque film over the Environment pass
  (PASS_BACKGROUND, which scene/film.cpp adds for it): the world the camera sees, and the world behind the
  catchers, which the copy records first (PATH_RAY_SHADOW_CATCHER_BACKGROUND).
- session/buffers.cpp get_actual_display_pass and blender/sync.cpp (sync_film): with a shadow catcher in the
  scene, Combined is the matte; "approximate" (with the shadow) unless the view layer's Shadow Catcher pass is
  on; the viewport is always approximate.
Not done as Cycles: the copy keeps the path's volume stack (Cycles rebuilds it from the catchers alone), and
the Ambient Occlusion and Bevel nodes of a catcher see every object on the copy too.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .interaction import RayInfo
from .paths import PathState
from .rays import concat_rays
from .scene.objects import HOLDOUT, SHADOW_CATCHER

# Planes the film records for shadow catchers (kernels.passes): the catcher pass (light of the copies), the matte
# (RGB and alpha of what never split and what came before a split), the splits per pixel; and the Environment pass
# (the approximate Combined of an opaque film lays the matte over it).
CATCHER, MATTE, SPLITS, BACKGROUND = "catcher", "catcher_matte", "catcher_samples", "environment"
# The view layer's Shadow Catcher pass (made from the planes when read).
PASS = "shadow_catcher"


@dataclass(frozen=True)
class Catchers:
    """A scene's shadow catchers as the paths of a wave see them.

    splits : (K,) bool per object row: camera paths split where they meet it (a shadow catcher, no holdout).
    emitters : (L + E + 1,) bool, the emitters of the light sampler (lights, emissive triangles, the world) the
        copies take light from, or None for all.
    lights : (L,) bool, the lights with a surface the copies' rays meet, or None for all.
    """
    splits: np.ndarray
    emitters: np.ndarray | None
    lights: np.ndarray | None


def has_catchers(visibility) -> bool:
    """Whether some object of the scene is a shadow catcher (visibility: the renderer's object_visibility table)."""
    return visibility is not None and bool((visibility & SHADOW_CATCHER).any())


def catchers(tables) -> Catchers | None:
    """The scene's Catchers (tables: the Renderer), None without shadow catchers."""
    vis = tables.visibility
    if not has_catchers(vis):
        return None
    catcher_rows = (vis & SHADOW_CATCHER) != 0
    sampler = tables.lights
    lamps = tables.scene.lights.shadow_catcher
    lamps = np.ones(sampler.light_count, bool) if lamps is None else np.asarray(lamps, bool)
    rows = tables.triangles.object_rows(sampler.tri_ids)
    triangles = np.ones(len(sampler.tri_ids), bool) if rows is None else np.take(catcher_rows, rows)
    emitters = np.concatenate([lamps, triangles, [True]])
    return Catchers(splits=catcher_rows & ((vis & HOLDOUT) == 0),
                    emitters=None if emitters.all() else emitters,
                    lights=None if lamps.all() else lamps)


def approximate(passes) -> bool:
    """Cycles' use_approximate_shadow_catcher: Combined shows the shadows unless the Shadow Catcher pass is on."""
    return PASS not in passes


def with_planes(settings, visibility):
    """The settings with the planes the film records for shadow catchers when the scene has one (the
    Environment pass for the approximate Combined of an opaque film), else as they are."""
    if not has_catchers(visibility):
        return settings
    planes = (CATCHER, MATTE, SPLITS)
    if approximate(settings.passes) and not settings.transparent_background:
        planes += (BACKGROUND,)
    return dataclasses.replace(settings, passes=tuple(dict.fromkeys(tuple(settings.passes) + planes)))


# ---------------------------------------------------------------- the paths of a wave
def start(tables, wave, n: int, new_wave):
    """The shadow catcher state of a wave of n paths (the integrator's wave.catcher: CatcherWave), None in a
    scene without shadow catchers, or in a render that records none of their planes: then nothing of them runs.
    new_wave: the integrator's wave record, made for the copies."""
    if wave.aux is None or MATTE not in wave.aux:
        return None
    found = catchers(tables)
    if found is None:
        return None
    copies = new_wave(wave.settings, wave.nee, wave.split, wave.max_scatters, wave.aux[CATCHER],
                      np.ones(n, np.float32))
    copies.spread_dd, copies.only_catchers = wave.spread_dd, found
    # What the copies see of the world and of emitters straight from the camera (through a transparent catcher)
    # goes to the Environment and Emission passes too: Cycles' film_write_emission_or_background_pass makes no
    # exception for them.
    copies.aux = {name: wave.aux[name] for name in ("environment", "emission") if name in wave.aux} or None
    return CatcherWave(found, copies, n)


class CatcherWave:
    """A wave's shadow catcher state (the integrator's wave.catcher).

    paths : the wave record of the copies (the integrator's): their light is the wave's catcher plane, their
        alpha a plane of their own (added to the wave's at the end), no other pass but Environment and Emission;
        only_catchers set.
    caught : (N,) bool per path of the wave, split already (PATH_RAY_SHADOW_CATCHER_HIT).
    going : the copies to trace next, (PathState, Rays), or None.
    """
    __slots__ = ("catchers", "paths", "caught", "going")

    def __init__(self, catchers: Catchers, paths, n: int):
        self.catchers, self.paths = catchers, paths
        self.caught = np.zeros(n, bool)
        self.going = None

    def add(self, going) -> None:
        """More copies to trace (what the integrator's surface stage returned for them, or None)."""
        if going is None:
            return
        self.going = going if self.going is None else \
            (PathState.concat(self.going[0], going[0]), concat_rays(self.going[1], going[1]))

    def take(self):
        """The copies to trace now, (PathState, Rays) or None; none are left after."""
        going, self.going = self.going, None
        return going


def split(tables, wave, state, rays, hits, found):
    """The paths `found` (rays of the state's paths that met a surface) still on their camera rays that meet a
    shadow catcher for the first time split: the film's planes record the split (the matte as it is now, its
    transparency, the count, the world behind the catcher), and the copies are returned to be shaded at the same
    hits, (PathState of the copies, their rows of `found`'s rays), or None."""
    c = wave.catcher
    at = found[np.take(state.bounce, found) == 0]
    if not len(at):
        return None
    at = at[~np.take(c.caught, state.path[at])]
    if len(at):
        at = at[np.take(c.catchers.splits, tables.triangles.object_rows(np.take(hits.prim, at)))]
    if not len(at):
        return None
    paths = state.path[at]
    c.caught[paths] = True
    aux = wave.aux
    throughput = np.take(state.throughput, at, axis=1)
    aux[SPLITS][0, paths] = 1.0
    matte = aux[MATTE]
    matte[:3, paths] = wave.radiance[:, paths]
    matte[3, paths] = wave.alpha[paths] - throughput.mean(axis=0)
    if not wave.settings.transparent_background and BACKGROUND in aux:
        _background(tables, wave, state, rays, at, paths, throughput)
    copies = state.rows(at)
    copies.features, copies.pass_weights = None, None   # (Cycles writes neither for the copies)
    return copies, at


def _background(tables, wave, state, rays, at, paths, throughput) -> None:
    """The world along the camera rays behind the catchers they split at, into the Environment pass (Cycles'
    PATH_RAY_SHADOW_CATCHER_BACKGROUND, on an opaque film)."""
    d = rays.dirs
    dx, dy, dz = (np.take(d[:, k], at) for k in range(3))
    ray = None
    if tables.environment.shader:
        ray = RayInfo(np.take(state.bounce, at), np.take(state.transparent, at), emission=True,
                      lobes=None if state.lobes is None else np.take(state.lobes, at, axis=1),
                      portal=None if state.portal is None else np.take(state.portal, at))
    if tables.lights.world_camera:   # (a world the camera does not see is black here too)
        wave.aux[BACKGROUND][:, paths] += throughput * tables.environment.radiance(dx, dy, dz, ray)


def finish(wave, radiance, alpha) -> None:
    """At the end of a wave: the matte of the paths that never split is their light and alpha; the copies'
    transparency counts in the wave's alpha; a path whose light came out NaN or infinite adds none to the
    planes (the renderer drops it from the image)."""
    c = wave.catcher
    aux = wave.aux
    kept = ~c.caught
    aux[MATTE][:3, kept] = radiance[:, kept]
    aux[MATTE][3, kept] = alpha[kept]
    alpha += c.paths.alpha - np.float32(1.0)
    for plane in (aux[CATCHER], aux[MATTE]):
        plane[:, ~np.isfinite(plane).all(axis=0)] = 0.0


# ---------------------------------------------------------------- reading the film
def shadow_pass(combined, matte, catcher, splits) -> np.ndarray:
    """(..., 3) the Shadow Catcher pass from the means of Combined (..., 4), the matte (..., 4), the catcher plane
    (..., 3) and the splits (..., 1) (Cycles' film_calculate_shadow_catcher)."""
    light = combined[..., :3] - matte[..., :3]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(catcher != 0, light / np.where(catcher != 0, catcher, 1.0), 1.0)
    alpha = np.clip(combined[..., 3:4], 0.0, 1.0)
    return np.where(splits > 0, (1.0 - alpha) + alpha * ratio, 1.0).astype(np.float32)


def combined(combined_rgba, matte, catcher, splits, background, approximate_: bool, shadow=None) -> np.ndarray:
    """(..., 4) Combined where the scene has shadow catchers: the matte, or with approximate_ the matte over the
    shadow (Cycles' film_calculate_shadow_catcher_matte_with_shadow), over `background` (the Environment pass's
    mean) when it is given (an opaque film), else with the shadow in alpha. shadow: the Shadow Catcher pass
    (..., 3) to take the shadow from (a denoise's: Cycles reads the denoised pass there), None: made from the
    planes."""
    alpha = np.clip(matte[..., 3:4], 0.0, 1.0)
    if not approximate_:
        return np.concatenate([matte[..., :3], alpha], axis=-1).astype(np.float32)
    if shadow is None:
        shadow = shadow_pass(combined_rgba, matte, catcher, splits)
    alpha = (1.0 - alpha) * (1.0 - np.clip(shadow.mean(axis=-1, keepdims=True), 0.0, 1.0)) + alpha
    if background is None:
        return np.concatenate([matte[..., :3], alpha], axis=-1).astype(np.float32)
    rgb = matte[..., :3] + background * (1.0 - alpha)
    return np.concatenate([rgb, np.ones_like(alpha)], axis=-1).astype(np.float32)
