"""A wave's rays and where they start: the record the path stages hand each other (origins, directions, t_max),
and rays spawned from surface hits, moved off the surface to the side they leave on."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .interaction import spawn_offset


class Rays(NamedTuple):
    """A wave's rays: origins (N, 3), unit directions (N, 3) and t_max (N,), float32."""
    origins: np.ndarray
    dirs: np.ndarray
    t_max: np.ndarray


def concat_rays(a: Rays, b: Rays) -> Rays:
    return Rays(*(np.concatenate([x, y]) for x, y in zip(a, b)))


def spawn(tables, hit, alive, bs) -> Rays:
    """The next rays of the paths alive (hit rows), along their BSDF samples bs."""
    rays = rays_from(tables, hit, alive, tuple(np.take(c, alive) for c in bs.wi), np.take(below(bs), alive))
    if bs.origin is not None:
        # A Ray Portal that moves the ray: it starts exactly there, and may meet this surface again.
        origin = np.take(bs.origin, alive, axis=1)
        moved = np.flatnonzero(np.isfinite(origin[0]))
        rays.origins[moved] = origin[:, moved].T
    return rays


def rays_from(tables, hit, rows, w, transmit) -> Rays:
    """Rays leaving the hits rows along directions w (3 tuple of (n,)), from origins moved off the surface
    to the side they leave on (below it where transmit)."""
    px, py, pz = (np.take(c, rows) for c in hit.p)
    sign = np.where(transmit, np.float32(-1.0), np.float32(1.0))
    gx, gy, gz = (np.take(c, rows) * sign for c in hit.ng)
    eps = spawn_offset(tables.ray_epsilon, px, py, pz)
    if hit.shapes is not None:
        eps = unlifted(hit, rows, eps)
    origins = np.stack([px + gx * eps, py + gy * eps, pz + gz * eps], axis=1)
    return Rays(origins, np.stack(w, axis=1), np.full(len(rows), np.inf, np.float32))


def unlifted(hit, rows, eps):
    """The offsets eps of rays leaving the hits rows, 0 where they leave a curve or a point: Cycles starts those
    on the surface itself (integrate_surface_ray_offset and shadow_ray_offset move off triangles only) and skips
    the primitive they leave, as Ember does (PathState.self_key); a ray leaving one of two coincident strands
    then meets the other one about half the time, as it does in Cycles."""
    return np.where(np.take(hit.shapes.kind, rows) != 0, np.float32(0.0), eps)


def leaves_its_side(w, g, transmit) -> np.ndarray:
    """(n,) bool: directions w leave on their side of the true surface (normal g, facing the ray it was hit
    by): a reflection above it, a transmission below it (Cycles' test)."""
    side = w[0] * g[0] + w[1] * g[1] + w[2] * g[2]
    return np.where(transmit, side < 0, side > 0)


def below(bs) -> np.ndarray:
    """(N,) bool: a BSDF sample's ray leaves below the surface (its label's side, unless it is untested)."""
    return bs.transmit if bs.through is None else bs.through
