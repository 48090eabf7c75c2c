"""The Voronoi Texture node over arrays of hits, as Cycles evaluates it (`kernel/svm/voronoi.h`).

    voronoi_texture(vector, w, scale, detail, ...) -> {"Distance": (N,), "Color": (N, 3), ...}

Space is cut into unit cells; each cell holds one point at a hashed offset scaled by Randomness. F1 / F2
are the nearest / second-nearest point of the 3^d neighbourhood, Smooth F1 a smooth minimum over the 5^d
neighbourhood, Distance to Edge the distance to the nearest bisector, N-Sphere Radius half the distance
from the nearest point to its own nearest point (one octave of each: kernels.shading.voronoi_cells).
Detail adds octaves like fBM (`fractal_voronoi_*`), summed here.
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, HALF, ONE, TWO, ZERO
from .cycles_math import interp
from .voronoi_cells import Cells, Metric, distance_to_edge, f1, f2, in_chunks, n_sphere_radius, smooth_f1, take

FIRST_DISTANCE = F32(8.0)          # fractal Distance to Edge starts from this

DIMENSIONS = {"1D": 1, "2D": 2, "3D": 3, "4D": 4}
FEATURES = ("F1", "F2", "SMOOTH_F1", "DISTANCE_TO_EDGE", "N_SPHERE_RADIUS")
METRICS = ("EUCLIDEAN", "MANHATTAN", "CHEBYCHEV", "MINKOWSKI")


def available_outputs(dimensions: str = "3D", feature: str = "F1") -> tuple[str, ...]:
    """The output sockets Blender shows for these options."""
    if feature == "DISTANCE_TO_EDGE":
        return ("Distance",)
    if feature == "N_SPHERE_RADIUS":
        return ("Radius",)
    d = DIMENSIONS[dimensions]
    return ("Distance", "Color") + (("Position",) if d > 1 else ()) + (("W",) if d in (1, 4) else ())


# ---- Inputs ------------------------------------------------------------------------------------------

def _param(x) -> np.ndarray:
    """A float input as a 0-d float32 array (a constant) or an (N,) one."""
    a = np.asarray(x, F32)
    return a.reshape(()) if a.size == 1 else a.reshape(-1)


# ---- Fractal sums ------------------------------------------------------------------------------------

def _octaves(detail, roughness):
    """Yield (i, sel) for the octaves of a fractal sum: sel indexes the hits that take octave i (None:
    all of them). Every hit takes octave 0; zero input (detail or roughness 0) stops there, others go on
    to ceil(detail)."""
    more = ~((detail == 0) | (roughness == 0))
    ceil_detail = np.ceil(detail)
    for i in range(int(np.max(ceil_detail)) + 1):
        if i == 0:
            yield i, None
            continue
        mask = more & (i <= ceil_detail)
        if np.ndim(mask) == 0:
            if not mask:
                return
            yield i, None
            continue
        if not mask.any():
            return
        yield i, (None if mask.all() else np.flatnonzero(mask))


def _store(acc, sel, value):
    if sel is None:
        acc[...] = value
    else:
        acc[sel] = value


def _fractal_fx(feature, coords, params, metric, want_color, want_position):
    """F1 / F2 / Smooth F1 summed over octaves (`fractal_voronoi_x_fx`): distance and colour add up
    with amplitude roughness^i, position lerps toward each octave's; returns them and max_amplitude."""
    n, d = len(coords[0]), len(coords)
    detail, roughness, lacunarity = params["detail"], params["roughness"], params["lacunarity"]
    distance = np.zeros(n, F32)
    color = [np.zeros(n, F32) for _ in range(3)] if want_color else None
    position = [np.zeros(n, F32) for _ in range(d)] if want_position else None
    max_amplitude = np.zeros(n, F32)
    amplitude = np.ones(n, F32)
    scale = np.ones(n, F32)
    for i, sel in _octaves(detail, roughness):
        s = take(scale, sel)
        cells = Cells([take(c, sel) * s for c in coords], take(params["randomness"], sel))
        m = metric.take(sel)
        if feature == "F2":
            od, oc, op = in_chunks(f2, cells, m, want_color)
        elif feature == "SMOOTH_F1":
            od, oc, op = smooth_f1(cells, m, take(params["smoothness"], sel), want_color)
        else:
            od, oc, op = in_chunks(f1, cells, m, want_color)
        amp = take(amplitude, sel)
        sub_detail = take(detail, sel)
        full = i <= sub_detail
        # The octave past floor(detail) enters with weight frac(detail): a lerp toward the full sum.
        rem = None if np.all(full) else sub_detail - np.floor(sub_detail)

        def blend(acc, new):
            if rem is not None:
                new = np.where(full, new, interp(take(acc, sel), new, rem))
            _store(acc, sel, new)

        blend(max_amplitude, take(max_amplitude, sel) + amp)
        blend(distance, take(distance, sel) + od * amp)
        if want_color:
            for acc, c in zip(color, oc):
                blend(acc, take(acc, sel) + c * amp)
        if want_position:
            for acc, c in zip(position, op):
                blend(acc, interp(take(acc, sel), c / s, amp))
        _store(scale, sel, s * take(lacunarity, sel))
        _store(amplitude, sel, amp * take(roughness, sel))
    return distance, color, position, max_amplitude


def _fractal_edge(coords, params):
    """Distance to Edge over octaves (`fractal_voronoi_distance_to_edge`): a running minimum of
    distance / scale, lerped by amplitude; returns it and the max_amplitude to normalise by."""
    n = len(coords[0])
    detail, roughness, lacunarity = params["detail"], params["roughness"], params["lacunarity"]
    max_distance = params["max_distance"]
    distance = np.full(n, FIRST_DISTANCE, F32)
    max_amplitude = np.empty(n, F32)
    max_amplitude[...] = max_distance
    amplitude = np.ones(n, F32)
    scale = np.ones(n, F32)
    zero_input = (detail == 0) | (roughness == 0)
    for i, sel in _octaves(detail, roughness):
        s = take(scale, sel)
        od = in_chunks(distance_to_edge, Cells([take(c, sel) * s for c in coords],
                                               take(params["randomness"], sel)))
        amp = take(amplitude, sel)
        old_dist, old_max = take(distance, sel), take(max_amplitude, sel)
        new_max = interp(old_max, take(max_distance, sel) / s, amp)
        scaled = od / s
        new_dist = interp(old_dist, np.where(scaled < old_dist, scaled, old_dist), amp)
        sub_detail = take(detail, sel)
        full = i <= sub_detail
        if not np.all(full):
            rem = sub_detail - np.floor(sub_detail)
            new_max = np.where(full, new_max, interp(old_max, new_max, rem))
            new_dist = np.where(full, new_dist,
                                interp(old_dist, np.where(new_dist < old_dist, new_dist, old_dist), rem))
        if i == 0 and np.any(zero_input):
            new_dist = np.where(zero_input, od, new_dist)       # zero input: the octave as it is
            new_max = np.where(zero_input, old_max, new_max)
        _store(max_amplitude, sel, new_max)
        _store(distance, sel, new_dist)
        _store(scale, sel, s * take(lacunarity, sel))
        _store(amplitude, sel, amp * take(roughness, sel))
    return distance, max_amplitude


# ---- The node ----------------------------------------------------------------------------------------

def voronoi_texture(vector=0.0, w=0.0, scale=5.0, detail=0.0, roughness=0.5, lacunarity=2.0,
                    smoothness=1.0, exponent=0.5, randomness=1.0, *, dimensions: str = "3D",
                    feature: str = "F1", distance: str = "EUCLIDEAN", normalize: bool = False,
                    outputs=None) -> dict:
    """Cycles' Voronoi Texture at N hits.

    vector : (N, 3) float32 (or a constant (3,)); w, scale, detail, roughness, lacunarity, smoothness,
        exponent, randomness : (N,) float32 or constants. Defaults are Blender's.
    dimensions "1D".."4D", feature (FEATURES), distance (METRICS), normalize: the node's options.
    outputs : names to compute (default: the sockets Blender shows, `available_outputs`); a name the
        feature does not produce comes back as zeros, as Cycles writes it.
    Returns {"Distance": (N,), "Color": (N, 3), "Position": (N, 3), "W": (N,), "Radius": (N,)} (those
    asked for), float32.
    """
    d = DIMENSIONS[dimensions]
    if feature not in FEATURES or distance not in METRICS:
        raise ValueError(f"unknown Voronoi option {feature!r} / {distance!r}")
    wanted = set(available_outputs(dimensions, feature) if outputs is None else outputs)

    vec = np.asarray(vector, F32)
    vec = np.broadcast_to(vec, (1, 3)) if vec.size == 1 else vec.reshape(-1, 3)
    w, scale = _param(w), _param(scale)
    # fmax / fmin: a NaN Detail is 0, as Cycles' clamp makes it.
    params = {"detail": np.fmin(np.fmax(_param(detail), ZERO), F32(15.0)),
              "roughness": np.clip(_param(roughness), ZERO, ONE),
              "lacunarity": _param(lacunarity),
              "smoothness": np.clip(_param(smoothness) / TWO, ZERO, HALF),
              "randomness": np.clip(_param(randomness), ZERO, ONE)}
    exponent = _param(exponent)
    lengths = [len(a) for a in (vec, w, scale, exponent, *params.values()) if a.ndim > 0 and a.size != 1]
    n = max(lengths, default=1)
    if n == 0:
        return {name: np.zeros((0, 3) if name in ("Color", "Position") else 0, F32) for name in wanted}

    # Coordinates: x, y, z scaled (2D uses x, y), then w for 1D and 4D.
    coords = [np.broadcast_to(vec[:, k] * scale, (n,)) for k in range(min(d, 3))] if d > 1 else []
    if d in (1, 4):
        coords.append(np.broadcast_to(w * scale, (n,)))
    coords = [np.ascontiguousarray(c, F32) for c in coords]

    result = {}
    if feature == "DISTANCE_TO_EDGE":
        params["max_distance"] = HALF + HALF * params["randomness"]
        if "Distance" in wanted:
            dist, max_amplitude = _fractal_edge(coords, params)
            result["Distance"] = dist / max_amplitude if normalize else dist
    elif feature == "N_SPHERE_RADIUS":
        if "Radius" in wanted:
            result["Radius"] = in_chunks(n_sphere_radius, Cells(coords, params["randomness"]))
    else:
        metric = Metric(d, distance, exponent)
        want_color = "Color" in wanted
        want_position = bool(wanted & {"Position", "W"})
        if feature == "SMOOTH_F1" and np.any(params["smoothness"] == 0):
            dist, color, position, max_amplitude = _smooth_split(coords, params, metric, want_color,
                                                                 want_position)
        else:
            dist, color, position, max_amplitude = _fractal_fx(feature, coords, params, metric,
                                                               want_color, want_position)
        if normalize:
            max_distance = metric.max_distance(params["randomness"]) * (TWO if feature == "F2" else ONE)
            dist = dist / (max_amplitude * max_distance)
            if want_color:
                color = [c / max_amplitude for c in color]
        if "Distance" in wanted:
            result["Distance"] = dist
        if want_color:
            result["Color"] = np.stack(color, axis=1)
        if want_position:
            with np.errstate(invalid="ignore", divide="ignore"):
                position = [np.where(scale != 0, c / scale, ZERO).astype(F32, copy=False)
                            for c in position]
            if "Position" in wanted:
                xyz_out = position[:3] if d > 1 else []
                xyz_out = xyz_out[:3] + [np.zeros(n, F32)] * (3 - len(xyz_out[:3]))
                result["Position"] = np.stack(xyz_out, axis=1)
            if "W" in wanted:
                result["W"] = position[-1] if d in (1, 4) else np.zeros(n, F32)

    for name in wanted - set(result):
        result[name] = np.zeros((n, 3) if name in ("Color", "Position") else n, F32)
    return result


def _smooth_split(coords, params, metric, want_color, want_position):
    """Smooth F1 where some hits have smoothness 0: those hits take F1 (as Cycles does), the rest
    Smooth F1; each group runs on its own hits and the results are scattered back."""
    n = len(coords[0])
    smooth = params["smoothness"] != 0
    outs = None
    for feature, mask in (("SMOOTH_F1", smooth), ("F1", ~smooth)):
        sel = np.flatnonzero(np.broadcast_to(mask, (n,)))
        if len(sel) == 0:
            continue
        sub = {k: take(v, sel) for k, v in params.items()}
        part = _fractal_fx(feature, [c[sel] for c in coords], sub, metric.take(sel), want_color,
                           want_position)
        if outs is None:
            outs = [None if p is None else ([np.zeros(n, F32) for _ in p] if isinstance(p, list)
                                            else np.zeros(n, F32)) for p in part]
        for acc, p in zip(outs, part):
            if isinstance(p, list):
                for a, c in zip(acc, p):
                    a[sel] = c
            elif p is not None:
                acc[sel] = p
    return tuple(outs)
