"""The world as a light: directions from its importance map (environment.Environment), and through its light
portals where a shading point has one (portals.Portals: half of the samples each, as Cycles' background light
samples, kernel/light/background.h background_light_sample and background_light_pdf), and their pdf.
"""
from __future__ import annotations

import numpy as np

from ..sampling import UNIFORM_SPHERE_PDF, sample_uniform_sphere
from ..vec import F32


def sample(sampler, out, idx, u1, u2, focus=None, px=None, py=None, pz=None):
    """World light samples for the shading points p (idx: their rows in out)."""
    portals = sampler.portals
    possible = None if portals is None or px is None else portals.possible(px, py, pz)
    through = np.zeros(len(u1), bool) if possible is None else possible.any(axis=0)
    if not _map_sampled(sampler):
        # Sampling Method None with portals: through them alone, a uniform direction where none is possible
        # (Cycles' fallback when no method is left, background_light_sample).
        wx, wy, wz, pdf = _uniform(u1, u2)
        rows = np.flatnonzero(through)
        if len(rows):
            wx[rows], wy[rows], wz[rows], pdf[rows] = portals.sample(px[rows], py[rows], pz[rows], u1[rows], u2[rows],
                                                                     possible[:, rows])
    elif not through.any():
        wx, wy, wz, pdf = sampler.environment.sample_direction(u1, u2, focus)
    else:
        # u1 < 1/2 picks the portals, where there are some, and both halves are stretched back to [0, 1).
        half = F32(0.5)
        portal = through & (u1 < half)
        u1 = np.where(through, np.where(portal, u1 / half, (u1 - half) / half), u1)
        u1 = np.minimum(u1, F32(1.0 - 2.0 ** -24))
        wx, wy, wz = (np.empty(len(u1), F32) for _ in range(3))
        sampled = np.flatnonzero(portal)
        wx[sampled], wy[sampled], wz[sampled], own = portals.sample(px[sampled], py[sampled], pz[sampled],
                                                                    u1[sampled], u2[sampled], possible[:, sampled])
        rows = np.flatnonzero(~portal)
        mapped = sampler.environment.sample_direction(u1[rows], u2[rows], None if focus is None else focus.take(rows))
        wx[rows], wy[rows], wz[rows] = mapped[:3]
        # A portal sample's own pdf, as Cycles' (the same as pdf() gives it, but where rounding puts the point on
        # the portal's very edge).
        pdf = _mixed_pdf(sampler, wx, wy, wz, focus, px, py, pz, possible, through, sampled, own)
    out.set(idx, wx, wy, wz, np.float32(np.inf), sampler.environment.radiance(wx, wy, wz), pdf)
    out.world[idx] = True


def pdf(sampler, dx, dy, dz, focus=None, receiver=None, ox=None, oy=None, oz=None) -> np.ndarray:
    """pdf (solid angle, with selection) with which NEE would have sampled world directions d from the points o
    the rays left (focus: as given to sample(); receiver: the light sets of those points, or None)."""
    if not sampler.samples_world():
        return np.zeros(len(dx), np.float32)
    portals = sampler.portals
    if portals is None or ox is None:
        direction_pdf = sampler.environment.direction_pdf(dx, dy, dz, focus)
    elif not _map_sampled(sampler):
        possible = portals.possible(ox, oy, oz)
        through = possible.any(axis=0)
        direction_pdf = np.full(len(dx), UNIFORM_SPHERE_PDF, F32)
        rows = np.flatnonzero(through)
        direction_pdf[rows] = portals.pdf(ox[rows], oy[rows], oz[rows], dx[rows], dy[rows], dz[rows],
                                          possible[:, rows])
    else:
        possible = portals.possible(ox, oy, oz)
        direction_pdf = _mixed_pdf(sampler, dx, dy, dz, focus, ox, oy, oz, possible, possible.any(axis=0))
    return sampler.distant_pmf(sampler.world_index, len(dx), receiver) * direction_pdf


def _map_sampled(sampler) -> bool:
    """Whether the world's own distribution is one of its light sampling's methods (not Sampling Method None)."""
    return bool(sampler.environment.world.light_sampled)


def _uniform(u1, u2):
    wx, wy, wz = sample_uniform_sphere(u1, u2)
    return wx, wy, wz, np.full(len(u1), UNIFORM_SPHERE_PDF, F32)


def _mixed_pdf(sampler, dx, dy, dz, focus, px, py, pz, possible, through, sampled=None, own=None) -> np.ndarray:
    """The map's pdf of directions d, half of it and half the portals' where points p have a possible portal
    (sampled: the rows whose portal pdf is known, own)."""
    map_pdf = sampler.environment.direction_pdf(dx, dy, dz, focus)
    if not through.any():
        return map_pdf
    portal_pdf = np.zeros(len(dx), F32)
    rows = np.flatnonzero(through) if sampled is None else np.setdiff1d(np.flatnonzero(through), sampled)
    portal_pdf[rows] = sampler.portals.pdf(px[rows], py[rows], pz[rows], dx[rows], dy[rows], dz[rows],
                                           possible[:, rows])
    if sampled is not None:
        portal_pdf[sampled] = own
    return np.where(through, F32(0.5) * map_pdf + F32(0.5) * portal_pdf, map_pdf).astype(F32)
