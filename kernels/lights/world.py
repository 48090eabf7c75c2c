"""The world as a light: directions from its importance map (environment.Environment), through its light portals
where a shading point has one (portals.Portals), and into a Sky Texture's sun disc (World.sun), mixed with Cycles'
weights (1 each for the map and the portals, 4 for the sun: kernel/light/background.h background_light_sample and
background_light_pdf), and their pdf.
"""
from __future__ import annotations

import numpy as np

from ..sampling import UNIFORM_SPHERE_PDF, local_to_world, sample_uniform_cone_precise, sample_uniform_sphere
from ..vec import F32


# Cycles' weight of a Sky Texture's sun disc among the background light's methods, against 1 for the map and 1 for
# the portals a point can use (scene/light.cpp device_update_background: "Empirical value").
SUN_WEIGHT = 4.0


def sample(sampler, out, idx, u1, u2, focus=None, px=None, py=None, pz=None):
    """World light samples for the shading points p (idx: their rows in out). With a sun disc to aim at
    (World.sun), a share of them (sun_share) is drawn uniformly from its cone, the rest as without it, and every
    sample's pdf is the mixture's, as Cycles' background_light_sample."""
    sun = _sun(sampler)
    if sun is None:
        _sample(sampler, out, idx, u1, u2, focus, px, py, pz)
        return
    share = sun_share(sampler, px, py, pz)
    # u1 < share picks the sun, and both parts are stretched back to [0, 1).
    aimed = u1 < share
    rest = np.flatnonzero(~aimed)
    if len(rest):
        q = share[rest]
        ur = np.minimum((u1[rest] - q) / (F32(1.0) - q), F32(1.0 - 2.0 ** -24))
        _sample(sampler, out, idx[rest], ur, u2[rest], None if focus is None else focus.take(rest),
                *((None,) * 3 if px is None else (px[rest], py[rest], pz[rest])))
    rows = np.flatnonzero(aimed)
    if len(rows):
        us = np.minimum(u1[rows] / share[rows], F32(1.0 - 2.0 ** -24))
        lx, ly, lz = sample_uniform_cone_precise(us, u2[rows], _one_minus_cos(sun[3]))
        wx, wy, wz = local_to_world(lx, ly, lz, *(np.full(len(rows), c, F32) for c in sun[:3]))
        out.set(idx[rows], wx, wy, wz, np.float32(np.inf), sampler.environment.radiance(wx, wy, wz),
                np.zeros(len(rows), F32))
        out.world[idx[rows]] = True
    # The mixture's pdf for every sample (what pdf() gives the same direction): the other methods' pdf is known for
    # their own samples (a portal's as its sample gave it).
    others = out.pdf[idx]
    if len(rows):
        at = idx[rows]
        others[rows] = _direction_pdf(sampler, out.wx[at], out.wy[at], out.wz[at],
                                      None if focus is None else focus.take(rows),
                                      *((None,) * 3 if px is None else (px[rows], py[rows], pz[rows])))
    out.pdf[idx] = ((F32(1.0) - share) * others + share * _sun_pdf(sun, out.wx[idx], out.wy[idx], out.wz[idx])
                    ).astype(F32)


def sun_share(sampler, px=None, py=None, pz=None) -> np.ndarray | float:
    """The share of the world's light samples aimed at its sun disc at points p: SUN_WEIGHT against 1 for the map
    and 1 where a point has a portal it can use (Cycles' background_light_sample); 0 without a sun."""
    if _sun(sampler) is None:
        return 0.0
    others = F32(1.0)
    portals = sampler.portals
    if portals is not None and px is not None:
        others = others + portals.possible(px, py, pz).any(axis=0).astype(F32)
    share = F32(SUN_WEIGHT) / (F32(SUN_WEIGHT) + others)
    return np.broadcast_to(share, (1 if px is None else len(px),)).astype(F32) if np.ndim(share) == 0 else share


def _sun(sampler):
    """The world's sun disc to aim at (World.sun), where the world is light-sampled; else None."""
    world = sampler.environment.world
    return world.sun if world.sun is not None and _map_sampled(sampler) else None


def _one_minus_cos(half_angle) -> np.float32:
    return F32(2.0) * F32(np.sin(0.5 * float(half_angle))) ** 2


def _sun_pdf(sun, dx, dy, dz) -> np.ndarray:
    """Cycles' pdf_uniform_cone of the sun's cone at directions d (the chord to the axis against the cone's, which
    keeps a half-degree cone apart in float32)."""
    ex, ey, ez = dx - sun[0], dy - sun[1], dz - sun[2]
    inside = ex * ex + ey * ey + ez * ez < F32(2.0) * _one_minus_cos(sun[3])
    return np.where(inside, F32(1.0) / (F32(2.0 * np.pi) * _one_minus_cos(sun[3])), F32(0.0)).astype(F32)


def _sample(sampler, out, idx, u1, u2, focus=None, px=None, py=None, pz=None):
    """sample() by the map and the portals alone."""
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


def pdf(sampler, dx, dy, dz, focus=None, receiver=None, ox=None, oy=None, oz=None, facing=None) -> np.ndarray:
    """pdf (solid angle, with selection) with which NEE would have sampled world directions d from the points o
    the rays left (focus: as given to sample(); receiver: the light sets of those points, or None; facing: their
    normals as the light choice reads them, choose_at's)."""
    if not sampler.samples_world():
        return np.zeros(len(dx), np.float32)
    direction_pdf = _direction_pdf(sampler, dx, dy, dz, focus, ox, oy, oz)
    sun = _sun(sampler)
    if sun is not None:
        share = sun_share(sampler, ox, oy, oz)
        direction_pdf = ((F32(1.0) - share) * direction_pdf + share * _sun_pdf(sun, dx, dy, dz)).astype(F32)
    return sampler.distant_pmf(sampler.world_index, len(dx), receiver, ox, oy, oz, facing) * direction_pdf


def _direction_pdf(sampler, dx, dy, dz, focus=None, ox=None, oy=None, oz=None) -> np.ndarray:
    """The pdf per solid angle of the map's and the portals' samples (_sample) of directions d from points o."""
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
    return direction_pdf


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
