"""Cycles' Ambient Occlusion pass (View Layer > Passes > Light > Ambient Occlusion) and AO bake
(kernel/integrator/shade_surface.h integrate_surface_ao, film/light_passes.h PATH_RAY_SHADOW_FOR_AO): at a
surface the camera sees (its first hit, or one behind transparent surfaces), one ray cosine-distributed about
the diffuse closures' normal (surface_shader_ao: their normals weighted by |mean weight|, the shading normal
without any), drawn from the vertex's BSDF numbers, as far as the world's AO distance, through transparent
surfaces; the pass takes the path's throughput times the surface's alpha (one minus its transparency) times
what the ray lets through: white where nothing is near, black in crevices.
"""
from __future__ import annotations

import numpy as np

from . import sampling
from .bsdf.lobes import BSSRDF, DIFFUSE_LOBES
from .lights import nee
from .passes import closure_alpha
from .rays import rays_from
from .vec import F32

# Cycles' CLOSURE_IS_BSDF_DIFFUSE (kernel/svm/types.h): a BSSRDF is none.
DIFFUSE_CLOSURES = tuple(k for k in DIFFUSE_LOBES if k != BSSRDF)


def ambient_occlusion(tables, wave, hit, cs, numbers, rows) -> np.ndarray:
    """(3, len(rows)) the AO of the hits rows: alpha times the transmittance of one cosine-distributed ray.
    cs: the hits' ClosureSet; numbers: the hits' (u1, u2) BSDF numbers (each (n,))."""
    n = len(hit)
    normal = np.stack([np.asarray(c, F32) for c in hit.ns]).copy()
    alpha = closure_alpha(cs, n)
    if len(cs):
        diffuse = np.flatnonzero(np.isin(cs.lobe, DIFFUSE_CLOSURES))
        if len(diffuse):
            w = np.abs(cs.weight[:, diffuse].mean(axis=0))
            summed = np.stack([np.bincount(cs.hit[diffuse], cs.normal[k, diffuse] * w, minlength=n) for k in range(3)])
            length = np.sqrt((summed * summed).sum(axis=0))
            ok = length > 0
            normal[:, ok] = (summed[:, ok] / length[ok]).astype(F32)
    m = len(rows)
    u1, u2 = (np.take(u, rows) for u in numbers)
    lx, ly, lz = sampling.sample_cosine_hemisphere(u1, u2)
    w = sampling.local_to_world(lx, ly, lz, *(np.take(c, rows) for c in normal))
    # A bumped normal's ray may point below the surface: it leaves on that side (Cycles' ray skips the
    # triangle it leaves and goes through).
    gx, gy, gz = (np.take(c, rows) for c in hit.ng)
    below = w[0] * gx + w[1] * gy + w[2] * gz < 0
    rays = rays_from(tables, hit, rows, w, below)
    distance = np.full(m, F32(tables.scene.world.ao_distance), F32)
    through = nee.shadow(tables, rays.origins, rays.dirs, distance, wave, np.zeros(m, np.int32))
    return through * np.take(alpha, rows, axis=1)
