"""Distance sampling in media by null scattering, as Cycles 5.x integrates volumes by default
(kernel/integrator/shade_volume.h: tentative collisions drawn against a majorant, each a real or a null
event; Mitsuba 3's volpath.cpp is the readable reference).

Along a ray segment [0, t_end) inside the media of a path's stack, collisions are drawn with density
majorant * exp(-majorant t) (the majorant: the sum of the stack's media's, medium.Media). At each one:

- the emission there is gathered, weight x emission / majorant (a collision estimate of the integral of
  transmittance times emission along the segment);
- a path that may scatter takes a real scattering event or a null event, as Cycles chooses
  (volume_scatter_probability): P_scatter is sigma_s / (sigma_s + sigma_n), sigma_n = majorant - sigma_t,
  averaged over the colour channels weighted by the path's weight times the albedo. Absorption is never an
  event: the null event's weight sigma_n / (majorant P_null) carries it, and a point that only absorbs takes
  the null event (ratio tracking). A point that exceeds the majorant takes its own extinction as the majorant
  since the previous collision, as Cycles does: biased where the estimate missed a thin, intense feature (light
  from behind it leaks through), where negative null weights would keep it unbiased at a variance that does not
  converge in practice.
  The scattering event's weight is 1 / (majorant P_scatter): the phase closures' weights (which sum to
  sigma_s) multiply it at the vertex;
- a path that may not scatter (past its bounces) multiplies its weight by sigma_n / majorant (ratio tracking).
  Either is stopped by Russian roulette once its weight is small. Shadow rays (transmittance()), and such paths
  through media that emit nothing, take Cycles' telescoping estimator of the transmittance instead
  (telescope.py); ratio tracking stays where a segment has no end or gathers emission.

Paths whose media are all homogeneous and that may not scatter take the closed forms: transmittance
exp(-sigma_t L) and emission (1 - exp(-sigma_t L)) / sigma_t x emission.

Each collision draws its two numbers from the path's stream hashed with the collision's number, without
advancing the stream: a path's numbers do not depend on which paths share its batch.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rng import keyed_uniforms as uniforms
from ..vec import F32, ONE, ZERO
from . import telescope
from .channels import channel_pdf
from .march import Marching, stack_steps
from .march import march as march_segments

MAX_COLLISIONS = 4096      # a segment's collisions at most (a guard: its path then ends)
ROULETTE_WEIGHT = F32(0.1)  # ratio tracking's weight below which Russian roulette may stop the path
TAIL, TAIL_BATCH = 2048, 8  # below TAIL paths still tracking, each shader call takes TAIL_BATCH collisions


@dataclass
class Segment:
    """What a segment of n paths through their media gave.

    scattered : (n,) bool, a real scattering event at distance t.
    t : (n,) float32 distance of that event (t_end elsewhere).
    weight : (3, n) float32 factor on the path's throughput: to the scattering event (times the phase closures'
        weights there), or through the whole segment; 0 for an absorbed path.
    emission : (3, n) float32 radiance emitted along the segment toward the ray's origin (times the path's
        throughput before the segment).
    shade_t : (n,) float32 distance of the point whose coefficients (phase closures) a scattering event takes,
        or None: the event's own point (ray marching shades a step at one point, march.py).
    """
    scattered: np.ndarray
    t: np.ndarray
    weight: np.ndarray
    emission: np.ndarray
    shade_t: np.ndarray | None = None


def track(media, stack, origins, dirs, t_end, seeds, may_scatter, ray=None, emission: bool = True,
          salt: int = 0, march: Marching | None = None, shadow: bool = False, rare=None) -> Segment:
    """Distance sampling for n paths (stack (K, n), origins and unit dirs (n, 3), t_end (n,) which may be
    inf, seeds: their (x, y) PCG2D states, may_scatter (n,) bool). With march (the Biased option), stacks with
    a varying medium are marched (march.py; shadow: the segments are shadow rays'), not tracked. rare: (n,)
    bool, the paths whose scattering in a homogeneous medium is made rarer (_homogeneous), or None."""
    n = len(t_end)
    if emission and hasattr(media, "stack_emits") and not media.stack_emits(stack).any():
        emission = False    # no medium here emits: neither shader calls nor collisions gather emission
    weight = np.ones((3, n), F32)
    gathered = np.zeros((3, n), F32)
    scattered = np.zeros(n, bool)
    t_event = np.array(t_end, F32, copy=True)
    shade_t = None
    majorant = media.stack_majorant(stack)
    closed = media.stack_homogeneous(stack) & (majorant > 0)
    if march is not None:
        steps = stack_steps(media, stack, march)
        marched = np.flatnonzero(np.isfinite(steps))
        if len(marched):
            out = march_segments(media, stack[:, marched], origins[marched], dirs[marched],
                                 np.asarray(t_end)[marched], tuple(np.take(s_, marched) for s_ in seeds),
                                 may_scatter[marched], steps[marched], march.max_steps, shadow, ray, emission, salt)
            scattered[marched], t_event[marched] = out[0], out[1]
            shade_t = t_event.copy()
            shade_t[marched] = out[2]
            weight[:, marched], gathered[:, marched] = out[3], out[4]
            majorant = majorant.copy()
            majorant[marched] = 0.0     # (the tracking below leaves them alone)
    varying = np.flatnonzero(~closed & (majorant > 0))
    if len(varying) and hasattr(media, "segment_majorant"):
        # Varying media: the largest majorant of the cells each segment crosses, not the medium's largest.
        majorant = majorant.copy()
        majorant[varying] = media.segment_majorant(stack[:, varying], origins[varying], dirs[varying],
                                                   np.asarray(t_end, F32)[varying])
    if march is None and len(varying):
        # Segments that only need their transmittance (shadow rays, paths that may not scatter through media
        # that emit nothing) take Cycles' shadow estimator (telescope.py), not ratio tracking.
        quiet = ~may_scatter[varying]
        if emission and not shadow:
            quiet &= ~media.stack_emits(stack[:, varying]) if hasattr(media, "stack_emits") else False
        ended = varying[quiet & np.isfinite(np.asarray(t_end)[varying]) & (majorant[varying] > 0)]
        if len(ended):
            weight[:, ended] = telescope.transmittance(media, stack[:, ended], origins[ended], dirs[ended],
                                                       np.asarray(t_end)[ended], tuple(np.take(s_, ended) for s_ in seeds),
                                                       majorant[ended], salt)
            majorant = majorant.copy()
            majorant[ended] = 0.0     # (the tracking below leaves them alone)
    if closed.any():
        _closed_form(media, stack, origins, dirs, t_end, closed & ~may_scatter, weight, gathered, emission)
        _homogeneous(media, stack, origins, dirs, t_end, closed & may_scatter, seeds, salt, weight, gathered,
                     scattered, t_event, emission, rare)
    live = np.flatnonzero(~closed & (majorant > 0))
    t = np.zeros(n, np.float64)
    x, y = seeds

    def collide(live, tl, c, u2, bar, dt):
        """One tentative collision of the paths live at distances tl, dt past their previous one (or the
        segment's start), with coefficients c: emission gathered, weights updated, events taken; returns the
        mask of those that stop."""
        w = weight[:, live]
        # A point whose extinction exceeds the majorant takes its own as the majorant since the previous
        # collision, as Cycles does (volume_null_event_coefficients, volume_integrate_step_scattering): the factor
        # exp(-(local - bar) dt) / bar in place of 1 / bar and a null coefficient local - sigma_t >= 0. Negative
        # null weights would keep the estimate unbiased, but behind a thin, intense feature the majorant missed
        # their products swing by orders of magnitude and a render does not converge in practice.
        local = np.maximum(c.sigma_t.max(axis=0), bar)
        over = local > bar
        if over.any():
            with np.errstate(over="ignore"):
                bar = np.where(over, bar * np.exp((local - bar) * dt).astype(F32), bar)
        inv = ONE / bar
        if emission:
            gathered[:, live] += w * c.emission * inv
        sigma_n = local - c.sigma_t
        scatter = may_scatter[live]
        new_w = w * sigma_n * inv            # ratio tracking (and the null event's weight when P_n = sigma_n/bar)
        ended = np.zeros(len(live), bool)
        if scatter.any():
            # Cycles' choice (volume_scatter_probability, shade_volume.h): a real scattering event or a null
            # one, never an absorption (it would only end the path: high variance); the null event carries the
            # absorption in its weight, sigma_n / (majorant P_n). The channels are weighted by the path's weight
            # times the albedo (volume_sample_channel_pdf); a point that only absorbs always takes the null event.
            s = np.flatnonzero(scatter)
            ss, sn = c.sigma_s[:, s], sigma_n[:, s]
            reach = ss + sn      # (sigma_n >= 0: a point above the majorant raised it)
            share = np.where(reach > 0, ss / np.where(reach > 0, reach, ONE), ZERO)
            p_s = (channel_pdf(w[:, s], ss, c.sigma_t[:, s]) * share).sum(0)
            real = u2[s] < p_s
            # Scattering: 1 / (majorant P_s), the phase closures' weights come at the vertex.
            p_n = ONE - p_s
            scale = np.where(real, ONE / (bar[s] * np.where(real, p_s, ONE)), ZERO)
            null_scale = np.where(p_n > 0, ONE / (bar[s] * np.where(p_n > 0, p_n, ONE)), ZERO)
            new_w[:, s] = np.where(real, w[:, s] * scale, w[:, s] * sn * null_scale)
            rows = live[s[real]]
            scattered[rows] = True
            t_event[rows] = tl[s[real]]
            ended[s] = real
            # The number that chose the null event, rescaled, is the roulette's (as Cycles reuses it).
            u2 = u2.copy()
            u2[s] = np.where(real, u2[s], np.clip((u2[s] - p_s) / np.where(p_n > 0, p_n, ONE), ZERO, ONE))
        plain = np.flatnonzero(~ended)
        if len(plain):
            # Russian roulette on the paths whose weight the null events have made small (Cycles'
            # volume_russian_roulette_termination).
            small = np.abs(new_w[:, plain]).max(axis=0)
            risky = small < ROULETTE_WEIGHT
            if risky.any():
                q = np.where(risky, small / ROULETTE_WEIGHT, ONE)
                survive = ~risky | (u2[plain] < q)
                new_w[:, plain] = np.where(survive, new_w[:, plain] / np.where(survive, q, ONE), ZERO)
                ended[plain] = ~survive
        weight[:, live] = new_w
        return ended

    k = 0
    while len(live) and k < MAX_COLLISIONS:
        # A few paths still tracking (a wave's tail) take several collisions per shader call: their points are
        # drawn ahead (the distances do not depend on the events) and evaluated at once; the events are then
        # taken in order, the same as one by one.
        batch = min(TAIL_BATCH if len(live) < TAIL else 1, MAX_COLLISIONS - k)
        keys = (x[live], y[live])
        draws = [uniforms(keys, k + j, salt) for j in range(batch)]
        bar = majorant[live]
        times, reach = [], t[live]
        for u1, _ in draws:
            reach = reach + -np.log1p(-u1.astype(np.float64)) / bar
            times.append(reach)
        ahead = np.stack(times)
        ends = t_end[live]
        jj, ii = np.nonzero(ahead < ends[None])
        slot = np.full(ahead.shape, -1, np.int64)
        slot[jj, ii] = np.arange(len(ii))
        tl_all = ahead[jj, ii].astype(F32)
        c_all = None
        if len(ii):
            rows = live[ii]
            c_all = media.stack_coefficients(stack[:, rows], origins[rows] + dirs[rows] * tl_all[:, None], dirs[rows],
                                             ray, emission)
        pos = np.arange(len(live))
        for j in range(batch):
            now = ahead[j, pos]
            dt = now - t[live[pos]]
            t[live[pos]] = now
            inside = now < ends[pos]
            pos, dt = pos[inside], dt[inside]
            if not len(pos):
                break
            at = slot[j, pos]
            c = c_all if batch == 1 else c_all.take(at)
            ended = collide(live[pos], tl_all[at], c, draws[j][1][pos], bar[pos], dt)
            pos = pos[~ended]
        live = live[pos]
        k += batch
    if len(live):
        weight[:, live] = 0.0
    return Segment(scattered, t_event, weight, gathered, shade_t)


def transmittance(media, stack, origins, dirs, t_end, seeds, salt: int = 1, march: Marching | None = None
                  ) -> np.ndarray:
    """(3, n) the transmittance of the segments: closed forms through homogeneous media; where a medium varies,
    Cycles' telescoping estimate (telescope.py; ratio tracking for a segment without end), or marched as shadow
    rays are with the Biased option."""
    return track(media, stack, origins, dirs, t_end, seeds, np.zeros(len(t_end), bool), emission=False,
                 salt=salt, march=march, shadow=True).weight


# The probability with which a `rare` path scatters in a homogeneous segment, as a share of the probability
# (1 - T) that light does: Cycles' scattering probability guiding for camera rays (VSPG, shade_volume.h
# volume_scatter_probability_homogeneous, defensive mix 0.75) where the guide finds no light scattered.
RARE_SCATTER_SHARE = 0.25


def _homogeneous(media, stack, origins, dirs, t_end, rows, seeds, salt, weight, gathered, scattered, t_event,
                 emission: bool, rare=None) -> None:
    """Paths that may scatter in homogeneous media: the distance drawn in proportion to one colour channel's
    extinction, the channel picked in proportion to the path's weight times the albedo and the channels
    combined by the one-sample MIS of their pdfs (Cycles' volume_sample_channel and homogeneous distance
    sampling, shade_volume.h); a medium that only absorbs is its transmittance exactly; the emission is
    its closed form."""
    idx = np.flatnonzero(rows)
    if not len(idx):
        return
    _closed_form(media, stack, origins, dirs, t_end, rows, weight, gathered, emission)
    c = media.stack_coefficients(stack[:, idx], origins[idx], dirs[idx], emission=False)
    sigma_t = c.sigma_t.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        albedo = np.where(sigma_t > 0, c.sigma_s / np.where(sigma_t > 0, sigma_t, 1.0), 0.0)
    w = albedo    # (the segment's weights start at 1: the channel in proportion to the albedo alone)
    total = w.sum(axis=0)
    some = total > 0
    if not some.any():
        return      # nothing scatters: the closed form's transmittance is exact
    idx, sigma_t, w, total = idx[some], sigma_t[:, some], w[:, some], total[some]
    p = w / total
    u1, u2 = uniforms(tuple(np.take(s_, idx) for s_ in seeds), 0, salt + 101)
    channel = np.minimum((u1[None] >= np.cumsum(p, axis=0)).sum(axis=0), 2)
    if rare is not None:
        few = np.flatnonzero(np.take(rare, idx))
        if len(few):
            _rare(idx[few], sigma_t[:, few], p[:, few], channel[few], u2[few].astype(np.float64), t_end, weight,
                  scattered, t_event)
            keep = np.ones(len(idx), bool)
            keep[few] = False
            idx, sigma_t, p, channel, u2 = idx[keep], sigma_t[:, keep], p[:, keep], channel[keep], u2[keep]
            if not len(idx):
                return
    rate = sigma_t[channel, np.arange(len(idx))]
    t = -np.log1p(-u2.astype(np.float64)) / rate
    end = t_end[idx].astype(np.float64)
    scatter = t < end
    at = np.where(scatter, t, np.where(np.isfinite(end), end, 0.0))
    decay = np.exp(-sigma_t * at)
    # pdf of the distance (scattering) or of passing (the segment's end), over the channels' mixture.
    pdf = np.where(scatter, (p * sigma_t * decay).sum(axis=0), (p * decay).sum(axis=0))
    through = np.where(np.isfinite(end) | scatter, 1.0, 0.0)
    new = np.where(pdf > 0, decay / np.where(pdf > 0, pdf, 1.0), 0.0) * through
    weight[:, idx] = new.astype(F32)   # in place of the closed form's transmittance
    scattered[idx] = scatter
    t_event[idx] = np.where(scatter, t, t_event[idx]).astype(F32)


def _rare(idx, sigma_t, p, channel, u, t_end, weight, scattered, t_event) -> None:
    """_homogeneous's choice for the paths idx with a scattering probability RARE_SCATTER_SHARE x (1 - T) per
    channel: a scattering distance drawn from the channel's exponential bounded to the segment, otherwise the
    segment passed; weights over the pdfs of the channels' mixture (Cycles' volume_integrate_homogeneous)."""
    n = len(idx)
    end = t_end[idx].astype(np.float64)
    kept = np.where(np.isfinite(end), -np.expm1(-sigma_t * np.where(np.isfinite(end), end, 0.0)), 1.0)   # 1 - T
    q = RARE_SCATTER_SHARE * kept
    q_ch = q[channel, np.arange(n)]
    scatter = u < q_ch
    rate = sigma_t[channel, np.arange(n)]
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.clip(u / q_ch, 0.0, 1.0)
        t = -np.log1p(-v * kept[channel, np.arange(n)]) / rate
        t = np.where(np.isfinite(end), np.minimum(t, end), t)
        at = np.where(scatter, t, np.where(np.isfinite(end), end, 0.0))
        decay = np.exp(-sigma_t * at)
        density = np.where(kept > 0, sigma_t * decay / kept, 0.0)
        pdf = np.where(scatter, (p * q * density).sum(axis=0), (p * (1.0 - q)).sum(axis=0))
        new = np.where(pdf > 0, decay / np.where(pdf > 0, pdf, 1.0), 0.0)
    new = new * np.where(np.isfinite(end) | scatter, 1.0, 0.0)
    weight[:, idx] = new.astype(F32)
    scattered[idx] = scatter
    t_event[idx] = np.where(scatter, t, t_event[idx]).astype(F32)


def _closed_form(media, stack, origins, dirs, t_end, rows, weight, gathered, emission: bool) -> None:
    idx = np.flatnonzero(rows)
    if not len(idx):
        return
    c = media.stack_coefficients(stack[:, idx], origins[idx], dirs[idx], emission=emission)
    length = t_end[idx].astype(F32)
    with np.errstate(invalid="ignore", over="ignore"):
        optical = c.sigma_t * length
        optical = np.where(c.sigma_t > 0, optical, ZERO)
        through = np.exp(-optical).astype(F32)
        weight[:, idx] = through
        if emission:
            # The emission integrated along the segment: (1 - T) / sigma_t, or L where sigma_t = 0.
            span = np.where(c.sigma_t > 0, (ONE - through) / np.where(c.sigma_t > 0, c.sigma_t, ONE),
                            np.where(np.isfinite(length), length, ZERO))
            gathered[:, idx] = c.emission * span
