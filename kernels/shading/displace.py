"""True displacement: a material's Displacement output evaluated at mesh vertices (Cycles'
GeometryManager::displace, scene/mesh_displace.cpp, with shader_setup_from_displace in
kernel/geom/shader_data.h and kernel_displace_evaluate in kernel/bake/bake.h), and the ops of the
Displacement and Vector Displacement nodes (kernel/svm/displace.h).

At a vertex Cycles shades as at a hit on the first triangle that uses it, at that corner: the world-space
position, the smooth (vertex) normal as N, Ng and the viewer direction, that corner's UVs and attributes.
What the output gives is a world-space offset, taken back to object space by the inverse transform.
"""
from __future__ import annotations

import numpy as np

from ..vec import F32
from .input_ops import object_normal, to_world
from .program import ProgramRun


class VertexInputs:
    """What input ops read at V mesh vertices (program.HitInputs' interface).

    p, n : (V, 3) float32 world-space positions and unit vertex normals. uv : (V, 2) float32 render UVs.
    attributes : {name: (V, C) float32}. b1, b2 : (V,) float32 the corner's barycentrics in its triangle.
    object_row : (OBJECT_COLUMNS,) float32 the object table row of the object shown. textures : the
    scene's kernels.textures.Texture list. tangents : (V, 4) float32 object-space tangent and sign, or None.
    """

    def __init__(self, p, n, uv, attributes, b1, b2, object_row, textures, tangents=None):
        self.n = len(p)
        self.idx = np.arange(self.n)
        self.P, self.N, self.Ng = p, n, n
        self.I = n                                  # Cycles' sd->wi = sd->N
        self.backfacing = np.zeros(self.n, bool)
        self.uv = np.concatenate([uv, np.zeros((self.n, 1), F32)], axis=1).astype(F32)
        self._attributes, self._bary = attributes, (b1, b2)
        self._objects = np.broadcast_to(object_row, (self.n, len(object_row)))
        self.scene = _VertexScene(textures)
        self.hit = _VertexFrame(tangents, n)
        self.dp = np.zeros(self.n, F32)
        self._cache = {}

    def memo(self, key, compute):
        if key not in self._cache:
            self._cache[key] = compute()
        return self._cache[key]

    def barycentrics(self):
        return self._bary

    def attribute(self, name: str, interpolate: bool = True):
        return self._attributes.get(name)

    def objects(self) -> np.ndarray:
        return self._objects

    def tracing(self):
        return None   # no rays are traced while displacing (Cycles' bake state)


class _VertexScene:
    def __init__(self, textures):
        self.textures = textures


class _VertexFrame:
    """What ops read of `hits.hit` at vertices: the tangent frame (interaction.SurfaceHit.tangent_frame)."""

    def __init__(self, tangents, n):
        self._tangents, self._n = tangents, n

    def tangent_frame(self, idx):
        if self._tangents is None:
            return None
        t = self._tangents[idx]
        return tuple(t[:, k] for k in range(3)), t[:, 3], tuple(self._n[idx, k] for k in range(3))


def displacement_offsets(program, ref, inputs: VertexInputs, ops: dict) -> np.ndarray:
    """(V, 3) float32 world-space offsets: the Displacement output (a Ref into program) at the vertices,
    non-finite components made 0 (Cycles' ensure_finite)."""
    with np.errstate(all="ignore"):
        value = ProgramRun(program, inputs, ops).value(ref)
    out = np.array(np.broadcast_to(value, (inputs.n, 3)), F32)
    out[~np.isfinite(out)] = 0.0
    return out


# ---------------------------------------------------------------- the nodes (kernel/svm/displace.h)
def displacement_node(hits, inputs, op):
    """Displacement: (height - midlevel) * scale along Normal (the shading normal when unlinked), in world
    space; in object space along the normal taken to object space, then back by the object's transform
    (so the length is in object units)."""
    n = hits.n
    amount = ((np.broadcast_to(np.asarray(inputs["Height"], F32), (n,))
               - np.broadcast_to(np.asarray(inputs["Midlevel"], F32), (n,)))
              * np.broadcast_to(np.asarray(inputs["Scale"], F32), (n,)))
    normal = inputs.get("Normal")
    normal = hits.N if normal is None else np.broadcast_to(np.asarray(normal, F32), (n, 3))
    if op.option("space", "OBJECT") == "OBJECT":
        return {"Displacement": to_world(hits, object_normal(hits, normal) * amount[:, None], "VECTOR")}
    return {"Displacement": (normal * amount[:, None]).astype(F32)}


def vector_displacement_node(hits, inputs, op):
    """Vector Displacement: (vector - midlevel) * scale, as world, object or tangent-space (x along the
    tangent, y along the normal, z along the bitangent) offset."""
    n = hits.n
    v = (np.broadcast_to(np.asarray(inputs["Vector"], F32), (n, 3))
         - np.broadcast_to(np.asarray(inputs["Midlevel"], F32), (n,))[:, None]) \
        * np.broadcast_to(np.asarray(inputs["Scale"], F32), (n,))[:, None]
    space = op.option("space", "TANGENT")
    if space == "TANGENT":
        normal = object_normal(hits, hits.N)
        frame = hits.hit.tangent_frame(hits.idx)
        if frame is None:
            tangent, sign = np.zeros((n, 3), F32), np.ones(n, F32)
        else:
            tangent, sign = np.stack(frame[0], axis=1).astype(F32), frame[1]
        bitangent = np.cross(normal, tangent)
        length = np.sqrt(np.einsum("ij,ij->i", bitangent, bitangent))
        bitangent = bitangent / np.where(length > 0, length, F32(1.0))[:, None] * sign[:, None]
        v = tangent * v[:, 0:1] + normal * v[:, 1:2] + bitangent * v[:, 2:3]
    if space != "WORLD":
        v = to_world(hits, v.astype(F32), "VECTOR")
    return {"Displacement": v.astype(F32)}
