"""Running a material's node program (kernels/programs.py) over the hits of that material in a wave.

Each op runs at most once per wave and set of hits, on the first request for one of its outputs
(a subgraph shared by several inputs is evaluated once), and only for the ops the closures read.
Values are (n,) float32 for VALUE sockets and (n, 3) float32 for VECTOR and RGBA sockets; the kernel's
closures read colours as (3, n), which Shading.param transposes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..programs import Program, Ref
from ..vec import F32, matmul
from .color_nodes import RGB_TO_Y, vector_to_float


# Attribute names whose values are per object row, not per corner.
OBJECT_ATTRIBUTE_PREFIXES = ("object:", "instancer:", "particle:")


@dataclass
class TracedHits:
    """The hits of a node program that may trace (program.HitInputs.tracing).

    rays : raytrace.ShaderRays. p, n, ng : (n, 3) float32 position, shading and true normal (both flipped to the
    viewer, as Cycles' sd->N and sd->Ng). backfacing : (n,) bool. objects : (n,) int32 object rows.
    keys : (x, y) uint32 of the paths (paths.ray_keys). time : accel.RayTimes or None.
    min_ray_pdf : (n,) float32 or None (the path's smallest BSDF pdf so far). split : spread ray queries
    over the accel's threads.
    """
    rays: object
    p: np.ndarray
    n: np.ndarray
    ng: np.ndarray
    backfacing: np.ndarray
    objects: np.ndarray
    keys: tuple
    time: object = None
    min_ray_pdf: np.ndarray | None = None
    split: bool = True

    def take(self, idx: np.ndarray) -> "TracedHits":
        return TracedHits(self.rays, self.p[idx], self.n[idx], self.ng[idx], self.backfacing[idx],
                          self.objects[idx], tuple(np.take(k, idx) for k in self.keys),
                          None if self.time is None else self.time.take(idx),
                          None if self.min_ray_pdf is None else self.min_ray_pdf[idx], self.split)


class HitInputs:
    """What the input nodes read at some hits of a wave (interaction.SurfaceHit + indices), computed on
    first use and kept: positions, normals, the viewer direction, UVs, attributes, object data.

    scene : the shading's scene data (kernels.shading.shader.ShadingData): textures, the object table,
        per-corner attributes, the camera.
    """

    def __init__(self, scene, hit, idx: np.ndarray, shift=None):
        self.scene, self.hit, self.idx = scene, hit, idx
        self.n = len(idx)
        self._cache = {}
        self._shift = shift

    def shifted(self, steps, e1: np.ndarray, e2: np.ndarray, flip=None) -> "HitInputs":
        """The same hits moved across their triangles (edges e1, e2 (n, 3)), once per barycentric step
        (db1, db2) of `steps`, as one set of len(steps) n hits end to end: position, UVs and attributes
        follow, normals and the viewer direction stay (the Bump node's offset evaluations, run together:
        every op works hit by hit, so each copy gets what a run of its own would). flip: (n,) bool or None,
        hits whose attributes step the other way while their position steps as given (Cycles' back faces,
        whose negated dPdu and dPdv turn the attributes' differentials around); P_bary follows the attributes."""
        copies = len(steps)
        sign = None if flip is None or not np.any(flip) else np.where(flip, F32(-1.0), F32(1.0))
        along = steps if sign is None else [(b1 * sign, b2 * sign) for b1, b2 in steps]
        db1, db2 = (np.concatenate([step[k] for step in along]) for k in (0, 1))
        out = HitInputs(self.scene, self.hit, np.tile(self.idx, copies), (db1, db2))
        for key in ("N", "Ng", "I", "D", "backfacing", "prim", "objects"):
            if key in self._cache:
                out._cache[key] = np.concatenate([self._cache[key]] * copies)
        out._cache["P"] = np.concatenate([(self.P + b1[:, None] * e1 + b2[:, None] * e2).astype(F32)
                                          for b1, b2 in steps])
        if sign is not None:
            out._cache["P_bary"] = np.concatenate([(self.P_bary + b1[:, None] * e1 + b2[:, None] * e2).astype(F32)
                                                   for b1, b2 in along])
        return out

    def moved(self, p: np.ndarray, n: np.ndarray) -> "HitInputs":
        """The same hits at the positions p with the shading normals n ((n, 3) world space each); the rest as
        here (the undisplaced surface Displacement and Bump's bump is evaluated on, kernels/shading/bump.py)."""
        out = HitInputs(self.scene, self.hit, self.idx, self._shift)
        for key in ("Ng", "I", "D", "backfacing", "prim", "objects", "bary"):
            if key in self._cache:
                out._cache[key] = self._cache[key]
        out._cache["P"], out._cache["N"] = np.asarray(p, F32), np.asarray(n, F32)
        return out

    def memo(self, key, compute):
        """compute() once for these hits (what input ops derive from the hits, e.g. Generated)."""
        if key not in self._cache:
            self._cache[key] = compute()
        return self._cache[key]

    def _vec(self, name, components):
        if name not in self._cache:
            self._cache[name] = np.stack([np.take(c, self.idx) for c in components], axis=1).astype(F32, copy=False)
        return self._cache[name]

    @property
    def P(self) -> np.ndarray:
        return self._vec("P", self.hit.p)

    @property
    def N(self) -> np.ndarray:
        return self._vec("N", self.hit.ns)

    @property
    def P_bary(self) -> np.ndarray:
        """The position as an attribute of the triangles' corners reads it here: P, but at hits shifted with flip."""
        return self._cache["P_bary"] if "P_bary" in self._cache else self.P

    @property
    def Ng(self) -> np.ndarray:
        return self._vec("Ng", self.hit.ng)

    @property
    def I(self) -> np.ndarray:  # noqa: E743 - Cycles' name: the direction toward the viewer
        if "I" not in self._cache:
            self._cache["I"] = -self._vec("D", self.hit.d)
        return self._cache["I"]

    @property
    def backfacing(self) -> np.ndarray:
        if "backfacing" not in self._cache:
            self._cache["backfacing"] = np.take(self.hit.backfacing, self.idx)
        return self._cache["backfacing"]

    def barycentrics(self):
        """(b1, b2) at the hits: the weights of corners 1 and 2."""
        if "bary" not in self._cache:
            b1, b2 = self.hit.barycentrics
            b1, b2 = np.take(b1, self.idx), np.take(b2, self.idx)
            if self._shift is not None:
                b1, b2 = b1 + self._shift[0], b2 + self._shift[1]
            self._cache["bary"] = (b1.astype(F32, copy=False), b2.astype(F32, copy=False))
        return self._cache["bary"]

    @property
    def dp(self) -> np.ndarray:
        """(n,) the rays' position spread at the hits (0 where the integrator gave none)."""
        ray = self.hit.ray
        if ray is None or ray.dp is None:
            return np.zeros(self.n, F32)
        return np.take(ray.dp, self.idx)

    @property
    def prim(self) -> np.ndarray:
        if "prim" not in self._cache:
            self._cache["prim"] = np.take(self.hit.prim, self.idx)
        return self._cache["prim"]

    def attribute(self, name: str, interpolate: bool = True) -> np.ndarray | None:
        """(n, C) float32 per-corner attribute (kernels.scene.SceneArrays.attributes) interpolated over the
        triangles (exactly the corners' value where all three are equal, as a face attribute is), or
        (interpolate=False, a face attribute) the first corner's; an object attribute
        ("object:", "instancer:": SceneArrays.object_attributes) of the hits' object rows. None when the
        scene does not have it."""
        key = ("attr", name, interpolate)
        if key not in self._cache:
            if name.startswith(OBJECT_ATTRIBUTE_PREFIXES):
                self._cache[key] = self.scene.object_attribute(name, self.prim)
                return self._cache[key]
            rows = self.scene.attribute(name, self.prim)          # (n, 3, C)
            if rows is None:
                self._cache[key] = None
            elif not interpolate:
                self._cache[key] = np.ascontiguousarray(rows[:, 0])
            else:
                b1, b2 = self.barycentrics()
                w0 = F32(1.0) - b1 - b2
                mixed = (rows[:, 0] * w0[:, None] + rows[:, 1] * b1[:, None] +
                         rows[:, 2] * b2[:, None]).astype(F32, copy=False)
                # A face attribute arrives as three equal corners: Cycles reads it per face, uninterpolated,
                # and the weighted sum of three equal values can miss the value by an ulp.
                same = (rows[:, 1] == rows[:, 0]) & (rows[:, 2] == rows[:, 0])
                self._cache[key] = np.where(same, rows[:, 0], mixed)
        return self._cache[key]

    @property
    def uv(self) -> np.ndarray:
        """(n, 3) the render UV map's (u, v, 0)."""
        if "uv" not in self._cache:
            u, v = self.hit.uv_at(self.idx, *self.barycentrics()) if self._shift is not None else \
                self.hit.uv_at(self.idx)
            self._cache["uv"] = np.stack([u, v, np.zeros_like(u)], axis=1)
        return self._cache["uv"]

    def tracing(self):
        """What the nodes that trace rays need at these hits (raytrace.TracedHits), or None where Cycles traces
        none: anywhere but a path's surface vertex (shadow rays' transparency, lights' emission), or without a
        scene to trace (ShadingData.rays)."""
        rays, ray = self.scene.rays, self.hit.ray
        if rays is None or ray is None or ray.keys is None:
            return None
        if "tracing" not in self._cache:
            idx = self.idx
            self._cache["tracing"] = TracedHits(
                rays, self.P, self.N, self.Ng, self.backfacing, rays.object_rows(self.prim),
                tuple(np.take(k, idx) for k in ray.keys), None if ray.time is None else ray.time.take(idx),
                None if ray.min_ray_pdf is None else np.take(ray.min_ray_pdf, idx), ray.split)
        return self._cache["tracing"]

    def objects(self) -> np.ndarray:
        """(n, OBJECT_COLUMNS) float32 object table rows of the hits' instances."""
        if "objects" not in self._cache:
            table = self.scene.objects
            rows = self.scene.object_rows(self.prim)
            self._cache["objects"] = np.take(table, rows, axis=0)
        return self._cache["objects"]


class ProgramRun:
    """A program over some hits: values(ref) computes what it needs, once."""

    def __init__(self, program: Program, inputs: HitInputs, ops: dict):
        self.program, self.hits, self._ops = program, inputs, ops
        self._outputs: dict[int, dict] = {}

    def elsewhere(self, hits: HitInputs) -> "ProgramRun":
        """A run of the same program and ops at other hits (the Bump node's offset points)."""
        return ProgramRun(self.program, hits, self._ops)

    def value(self, ref: Ref) -> np.ndarray:
        """The output ref points to, converted to the type the consumer wants: (n,) or (n, 3)."""
        outputs = self._outputs.get(ref.op)
        if outputs is None:
            self._evaluate(ref.op)
            outputs = self._outputs[ref.op]
        return convert(outputs[ref.output], ref.type, ref.want, self.hits.n)

    def _evaluate(self, target: int) -> None:
        """Run op target and the ops it reads that have not run yet, each op's inputs first and in the
        order they are listed: on an explicit stack, so a chain of any length runs without recursion."""
        stack = [target]
        while stack:
            i = stack[-1]
            if i in self._outputs:
                stack.pop()
                continue
            waiting = [v.op for _, v in self.program.ops[i].inputs
                       if isinstance(v, Ref) and v.op not in self._outputs]
            if waiting:
                stack.extend(reversed(waiting))
                continue
            stack.pop()
            self._outputs[i] = self._run(i)

    def _run(self, i: int) -> dict:
        op = self.program.ops[i]
        if op.kind == "ShaderNodeBump":   # it evaluates its Height again at other points: it takes the run
            return self._ops[op.kind](self, op)
        inputs = {}
        for name, value in op.inputs:
            inputs[name] = self.value(value) if isinstance(value, Ref) else constant(value)
        return self._ops[op.kind](self.hits, inputs, op)


def make_orthonormals(n: np.ndarray):
    """Cycles' make_orthonormals of (n, 3) unit vectors: a = normalize((1,1,1) x N) (or (-1,1,1) x N when
    the components are equal), b = N x a."""
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    equal = (x == y) & (x == z)
    a = np.stack([z - y, np.where(equal, x + z, x - z), np.where(equal, -y - x, y - x)], axis=1)
    a = a / np.maximum(np.sqrt(np.einsum("ij,ij->i", a, a)), F32(1e-30))[:, None]
    return a.astype(F32), np.cross(n, a).astype(F32)


def full(x, n: int, channels: int = 1) -> np.ndarray:
    """An input as a full (n,) or (n, 3) float32 array (constants broadcast, not copied)."""
    a = np.asarray(x, F32)
    return np.broadcast_to(a, (n,) if channels == 1 else (n, 3))


def constant(value: tuple):
    """A folded input: a Python float for VALUE, a (3,) float32 array for VECTOR and RGBA."""
    return float(value[0]) if len(value) == 1 else np.asarray(value, F32)


def convert(a, have: str, want: str, n: int) -> np.ndarray:
    """A value between socket types as Blender converts on a link: colour to float by Cycles' luminance
    (color_nodes.RGB_TO_Y), vector to float by the average, float to vector or colour by splatting."""
    a = np.asarray(a, F32)
    if have == want or (have != "VALUE" and want != "VALUE"):
        out = a
    elif want == "VALUE":
        out = matmul(a, RGB_TO_Y) if have == "RGBA" else vector_to_float(a)
    else:
        out = np.repeat(np.reshape(a, (-1, 1)), 3, axis=1) if a.ndim else np.full(3, a, F32)
    if out.ndim == 0 or (want == "VALUE" and out.shape[0] != n) or (want != "VALUE" and out.ndim == 1):
        out = np.broadcast_to(out, (n,) if want == "VALUE" else (n, 3))
    return out.astype(F32, copy=False)
