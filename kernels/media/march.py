"""Ray marching through varying media: Cycles' Biased volume option (Render > Volumes > Biased; kernel/integrator/
shade_volume.h, volume_integrate_ray_marching and volume_shadow_ray_marching), the alternative to null scattering
(tracking.py) that Cycles 5.x keeps for scenes made with its older look.

A segment [0, t_end) through a stack whose media vary is cut into steps of one size, and each step's media are
taken to be constant, with the coefficients the shader gives at one point of the step: piecewise constant, so
biased, the error shrinking with the step. Cycles' rules, followed here:

- The step size: per varying medium, its object's voxel size in world space (the smallest component of a grid's
  index-to-world transform applied to (1, 1, 1)), or the Volume object's own Step Size (object or world space),
  or a tenth of the mean side of its bounds for a mesh; times its material's Step Rate (the world's Step Size for
  the world), times the scene's Step Rate (scene/object.cpp compute_volume_step_size, scene/volume.cpp
  update_step_size). A stack takes the smallest of its varying media's; homogeneous media do not limit it: a stack
  of homogeneous media is one step, the closed forms tracking.py already takes.
- Max Steps: a segment longer than max_steps steps takes longer steps (length / max_steps), and no more than
  max_steps are taken (volume_step_init, volume_ray_marching_advance).
- The first step of a path's segment is shortened by a random fraction of a step (its offset; shadow rays take
  none) against banding, and each step is shaded at a random fraction of its length, one number per segment.
- Per step: the emission integrated over the step, (1 - exp(-sigma_t dt)) / sigma_t x emission, counted until the
  path scatters (volume_emission_integrate); the scattering distance drawn with one colour channel, picked in
  proportion to the weight times the albedo and rescaled to reuse, its number carried from step to step by
  rescaling (volume_sample_indirect_scatter_ray_marching); the channels combined by the one-sample MIS of their
  pdfs. The phase closures of a scattering event are the step's (shaded at its point), not the event's own point.
- Shadow rays (and paths that may not scatter): the product of the steps' transmittances, stopped once below
  VOLUME_THROUGHPUT_EPSILON.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rng import keyed_uniforms as uniforms
from ..vec import F32
from .channels import channel_pdf

THROUGHPUT_EPSILON = 1e-6   # Cycles' VOLUME_THROUGHPUT_EPSILON: a shadow ray's marching stops below it
PDF_CUTOFF = 1e-8           # Cycles' VOLUME_SAMPLE_PDF_CUTOFF: a scattering distance of smaller pdf is not taken
FAR = float(np.finfo(np.float32).max)   # a segment without end marches to FLT_MAX, as Cycles' rays do
MARCH_SALT = 211            # rng.keyed_uniforms salt of a segment's marching numbers


@dataclass(frozen=True)
class Marching:
    """The Biased option's settings: the scene's step rate and max steps."""
    rate: float = 1.0
    max_steps: int = 1024


def marching(settings) -> Marching | None:
    """The marching of a render's RenderSettings, None for null scattering (the default)."""
    if not getattr(settings, "volume_biased", False):
        return None
    return Marching(float(settings.volume_step_rate), int(settings.volume_max_steps))


def stack_steps(media, stack: np.ndarray, march: Marching) -> np.ndarray:
    """(n,) the step size of each path's stack (K, n): the smallest of its media's (Media.step, inf for a
    homogeneous one) times the scene's rate; inf where every medium of the stack is homogeneous."""
    table = np.append(np.asarray(media.step, np.float64), np.inf)
    return np.take(table, stack).min(axis=0) * march.rate


def march(media, stack, origins, dirs, t_end, seeds, may_scatter, steps, max_steps: int, shadow: bool, ray,
          emission: bool, salt: int):
    """March n segments (stack (K, n), origins and unit dirs (n, 3), t_end (n,) which may be inf, steps (n,) their
    step sizes, may_scatter (n,) bool). Returns (scattered, t, shade_t, weight,
    emission) as tracking.Segment holds them, shade_t the distance of the point whose coefficients the
    scattering event takes."""
    n = len(t_end)
    weight = np.ones((3, n), np.float64)
    gathered = np.zeros((3, n), np.float64)
    scattered = np.zeros(n, bool)
    t_event = np.array(t_end, F32, copy=True)
    shade_t = t_event.copy()
    length = np.where(np.isfinite(t_end), np.asarray(t_end, np.float64), FAR)
    size = np.minimum(np.asarray(steps, np.float64), length)
    size = np.where(length > max_steps * size, length / max_steps, size)
    u_offset, u_shade = uniforms(seeds, 0, salt + MARCH_SALT)
    r_scatter, r_channel = (u.astype(np.float64) for u in uniforms(seeds, 1, salt + MARCH_SALT))
    offset = np.ones(n) if shadow else u_offset.astype(np.float64)
    shade = u_shade.astype(np.float64)
    reached = np.zeros(n)
    live = np.flatnonzero(length > 0)
    for k in range(max_steps):
        if not len(live):
            break
        lo = reached[live]
        hi = np.minimum(length[live], (k + offset[live]) * size[live])
        reached[live] = hi
        dt = hi - lo
        at = lo + shade[live] * dt
        p = (origins[live] + dirs[live] * at[:, None]).astype(F32)
        c = media.stack_coefficients(stack[:, live], p, dirs[live], ray, emission)
        sigma_t = np.nan_to_num(c.sigma_t.astype(np.float64), posinf=0.0)
        optical = sigma_t * dt
        through = np.exp(-optical)
        w = weight[:, live]
        if emission:
            # The emission over the step toward its start; Cycles' second-order expansion where it is thin.
            span = np.where(optical > 1e-5, (1.0 - through) / np.where(sigma_t > 0, sigma_t, 1.0),
                            dt * (1.0 - 0.5 * optical))
            gathered[:, live] += w * np.nan_to_num(c.emission.astype(np.float64)) * span
        sigma_s = np.nan_to_num(c.sigma_s.astype(np.float64), posinf=0.0)
        scatter = may_scatter[live] & (sigma_s > 0).any(axis=0)
        new_w = w * through               # absorption only, or a path that may not scatter
        done = np.zeros(len(live), bool)
        if scatter.any():
            s = np.flatnonzero(scatter)
            rows = live[s]
            st, tr = sigma_t[:, s], through[:, s]
            shares = channel_pdf(w[:, s], sigma_s[:, s], st)
            rc = r_channel[rows]
            upper = np.cumsum(shares, axis=0)
            channel = np.minimum((rc[None] >= upper).sum(axis=0), 2)
            cols = np.arange(len(s))
            below = np.where(channel > 0, upper[np.maximum(channel - 1, 0), cols], 0.0)
            own = shares[channel, cols]
            r_channel[rows] = np.where(own > 0, (rc - below) / np.where(own > 0, own, 1.0), rc)
            t_channel = tr[channel, cols]
            rs = r_scatter[rows]
            sigma_channel = st[channel, cols]
            inside = (1.0 - rs >= t_channel) & (sigma_channel > 0)
            with np.errstate(divide="ignore", invalid="ignore"):
                new_dt = -np.log1p(-rs) / np.where(sigma_channel > 0, sigma_channel, 1.0)
            decay = np.exp(-st * new_dt[None])
            pdf_at = (shares * st * decay).sum(axis=0)
            taken = inside & (pdf_at > PDF_CUTOFF)
            passing = ~inside
            pdf_through = (shares * tr).sum(axis=0)
            ws = w[:, s]
            ws = np.where(taken, ws * decay / np.where(taken, pdf_at, 1.0),
                          np.where(passing, ws * tr / np.where(pdf_through > 0, pdf_through, 1.0), ws))
            new_w[:, s] = ws
            r_scatter[rows] = np.where(passing, 1.0 - (1.0 - rs) / np.where(t_channel > 0, t_channel, 1.0), rs)
            hit = rows[taken]
            scattered[hit] = True
            t_event[hit] = (lo[s] + new_dt)[taken]
            shade_t[hit] = at[s][taken]
            done[s] = taken
        weight[:, live] = new_w
        peak = np.abs(new_w).max(axis=0)
        done |= (hi >= length[live]) | (peak < THROUGHPUT_EPSILON if shadow else peak == 0)
        live = live[~done]
    return scattered, t_event, shade_t, weight.astype(F32), gathered.astype(F32)
