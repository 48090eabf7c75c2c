"""The Image Texture and Environment Texture ops (Cycles' svm_node_tex_image, svm_node_tex_image_box and
svm_node_tex_environment), and the texture lookups under them (the filters and extensions of
kernel/device/cpu/image.h, over kernels.textures.Texture and its sample_texture): `map_to_sphere`,
`map_to_tube`.

Each op is as kernels.shading.ops describes it, `op(hits, inputs, op) -> {output name: array}`.
"""
from __future__ import annotations

import numpy as np

from ..textures import finite_uv, sample_texture, srgb_to_linear
from ..vec import F32, HALF, INV_2PI, INV_PI, ONE, ZERO, dot_rows_einsum
from .input_ops import object_normal
from .program import full


# ---------------------------------------------------------------- the ops
def image(hits, inputs, op):
    """The Image Texture node (Cycles' svm_node_tex_image and svm_node_tex_image_box, with the lookups of
    kernel/device/cpu/image.h): Closest, Linear or Cubic (B-spline) interpolation; Repeat, Extend, Clip
    (texels outside read zero) or Mirror extension; Flat, Box (blended by the object-space normal),
    Sphere and Tube projection. 8-bit sRGB images are filtered encoded and decoded after. A tiled (UDIM) image
    (option "tiles": (tile number, texture), ...) reads each lookup from its tile (_udim_lookup)."""
    n = hits.n
    texture = op.option("texture", -1)
    vector = inputs.get("Vector")
    p = hits.uv if vector is None else full(vector, n, 3)
    if texture < 0:  # missing image: Cycles' magenta
        return {"Color": np.broadcast_to(np.array([1.0, 0.0, 1.0], F32), (n, 3)), "Alpha": np.ones(n, F32)}
    tiles = op.option("tiles")
    if tiles is None:
        tex = hits.scene.textures[texture]

        def lookup(u, v):
            return _image_lookup(tex, u, v, op)
    else:
        def lookup(u, v):
            return _udim_lookup(hits.scene.textures, tiles, u, v, op)
    projection = op.option("projection", "FLAT")
    if projection == "BOX":
        color, alpha = _box(hits, lookup, p, op)
    else:
        if projection in ("SPHERE", "TUBE"):  # from the [0, 1] box to [-1, 1] first
            p = (map_to_sphere if projection == "SPHERE" else map_to_tube)((p - HALF) * F32(2.0))
        color, alpha = lookup(p[:, 0], p[:, 1])
    return {"Color": np.ascontiguousarray(color.T, F32), "Alpha": alpha.astype(F32)}


def environment(hits, inputs, op):
    """The Environment Texture node (svm_node_tex_environment): the direction, normalized, looked up in an
    equirectangular map or a mirror ball."""
    n = hits.n
    texture = op.option("texture", -1)
    if texture < 0:
        return {"Color": np.broadcast_to(np.array([1.0, 0.0, 1.0], F32), (n, 3)), "Alpha": np.ones(n, F32)}
    d = full(inputs["Vector"], n, 3)
    length = np.sqrt(dot_rows_einsum(d, d))
    d = d / np.where(length > 0, length, ONE)[:, None]
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    if op.option("projection", "EQUIRECTANGULAR") == "EQUIRECTANGULAR":
        u = HALF - np.arctan2(y, x) * INV_2PI
        v = ONE - np.arccos(np.clip(z, -ONE, ONE)) * INV_PI
        zero = length == 0
        u, v = np.where(zero, ZERO, u), np.where(zero, ZERO, v)
    else:  # mirror ball: the inverse of Cycles' mirrorball_to_direction
        y = y - ONE
        div = F32(2.0) * np.sqrt(np.maximum(F32(-0.5) * y, ZERO))
        div = np.where(div > 0, div, ONE)
        u, v = HALF * (x / div + ONE), HALF * (z / div + ONE)
    color, alpha = _image_lookup(hits.scene.textures[texture], u, v, op)
    return {"Color": np.ascontiguousarray(color.T, F32), "Alpha": alpha.astype(F32)}


# ---------------------------------------------------------------- lookups
def _image_lookup(tex, u, v, op):
    """(colour (3, n), alpha (n,)) of one image lookup, unassociated and decoded as the node asks."""
    values = sample_texture(tex, u, v, op.option("interpolation", "Linear"), op.option("extension", "REPEAT"))
    color = values[:3]
    alpha = values[3] if tex.has_alpha else np.ones(len(u), F32)
    if op.option("unassociate", False) and tex.has_alpha:
        partial = (alpha != 0) & (alpha != 1)
        color = np.where(partial, color / np.where(partial, alpha, ONE), color)
    if tex.srgb:
        color = srgb_to_linear(color)
    return color, alpha


def _udim_lookup(textures, tiles, u, v, op):
    """(colour (3, n), alpha (n,)) of lookups in a tiled (UDIM) image, as Cycles' kernel_image_udim_map: the tile
    numbered 1001 + 10 x int(v) + int(u) (truncated toward zero; u in [0, 10), v >= 0), looked up at the UV less
    that offset with the node's filter and extension within the tile; magenta where the image has no such
    tile."""
    u, v = finite_uv(u, v)
    tx, ty = np.trunc(u), np.trunc(v)
    number = np.where((tx >= 0) & (ty >= 0) & (tx < 10), F32(1001) + F32(10) * ty + tx, F32(-1)).astype(np.int64)
    color = np.empty((3, len(u)), F32)
    color[:] = np.array([1.0, 0.0, 1.0], F32)[:, None]
    alpha = np.ones(len(u), F32)
    for tile, texture in tiles:
        sel = np.flatnonzero(number == tile)
        if len(sel):
            color[:, sel], alpha[sel] = _image_lookup(textures[texture], u[sel] - tx[sel], v[sel] - ty[sel], op)
    return color, alpha


def _box(hits, lookup, p, op):
    """Box projection: three planar lookups (lookup(u, v) -> colour, alpha) weighted by the object-space normal's
    share of each axis."""
    signed = object_normal(hits, hits.N)
    a = np.abs(signed)
    a = a / np.maximum(a.sum(axis=1, keepdims=True), F32(1e-30))
    weight = _box_weights(a[:, 0], a[:, 1], a[:, 2], F32(op.option("projection_blend", 0.0)))
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    planes = ((np.where(signed[:, 0] < 0, ONE - y, y), z), (np.where(signed[:, 1] > 0, ONE - x, x), z),
              (np.where(signed[:, 2] > 0, ONE - y, y), x))
    color = np.zeros((3, hits.n), F32)
    alpha = np.zeros(hits.n, F32)
    for k, (u, v) in enumerate(planes):
        sel = np.flatnonzero(weight[k] > 0)
        if len(sel):
            c, al = lookup(u[sel], v[sel])
            color[:, sel] += weight[k][sel] * c
            alpha[sel] += weight[k][sel] * al
    return color, alpha


def _box_weights(nx, ny, nz, blend):
    """(3, n) weights of the X, Y and Z projections (svm_node_tex_image_box's seven zones)."""
    limit = HALF * (ONE + blend)
    w = np.zeros((3, len(nx)), F32)
    only_x = (nx > limit * (nx + ny)) & (nx > limit * (nx + nz))
    only_y = ~only_x & (ny > limit * (nx + ny)) & (ny > limit * (ny + nz))
    only_z = ~only_x & ~only_y & (nz > limit * (nx + nz)) & (nz > limit * (ny + nz))
    rest = ~(only_x | only_y | only_z)
    w[0, only_x], w[1, only_y], w[2, only_z] = 1, 1, 1
    if not blend > 0:
        w[0, rest] = 1  # Cycles falls back to one side
        return w
    with np.errstate(invalid="ignore", divide="ignore"):
        def ramp(a, b):
            return np.clip((a / (a + b) - HALF * (ONE - blend)) / blend, ZERO, ONE)
        xy = rest & (nz < (ONE - limit) * (ny + nx))
        yz = rest & ~xy & (nx < (ONE - limit) * (ny + nz))
        xz = rest & ~xy & ~yz & (ny < (ONE - limit) * (nx + nz))
        three = rest & ~xy & ~yz & ~xz
        t = ramp(nx, ny)
        w[0] = np.where(xy, t, w[0])
        w[1] = np.where(xy, ONE - t, w[1])
        t = ramp(ny, nz)
        w[1] = np.where(yz, t, w[1])
        w[2] = np.where(yz, ONE - t, w[2])
        t = ramp(nx, nz)
        w[0] = np.where(xz, t, w[0])
        w[2] = np.where(xz, ONE - t, w[2])
        for k, c in enumerate((nx, ny, nz)):
            w[k] = np.where(three, ((F32(2.0) - limit) * c + (limit - ONE)) / (F32(2.0) * limit - ONE), w[k])
    return w


def map_to_sphere(p: np.ndarray) -> np.ndarray:
    """Cycles' map_to_sphere (util/math_float3.h) of (n, 3) points: (u, v, 0), float32."""
    p = np.asarray(p, F32)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    length2 = x * x + y * y + z * z
    u = np.where((x == 0) & (y == 0), ZERO, HALF - np.arctan2(x, y) * INV_2PI)
    with np.errstate(invalid="ignore", divide="ignore"):
        v = ONE - np.arccos(np.clip(z / np.sqrt(length2), -ONE, ONE)) * INV_PI
    some = length2 > 0
    return np.stack([np.where(some, u, ZERO), np.where(some, v, ZERO), np.zeros_like(u)], 1).astype(F32)


def map_to_tube(p: np.ndarray) -> np.ndarray:
    """Cycles' map_to_tube (util/math_float3.h) of (n, 3) points: (u, v, 0), float32."""
    p = np.asarray(p, F32)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    length = np.sqrt(x * x + y * y)
    some = length > 0
    safe = np.where(some, length, ONE)
    u = (ONE - np.arctan2(x / safe, y / safe) * INV_PI) * HALF
    v = (z + ONE) * HALF
    return np.stack([np.where(some, u, ZERO), np.where(some, v, ZERO), np.zeros_like(u)], 1).astype(F32)
