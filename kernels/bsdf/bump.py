"""The bump shadowing term of closures whose normal is not their hit's shading normal (a normal map, the
specular tilt of Bump Map Correction): Cycles' `bump_shadowing_term` (`kernel/closure/bsdf.h`).

Evaluated, it is zero where the light and the closure's normal sit on different sides of the shading
normal's plane, and diffuse closures are softened by a GGX shadowing term of the normal's deviation (Chiang
et al., "Taming the Shadow Terminator"); sampled, only diffuse reflection takes the term, as in Cycles
(mixture_sample).
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, ONE, ZERO
from .lobes import DIFFUSE_LOBES


class BumpShadowing:
    """What the term reads of a closure set's C closures, made only when some closure is on another normal.

    bumped : (C,) bool, the closures whose normal is not their hit's shading normal.
    shading : (3, C) float32, each closure's hit's shading normal.
    cos_d : (C,) float32, the cosine between that shading normal and the closure's own.
    diffuse : (C,) bool, the diffuse closures (lobes.DIFFUSE_LOBES), which the term may soften.
    """
    __slots__ = ("bumped", "shading", "cos_d", "diffuse")

    def __init__(self, bumped, shading, cos_d, diffuse):
        self.bumped, self.shading, self.cos_d, self.diffuse = bumped, shading, cos_d, diffuse

    @classmethod
    def of(cls, normal, shading, lobe, exempt=None) -> "BumpShadowing | None":
        """From the closures' normals (3, C), their hits' shading normals (3, C) and their lobes (C,); None
        when every closure is on its shading normal. exempt (C,) bool: closures that take no term whatever
        their normal (those of hits on curves, as Cycles skips the term there)."""
        bumped = np.any(normal != shading, axis=0)
        if exempt is not None:
            bumped &= ~exempt
        if not bumped.any():
            return None
        return cls(bumped, shading.astype(F32), np.einsum("ij,ij->j", shading, normal).astype(F32),
                   np.isin(lobe, DIFFUSE_LOBES))

    def term(self, rows, wi_world, normal, soften):
        """(n,) the term of closures rows evaluated toward wi_world (module docstring), None when none of them
        needs it. normal (3, C) and soften (C,) are the closure set's columns."""
        bumped = self.select(rows, wi_world, normal, soften)
        if bumped is None:
            return None
        term = np.ones(len(rows), F32)
        term[bumped[0]] = bumped[1]
        return term

    def select(self, rows, wi_world, normal, soften):
        """(sel, term): the entries of rows whose closure is on another normal than the shading normal,
        and their bump shadowing term; None when there are none (the term is 1 at every other entry)."""
        sel = np.flatnonzero(self.bumped[rows])
        if not len(sel):
            return None
        rows = rows[sel]
        wx, wy, wz = (np.take(c, sel) for c in wi_world)
        diffuse = self.diffuse[rows]
        ns = np.take(self.shading, rows, axis=1)
        cos_si = wx * ns[0] + wy * ns[1] + wz * ns[2]
        n = np.take(normal, rows, axis=1)
        cos_ni = wx * n[0] + wy * n[1] + wz * n[2]
        cos_d = self.cos_d[rows]
        reject = cos_si * cos_d * cos_ni < 0
        term = np.where(reject, ZERO, ONE)
        soft = diffuse & ~reject & (soften[rows] > 0)
        if soft.any():
            ci, cd = np.abs(cos_si), np.abs(cos_d)
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                alpha2 = np.clip(F32(0.125) * (ONE / (cd * cd) - ONE), 0.0, 1.0)
                tan2 = np.maximum(ONE / (ci * ci) - ONE, ZERO)
                g = F32(2.0) / (ONE + np.sqrt(ONE + alpha2 * tan2))
            g = np.where(ci < F32(1e-6), ZERO, g)
            term = np.where(soft & (cd < ONE) & (ci < ONE), g, term)
        return sel, term.astype(F32)
