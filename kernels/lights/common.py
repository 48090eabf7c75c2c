"""What every kind of emitter module shares: the kinds' ids, a direction and distance toward a sampled point,
and the change of a pdf from area to solid angle.
"""
from __future__ import annotations

import numpy as np

from ..scene import LIGHT_KINDS

POINT, SPOT, SUN, RECT, DISK = (LIGHT_KINDS[k] for k in ("POINT", "SPOT", "SUN", "RECT", "DISK"))


def direction(px, py, pz, qx, qy, qz):
    dx, dy, dz = qx - px, qy - py, qz - pz
    dist = np.sqrt(dx * dx + dy * dy + dz * dz)
    inv = np.float32(1.0) / np.maximum(dist, np.float32(1e-30))
    return dx * inv, dy * inv, dz * inv, dist


def area_to_solid_angle(area, dist, cos_l):
    """pdf per solid angle of a point sampled uniformly on `area`, seen at dist under cos_l."""
    with np.errstate(divide="ignore", invalid="ignore"):
        pdf = dist * dist / (area * cos_l)
    return np.where((cos_l > 0) & np.isfinite(pdf), pdf, np.float32(0.0)).astype(np.float32)
