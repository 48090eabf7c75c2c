"""The Radial Tiling node over arrays of hits, as Cycles evaluates it (`kernel/svm/radial_tiling.h`, the
formulas in `kernel/svm/radial_tiling_shared.h`).

    radial_tiling(vector, sides=5.0, roundness=0.0, *, normalize=False, outputs=OUTPUTS, cycles_version=None,
                  constant=False)
        -> {"Segment Coordinates": (N, 3), "Segment ID": (N,), "Segment Width": (N,), "Segment Rotation": (N,)}

The plane around the origin is cut into Sides wedges (the Vector's x and y; z is not read) bounded by a
polygon whose corners Roundness rounds off. A fractional Sides leaves one narrower last wedge, just below
angle 2 pi. Per hit, in the wedge the hit lies in:

- Segment Coordinates: x, the signed distance from the wedge's bisector along the polygon's side (or the
  arc length around a rounded corner), y, the distance along the bisector measured so that the polygon's
  edge is at 1; with Normalize x is mapped to [0, 1] across the wedge and y is kept, without it y - 1.
- Segment ID: floor(Sides * angle / 2 pi), the angle in [0, 2 pi) from the x axis.
- Segment Width: the x the wedge's side reaches at y = 1 (its half width in x's units).
- Segment Rotation: the angle of the wedge's bisector.

Each hit falls in one "part" of its wedge (straight side, rounded corner, the last wedge's straight side or
its two kinds of rounded corner, plus Cycles' own shortcuts for Roundness 0 and, with whole Sides, 1);
Cycles branches per hit, here each part's formulas run over the index array of its hits. Cycles clamps
Sides to at least 2 and Roundness to [0, 1]; its SVM evaluates every part's formulas whichever outputs are
linked, except Segment ID, a formula of its own computed only when that output is read. Where the formulas
give NaN (Sides 2 with rounded corners: the circle's centre is at infinity) so does this; the film zeroes
it, as Cycles' does.

Cycles' arithmetic is float32 and so is this, in its order of operations, with the multiply-adds its AVX2
kernel fuses: Blender 5.0's and 5.1's (and later) kernels fuse different ones (`cycles_rounding`), found
by comparing against each. A node whose inputs are all constants is evaluated by Blender itself, rounded
its own way (`constant`, the note on PI_D). sinf and cosf are glibc's bit for bit
(kernels.shading.libm); tanf, atanf and atan2f are rounded from float64, within an ulp of glibc's. With
glibc's own three in their place the results are bit-identical to Cycles 5.0's and 5.3's and to Blender's
constants; with these, they differ by what a last-bit change of those functions makes, which the node's
subtractions of nearly equal angles amplify (tests/test_nodes_radial_tiling.py).
"""
from __future__ import annotations

import threading
from contextlib import contextmanager

import numpy as np

from ..vec import F32, F64, HALF, ONE, PI, TWO, TWO_PI, ZERO, fma
from .libm import atan2f, atanf, cosf, sinf, tanf

OUTPUTS = ("Segment Coordinates", "Segment ID", "Segment Width", "Segment Rotation")
MIN_SIDES = F32(2.0)
# Blender 5.0's Cycles was compiled with -ffp-contract=fast, 5.1's and later with =on (Cycles commit
# 91a635bef): the first fuses a product into the adds that are its only uses within one basic block, across
# statements; the second within one C expression only. Probed on 5.0.1 and 5.3.0 (5.1 and 5.2 share 5.3's
# flags).
CONTRACT_ON_FROM = (5, 1)
# A node whose inputs are all constants is not Cycles' to evaluate: Blender hands Cycles its
# value, computed by its own (geometry nodes') variant of radial_tiling_shared.h: no fused multiply-adds, pi and
# 2 pi as doubles (so the expressions holding them are evaluated in double), mix as a (1 - t) + b t, and its own
# formulas for Roundness 1 with fractional Sides. Probed: bit for bit on 5.0.1 and 5.3.0.
PI_D, TWO_PI_D = F64(np.pi), F64(2.0 * np.pi)
_ROUNDING = threading.local()


@contextmanager
def cycles_rounding(version, constant=False):
    """Round, on this thread and inside the block, as the Cycles of Blender `version` ((major, minor, ...))
    does (None: Blender 5.0's), or as Blender evaluates a node of constant inputs (`constant`)."""
    before = getattr(_ROUNDING, "mode", "fast")
    fast = version is None or tuple(version[:2]) < CONTRACT_ON_FROM
    _ROUNDING.mode = "blender" if constant else "fast" if fast else "on"
    try:
        yield
    finally:
        _ROUNDING.mode = before


def _mode() -> str:
    """"fast" (Blender 5.0's kernel, -ffp-contract=fast), "on" (5.1's and later), "blender" (constant inputs)."""
    return getattr(_ROUNDING, "mode", "fast")


def _fast() -> bool:
    return _mode() == "fast"


def _fused(a, b, c):
    """a * b + c as both of Cycles' kernels fuse it; unfused where Blender evaluates."""
    return a * b + c if _mode() == "blender" else fma(a, b, c)


def _mad(a, b, c, *, on=True, fast=True):
    """a * b + c, fused (rounded once) where the kernel of the current rounding fuses it: `on` for
    -ffp-contract=on, `fast` for =fast."""
    if {"fast": fast, "on": on}.get(_mode(), False):
        return fma(a, b, c)
    return a * b + c


def _wide(x):
    """x as an operand beside pi or 2 pi: float64 where Blender evaluates (C promotes float to double there)."""
    return np.asarray(x, F64) if _mode() == "blender" else x


def _two_pi():
    return TWO_PI_D if _mode() == "blender" else TWO_PI


def _narrow(x):
    return np.asarray(x, F32)


def radial_tiling(vector, sides=5.0, roundness=0.0, *, normalize=False, outputs=OUTPUTS,
                  cycles_version=None, constant=False) -> dict:
    """The Radial Tiling node at (N, 3) or constant `vector` with per-hit or constant Sides and Roundness;
    only the `outputs` named are computed, rounded as the Cycles of Blender `cycles_version` (None: 5.0's), or,
    where `constant` (the node's inputs are all constants), as Blender evaluates it."""
    with cycles_rounding(cycles_version, constant):
        return _radial_tiling(vector, sides, roundness, normalize, outputs)


def _radial_tiling(vector, sides, roundness, normalize, outputs):
    v = np.asarray(vector, F32)
    v = np.full((1, 3), v.reshape(()), F32) if v.size == 1 else v.reshape(-1, 3)
    per_hit = {len(v), np.size(sides), np.size(roundness)} - {1}
    n = per_hit.pop() if per_hit else 1
    x, y = (np.ascontiguousarray(np.broadcast_to(v[:, i], (n,))) for i in (0, 1))
    sides = np.broadcast_to(np.fmax(np.asarray(sides, F32).reshape(-1), MIN_SIDES), (n,))
    roundness = np.broadcast_to(np.fmin(np.fmax(np.asarray(roundness, F32).reshape(-1), ZERO), ONE), (n,))
    out = {}
    with np.errstate(all="ignore"):
        if "Segment ID" in outputs:
            out["Segment ID"] = segment_id(x, y, sides)
        if any(name in outputs for name in OUTPUTS if name != "Segment ID"):
            l_bisector, parameter, width, rotation = _segment_fields(x, y, sides, roundness, bool(normalize))
            out["Segment Coordinates"] = np.stack([parameter, l_bisector, np.zeros(n, F32)], axis=1)
            out["Segment Width"], out["Segment Rotation"] = width, rotation
    return {k: v for k, v in out.items() if k in outputs}


def segment_id(x, y, sides):
    """Segment ID: floor(sides * (the angle / 2 pi)), the angle counterclockwise from +x in [0, 2 pi) (Cycles'
    calculate_out_segment_id, its own formula: it can differ from the wedge the other outputs use by one
    where float rounding puts a hit on the other side of a wedge boundary)."""
    below = (y < ZERO).astype(F32)
    if _mode() == "blender":
        return _narrow(np.floor(_wide(sides) * (_wide(atan2f(y, x)) / TWO_PI_D + below)))
    return np.floor(sides * fma(atan2f(y, x), ONE / TWO_PI, below))


# ---------------------------------------------------------------- where a hit lies
class _Wedge:
    """A hit's angle and the wedge it is in, the names Cycles' radial_tiling_shared.h gives them (x_A_y:
    the angle from x to y): `angle` the hit's angle from +x in [0, 2 pi); `bisector` the angle between a
    wedge's side (segment divider) and its bisector, pi / sides; `wedge` = 2 bisector; `index` the wedge
    the angle falls in; `local` the hit's angle from that wedge's first side."""

    def __init__(self, x, y, sides):
        self.angle = _narrow(_wide(atan2f(y, x)) + np.where(y < ZERO, _two_pi(), ZERO))
        self.bisector = _narrow(PI_D / _wide(sides)) if _mode() == "blender" else PI / sides
        self.wedge = TWO * self.bisector
        self.index = np.floor(self.angle / self.wedge)
        self.local = _mad(-self.index, self.wedge, self.angle, fast=False)

    def rotation(self, to_bisector):
        """Segment Rotation: the wedge's first side's angle plus `to_bisector`."""
        return _mad(self.index, self.wedge, to_bisector, fast=False)


def _segment_fields(x, y, sides, roundness, normalize):
    """(length along the bisector, parameter, width, rotation), each (N,) float32: Cycles'
    calculate_out_variables, its final adjustments included."""
    n = len(x)
    l_coord = np.sqrt(_mad(y, y, x * x, on=False))
    fields = np.zeros((4, n), F32)
    whole = sides - np.floor(sides) == ZERO       # Cycles' fractf(sides) == 0
    sharp, full = roundness == ZERO, roundness == ONE
    parts = ((whole & sharp, _sharp), (whole & full, _circular), (whole & ~sharp & ~full, _rounded_regular),
             (~whole & sharp, _sharp_irregular), (~whole & ~sharp, _rounded_irregular))
    for mask, part in parts:
        idx = np.flatnonzero(mask)
        if len(idx):
            fields[:, idx] = part(x[idx], y[idx], l_coord[idx], sides[idx], roundness[idx], normalize)
    l_bisector, parameter, width, rotation = fields
    parameter[(x == ZERO) & (y == ZERO)] = ZERO        # defined as 0 at the origin
    if normalize:
        parameter = _mad(HALF, parameter, HALF)        # [-1, 1] -> [0, 1]
    else:
        l_bisector = l_bisector - ONE
    return l_bisector, parameter, width, rotation


# ---------------------------------------------------------------- shared formulas
def _signed(value, negative):
    """The parameter's sign: negative before the bisector (Cycles' `*= -1`)."""
    return np.where(negative, -value, value)


def _straight(l_bisector, to_bisector, negative):
    """The parameter on a straight side: the distance from the bisector, l tan(angle to the bisector)."""
    return _signed(l_bisector * tanf(np.abs(to_bisector)), negative)


def _straight_norm(l, tan_bevel, spline, tail, tail_fast=False):
    """The parameter's range along a straight side at length l (Cycles' normalize_based_on_l_angle_bisector):
    l tan(bevel to bisector) + spline (l / 2 + 1/2) + tail, `tail` a product's two factors (fused in
    5.0's kernel where `tail_fast`)."""
    return _mad(*tail, _mad(l, tan_bevel, spline * _mad(HALF, l, HALF)), fast=tail_fast)


def _curved_norm(l, sin_bevel, cos_bevel, spline, tail, tail_fast=False, base_shared=True):
    """The same range at a rounded corner, at the hit's distance l (normalize_based_on_l_coord)."""
    half = _mad(HALF * l, cos_bevel, HALF)
    if _fast():
        if base_shared:
            return _mad(*tail, fma(spline, half, l * sin_bevel), fast=tail_fast)
        return _mad(*tail, fma(l, sin_bevel, spline * half), fast=tail_fast)
    return _fused(*tail, _fused(l, sin_bevel, spline * half))


def _mix(a, b, t):
    """Cycles' mix: a + t (b - a); Blender's interpolate: a (1 - t) + b t."""
    return a * (ONE - t) + b * t if _mode() == "blender" else fma(t, b - a, a)


def _spline(l, cos_bevel, to_bevel_start, spline):
    """What a rounded corner adds to l sin(bevel to bisector): a quadratic spline over the first `spline`
    radians past the bevel start, then linear in the angle."""
    quadratic = _mad(l * cos_bevel, to_bevel_start,
                    HALF * _mad(-l, cos_bevel, ONE, fast=False) * (to_bevel_start * to_bevel_start) / spline)
    return np.where(to_bevel_start < spline, quadratic, _mad(spline, _mad(HALF * l, cos_bevel, -HALF), to_bevel_start))


def _bevel_start(to_bisector, roundness):
    """The angle from a side at which its rounded corner ends and the straight part begins."""
    return to_bisector - atanf((ONE - roundness) * tanf(to_bisector))


def _last_bisector(sides, bisector, fast):
    """The last wedge's half angle, pi - floor(sides) * bisector (`fast`: fused in 5.0's kernel)."""
    if _mode() == "blender":
        return _narrow(PI_D - _wide(np.floor(sides) * bisector))
    return _mad(-np.floor(sides), bisector, PI, fast=fast)


# ---------------------------------------------------------------- whole Sides
def _sharp(x, y, l_coord, sides, roundness, normalize):
    """Roundness 0, whole Sides: a regular polygon (Sides 2 has no width and is not normalized)."""
    w = _Wedge(x, y, sides)
    return _sharp_regular(w, l_coord, normalize, sides != MIN_SIDES)


def _sharp_regular(w, l_coord, normalize, has_width):
    d = w.bisector - w.local
    l_bisector = l_coord * cosf(d)
    parameter = _straight(l_bisector, d, w.local < w.bisector)
    tan_bisector = tanf(w.bisector)
    if normalize:
        parameter = np.where(has_width, parameter / (l_bisector * tan_bisector), parameter)
    width = np.where(has_width, tan_bisector, ZERO)
    return l_bisector, parameter, width, w.rotation(w.bisector)


def _circular(x, y, l_coord, sides, roundness, normalize):
    """Roundness 1, whole Sides: a circle; the parameter is the angle from the bisector."""
    w = _Wedge(x, y, sides)
    parameter = _signed(np.abs(w.bisector - w.local), w.local < w.bisector)
    if normalize:
        parameter = parameter / w.bisector
    return l_coord, parameter, w.bisector, w.rotation(w.bisector)


def _rounded_regular(x, y, l_coord, sides, roundness, normalize):
    """0 < Roundness < 1, whole Sides: every wedge is regular, a straight side between rounded corners."""
    w = _Wedge(x, y, sides)
    bevel = _bevel_start(w.bisector, roundness)
    corner = (w.local >= w.wedge - bevel) | (w.local < bevel)
    return _regular_parts(w, l_coord, roundness, bevel, corner, np.zeros(len(x), bool), None, normalize)


def _regular_parts(w, l_coord, r, bevel, corner, outer, last, normalize):
    """A regular wedge's straight side and rounded corners (`corner`). Where `outer` (the first and the
    last regular wedge of fractional Sides, beside the irregular one) the straight side's parameter is
    normalized by the range of the irregular wedge's outer corner, `last` (_LastWedge)."""
    to_bevel = w.bisector - bevel
    spline = (ONE - r) * bevel
    tail = (r, bevel)
    width = _mad(r, bevel, tanf(to_bevel) + spline, fast=False)
    negative = w.local < w.bisector
    d = w.bisector - w.local
    # the straight side
    l_bisector = l_coord * cosf(d)
    parameter = _straight(l_bisector, d, negative)
    if normalize:
        norm = _straight_norm(l_bisector, tanf(to_bevel), spline, tail)
        if outer.any():
            outer_norm = _straight_norm(l_bisector, tanf(last.outer_to_bisector), last.outer_spline,
                                        last.outer_tail, tail_fast=True)
            norm = np.where(outer, outer_norm, norm)
        parameter = parameter / norm
    # the rounded corners: on a circle of radius r, centred on the bisector, touching both sides
    nearest_side = np.where(w.local > w.bisector, w.local - w.wedge, w.local)
    centre = (ONE - r) / cosf(w.bisector)
    c = cosf(nearest_side) * centre
    under_root = _mad(-centre, centre, _mad(c, c, r * r, on=False), on=False)
    corner_l_bisector = l_coord / _mad(cosf(nearest_side), centre, np.sqrt(under_root), fast=False)
    to_start = bevel - np.abs(nearest_side)
    sin_bevel, cos_bevel = sinf(to_bevel), cosf(to_bevel)
    corner_parameter = _signed(l_coord * sin_bevel + _spline(l_coord, cos_bevel, to_start, spline), negative)
    if normalize:
        corner_parameter = corner_parameter / _mix(_straight_norm(corner_l_bisector, tanf(to_bevel), spline, tail),
                                                   _curved_norm(l_coord, sin_bevel, cos_bevel, spline, tail),
                                                   to_start / bevel)
    if _mode() == "blender":       # Roundness 1: Blender's own formulas, the circle's (_circular)
        full = r == ONE
        arc = _signed(np.abs(w.bisector - w.local), negative)
        corner_parameter = np.where(full, arc / w.bisector if normalize else arc, corner_parameter)
        corner_l_bisector = np.where(full, l_coord, corner_l_bisector)
    return (np.where(corner, corner_l_bisector, l_bisector), np.where(corner, corner_parameter, parameter),
            width, w.rotation(w.bisector))


# ---------------------------------------------------------------- fractional Sides
def _sharp_irregular(x, y, l_coord, sides, roundness, normalize):
    """Roundness 0, fractional Sides: regular wedges, then the narrower last one, whose side is the
    regular polygon's side line scaled to meet it (so y stays 1 along the polygon's edge)."""
    w = _Wedge(x, y, sides)
    last_bisector = _last_bisector(sides, w.bisector, fast=True)
    regular = w.angle < _two_pi() - _wide(TWO * last_bisector)
    fields = np.stack(_sharp_regular(w, l_coord, normalize, True))
    last = np.flatnonzero(~regular)
    if len(last):
        ratio = cosf(w.bisector[last]) / cosf(last_bisector[last])
        l_last = l_coord[last] * cosf(last_bisector[last] - w.local[last])
        d = last_bisector[last] - w.local[last]
        parameter = _signed(ratio * l_last * tanf(np.abs(d)), w.local[last] < last_bisector[last])
        if normalize:
            parameter = parameter / (ratio * l_last * tanf(last_bisector[last]))
        fields[:, last] = (ratio * l_last, parameter, tanf(last_bisector[last]),
                           _mad(w.index[last], w.wedge[last], last_bisector[last], fast=False))
    return tuple(fields)


class _LastWedge:
    """The rounded corners of the last, narrower wedge of fractional Sides (Cycles'
    calculate_out_variables_irregular_circular): its half angle `bisector` (last_angle_bisector_A_x_axis),
    the angle at which its inner corners end (`bevel`), and the circle of each outer corner (the one it
    shares with the first or the last regular wedge; mirrored about the last bisector), whose ends are
    at `outer_start` from the x axis."""

    def __init__(self, w: _Wedge, sides, r):
        self.bisector = _last_bisector(sides, w.bisector, fast=False)
        self.wedge = TWO * self.bisector
        self.bevel = _bevel_start(self.bisector, r)
        self.radius = r * tanf(self.bisector) / tanf(HALF * (w.bisector + self.bisector))
        k = cosf(self.bisector - self.bevel)
        self.centre_x = _mad(-self.radius, cosf(self.bisector), cosf(self.bevel) / k)
        self.centre_y = _mad(self.radius, sinf(self.bisector), -(sinf(self.bevel) / k))
        start_x = _mad(self.radius, cosf(w.bisector), self.centre_x, on=False)
        start_y = _mad(self.radius, sinf(w.bisector), self.centre_y, on=False)
        self.outer_start = atanf(start_y / start_x)
        self.outer_to_bisector = w.bisector - self.outer_start
        # the outer corner's roundness as its circle makes it: that of the regular wedge it belongs to
        self.effective = ONE - tanf(self.outer_to_bisector) / tanf(w.bisector)
        self.outer_spline = (ONE - self.effective) * self.outer_start

    @property
    def outer_tail(self):
        return self.effective, self.outer_start


def _take(obj, idx):
    """A _Wedge or _LastWedge restricted to the hits `idx`."""
    out = object.__new__(type(obj))
    out.__dict__.update({k: v[idx] for k, v in obj.__dict__.items()})
    return out


def _rounded_irregular(x, y, l_coord, sides, r, normalize):
    """0 < Roundness <= 1, fractional Sides."""
    w = _Wedge(x, y, sides)
    last = _LastWedge(w, sides, r)
    regular_end = _two_pi() - _wide(last.wedge)     # where the last wedge begins
    fields = np.zeros((4, len(x)), F32)
    in_regular = (w.angle >= last.outer_start) & (w.angle < regular_end - last.outer_start)
    idx = np.flatnonzero(in_regular)
    if len(idx):
        wi, li = _take(w, idx), _take(last, idx)
        bevel = _bevel_start(wi.bisector, r[idx])
        ends = regular_end[idx]
        straight = ((wi.local >= bevel) & (wi.local < wi.wedge - bevel)) | (wi.angle >= ends - bevel) | \
            (wi.angle < bevel)
        outer = (wi.angle >= ends - wi.bisector) | (wi.angle < wi.bisector)
        fields[:, idx] = _regular_parts(wi, l_coord[idx], r[idx], bevel, ~straight, outer, li, normalize)
    idx = np.flatnonzero(~in_regular)
    if len(idx):
        fields[:, idx] = _last_parts(_take(w, idx), _take(last, idx), x[idx], y[idx], l_coord[idx], r[idx],
                                     normalize)
    return tuple(fields)


def _last_parts(w, last, x, y, l_coord, r, normalize):
    """The last wedge's straight side, its inner corners and the outer corners beside it."""
    fields = np.zeros((4, len(x)), F32)
    ratio = cosf(w.bisector) / cosf(last.bisector)      # its bisector's length to the regular ones'
    spline = (ONE - r) * last.bevel
    to_bevel = last.bisector - last.bevel
    width = _mad(ratio, _mad(spline, HALF / ratio + HALF, r * last.bevel), tanf(to_bevel))
    straight = (w.angle >= _two_pi() - _wide(last.wedge) + last.bevel) & (w.angle < _two_pi() - _wide(last.bevel))
    idx = np.flatnonzero(straight)
    if len(idx):
        d = last.bisector[idx] - w.local[idx]
        l_last = l_coord[idx] * cosf(d)
        parameter = _signed(ratio[idx] * l_last * tanf(np.abs(d)), w.local[idx] < last.bisector[idx])
        if normalize:
            parameter = parameter / (ratio[idx] * _straight_norm(l_last, tanf(to_bevel[idx]), spline[idx],
                                                                 (r[idx], last.bevel[idx])))
        fields[:, idx] = (ratio[idx] * l_last, parameter, width[idx], w.rotation(last.bisector)[idx])
    idx = np.flatnonzero(~straight)
    if len(idx):
        fields[:, idx] = _last_corners(_take(w, idx), _take(last, idx), x[idx], y[idx], l_coord[idx], r[idx],
                                       ratio[idx], spline[idx], to_bevel[idx], width[idx], normalize)
    return fields


def _last_corners(w, last, x, y, l_coord, r, ratio, spline, to_bevel, width, normalize):
    """The rounded corners around the last wedge, its angles mirrored about its bisector so that one circle
    serves both sides: `side_angle` < 0 inside the last wedge (its inner corner), >= 0 beyond it (the
    outer corner, in the neighbouring regular wedge)."""
    side_angle = atan2f(y, x)
    mirror = (w.angle >= _two_pi() - _wide(last.wedge) - last.outer_start) & \
        (w.angle < _two_pi() - _wide(last.bisector))
    side_angle = np.where(mirror, -(side_angle + last.wedge), side_angle)
    t = _mad(sinf(side_angle), last.centre_y, cosf(side_angle) * last.centre_x)
    cx, cy, radius = last.centre_x, last.centre_y, last.radius
    if _fast():
        under_root = fma(-cy, cy, fma(-cx, cx, fma(t, t, radius * radius)))
    else:
        under_root = t * t + radius * radius - cx * cx - cy * cy
    to_circle = t + np.sqrt(under_root)
    l_last = l_coord / to_circle
    full = (r == ONE) & (_mode() == "blender")     # Blender's own formulas for Roundness 1
    l_bisector = np.where(full, ratio * l_coord / to_circle, ratio * l_last)
    inner = side_angle < ZERO
    # inner: its own bevel, scaled by ratio
    to_start = last.bevel - np.abs(side_angle)
    sin_bevel, cos_bevel = sinf(to_bevel), cosf(to_bevel)
    base, added = ratio * l_coord * sin_bevel, _spline(l_coord, cos_bevel, to_start, spline)
    # 5.1's kernel fuses this multiply-add past the quadratic part only, 5.0's on both
    parameter = np.where(to_start < spline, _mad(ratio, added, base, on=False), _fused(ratio, added, base))
    parameter = _signed(parameter, w.local < last.bisector)
    if normalize:
        tail = (r, last.bevel)
        norm = _mix(_straight_norm(l_last, tanf(to_bevel), spline, tail),
                    _curved_norm(l_coord, sin_bevel, cos_bevel, spline, tail, base_shared=False),
                    to_start / last.bevel)
        parameter = parameter / (ratio * np.where(full, last.bisector, norm))
    # outer: the regular wedge's corner, with its effective roundness
    o_start = last.outer_start - np.abs(side_angle)
    o_sin, o_cos = sinf(last.outer_to_bisector), cosf(last.outer_to_bisector)
    o_parameter = _signed(l_coord * o_sin + _spline(l_coord, o_cos, o_start, last.outer_spline),
                          w.local < w.bisector)
    if normalize:
        o_parameter = o_parameter / _mix(
            _straight_norm(l_bisector, tanf(last.outer_to_bisector), last.outer_spline, last.outer_tail, True),
            _curved_norm(l_coord, o_sin, o_cos, last.outer_spline, last.outer_tail, True), o_start / last.outer_start)
    bevel = _bevel_start(w.bisector, r)
    o_width = _mad(r, bevel, _mad(ONE - r, bevel, tanf(w.bisector - bevel), on=False))
    return (l_bisector, np.where(inner, parameter, o_parameter), np.where(inner, width, o_width),
            w.rotation(np.where(inner, last.bisector, w.bisector)))
