"""The state that travels with every live path of a wave, declared once, with one compact()."""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from .accel import RayTimes
from .environment import WorldFocus
from .rng import PathRng, seed_paths
from .samples import LIGHT, Samples, sample_strata

# Russian roulette decides on the surfaces that rays hit once their path has scattered this many times
# (Cycles: bounce > min_bounce, min_bounce 1 by default; NEE_MIS only: LECTURE and COSINE stay the plain
# estimators they are, for teaching and as references).
ROULETTE_DEPTH = 2

# Cycles' closure labels, as PathState.lobes[0] holds the last bounce's (kernel/closure/bsdf_util.h).
DIFFUSE, GLOSSY, SINGULAR, REFLECT, TRANSMIT = 1, 2, 4, 8, 16
VOLUME_SCATTER = 32   # the last bounce scattered in a medium (Cycles' LABEL_VOLUME_SCATTER)
# Not a label: set in PathState.lobes[0] once any bounce was diffuse, and kept (Cycles' PATH_RAY_DIFFUSE_ANCESTOR,
# after which a Christensen-Burley closure is diffuse).
DIFFUSE_ANCESTOR = 64


def facing_of(mis_facing, rows=None):
    """PathState.mis_facing (or its columns rows) as the light choice's facing tuple (nx, ny, nz, two_sided);
    None for None."""
    if mis_facing is None:
        return None
    m = mis_facing if rows is None else np.take(mis_facing, rows, axis=1)
    return m[0], m[1], m[2], m[3] > 0


def kept_origins(state, rays, rows=None, ray_rows=None):
    """The rays' origins as Cycles keeps them through transparent surfaces (PathState.mis_origin), (n, 3), and how
    far back along each ray that lies, (n,) float32 (0 where the ray passed nothing): Cycles meets lamps from
    there with tmin that distance, and weighs emitters and portals from there. rows: state rows (an index array
    or a slice; None: all); ray_rows: the rows of `rays` they are (None: rows)."""
    rows = slice(None) if rows is None else rows
    ray_rows = rows if ray_rows is None else ray_rows
    o = rays.origins[ray_rows]
    if state.mis_origin is None:
        return o, np.zeros(len(o), np.float32)
    kept = state.mis_origin[:, rows].T
    fresh = np.isnan(kept[:, 0])
    if fresh.all():
        return o, np.zeros(len(o), np.float32)
    kept = np.where(fresh[:, None], o, kept)
    back = np.maximum(np.einsum("ij,ij->i", o - kept, rays.dirs[ray_rows]), np.float32(0)).astype(np.float32)
    return kept, back


@dataclass
class PathState:
    path: np.ndarray        # (N,) int64: wave index of the path, where its radiance is accumulated
    throughput: np.ndarray  # (3, N) float32: product of BSDF weights (and 1/q of Russian roulette)
    bsdf_pdf: np.ndarray    # (N,) float32: pdf of the direction that led here (for MIS); inf = camera ray
    samples: Samples        # the paths' random numbers
    bounce: np.ndarray      # (N,) int32: scattering events so far (0 = still the camera ray)
    transparent: np.ndarray  # (N,) int32: transparent surfaces passed straight through so far
    dp: np.ndarray          # (N,) float32: the ray's position spread (Cycles' compact differential dP)
    min_ray_pdf: np.ndarray | None = None  # (N,) float32: the smallest BSDF pdf of the path so far (Filter
    #                                        Glossy, Bevel), inf for camera rays; None when neither reads it
    lobes: np.ndarray | None = None  # (4, N) int32 or None: the last bounce's LABEL_* bits and the diffuse,
    #                                  glossy and transmission bounce counts (Light Path), when read
    time: object = None     # accel.RayTimes or None: the paths' times in the shutter (motion blur)
    features: np.ndarray | None = None  # (3, N) float32 denoising feature throughput, NaN once written
    #                                     (kernels.passes), or None when the denoiser's passes are not recorded
    pass_weights: np.ndarray | None = None  # (6, N) float32 diffuse and glossy shares (RGB) of the first bounce
    #                                         (Cycles' light passes), or None when no light pass is recorded
    continuation: np.ndarray | None = None  # (N,) float32 Russian roulette's verdict on the surface the ray
    #                                         will hit: 1 shade it, q in (0, 1) shade it and divide by q, 0
    #                                         only take its emission (Cycles' continuation_probability and
    #                                         PATH_RAY_TERMINATE_ON_NEXT_SURFACE); None before any roulette
    escape_scale: np.ndarray | None = None  # (N,) float32 factor on what the ray finds if it leaves the
    #                                         scene at once: the probability of the smooth-glass branch it
    #                                         took (glass_escapes.py), 1 elsewhere; None when no path
    #                                         took one at its last bounce
    focus: object = None    # environment.WorldFocus or None: how the vertex that sent each ray focused its
    #                         light samples of the world (for the MIS weight of the world the ray finds)
    partner: np.ndarray | None = None  # (N,) int64 or None: the coincident triangle each ray meets where it
    #                                    leaves its surface, -1 none (kernels.coincident); None in scenes
    #                                    without coincident surfaces
    partner_uv: np.ndarray | None = None  # (2, N) float32: that hit's barycentrics (u, v)
    handed: np.ndarray | None = None   # (N,) bool: the ray's hit was handed over from a coincident one (its
    #                                    own crossing is not handed on again)
    portal: np.ndarray | None = None   # (N,) int32 Ray Portals passed (Light Path's Portal Depth); None in
    #                                    scenes without Ray Portal closures
    segments: np.ndarray | None = None  # (N,) int32: the rays traced so far (the wave loop's step count)
    media: np.ndarray | None = None    # (STACK_SIZE, N) int32 or None: the media each path is inside (ids of
    #                                    kernels.media.Media, -1 empty slots: Cycles' volume stack); None in
    #                                    scenes without media
    volume_bounces: np.ndarray | None = None  # (N,) int32 scattering events in media so far (with media)
    volume_bounds: np.ndarray | None = None   # (N,) int32 volume boundaries passed (with media; Cycles'
    #                                           volume_bounds_bounce)
    mis_facing: np.ndarray | None = None  # (4, N) float32: the shading normal of the vertex each ray left and
    #                                       1 where its closures transmit (Cycles' mis_origin_n and
    #                                       PATH_RAY_MIS_HAD_TRANSMISSION; zeros: none), for the light tree's
    #                                       choice in MIS pdfs; None where the light choice reads no normal
    mis_origin: np.ndarray | None = None  # (3, N) float32: where the ray started before the transparent surfaces it
    #                                       passed since its last vertex (Cycles keeps a ray's P through them and
    #                                       moves only its tmin), NaN where it passed none; lamps, emitters and
    #                                       portals are met and weighed from there. None in scenes where rays can
    #                                       pass nothing or find no such light
    link_set: np.ndarray | None = None  # (N,) uint8 or None: the light set of the object the ray left (Light
    #                                     Linking; Cycles' mis_ray_object), 0 for camera rays; None in scenes
    #                                     without linking
    scattered: np.ndarray | None = None  # (N,) bool or None (with link_set): the ray leaves a scattering, not a
    #                                      transparent pass-through (shadow linking's dedicated rays follow it)
    self_key: np.ndarray | None = None  # (N,) int64 the curve or point the ray leaves, which it skips
    #                                     (kernels.geometry.primitives), -1 none; None in scenes without them
    see_through: np.ndarray | None = None  # (N,) bool: the path has only passed transparent surfaces and smooth
    #                                        glass since the camera (Cycles' PATH_RAY_TRANSPARENT_BACKGROUND past
    #                                        bounce 0); None without Transparent Glass (settings.transparent_glass)
    dd: np.ndarray | None = None  # (N,) float32: the ray's direction spread (Cycles' compact differential dD) where
    #                               bounces widen it (RenderSettings.widen_differentials); None: the wave's spread_dd
    data_pending: np.ndarray | None = None  # (N,) bool: the camera path has not yet met the surface its data passes
    #                                         (Depth, Normal, ...) take: one less transparent than the settings'
    #                                         pass_alpha_threshold (Cycles' PATH_RAY_SINGLE_PASS_DONE unset); None
    #                                         without such passes

    @classmethod
    def start(cls, n: int, samples: Samples) -> "PathState":
        return cls(np.arange(n), np.ones((3, n), np.float32), np.full(n, np.inf, np.float32), samples,
                   np.zeros(n, np.int32), np.zeros(n, np.int32), np.zeros(n, np.float32),
                   segments=np.zeros(n, np.int32))

    def compact(self, idx: np.ndarray) -> None:
        """Keep only the paths idx (in that order)."""
        self.path = self.path[idx]
        self.throughput = np.take(self.throughput, idx, axis=1)
        self.bsdf_pdf = np.take(self.bsdf_pdf, idx)
        self.samples = self.samples.take(idx)
        self.bounce = np.take(self.bounce, idx)
        self.transparent = np.take(self.transparent, idx)
        self.dp = np.take(self.dp, idx)
        if self.lobes is not None:
            self.lobes = np.take(self.lobes, idx, axis=1)
        if self.min_ray_pdf is not None:
            self.min_ray_pdf = np.take(self.min_ray_pdf, idx)
        if self.time is not None:
            self.time = self.time.take(idx)
        if self.features is not None:
            self.features = np.take(self.features, idx, axis=1)
        if self.pass_weights is not None:
            self.pass_weights = np.take(self.pass_weights, idx, axis=1)
        if self.continuation is not None:
            self.continuation = np.take(self.continuation, idx)
        if self.escape_scale is not None:
            self.escape_scale = np.take(self.escape_scale, idx)
        if self.focus is not None:
            self.focus = self.focus.take(idx)
        if self.partner is not None:
            self.partner = np.take(self.partner, idx)
            self.partner_uv = np.take(self.partner_uv, idx, axis=1)
            self.handed = np.take(self.handed, idx)
        if self.portal is not None:
            self.portal = np.take(self.portal, idx)
        if self.segments is not None:
            self.segments = np.take(self.segments, idx)
        if self.media is not None:
            self.media = np.take(self.media, idx, axis=1)
            self.volume_bounces = np.take(self.volume_bounces, idx)
            self.volume_bounds = np.take(self.volume_bounds, idx)
        if self.mis_facing is not None:
            self.mis_facing = np.take(self.mis_facing, idx, axis=1)
        if self.mis_origin is not None:
            self.mis_origin = np.take(self.mis_origin, idx, axis=1)
        if self.link_set is not None:
            self.link_set = np.take(self.link_set, idx)
            self.scattered = np.take(self.scattered, idx)
        if self.self_key is not None:
            self.self_key = np.take(self.self_key, idx)
        if self.see_through is not None:
            self.see_through = np.take(self.see_through, idx)
        if self.data_pending is not None:
            self.data_pending = np.take(self.data_pending, idx)
        if self.dd is not None:
            self.dd = np.take(self.dd, idx)

    @classmethod
    def concat(cls, a: "PathState", b: "PathState") -> "PathState":
        """The paths of a, then those of b: two batches of one wave, both past their camera rays (their
        first vertex's stratified numbers drawn). A per-vertex record one batch lacks (None) is what it
        means there: continuation and escape scale 1, the world focus none."""
        def cat(x, y, fill, axis=-1):
            if x is None and y is None:
                return None
            if x is None:
                x = fill(len(a), y)
            if y is None:
                y = fill(len(b), x)
            return np.concatenate([x, y], axis=axis)

        def ones(n, like):
            return np.ones(n, like.dtype)

        def required(n, like):
            raise ValueError("PathState.concat: the batches record different things")

        state = cls(cat(a.path, b.path, required), cat(a.throughput, b.throughput, required),
                    cat(a.bsdf_pdf, b.bsdf_pdf, required), Samples.concat(a.samples, b.samples),
                    cat(a.bounce, b.bounce, required), cat(a.transparent, b.transparent, required),
                    cat(a.dp, b.dp, required))
        for name in ("min_ray_pdf", "lobes", "features", "pass_weights", "partner", "partner_uv", "handed",
                     "portal", "segments", "media", "volume_bounces", "volume_bounds", "mis_facing", "mis_origin", "link_set",
                     "scattered", "self_key", "see_through", "data_pending", "dd"):
            setattr(state, name, cat(getattr(a, name), getattr(b, name), required))
        state.continuation = cat(a.continuation, b.continuation, ones)
        state.escape_scale = cat(a.escape_scale, b.escape_scale, ones)
        if a.focus is not None or b.focus is not None:
            fa = a.focus if a.focus is not None else WorldFocus.none(len(a))
            fb = b.focus if b.focus is not None else WorldFocus.none(len(b))
            state.focus = WorldFocus.concat(fa, fb)
        if a.time is not None or b.time is not None:
            state.time = RayTimes.concat(a.time, b.time)
        return state

    def rows(self, idx: np.ndarray) -> "PathState":
        """A new state of the paths idx only (this one unchanged)."""
        part = copy.copy(self)
        part.compact(idx)
        return part

    def track_lobes(self, bs, closures, passing: np.ndarray) -> None:
        """After a bounce (bs: the BsdfSample, closures: the ClosureSet it came from): Cycles' ray labels
        and per-type bounce counts (path_state_next); transparent pass-throughs change nothing."""
        scattered = ~passing & (bs.row >= 0)
        if not scattered.any():
            return
        idx = np.flatnonzero(scattered)
        diffuse = closures.is_diffuse(bs.row[idx])
        delta = bs.delta[idx]
        transmit = bs.transmit[idx]
        label = np.where(transmit, TRANSMIT, REFLECT) | np.where(diffuse, DIFFUSE, np.where(delta, GLOSSY | SINGULAR,
                                                                                             GLOSSY))
        self.lobes[0, idx] = label | np.where(diffuse, DIFFUSE_ANCESTOR, self.lobes[0, idx] & DIFFUSE_ANCESTOR)
        self.lobes[1, idx] += ~transmit & diffuse
        self.lobes[2, idx] += ~transmit & ~diffuse
        self.lobes[3, idx] += transmit

    def __len__(self) -> int:
        return len(self.path)


def seen_through(state, rows=None) -> np.ndarray:
    """(n,) bool of the paths rows (all where None): still seen from the camera, for a transparent film and
    holdouts (Cycles' PATH_RAY_TRANSPARENT_BACKGROUND): camera rays past transparent surfaces only, and with
    Transparent Glass past smooth glass too (PathState.see_through)."""
    bounce = state.bounce if rows is None else np.take(state.bounce, rows)
    if state.see_through is None:
        return bounce == 0
    return (bounce == 0) | (state.see_through if rows is None else np.take(state.see_through, rows))


def ray_keys(state, rows):
    """The keys (x, y) of the current rays of the paths rows (state rows) for rng.keyed_uniforms: their PCG2D
    states mixed with the number of rays they traced before (segments, and volume boundaries passed where the
    scene has media), so that every ray of a path (whose stream does not advance at a first vertex's
    stratified numbers, nor at a volume's boundary) draws its own."""
    rng = state.samples.rng
    count = np.take(state.segments, rows)
    if state.volume_bounds is not None:
        count = count + np.take(state.volume_bounds, rows)
    count = count.astype(np.uint32)
    return (np.take(rng.x, rows) ^ (count * np.uint32(0x9E3779B9)),
            np.take(rng.y, rows) + count * np.uint32(0x632BE5AB))


def type_limits(settings):
    """The per-type bounce limits (diffuse, glossy, transmission) that can end a path before max_bounces does,
    as a (3, 1) int32 column (a limit of its own or max_bounces), or None when none of them can."""
    top = int(settings.max_bounces)
    limits = [top if v is None else int(v) for v in (settings.diffuse_bounces, settings.glossy_bounces,
                                                    settings.transmission_bounces)]
    return None if min(limits) >= top else np.array(limits, np.int32)[:, None]


def roulette_verdict(wave, state, throughput, numbers, eligible):
    """Russian roulette's verdict on what the paths' next rays hit (PathState.continuation), or None: after
    ROULETTE_DEPTH bounces (state.bounce counts the one just taken), where eligible, q = min(sqrt(max
    throughput), 1) and the verdict q if u < q (u: the vertex's second LIGHT number), else 0."""
    if not wave.nee:
        return None
    u = numbers[LIGHT][1]
    roulette = eligible & (state.bounce >= ROULETTE_DEPTH)
    if not roulette.any():
        return None
    q = np.sqrt(np.minimum(np.maximum(np.maximum(throughput[0], throughput[1]), throughput[2]), np.float32(1.0)))
    q = np.where(roulette, q, np.float32(1.0))
    return np.where(u < q, q, np.float32(0.0))


def roulette_stops(tables, state, hits, found) -> np.ndarray:
    """found without the paths that Russian roulette stopped at a surface that does not emit: those end
    here; a stopped path whose surface emits stays for its emission (roulette_weights then ends it)."""
    stop = np.take(state.continuation, found) == 0
    if not stop.any():
        return found
    if tables.emissive:
        stopped = np.flatnonzero(stop)
        mats = tables.triangles.materials(np.take(hits.prim, np.take(found, stopped)))
        stop[stopped] = ~np.take(tables.shading.emissive, mats)
    return found[~stop]


def roulette_weights(state) -> None:
    """After a surface's emission counted: the paths Russian roulette stopped here end (their throughput
    becomes 0, so they add nothing and no longer go on); the others are divided by their q (Cycles'
    integrate_surface_terminate)."""
    c = state.continuation
    state.throughput = np.where(c > 0, state.throughput / np.where(c > 0, c, np.float32(1.0)), np.float32(0.0))
    state.continuation = None


def fast_gi_replaced(settings, state, rows=None) -> np.ndarray | None:
    """(n,) bool the paths rows (all where None) past Fast GI's AO bounces, whose rays Replace ends (Cycles'
    path_state_ao_bounce: bounce - transmissions - (any glossy bounce) + 1 > ao_bounces), or None when Replace is
    off (Cycles' kernel takes ao_bounces only with an AO factor, scene/integrator.cpp)."""
    if not int(settings.ao_bounces) or not float(settings.ao_factor):
        return None
    bounce, lobes = state.bounce, state.lobes
    if rows is not None:
        bounce, lobes = np.take(bounce, rows), np.take(lobes, rows, axis=1)
    return bounce - lobes[3] - (lobes[2] > 0) + 1 > int(settings.ao_bounces)


def transparent_limit(settings) -> int:
    """The transparent pass-throughs after which a path takes only the emission of the surface it meets next (and
    the world, if it meets none): Transparent Max Bounces, at least 1 (Cycles' path_state_next sets
    PATH_RAY_TERMINATE_ON_NEXT_SURFACE once transparent_bounce, counted after the pass, reaches the limit: a limit
    of 0 ends paths as one of 1 does)."""
    return max(int(settings.transparent_max_bounces), 1)


def may_scatter(wave, state) -> np.ndarray:
    """(N,) bool: the paths that may still scatter at their hits (light samples, BSDF samples): not past
    max_bounces, nor past a per-type limit (Cycles ends a path after the bounce that reaches either, letting it
    take only the emission and the world of what it meets next: PATH_RAY_TERMINATE_AFTER_TRANSPARENT), nor at the
    transparent limit (transparent_limit: only the emission of this surface, PATH_RAY_TERMINATE_ON_NEXT_SURFACE)."""
    ok = (state.bounce < wave.max_scatters) & (state.transparent < transparent_limit(wave.settings))
    limits = type_limits(wave.settings)
    if limits is not None:
        ok &= np.all(state.lobes[1:4] <= limits, axis=0)
    if state.volume_bounces is not None:
        ok &= state.volume_bounces <= int(wave.settings.volume_bounces)
    replaced = fast_gi_replaced(wave.settings, state)
    if replaced is not None:   # Fast GI: such a path takes only the emission and transparency of what it meets
        ok &= ~replaced
    return ok


class GivenPaths:
    """Paths given whole: their random number streams, rows, columns and strata (trace_paths)."""
    spp = 1   # paths per pixel side by side (a batch starts anywhere)

    def __init__(self, rng: PathRng, row, col, strata):
        self.rng, self.row, self.col, self.strata = rng, row, col, strata

    def __len__(self) -> int:
        return len(self.row)

    def batch(self, start: int, end: int):
        """(PathRng, row, col, strata) of the paths [start, end)."""
        if start == 0 and end == len(self.row):
            return self.rng, self.row, self.col, self.strata
        part = slice(start, end)
        # (A stratum shared by every path is one value.)
        strata = None if self.strata is None else tuple(s if np.size(s) == 1 else s[part] for s in self.strata)
        return PathRng(self.rng.x[part], self.rng.y[part]), self.row[part], self.col[part], strata


class WavePaths:
    """The paths of a wave, pixel-major: path k is sample first + k % spp of pixel pixels[k // spp] of the
    band of image rows `rows` (a range; its pixels numbered along its rows of `width`, from column x0). What a
    path starts from is made for each batch as it starts (the same values as for the whole wave at once)."""

    def __init__(self, settings, camera, x0: int, rows: range, width: int, pixels: np.ndarray, first: int,
                 spp: int):
        self.settings, self.camera = settings, camera
        self.x0, self.rows, self.width = x0, rows, width
        self.pixels, self.first, self.spp = pixels, first, spp

    def __len__(self) -> int:
        return len(self.pixels) * self.spp

    def pixel_and_sample(self, start: int = 0, end: int | None = None):
        """(pixel (n,) int64 within the band, sample (n,) uint32) of the paths [start, end)."""
        k = np.arange(start, len(self) if end is None else end, dtype=np.int64)
        return np.take(self.pixels, k // self.spp), (self.first + k % self.spp).astype(np.uint32)

    def batch(self, start: int, end: int):
        """(PathRng, row, col, strata) of the paths [start, end)."""
        settings, cam, spp = self.settings, self.camera, self.spp
        pix, sample = self.pixel_and_sample(start, end)
        row = (pix // self.width * self.rows.step + self.rows.start).astype(np.int32)
        col = (pix % self.width + self.x0).astype(np.int32)
        pixel_index = row.astype(np.uint32) * np.uint32(cam.width) + col.astype(np.uint32)
        rng = PathRng(*seed_paths(pixel_index, sample, settings.seed))
        # Whole pixels: each pixel's place in the sequence is found once for its spp paths.
        whole = start % spp == 0 and (end - start) % spp == 0
        strata = sample_strata(settings.sampling_pattern, settings.seed, cam.width, cam.height,
                               int(settings.sample_offset) + int(settings.samples), row, col, pixel_index, sample,
                               ranged=int(settings.sample_offset) > 0, first=bool(settings.blue_noise_first),
                               repeats=spp if whole else 1)
        return rng, row, col, strata
