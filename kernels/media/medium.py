"""The scene's participating media, as Cycles keeps them on its volume stack: one medium per (object,
material) pair whose material has a Volume output (the inside of that object's closed surfaces of that
material), and the world's Volume output (everywhere), each with a majorant: a bound on its extinction (and
emission) that null-scattering distance sampling draws tentative collisions against (kernels.media.tracking).

A medium whose inputs are all constants is homogeneous: evaluated once, its majorant is its largest
extinction. Otherwise the majorant is estimated as Cycles estimates its octree's (bvh/octree.cpp,
kernel/bake/bake.h kernel_volume_density_evaluate): the shader evaluated at random points of cells over the
medium's bounds, the largest extinction or emission found, here with Cycles' run-time margin (x 1.5,
shade_volume.h volume_estimate_extrema). Where a point still exceeds it, tracking takes that point's own
extinction as the majorant since the previous collision, as Cycles does (tracking.py).
"""
from __future__ import annotations

import numpy as np

from ..geometry import E1, E2, NG, P0
from ..shading.volume import PhaseClosure, VolumeCoefficients, VolumeShader
from ..vec import F32

STACK_SIZE = 8            # media a path can be inside at once (Cycles sizes its stack to the scene's nesting)
MAJORANT_CELLS = 12       # cells per axis over a heterogeneous medium's bounds for the majorant estimate
MAJORANT_SAMPLES = 4      # random points per cell
MAJORANT_MARGIN = 1.5     # Cycles' margin on an estimated majorant
CAMERA_PROBE = (0.30151134, 0.30151134, 0.90453403)  # the direction the camera's media are found along


class Media:
    """The media of a scene and their majorants. Ids index the tables; -1 on a stack is an empty slot."""

    def __init__(self, shading, triangles, world_volume, extent, data, volumes=(), instances=None):
        """shading : shading.Shading (its shaders' volume closures); triangles : geometry.TriangleTable;
        world_volume : kernels.scene.Shader or None; extent : (lo, hi) of the scene, for a world medium that
        varies; data : shading.shader.ShadingData; volumes : SceneArrays.volumes (the objects' grids);
        instances : SceneArrays.instances (instanced meshes' volumes: a medium per instance)."""
        self.grids = {int(row): (grids, float(scale)) for row, grids, scale, _ in volumes}
        voxel_steps = {int(row): float(step) for row, _, _, step in volumes}
        self.shaders = {m: VolumeShader(s, data) for m, s in enumerate(shading.shaders) if s.volume}
        self.triangles = triangles
        count = len(shading.shaders)
        self.has_volume = np.zeros(count, bool)
        self.has_volume[list(self.shaders)] = True
        self.boundary = np.array([bool(s.volume_only) for s in shading.shaders], bool)
        self.material, self.object, self.lo, self.hi = [], [], [], []
        self.world = -1
        if world_volume is not None:
            self.world = self._add(-1, -1, np.asarray(extent[0], F32), np.asarray(extent[1], F32))
            self.shaders[-1] = VolumeShader(world_volume, data)
        self._keys = np.zeros(0, np.int64)
        self._ids = np.zeros(0, np.int32)
        self._count = count
        if self.shaders.keys() - {-1} and triangles is not None:
            self._index_meshes(triangles, count, instances)
        self.material = np.asarray(self.material, np.int32)
        self.object = np.asarray(self.object, np.int32)
        self.lo, self.hi = np.asarray(self.lo, F32).reshape(-1, 3), np.asarray(self.hi, F32).reshape(-1, 3)
        self.homogeneous = np.array([self.shaders[m].constant and not (self.shaders[m].reads_grids and
                                                                       int(o) in self.grids)
                                     for m, o in zip(self.material, self.object)], bool)
        rates = [float(getattr(s, "volume_step_rate", 1.0)) for s in shading.shaders]
        world_rate = float(getattr(world_volume, "volume_step_rate", 1.0))
        self.step = np.array([self._step_size(i, rates, world_rate, voxel_steps) for i in range(len(self.material))],
                             np.float64).reshape(-1)
        # Per medium (and -1, an empty slot: last) whether its shader has an emission closure (stack_emits).
        self._emits = np.append(np.array([self.shaders[int(m)].emits for m in self.material], bool), False)
        self._constant: dict[int, VolumeCoefficients] = {}
        self.cell_majorants: dict[int, tuple] = {}   # varying media: (cells^3 majorants, their lo, cell size)
        self.majorant = np.array([self._estimate_majorant(i) for i in range(len(self.material))], F32)

    def __len__(self) -> int:
        return len(self.material)

    def _add(self, material: int, obj: int, lo, hi) -> int:
        self.material.append(material)
        self.object.append(obj)
        self.lo.append(lo)
        self.hi.append(hi)
        return len(self.material) - 1

    def _index_meshes(self, triangles, count: int, instances=None) -> None:
        """A medium per (object, material) of the triangles whose material has a volume, with its bounds: the
        plain triangles' objects, and each instance of a prototype with such triangles."""
        keys, bounds = [], []
        prim = np.flatnonzero(np.take(self.has_volume, triangles.material_ids[:triangles.plain_count]))
        if len(prim):
            objects = triangles.object_rows(prim)
            objects = np.zeros(len(prim), np.int32) if objects is None else objects
            plain = objects.astype(np.int64) * count + np.take(triangles.material_ids, prim)
            unique, inverse = np.unique(plain, return_inverse=True)
            g = triangles.gather(prim)
            corners = [np.stack([g[P0 + k], g[P0 + k] + g[E1 + k], g[P0 + k] + g[E2 + k]]) for k in range(3)]
            for j, key in enumerate(unique):
                rows = np.flatnonzero(inverse == j)
                keys.append(int(key))
                bounds.append((np.array([c[:, rows].min() for c in corners], F32),
                               np.array([c[:, rows].max() for c in corners], F32)))
        if instances is not None:
            for key, lo, hi in _instanced_media(instances, self.has_volume, count):
                keys.append(key)
                bounds.append((lo, hi))
        order = np.argsort(keys, kind="stable")
        ids = [self._add(keys[i] % count, keys[i] // count, *bounds[i]) for i in order]
        self._keys, self._ids = np.asarray(keys, np.int64)[order], np.asarray(ids, np.int32)

    # ---------------------------------------------------------------- where
    def of_hits(self, prim: np.ndarray) -> np.ndarray:
        """(n,) the medium behind each hit triangle's surface, -1 where its material has no volume."""
        out = np.full(len(prim), -1, np.int32)
        if not len(self._keys):
            return out
        mats = self.triangles.materials(prim)
        inside = np.flatnonzero(np.take(self.has_volume, mats))
        if not len(inside):
            return out
        objects = self.triangles.object_rows(prim[inside])
        objects = np.zeros(len(inside), np.int32) if objects is None else objects
        keys = objects.astype(np.int64) * self._count + mats[inside]
        at = np.minimum(np.searchsorted(self._keys, keys), len(self._keys) - 1)
        found = self._keys[at] == keys
        out[inside[found]] = self._ids[at[found]]
        return out

    def start_stack(self, n: int, accel=None, eye=None) -> np.ndarray:
        """(STACK_SIZE, n) int32 the stack a camera path starts with: the world's medium, and the media whose
        closed surfaces hold the camera (Cycles' volume_stack_init and integrator_intersect_volume_stack: along
        a ray from the eye, a medium whose surface is met from behind before from the front holds it)."""
        stack = np.full((STACK_SIZE, n), -1, np.int32)
        slot = 0
        if self.world >= 0:
            stack[0] = self.world
            slot = 1
        for medium in self.camera_media(accel, eye):
            if slot < STACK_SIZE:
                stack[slot] = medium
                slot += 1
        return stack

    def camera_media(self, accel, eye) -> list:
        if accel is None or eye is None or not len(self._keys):
            return []
        origin = np.asarray(eye, F32).reshape(1, 3)
        direction = np.asarray(CAMERA_PROBE, F32).reshape(1, 3)
        entered, inside = set(), []
        t_min = 0.0
        for _ in range(256):
            hits = accel.intersect(origin + direction * np.float32(t_min), direction, np.full(1, np.inf, F32))
            if hits.prim[0] < 0:
                break
            prim = hits.prim[:1]
            medium = int(self.of_hits(prim)[0])
            if medium >= 0:
                g = self.triangles.gather(prim)
                behind = float(g[NG][0] * direction[0, 0] + g[NG + 1][0] * direction[0, 1] +
                               g[NG + 2][0] * direction[0, 2]) > 0
                if behind and medium not in entered and medium not in inside:
                    inside.append(medium)
                elif not behind:
                    entered.add(medium)
            t_min += float(hits.t[0]) + 1e-4 * max(1.0, abs(t_min))
        return inside

    # ---------------------------------------------------------------- what
    def coefficients(self, ids: np.ndarray, p: np.ndarray, d: np.ndarray, ray=None,
                     emission: bool = True) -> VolumeCoefficients:
        """The coefficients of media ids (n,) (-1: none, zeros) at points p (n, 3) seen along d (n, 3)."""
        n = len(ids)
        if n and ids[0] >= 0 and (ids == ids[0]).all():   # one medium at every point: no scatter into zeros
            return self._evaluate(int(ids[0]), p, d, ray, emission)
        out = VolumeCoefficients.zeros(n)
        for medium in np.unique(ids):
            if medium < 0:
                continue
            idx = np.flatnonzero(ids == medium)
            out.add(self._evaluate(int(medium), p[idx], d[idx], ray, emission), idx)
        return out

    def stack_coefficients(self, stack: np.ndarray, p: np.ndarray, d: np.ndarray, ray=None,
                           emission: bool = True) -> VolumeCoefficients:
        """The sum of the coefficients of each path's media (stack (K, n))."""
        used = [k for k in range(stack.shape[0]) if (stack[k] >= 0).any()]
        if len(used) == 1:
            return self.coefficients(stack[used[0]], p, d, ray, emission)
        out = VolumeCoefficients.zeros(stack.shape[1])
        for k in used:
            out.add(self.coefficients(stack[k], p, d, ray, emission))
        return out

    def stack_majorant(self, stack: np.ndarray) -> np.ndarray:
        """(n,) the sum of the majorants of each path's media."""
        table = np.append(self.majorant, F32(0.0))
        return np.take(table, stack).sum(axis=0).astype(F32)

    def stack_emits(self, stack: np.ndarray) -> np.ndarray:
        """(n,) some medium of each path's stack has an emission closure."""
        return np.take(self._emits, stack).any(axis=0)

    def stack_homogeneous(self, stack: np.ndarray) -> np.ndarray:
        """(n,) each path's media are all homogeneous."""
        table = np.append(self.homogeneous, True)
        return np.take(table, stack).all(axis=0)

    def _evaluate(self, medium: int, p, d, ray, emission: bool) -> VolumeCoefficients:
        material = int(self.material[medium])
        shader = self.shaders[material]
        n = len(p)
        if self.homogeneous[medium]:
            c = self._constant.get(medium)
            if c is None:
                c = self._constant[medium] = self._scaled(medium, shader.evaluate(p[:1], d[:1],
                                                                                  self._objects(medium, 1)))
            return _broadcast(c, n, emission)
        grids = self.grids.get(int(self.object[medium]), ({}, 1.0))[0]
        return self._scaled(medium, shader.evaluate(p, d, self._objects(medium, n), grids, ray=ray,
                                                    emission=emission))

    def _scaled(self, medium: int, c: VolumeCoefficients) -> VolumeCoefficients:
        """A Volume object's coefficients times its density scale (Object space: they follow its scale)."""
        scale = self.grids.get(int(self.object[medium]), (None, 1.0))[1]
        if scale == 1.0:
            return c
        scale = F32(scale)
        for phase in c.phases:
            phase.weight = phase.weight * scale
        return VolumeCoefficients(c.sigma_s * scale, c.sigma_t * scale, c.emission * scale, c.phases)

    def _objects(self, medium: int, n: int):
        obj = int(self.object[medium])
        return None if obj < 0 else np.full(n, obj, np.int32)

    def _step_size(self, medium: int, rates, world_rate: float, voxel_steps: dict) -> float:
        """The step the Biased option marches medium with (march.py), before the scene's Step Rate: inf for a
        homogeneous one; the world's Step Size; per object its voxel size (or its own Step Size) or a tenth of
        its bounds' mean side, times its material's Step Rate (Cycles' Object::compute_volume_step_size)."""
        if self.homogeneous[medium]:
            return np.inf
        obj = int(self.object[medium])
        if obj < 0:
            return world_rate
        voxel = voxel_steps.get(obj, 0.0)
        size = voxel if voxel > 0 else 0.1 * float(np.mean(self.hi[medium].astype(np.float64) -
                                                             self.lo[medium].astype(np.float64)))
        return size * rates[int(self.material[medium])]

    def _estimate_majorant(self, medium: int) -> float:
        lo, hi = self.lo[medium].astype(np.float64), self.hi[medium].astype(np.float64)
        if self.homogeneous[medium]:
            points = ((lo + hi) / 2)[None].astype(F32)
            cells = 1
        else:
            # Grids have finer features than node programs usually do: twice the cells per axis.
            cells = MAJORANT_CELLS * (2 if int(self.object[medium]) in self.grids else 1)
            rng = np.random.default_rng(0x15B4F88D + medium)
            size = (hi - lo) / cells
            pad = 0.2 * size    # Cycles pads each cell by 0.2 of its size (octree.cpp fill_shader_input)
            index = np.stack(np.meshgrid(*(np.arange(cells),) * 3, indexing="ij"), -1).reshape(-1, 1, 3)
            jitter = rng.random((len(index), MAJORANT_SAMPLES, 3))
            points = (lo - pad + index * size + jitter * (size + 2 * pad)).reshape(-1, 3).astype(F32)
        d = np.zeros_like(points)
        d[:, 2] = -1.0
        c = self._evaluate(medium, points, d, None, True)
        per_point = np.maximum(c.sigma_t.max(axis=0), c.emission.max(axis=0))
        peak = float(per_point.max(initial=0.0))
        if cells == 1:
            return peak
        # Per cell, the largest value of it and its neighbours (a point between samples of two cells), with the
        # margin: the majorant of a segment is the largest over the cells it crosses (segment_majorant).
        grid = per_point.reshape((cells,) * 3 + (MAJORANT_SAMPLES,)).max(axis=3).astype(np.float64)
        padded = np.pad(grid, 1, mode="edge")
        dilated = np.max([padded[a:a + cells, b:b + cells, c_:c_ + cells] for a in range(3) for b in range(3)
                          for c_ in range(3)], axis=0)
        if int(self.object[medium]) < 0:   # the world's fog goes on past the scene's bounds: its own majorant
            return max(peak * MAJORANT_MARGIN, 1e-6) if peak > 0 else 0.0
        self.cell_majorants[medium] = (np.maximum(dilated * MAJORANT_MARGIN, 1e-6).astype(F32),
                                       lo.astype(F32), ((hi - lo) / cells).astype(F32))
        return max(peak * MAJORANT_MARGIN, 1e-6) if peak > 0 else 0.0

    def segment_majorant(self, stack: np.ndarray, origins: np.ndarray, dirs: np.ndarray,
                         t_end: np.ndarray) -> np.ndarray:
        """(n,) the majorant of each segment [0, t_end) through its stack's media: per varying medium, the largest
        of its cells (cell_majorants) that points along the segment (a cell apart, within the medium's
        bounds) fall in; the medium's own majorant for a segment without end (the world's fog) or past
        SEGMENT_SAMPLES points."""
        n = stack.shape[1]
        out = np.zeros(n, F32)
        for k in range(stack.shape[0]):
            ids = stack[k]
            for medium in np.unique(ids[ids >= 0]):
                rows = np.flatnonzero(ids == medium)
                value = np.full(len(rows), self.majorant[medium], F32)
                cells = self.cell_majorants.get(int(medium))
                if cells is not None:
                    value = _along(cells, self.lo[medium], self.hi[medium], origins[rows], dirs[rows], t_end[rows],
                                   value)
                out[rows] += value
        return out


def _instanced_media(instances, has_volume, count):
    """(key, lo, hi) per instance and material with a volume in its prototype: key = object row * count +
    material, the world box of the prototype's triangles of that material under the instance's transform."""
    out = []
    for p, proto in enumerate(instances.prototypes):
        mats = np.unique(proto.material_ids[np.take(has_volume, proto.material_ids)])
        if not len(mats):
            continue
        boxes = {}
        for m in mats:
            corners = proto.positions[proto.material_ids == m].reshape(-1, 3).astype(np.float64)
            lo, hi = corners.min(axis=0), corners.max(axis=0)
            boxes[int(m)] = np.array([[(hi if (c >> a) & 1 else lo)[a] for a in range(3)] for c in range(8)])
        for k in np.flatnonzero(instances.prototype == p):
            matrix = np.asarray(instances.world_from_object[k], np.float64)
            row = int(instances.object_ids[k]) if instances.object_ids is not None else 0
            for m, box in boxes.items():
                world = box @ matrix[:3, :3].T + matrix[:3, 3]
                out.append((row * count + m, world.min(axis=0).astype(F32), world.max(axis=0).astype(F32)))
    return out


SEGMENT_SAMPLES = 64   # points a segment's majorant looks at, at most (a cell apart)


def _along(cells, lo, hi, origins, dirs, t_end, fallback) -> np.ndarray:
    """The largest cell majorant over points a cell apart (the cells' smallest side) along the segments' parts
    inside [lo, hi]; fallback for segments too long (more than SEGMENT_SAMPLES points) or without end. Every
    point of a segment is then within half a cell of a sample, so in its cell or a neighbour on each axis, whose
    value the sample's dilated majorant holds."""
    grid, base, size = cells
    g = np.asarray(grid.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(dirs != 0, 1.0 / dirs, np.inf)
        t0 = np.nanmax(np.minimum((lo - origins) * inv, (hi - origins) * inv), axis=1)
        t1 = np.nanmin(np.maximum((lo - origins) * inv, (hi - origins) * inv), axis=1)
    t0 = np.maximum(t0, 0.0)
    t1 = np.minimum(t1, t_end)
    step = float(size.min())
    count = np.ceil(np.maximum(t1 - t0, 0.0) / step).astype(np.int64) + 1
    usable = np.isfinite(t1) & (count <= SEGMENT_SAMPLES)
    out = fallback.copy()
    rows = np.flatnonzero(usable)
    if not len(rows):
        return out
    k = int(count[rows].max())
    t = t0[rows, None] + np.minimum(np.arange(k, dtype=np.float32)[None], count[rows, None] - 1) * np.float32(step)
    t = np.minimum(t, t1[rows, None]).astype(np.float32)
    # Cell coordinates along each ray: a + b t per axis, flattened into the grid's index (float32 and int32
    # passes: the grid has a few thousand cells).
    a = ((origins[rows] - base) / size).astype(np.float32)
    b = (dirs[rows] / size).astype(np.float32)
    flat = None
    for axis in range(3):
        coordinate = b[:, axis, None] * t
        coordinate += a[:, axis, None]
        np.floor(coordinate, out=coordinate)
        np.clip(coordinate, 0, g[axis] - 1, out=coordinate)
        index = coordinate.astype(np.int32)
        flat = index if flat is None else flat * np.int32(g[axis]) + index
    values = np.take(grid.reshape(-1), flat)
    empty = t1[rows] <= t0[rows]
    out[rows] = np.where(empty, np.float32(0.0), values.max(axis=1))
    return out


def _broadcast(c: VolumeCoefficients, n: int, emission: bool) -> VolumeCoefficients:
    phases = [PhaseClosure(p.phase, np.repeat(p.weight, n, axis=1),
                           {k: np.repeat(v, n) for k, v in p.params.items()}) for p in c.phases]
    return VolumeCoefficients(np.repeat(c.sigma_s, n, axis=1), np.repeat(c.sigma_t, n, axis=1),
                              np.repeat(c.emission, n, axis=1) if emission else np.zeros((3, n), F32), phases)
