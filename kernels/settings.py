"""The frozen settings record a render is handed (RenderSettings), and the sampling modes it may name."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import passes
from .samples import SAMPLING_PATTERNS

SAMPLING_MODES = ("NEE_MIS", "COSINE", "LECTURE")


@dataclass(frozen=True)
class RenderSettings:
    """How to render. region is (x0, y0, x1, y1) in full-frame pixels, row 0 at the top, end
    exclusive; None for the whole frame. time_limit_s = 0 means none. A wave holds at most
    wave_size paths, which bounds memory whatever the resolution (None: automatic, WAVE_SPAN times the
    paths traced at once, WAVE_SIZE or, for materials that mix lobes, LAYERED_WAVE_SIZE; the image is the
    same for any wave size to float rounding, and the same bit for bit for any thread count)."""
    samples: int = 64
    max_bounces: int = 8
    mode: str = "NEE_MIS"
    seed: int = 0
    time_limit_s: float = 0.0
    region: tuple | None = None
    transparent_background: bool = False
    # Cycles' Film > Transparent > Transparent Glass, with transparent_background: the Roughness Threshold, or None
    # for off. The world seen through glass whose transmission is that smooth (and transparent surfaces) makes
    # alpha, as the world seen straight from the camera does.
    transparent_glass: float | None = None
    # Cycles' Film > Exposure: Combined and the light passes are read out multiplied by it (kernels.film.Film).
    exposure: float = 1.0
    # Cycles' Sampling > Lights > Light Threshold, which Cycles applies only without the light tree (0: off): a light
    # sample whose contribution before the path's throughput, times the exposure, is below it has its shadow ray
    # traced with probability contribution / threshold and is weighted up by its inverse (light_sample_terminate).
    light_threshold: float = 0.0
    # Cycles 5.2's widened ray differentials (bsdf_widen_dD): after a bounce that is not singular, the ray's direction
    # spread is at least the square root of its closures' roughness squared averaged by their pdfs toward the
    # sampled direction (a diffuse bounce: 1 radian), so that what reads the footprint (Bump, hair coverage) sees a
    # wide one at indirect hits. Off: the camera's pixel spread throughout, as Cycles up to 5.1.
    widen_differentials: bool = False
    wave_size: int | None = None
    transparent_max_bounces: int = 8
    # Cycles' per-type limits (Light Paths > Max Bounces: Diffuse, Glossy, Transmission), None for none: a path
    # that has reflected diffusely (glossily) more often than diffuse_bounces (glossy_bounces), or gone through
    # surfaces more often than transmission_bounces, only takes the emission and the world of what it meets
    # next, as after max_bounces.
    diffuse_bounces: int | None = None
    glossy_bounces: int | None = None
    transmission_bounces: int | None = None
    # Cycles' Volume bounces (Light Paths > Max Bounces > Volume, 0 by default): a path scatters in media at
    # most volume_bounces + 1 times; after that it takes only what it meets, as after max_bounces.
    volume_bounces: int = 0
    # Cycles' Biased volume option (Render > Volumes): media that vary are ray-marched (kernels/media/march.py)
    # with steps of their own size times volume_step_rate, at most volume_max_steps per segment, instead of
    # null scattering.
    volume_biased: bool = False
    volume_step_rate: float = 1.0
    volume_max_steps: int = 1024
    # Cycles' Fast GI Approximation (Light Paths > Fast GI; ambient occlusion from the world's AO settings,
    # World.ao_distance the reach). Replace: a path more than ao_bounces deep (Cycles' path_state_ao_bounce: its
    # transmissions and a first glossy bounce not counted) traces rays of that reach only, ends at the surface it
    # meets (its emission and transparency still count), and sees the world times ao_factor where it meets
    # nothing (0: off). Add: every surface adds its diffuse closures' weight times ao_additive times the AO of one
    # ray (0: off), the paths left as they are.
    ao_bounces: int = 0
    ao_factor: float = 0.0
    ao_additive: float = 0.0
    # Cycles' Clamp Direct and Clamp Indirect: a contribution whose |R| + |G| + |B| exceeds 3 x the limit
    # is scaled down to it (0: off). Direct: light reaching the first hit or the camera; indirect: the rest.
    clamp_direct: float = 0.0
    clamp_indirect: float = 0.0
    # Cycles' Filter Glossy (0: off): after a bounce of small pdf, glossy closures are made at least
    # sqrt(1 - f x pdf) / 2 rough, f = 1 / filter_glossy, trading a little blur for fewer fireflies.
    filter_glossy: float = 0.0
    # Cycles' Caustics switches (Light Paths > Caustics): off, a ray that comes from a diffuse bounce finds
    # no glossy reflection (reflective) or no refraction (refractive) closures where it lands, so that
    # light no longer reaches diffuse surfaces through mirrors and glass: no caustics, and their noise, at
    # the cost of that light.
    caustics_reflective: bool = True
    caustics_refractive: bool = True
    # Adaptive sampling as Cycles' (0: off): after adaptive_min_samples (0: Cycles' automatic count,
    # ceil(16 / threshold^0.3)) and every ADAPTIVE_STEP samples, pixels whose noise estimate is under the
    # threshold stop taking samples.
    adaptive_threshold: float = 0.0
    adaptive_min_samples: int = 0
    # Data passes to record besides the image (kernels.passes.PASSES names), e.g. ("depth", "normal").
    passes: tuple = ()
    # View Layer > Passes > Alpha Threshold (Cycles' pass_alpha_threshold): a camera path's data passes (Depth,
    # Position, indices, Normal, UV, Vector) take the first surface it meets whose alpha is at least this, past
    # more transparent ones (0: the first surface, whatever its alpha).
    pass_alpha_threshold: float = 0.5
    # The Mist pass: (start, depth, falloff exponent) in scene units (the world's Mist Pass settings).
    mist: tuple = (5.0, 25.0, 2.0)
    # A sample range of the frame (Cycles' Sample Offset): samples sample_offset .. sample_offset + samples - 1
    # of each pixel's sequence, so that ranges rendered apart and merged by sample count make the whole.
    sample_offset: int = 0
    # How the first vertex's numbers are laid out (kernels.samples.sample_strata, Cycles' Sampling Pattern):
    # "AUTOMATIC", one Owen-scrambled Sobol sequence shared by the pixels so that neighbours' errors are blue
    # noise, as Cycles' final renders; "SOBOL_BURLEY", a sequence of each pixel's own, which sample ranges
    # of one frame need to merge into exactly the whole (the blue-noise layout depends on the sample count).
    sampling_pattern: str = "AUTOMATIC"
    # With AUTOMATIC, sample 0 of every pixel from a one-sample blue-noise sequence of its own, so that the
    # first image is blue noise by itself (Cycles' pattern for interactive renders: the viewport's).
    blue_noise_first: bool = False
    # A first pass of one sample per pixel, for a quick first image (the interface and the viewport); a
    # render nobody watches (background mode) starts with full passes, which keep every core busy at once.
    quick_first_pass: bool = True
    # Cryptomatte: the kinds to record ("object", "material", "asset") and the ids kept per pixel (Levels).
    cryptomatte: tuple = ()
    cryptomatte_depth: int = 6

    def validate(self, width: int, height: int) -> tuple[int, int, int, int]:
        if self.mode not in SAMPLING_MODES:
            raise ValueError(f"mode: must be one of {SAMPLING_MODES}, got {self.mode!r}")
        if int(self.samples) < 1:
            raise ValueError(f"samples: must be at least 1, got {self.samples}")
        if self.sampling_pattern not in SAMPLING_PATTERNS:
            raise ValueError(f"sampling_pattern: must be one of {SAMPLING_PATTERNS}, got {self.sampling_pattern!r}")
        if int(self.sample_offset) < 0:
            raise ValueError(f"sample_offset: must be non-negative, got {self.sample_offset}")
        unknown = [p for p in self.passes if not passes.known(p)]
        if unknown:
            raise ValueError(f"passes: unknown {unknown}, known {tuple(passes.PASSES)}")
        unknown = [k for k in self.cryptomatte if k not in passes.CRYPTO_KINDS]
        if unknown:
            raise ValueError(f"cryptomatte: unknown {unknown}, known {passes.CRYPTO_KINDS}")
        if int(self.max_bounces) < 0:
            raise ValueError(f"max_bounces: must be non-negative, got {self.max_bounces}")
        if not (np.isfinite(self.time_limit_s) and self.time_limit_s >= 0):
            raise ValueError(f"time_limit_s: must be finite and non-negative, got {self.time_limit_s}")
        if int(self.transparent_max_bounces) < 0:
            raise ValueError(f"transparent_max_bounces: must be non-negative, got {self.transparent_max_bounces}")
        if int(self.volume_bounces) < 0:
            raise ValueError(f"volume_bounces: must be non-negative, got {self.volume_bounces}")
        if not float(self.volume_step_rate) > 0:
            raise ValueError(f"volume_step_rate: must be positive, got {self.volume_step_rate}")
        if int(self.volume_max_steps) < 1:
            raise ValueError(f"volume_max_steps: must be at least 1, got {self.volume_max_steps}")
        for name in ("diffuse_bounces", "glossy_bounces", "transmission_bounces"):
            value = getattr(self, name)
            if value is not None and int(value) < 0:
                raise ValueError(f"{name}: must be non-negative (None: no limit of its own), got {value}")
        if self.wave_size is not None and int(self.wave_size) < 1:
            raise ValueError(f"wave_size: must be positive, got {self.wave_size}")
        if int(self.adaptive_min_samples) < 0:
            raise ValueError(f"adaptive_min_samples: must be non-negative (0 is automatic), got "
                             f"{self.adaptive_min_samples}")
        if not 0.0 <= float(self.pass_alpha_threshold) <= 1.0:
            raise ValueError(f"pass_alpha_threshold: must be within [0, 1], got {self.pass_alpha_threshold}")
        if int(self.ao_bounces) < 0:
            raise ValueError(f"ao_bounces: must be non-negative, got {self.ao_bounces}")
        for name in ("ao_factor", "ao_additive"):
            if not np.isfinite(getattr(self, name)):
                raise ValueError(f"{name}: must be finite, got {getattr(self, name)}")
        if not (np.isfinite(self.exposure) and self.exposure >= 0):
            raise ValueError(f"exposure: must be finite and non-negative, got {self.exposure}")
        for name in ("clamp_direct", "clamp_indirect", "filter_glossy", "adaptive_threshold", "light_threshold"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: must be finite and non-negative (0 is off), got {value}")
        x0, y0, x1, y1 = self.region if self.region is not None else (0, 0, width, height)
        if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
            raise ValueError(f"region: {self.region} is empty or outside the {width}x{height} frame")
        return int(x0), int(y0), int(x1), int(y1)

