"""Data passes: what the film records about each pixel's first visible surface besides its colour, as
Cycles' data passes do (kernel/film/data_passes.h, scene/pass.cpp).

Two kinds, as in Cycles:
- FIRST: written by the pixel's sample 0 only and never averaged (Cycles' "overwrite" passes, unfiltered):
  Depth (distance along the camera's view axis; 1e10 where sample 0 saw no surface), Position,
  Object Index and Material Index (the pass indices; 0 for the background).
- MEAN: accumulated over every sample and divided by the sample count (misses count as 0): Normal (the
  closures' average normal, weighted by their sample weights), UV (u, v, 0 of the render UV map),
  Denoising Albedo and Denoising Normal, as Cycles' denoising features (kernel/film/denoising_passes.h):
  read at the first hit whose closures are not mostly specular (75% or more of the sample weight in
  closures of roughness^2 below 0.075^2: the path waits for the next bounce, its feature throughput
  multiplied by their albedo), the albedo summed over the diffuse-like closures (each closure's weight
  times its albedo estimate), the normal in camera space (x right, y up, z forward); where the path leaves
  to the world, the world's colour times that throughput. Albedo is clipped to [0, 1] for the denoiser.
- MIST: Cycles' mist, 1 minus the mean over samples of (1 - mist) x the camera ray's throughput at its first
  hit, mist = clamp((distance - start) / depth, 0, 1) ^ falloff (the world's Mist Pass settings); 1 where
  the camera sees the world.
- Emission and Environment (MEAN): what the camera sees of emitting surfaces and of the world directly
  (Environment even where a transparent film leaves it out of Combined), as Cycles' passes of those names.
- LIGHT: Cycles' Diffuse, Glossy and Transmission Direct and Indirect (kernel/film/light_passes.h): every
  contribution after the camera's first hit, split by the shares of the path's first bounce among the
  closure classes (diffuse-like; reflecting microfacets and glass seen from outside; the rest), direct when
  it lit the first hit. Read, as Cycles reads them, divided by the class's Color pass (the first hit's
  closure colours of that class): Combined = Emission + Environment + sum over classes of
  (Direct + Indirect) x Color + Volume Direct + Volume Indirect. Volume Direct and Indirect (no Color pass, as
  in Cycles) take what paths whose first scattering was in a medium find.
- Vector (WEIGHTED): Cycles' motion vectors, in pixels: (previous - current) and (current - next) raster
  positions of the camera rays' first surface point (x right, y up), the object's and the camera's
  transforms one frame before and after; averaged over the samples that hit a surface.
- Shader AOVs ("aov:<name>:color" or ":value", MEAN): the AOV Output node of that name at the camera rays'
  first hit (0 where the material has none), averaged over samples.
- LIGHTGROUP ("lightgroup:<k>", MEAN): the Combined light of the emitters of light group k (View Layer > Light
  Groups, Blender's "Combined_<name>"), with the path's throughput, MIS weights and clamping as in Combined, as
  Cycles writes its light group passes (kernel/film/light_passes.h); kernels/light_groups.py finds each
  contribution's emitter. Emitters in no group add to Combined only.
- NOISE: an unbiased estimate of the variance of each pixel's mean: the squared difference between the
  mean of its odd-numbered samples and the mean of all (Cycles' adaptive sampling compares the same two);
  one estimate per pixel, so itself noisy (blur it to read it); 0 with fewer than two samples.
- Shadow catchers (kernels/shadow_catcher.py): the planes Cycles keeps for them (MEAN; the renderer records
  them whenever the scene has a shadow catcher) and the Shadow Catcher pass (CATCHER), made from them and
  Combined when read, as Cycles' pass accessor makes it.
"""
from __future__ import annotations

import numpy as np

from . import panorama
from .bsdf.light_passes import class_albedo, closure_albedos, eval_split, pass_classes
from .cryptomatte import CryptoFilm
from .bsdf.lobes import MICROFACET_LOBES, SINGULAR_LOBES, TRANSPARENT
from .camera import view_plane
from .paths import seen_through, transparent_limit
from .scene import OBJ_PASS_INDEX, Camera
from .vec import matmul

# name -> (channels, kind)
PASSES = {
    "depth": (1, "FIRST"),
    "position": (3, "FIRST"),
    "object_index": (1, "FIRST"),
    "material_index": (1, "FIRST"),
    "normal": (3, "MEAN"),
    "uv": (3, "MEAN"),
    "denoising_albedo": (3, "MEAN"),
    "denoising_normal": (3, "MEAN"),
    "denoising_depth": (1, "MEAN"),
    "mist": (1, "MIST"),
    "emission": (3, "MEAN"),
    "environment": (3, "MEAN"),
    "ao": (3, "MEAN"),
    "noise": (3, "NOISE"),
    "vector": (4, "WEIGHTED"), "vector_weight": (1, "MEAN"),
    "diffuse_direct": (3, "LIGHT"), "diffuse_indirect": (3, "LIGHT"), "diffuse_color": (3, "MEAN"),
    "glossy_direct": (3, "LIGHT"), "glossy_indirect": (3, "LIGHT"), "glossy_color": (3, "MEAN"),
    "transmission_direct": (3, "LIGHT"), "transmission_indirect": (3, "LIGHT"), "transmission_color": (3, "MEAN"),
    "volume_direct": (3, "LIGHT"), "volume_indirect": (3, "LIGHT"),
    "catcher": (3, "MEAN"), "catcher_matte": (4, "MEAN"), "catcher_samples": (1, "MEAN"),
    "shadow_catcher": (3, "CATCHER"),
}
# PathState.pass_weights' rows: the diffuse and glossy shares (RGB) of the first bounce, and in scenes with media
# a seventh, 1 where the first scattering was in a medium (Cycles' PATH_RAY_VOLUME_PASS).
VOLUME_ROW = 6
BACKGROUND_DEPTH = 1e10


CRYPTO_KINDS = ("object", "material", "asset")
# Light group k's pass: GROUP_PREFIX + str(k).
GROUP_PREFIX = "lightgroup:"


def channels(name: str) -> int:
    if name.startswith("aov:"):  # Shader AOVs: "aov:<name>:color" (3) or "aov:<name>:value" (1)
        return 3 if name.endswith(":color") else 1
    if name.startswith(GROUP_PREFIX):
        return 3
    return PASSES[name][0]


def is_first(name: str) -> bool:
    return kind(name) == "FIRST"


def kind(name: str) -> str:
    if name.startswith(GROUP_PREFIX):
        return "LIGHTGROUP"
    return "MEAN" if name.startswith("aov:") else PASSES[name][1]


def exposed(name: str) -> bool:
    """Whether Film > Exposure scales the pass, as Cycles' (scene/pass.cpp use_exposure): the light passes,
    Emission, Environment and the light groups; not the data passes, the colours nor the Shadow Catcher."""
    return kind(name) in ("LIGHT", "LIGHTGROUP") or name in ("emission", "environment")


def recorded(name: str) -> bool:
    """Whether the paths write the pass (a CATCHER pass is made from others when read)."""
    return kind(name) != "CATCHER"


def known(name: str) -> bool:
    return name in PASSES or (name.startswith("aov:") and name.endswith((":color", ":value"))) or \
        (name.startswith(GROUP_PREFIX) and name[len(GROUP_PREFIX):].isdigit())


def group_pass(k: int) -> str:
    """The pass name of light group k."""
    return f"{GROUP_PREFIX}{int(k)}"


def denoising_features(closures, n_hits: int, fallback):
    """Per hit: (normal (3, n) sample-weighted, diffuse albedo (3, n), specular albedo (3, n), done (n,)):
    done where the diffuse-like closures hold more than a quarter of the sample weight (or there is no
    closure), as Cycles' film_write_denoising_features_surface decides."""
    normal = closure_normal(closures, n_hits, fallback)
    diffuse = np.zeros((3, n_hits), np.float32)
    specular = np.zeros((3, n_hits), np.float32)
    if not len(closures):
        return normal, diffuse, specular, np.ones(n_hits, bool)
    albedo = closure_albedos(closures)
    sw = np.asarray(closures.sw, np.float32)
    # Cycles' bsdf_get_specular_roughness_squared: alpha_x alpha_y for microfacet lobes, 0 for singular ones,
    # 1 for the rest (diffuse, sheen, toon).
    rough2 = np.broadcast_to(closures.ax, sw.shape) * np.broadcast_to(closures.ay, sw.shape)
    diffuse_like = ~(np.isin(closures.lobe, SINGULAR_LOBES) | (
        np.isin(closures.lobe, MICROFACET_LOBES) & ~(rough2 > np.float32(0.075 ** 2))))
    for k in range(3):
        diffuse[k] = np.bincount(closures.hit, np.where(diffuse_like, albedo[k], 0), minlength=n_hits)
        specular[k] = np.bincount(closures.hit, np.where(diffuse_like, 0, albedo[k]), minlength=n_hits)
    total = np.bincount(closures.hit, sw, minlength=n_hits)
    nonspecular = np.bincount(closures.hit, np.where(diffuse_like, sw, 0), minlength=n_hits)
    done = (total == 0) | (nonspecular * 4 > total)
    return normal, diffuse, specular, done


def closure_normal(closures, n_hits: int, fallback) -> np.ndarray:
    """(3, n) the closures' average normal per hit, weighted by sample weight; the shading normal where a
    hit has no closure."""
    out = np.stack([np.asarray(c, np.float32) for c in fallback]).copy()
    if not len(closures):
        return out
    sw = np.asarray(closures.sw, np.float32)
    summed = np.stack([np.bincount(closures.hit, closures.normal[k] * sw, minlength=n_hits) for k in range(3)])
    length = np.sqrt((summed * summed).sum(axis=0))
    ok = length > 0
    out[:, ok] = (summed[:, ok] / length[ok]).astype(np.float32)
    return out


# ---------------------------------------------------------------- a wave's buffers and planes
def path_bytes(settings) -> int:
    """Bytes a wave keeps per path from its start to its end: radiance and alpha (float32) and wave_buffers'."""
    channels_kept = 4 + sum(channels(name) for name in settings.passes if recorded(name))
    if settings.cryptomatte:   # a row per surface seen, the first one here (more behind transparent ones grow it)
        channels_kept += len(settings.cryptomatte) + 1
    return 4 * channels_kept


def wave_buffers(settings, n: int) -> dict | None:
    """Per-path buffers of a wave of n paths for the passes and Cryptomatte the settings ask for (None: none)."""
    if not (settings.passes or settings.cryptomatte):
        return None
    aux = {name: np.zeros((channels(name), n), np.float32) for name in settings.passes if recorded(name)}
    for kind in settings.cryptomatte:
        aux["crypto_" + kind] = np.zeros((1, n), np.float32)
    if settings.cryptomatte:
        aux["crypto_weight"] = np.zeros((1, n), np.float32)
    return aux


def wave_planes(aux: dict, settings, pix, sample, pixels, spp: int, rows: int, width: int, radiance) -> dict:
    """A wave's pass planes from its per-path buffers: each path's pixel `pix` (its place in the wave's
    rows x width) and sample number `sample`; `pixels` the wave's pixels that took spp samples each; FIRST passes
    as (plane, written) from sample 0, the others summed per pixel; Cryptomatte as a CryptoFilm per kind."""
    npix = rows * width
    out = {}
    first = sample == 0
    if "noise" in aux:  # the odd-numbered samples' sum (Cycles' adaptive sampling estimate)
        aux["noise"] = np.where((sample & np.uint32(1)).astype(bool), radiance, 0.0).astype(np.float64)
    weight = aux.pop("crypto_weight", None)
    for kind in settings.cryptomatte:
        ids = aux.pop("crypto_" + kind)
        wave_film = CryptoFilm(rows, width, settings.cryptomatte_depth)
        # Row r: each path's r-th surface seen (behind r transparent ones), all in one call.
        wave_film.add(np.tile(pix, len(ids)), ids.reshape(-1), weight.reshape(-1))
        out["crypto_" + kind] = wave_film
    for name, values in aux.items():
        c = len(values)
        if is_first(name):
            plane = np.zeros((npix, c), np.float32)
            written = np.zeros(npix, bool)
            plane[pix[first]] = values[:, first].T
            written[pix[first]] = True
            out[name] = (plane.reshape(rows, width, c), written.reshape(rows, width))
        else:
            total = np.zeros((npix, c), np.float64)
            total[pixels] = values.reshape(c, len(pixels), spp).sum(axis=2).T
            out[name] = total.reshape(rows, width, c)
    return out


# ---------------------------------------------------------------- writing: a wave's paths into the passes
# Functions over (scene tables, wave, path state), as the integrator's stages (kernels/integrator.py).


def add_light(tables, wave, state, rows, value, first_shares, groups=None) -> None:
    """Add (3, n) contributions of light found from the current vertex of the paths rows (state rows): by
    a shadow ray, or along the glass branch not taken. Clamped as direct light at the first hit, indirect
    deeper; in the light passes, split at the first hit by first_shares(positions in rows) -> (6, k)
    class shares, deeper as the path's first bounce was. groups: the light groups' parts of value (write_parts),
    or None."""
    scale = clamp_scale(wave, value, np.take(state.bounce, rows) > 0)
    unclamped = value
    value = value if scale is None else value * scale
    accumulate(wave.radiance, state.path[rows], value)
    if groups is not None and wave.groups is not None:
        write_parts(wave, state.path[rows], groups, unclamped, scale)
    if state.pass_weights is not None:
        first = np.flatnonzero(np.take(state.bounce, rows) == 0)
        shares = first_shares(first) if len(first) else None
        write_light(tables, wave, state, rows, value, shadow=True, first=(first, shares))


def clamp(wave, value: np.ndarray, indirect: np.ndarray) -> np.ndarray:
    """Cycles' sample clamping (film_clamp_light) of (3, n) contributions: scaled so that |R| + |G| + |B|
    is at most 3 x Clamp Indirect where `indirect`, 3 x Clamp Direct elsewhere (Cycles triples the
    setting, scene/integrator.cpp); a limit of 0 is off. Direct is
    Cycles' bounce - 1 <= 0 for light found by rays (the camera's, or the first hit's BSDF ray) and the
    first hit's own shadow rays."""
    scale = clamp_scale(wave, value, indirect)
    return value if scale is None else value * scale


def clamp_scale(wave, value: np.ndarray, indirect: np.ndarray) -> np.ndarray | None:
    """(n,) float32 factors by which clamp() scales the contributions value (3, n), None when it leaves them."""
    direct_limit, indirect_limit = wave.settings.clamp_direct, wave.settings.clamp_indirect
    if not direct_limit and not indirect_limit:
        return None
    limit = np.where(indirect, np.float32(3 * indirect_limit or np.inf), np.float32(3 * direct_limit or np.inf))
    total = np.abs(value).sum(axis=0)
    over = total > limit
    if not over.any():
        return None
    return np.where(over, limit / np.where(over, total, np.float32(1.0)), np.float32(1.0)).astype(np.float32)


def accumulate(radiance: np.ndarray, paths: np.ndarray, value: np.ndarray) -> None:
    """radiance[:, paths] += value, one channel at a time (3x faster than the 2-D fancy index)."""
    for k in range(3):
        channel = radiance[k]
        channel[paths] += value[k]


# ---- light groups' passes: a contribution in the pass of its emitter's group (kernels/light_groups.py finds it)
def wave_groups(aux: dict | None) -> dict | None:
    """{group: its (3, N) buffer of aux} for the light groups a wave records, None when it records none."""
    if aux is None:
        return None
    found = {int(name[len(GROUP_PREFIX):]): values for name, values in aux.items() if name.startswith(GROUP_PREFIX)}
    return found or None


def write_groups(wave, paths: np.ndarray, value: np.ndarray, groups) -> None:
    """Add contributions value (3, n) of the wave's paths `paths` to the passes of their emitters' groups: groups
    (n,) int, or one int for all (NO_GROUP, -1, and groups without a pass: nowhere)."""
    if np.ndim(groups) == 0:
        target = wave.groups.get(int(groups))
        if target is not None:
            accumulate(target, paths, value)
        return
    for k, target in wave.groups.items():
        mine = np.flatnonzero(groups == k)
        if len(mine):
            accumulate(target, paths[mine], value[:, mine])


def write_parts(wave, paths: np.ndarray, parts, value: np.ndarray, scale: np.ndarray | None = None) -> None:
    """write_groups for contributions value (3, n) of paths (n,) made of parts from emitters of different groups
    (the world and the sun discs a ray looks into): parts, a list of (columns (m,) or None for all, groups (m,) or
    one int, the part (3, m) or None for value's own); scale: the contributions' clamp_scale (None: unclamped)."""
    for columns, groups, part in parts:
        if part is None:
            part = value if columns is None else value[:, columns]
        if scale is not None:
            part = part * (scale if columns is None else scale[columns])
        write_groups(wave, paths if columns is None else paths[columns], part, groups)


# ---- light passes: what a contribution to the image adds to Cycles' Diffuse/Glossy/Transmission passes
def write_light(tables, wave, state, rows, value, shadow: bool = False, first=None) -> None:
    """value (3, m): clamped contributions of the paths rows (state rows). Light found by a ray is direct
    at bounce 1 (it lit the first hit), by a shadow ray at bounce 0; deeper it is indirect. Each splits by
    the path's class shares of its first bounce (first: (positions, (6, k) shares) for shadow rays at
    the first hit, split by the closures there)."""
    if not len(rows):
        return
    aux = wave.aux
    if wave.catcher is not None:   # paths split at a shadow catcher write no light pass (Cycles' light_passes.h)
        value = value * ~np.take(wave.catcher.caught, state.path[rows])
    shares = np.take(state.pass_weights, rows, axis=1)
    bounce = np.take(state.bounce, rows)
    direct = bounce == (0 if shadow else 1)
    if first is not None and len(first[0]):
        given = first[1]
        shares[:len(given), first[0]] = given
        if len(given) < len(shares):   # a surface's own split: none of it is the medium's
            shares[len(given):, first[0]] = 0.0
    paths = state.path[rows]
    surface = np.float32(1)
    parts = [("diffuse", shares[:3]), ("glossy", shares[3:6]), ("transmission", None)]
    if len(shares) > VOLUME_ROW:
        surface = np.float32(1) - shares[VOLUME_ROW]
        parts.append(("volume", shares[VOLUME_ROW:VOLUME_ROW + 1]))
        shares = shares[:VOLUME_ROW] * surface
    parts[0], parts[1] = ("diffuse", shares[:3]), ("glossy", shares[3:6])
    parts[2] = ("transmission", surface - shares[:3] - shares[3:6])
    for cls, share in parts:
        for suffix, sel in (("direct", direct), ("indirect", ~direct)):
            name = f"{cls}_{suffix}"
            if name in aux:
                pick = np.flatnonzero(sel)
                if len(pick):
                    aux[name][:, paths[pick]] += value[:, pick] * share[:, pick]


def first_bounce_shares(tables, state, closures, bs) -> None:
    """At the first scattering (not a transparent pass-through), the class shares of the sampled
    direction: the chosen closure's class for a singular lobe, the mixture's split otherwise (Cycles'
    pass_diffuse_weight and pass_glossy_weight)."""
    rows = np.flatnonzero((state.bounce == 0) & ~bs.transparent & (bs.row >= 0))
    if not len(rows):
        return
    wi = tuple(np.take(c, rows) for c in bs.wi)
    delta = np.take(bs.delta, rows)
    shares = np.zeros((6, len(rows)), np.float32)
    d = np.flatnonzero(delta)
    if len(d):
        diffuse, glossy = pass_classes(closures, np.take(bs.row, rows[d]), tuple(c[d] for c in wi))
        shares[:3, d], shares[3:, d] = diffuse.astype(np.float32), glossy.astype(np.float32)
    m = np.flatnonzero(~delta)
    if len(m):
        shares[:, m] = class_shares(*eval_split(closures, rows[m], tuple(c[m] for c in wi)))
    state.pass_weights[:VOLUME_ROW, rows] = shares
    if len(state.pass_weights) > VOLUME_ROW:
        state.pass_weights[VOLUME_ROW, rows] = 0.0


def class_shares(f, f_diffuse, f_glossy) -> np.ndarray:
    """(6, n): the diffuse and glossy parts of f per channel (Cycles' safe_divide: 0 where f is 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.nan_to_num(np.concatenate([f_diffuse / f, f_glossy / f]), nan=0.0, posinf=0.0,
                             neginf=0.0).astype(np.float32)


# Data passes a camera path takes from one surface: the first it meets that is opaque enough (Cycles'
# PATH_RAY_SINGLE_PASS_DONE); the first four from each surface before it too, the last one's value kept.
SINGLE_PASSES = ("depth", "position", "object_index", "material_index", "normal", "uv", "vector")
_OVERWRITTEN = ("depth", "position", "object_index", "material_index")


def has_single_passes(aux) -> bool:
    """Whether the wave records a pass that stops at a camera path's one surface (SINGLE_PASSES, the AOVs)."""
    return aux is not None and any(name in SINGLE_PASSES or name.startswith("aov:") for name in aux)


def behind_transparent(aux) -> bool:
    """Whether the wave records a pass the surfaces behind transparent ones add to (Colors, Mist, Cryptomatte)."""
    return any(name in aux for name in ("diffuse_color", "glossy_color", "transmission_color", "mist",
                                        "crypto_weight"))


# ---- stage: data passes of the surfaces the camera sees (kernels.passes)
def write_data(tables, aux: dict, state, hit, closures, settings, first: bool) -> None:
    """The data passes at the surfaces the camera sees, as Cycles' film_write_data_passes: at a camera path's first
    surface (first: the camera rays' step) and at those behind transparent surfaces (rows still seen through).
    Depth, Position and the indices are taken at each such surface until one is opaque enough (alpha at least
    settings.pass_alpha_threshold, or no transparent closure), which alone gives Normal, UV and Vector; the
    Color passes and Mist add every such surface's share (throughput, and alpha for Mist); AOVs add the values of
    the surfaces up to that one (Cycles' svm_node_aov_check); Cryptomatte records every such surface, each weighed
    by its share (throughput times alpha: Cycles' matte_weight), in a row of its own per path."""
    if first:
        rows = np.arange(len(hit))
    else:
        # Not at the surface a path meets at the transparent limit: Cycles ends it there before the passes.
        rows = np.flatnonzero(seen_through(state) & (state.transparent < transparent_limit(settings)))
        if not len(rows):
            return
    pending = state.data_pending
    single = rows if pending is None or first else rows[np.take(pending, rows)]
    alpha = None
    if pending is not None and len(single):
        alpha = closure_alpha(closures, len(hit))
        done = np.ones(len(hit), bool) if settings.pass_alpha_threshold <= 0 else \
            alpha.mean(axis=0) >= np.float32(settings.pass_alpha_threshold)
        taken = single[done[single]]
        state.data_pending[single] = ~done[single]
    else:
        taken = single
    level = None
    if "crypto_weight" in aux:
        # Each path's next free row: one per surface of weight above 0 so far (a surface seen with none, wholly
        # transparent, leaves its row to the next).
        level = np.zeros(len(rows), np.int64) if first else \
            np.count_nonzero(aux["crypto_weight"][:, state.path[rows]], axis=0)
        grow = int(level.max(initial=0)) + 1 - len(aux["crypto_weight"])
        if grow > 0:
            for name in [k for k in aux if k.startswith("crypto_")]:
                aux[name] = np.concatenate([aux[name], np.zeros((grow, aux[name].shape[1]), np.float32)])
    _write_data(tables, aux, state, hit, closures, settings, rows, single, taken, first, alpha, level)


def closure_alpha(closures, n: int) -> np.ndarray:
    """(3, n) Cycles' surface_shader_alpha of the hits: one minus their transparent closures' weight, in [0, 1]."""
    alpha = np.ones((3, n), np.float32)
    if len(closures):
        clear = np.flatnonzero(closures.lobe == TRANSPARENT)
        if len(clear):
            transparency = np.stack([np.bincount(closures.hit[clear], closures.weight[k, clear], minlength=n)
                                     for k in range(3)])
            alpha = np.clip(1.0 - transparency, 0.0, 1.0).astype(np.float32)
    return alpha


def _write_data(tables, aux, state, hit, closures, settings, rows, single, taken, first, alpha, level=None) -> None:
    """write_data's passes: rows see the camera, single those still looking for their one surface, taken those
    that find it here; level: the Cryptomatte row each of rows writes."""
    paths = state.path
    n = len(hit)
    colours = None  # the closure classes' colours, made once for the three Color passes
    for name, out in aux.items():
        if name in _OVERWRITTEN:
            at = single
        elif name in SINGLE_PASSES:
            at = taken
        elif name.startswith("crypto_"):
            at = rows
        elif name.startswith("aov:"):   # Cycles' svm_node_aov_check: until the one surface, added up
            at = single
        else:
            at = rows
        if not len(at):
            continue
        whole = len(at) == n
        p = paths if whole else paths[at]

        def pick(values):   # (C, n) -> the columns at
            return values if whole else np.take(values, at, axis=-1)

        if name == "depth":
            eye, rotation = tables.camera_frame
            d = np.stack([c.astype(np.float64) for c in hit.p]) - eye[:, None]
            out[0, p] = pick(np.sqrt((d * d).sum(axis=0)) if tables.scene.camera.kind == "PANO" else
                             -matmul(rotation[:, 2], d))
        elif name == "position":
            out[:, p] = pick(np.stack(hit.p))
        elif name == "object_index":
            if tables.scene.objects is not None:
                objects = tables.triangles.object_rows(hit.prim)
                out[0, p] = pick(np.take(tables.scene.objects[:, OBJ_PASS_INDEX], objects))
        elif name == "material_index":
            indices = np.asarray(tables.scene.materials.pass_indices or (0,) * tables.scene.materials.count,
                                 np.float32)
            out[0, p] = pick(np.take(indices, hit.mat))
        elif name == "normal":
            out[:, p] = pick(closure_normal(closures, n, hit.ns))
        elif name == "uv":
            u, v = hit.uv_at(np.arange(n))
            out[0, p], out[1, p] = pick(u), pick(v)
        elif name.startswith("crypto_"):
            kind = name[len("crypto_"):]
            table = (tables.scene.crypto_ids or {}).get(kind)
            if kind == "weight":  # the sample's matte weight: what reaches the camera from here, times alpha
                if alpha is None:
                    alpha = closure_alpha(closures, n)
                out[level, p] = pick(state.throughput.mean(axis=0) * alpha.mean(axis=0))
            elif table is not None and len(table):
                objects = hit.mat if kind == "material" else \
                    tables.triangles.object_rows(hit.prim)
                if objects is not None:
                    out[level, p] = pick(np.take(table, objects))
        elif name == "vector":
            if tables.scene.vector_motion is not None:
                out[:, p] = pick(motion_vectors(tables, hit))
            if "vector_weight" in aux:
                aux["vector_weight"][0, p] = 1.0
        elif name.startswith("aov:"):
            _, aov_name, which = name.split(":")
            value = pick(tables.shading.aov(hit, aov_name, 3 if which == "color" else 1))
            if first:
                out[:, p] = value
            else:
                out[:, p] += value
        elif name in ("diffuse_color", "glossy_color", "transmission_color"):
            if colours is None:
                colours = dict(zip(("diffuse_color", "glossy_color", "transmission_color"),
                                   class_albedo(closures, n)))
            value = pick(colours[name] * state.throughput)
            if first:
                out[:, p] = value
            else:   # the surfaces behind transparent ones add theirs
                accumulate(out, p, value)
        elif name == "mist":
            eye, rotation = tables.camera_frame
            d = np.stack([c.astype(np.float64) for c in hit.p]) - eye[:, None]
            distance = np.abs(matmul(rotation[:, 2], d)) if tables.scene.camera.kind == "ORTHO" else \
                np.sqrt((d * d).sum(axis=0))
            start, depth, falloff = settings.mist
            mist = np.clip((distance - start) / max(depth, 1e-30), 0.0, 1.0) ** falloff
            if alpha is None:
                alpha = closure_alpha(closures, n)
            value = pick((1.0 - mist) * (state.throughput * alpha).mean(axis=0))
            if first:
                out[0, p] = value
            else:
                out[0, p] += value


def motion_vectors(tables, hit) -> np.ndarray:
    """(4, n) Cycles' Vector pass at the hits: (previous - current, current - next) raster positions."""
    before, after, cam_before, cam_after = tables.scene.vector_motion
    p = np.stack([c.astype(np.float64) for c in hit.p])          # (3, n)
    rows = tables.triangles.object_rows(hit.prim)
    if rows is None:
        rows = np.zeros(len(hit), np.int64)
    camera = tables.scene.camera

    def moved(m):  # (K, 3, 4) per object row
        m = m[rows]
        return np.einsum("nij,jn->in", m[:, :, :3], p) + m[:, :, 3].T

    p_pre, p_post = moved(before), moved(after)
    ids = tables.scene.vector_deform_ids
    if ids is not None:   # deforming triangles: their corners at both frames at the hit's barycentrics
        prim = np.asarray(hit.prim)
        columns = np.where((prim >= 0) & (prim < len(ids)), np.take(ids, np.clip(prim, 0, len(ids) - 1)), -1)
        at = np.flatnonzero(columns >= 0)
        if len(at):
            b1, b2 = (np.take(b, at).astype(np.float64) for b in hit.barycentrics)
            weights = np.stack([1.0 - b1 - b2, b1, b2])                # (3 corners, m)
            corners = tables.scene.vector_deform[:, columns[at]].astype(np.float64)   # (2, m, 3 corners, 3)
            p_pre[:, at] = np.einsum("cm,mcj->jm", weights, corners[0])
            p_post[:, at] = np.einsum("cm,mcj->jm", weights, corners[1])
    centre = _raster(camera, camera.world_from_camera, p)
    pre = _raster(camera, cam_before, p_pre)
    post = _raster(camera, cam_after, p_post)
    return np.concatenate([pre - centre, centre - post]).astype(np.float32)


def _raster(camera: Camera, world_from_camera, p: np.ndarray) -> np.ndarray:
    """(2, n) raster positions (x right, y up, in pixels of the full frame) of world points p (3, n) seen by
    `camera` placed at world_from_camera (4, 4)."""
    m = np.asarray(world_from_camera, np.float64)
    rotation = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0)
    local = matmul(rotation.T, p - m[:3, 3][:, None])
    if camera.kind == "PANO":
        sx, sy = panorama.panorama_raster(camera, (local / np.linalg.norm(local, axis=0)).T)
        return np.stack([sx, camera.height - sy])
    xmin, xmax, ymin, ymax = view_plane(camera)
    if camera.kind == "ORTHO":
        px, py = local[0], local[1]
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            px, py = local[0] / -local[2], local[1] / -local[2]
    return np.stack([(px - xmin) / (xmax - xmin) * camera.width, (py - ymin) / (ymax - ymin) * camera.height])


def write_denoising_features(tables, aux: dict, state, hit, shading, t_hit, settings=None) -> None:
    """Cycles' denoising features: written at the first hit that is not mostly specular (the depth
    summed over the segments until then, each weighted by the feature throughput). The albedo also
    takes the emission of emitters that paths still looking for it meet, times the feature throughput,
    as the world's colour (Cycles' film_write_emission_or_background_pass): an emitter the camera sees
    has its emission as albedo. Albedo is kept within [0, 1], what OpenImageDenoise reads. At the surface a
    path meets at the transparent limit (settings' transparent_limit) only the emission's albedo: Cycles ends
    the path there before film_write_denoising_features_surface."""
    closures = shading.closures
    open_ = np.flatnonzero(~np.isnan(state.features[0]))
    if not len(open_):
        return
    if "denoising_albedo" in aux and tables.emissive:
        lit = open_[np.take(tables.shading.emissive, np.take(hit.mat, open_))]
        if len(lit):
            add_albedo(aux, state.path[lit], state.features[:, lit] * np.take(shading.emission, lit, axis=1))
    if settings is not None:
        open_ = open_[np.take(state.transparent, open_) < transparent_limit(settings)]
        if not len(open_):
            return
    if "denoising_depth" in aux:
        aux["denoising_depth"][0, state.path[open_]] += state.features[:, open_].mean(axis=0) * \
            np.take(t_hit, open_)
    normal, diffuse, specular, done = denoising_features(closures, len(hit), hit.ns)
    rows = open_[done[open_]]
    if len(rows):
        paths = state.path[rows]
        if "denoising_albedo" in aux:
            add_albedo(aux, paths, state.features[:, rows] * diffuse[:, rows])
        if "denoising_normal" in aux:
            rotation = tables.camera_frame[1].astype(np.float32)  # columns: right, up, back
            aux["denoising_normal"][:, paths] = matmul(rotation.T, normal[:, rows]) * \
                np.array([1, 1, -1], np.float32)[:, None]
        state.features[:, rows] = np.nan
    waiting = open_[~done[open_]]
    state.features[:, waiting] *= specular[:, waiting]


def add_albedo(aux: dict, paths: np.ndarray, albedo: np.ndarray) -> None:
    """Add (3, n) albedo to the Denoising Albedo of paths (one entry per path), kept within [0, 1]."""
    aux["denoising_albedo"][:, paths] = np.minimum(aux["denoising_albedo"][:, paths] + np.maximum(albedo, 0.0), 1.0)
