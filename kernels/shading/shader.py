"""Evaluating materials over a wave's hits: inputs as arrays, then each closure node's closures."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..bsdf.closures import ClosureBuilder, ClosureSet
from ..bsdf.lobes import LAMBERT
from ..camera import camera_frame, view_plane
from ..scene import (OBJ_FROM_WORLD, OBJ_SHADING_OFFSET, OBJ_WORLD_LINEAR, Camera, Closure, Materials, Param,
                     object_row)
from ..textures import Texture, finite_uv, luminance
from ..vec import F32, ZERO
from . import nodes, normals
from .bsdf_nodes import portal_weight
from .node_context import CUTOFF, DEFAULTS, BatchParam, Context
from .input_ops import reads_lobes
from .ops import OPS
from .program import HitInputs, ProgramRun


VOLUME_BOUNDARY = Closure("TRANSPARENT", (("Color", Param.of((1.0, 1.0, 1.0))),))


class SurfaceShading:
    """What the materials make of N hits.

    closures : the BSDF mixture (None when only emission was asked for).
    emission : (3, N) float32 radiance emitted toward the viewer (both sides, as in Cycles).
    holdout : (N,) float32 weight of Holdout closures (the share of the hit that cuts a hole in alpha).
    """
    __slots__ = ("closures", "emission", "holdout")

    def __init__(self, closures: ClosureSet | None, emission: np.ndarray, holdout: np.ndarray):
        self.closures, self.emission, self.holdout = closures, emission, holdout


class ShadingData:
    """What node programs read besides the hits: textures, per-corner attributes, the object table and
    the camera (kernels.scene.SceneArrays, prepared)."""

    def __init__(self, textures: list[Texture], scene=None, triangles=None):
        """triangles : the scene's kernels.geometry.TriangleTable (attributes and object rows by scene
        triangle number)."""
        self.textures = textures
        self.triangles = triangles
        # raytrace.ShaderRays, what the Ambient Occlusion and Bevel nodes trace with: the renderer gives it once
        # the scene's BVH is built; None traces nothing (AO 1, Bevel the shading normal).
        self.rays = None
        self.set_objects(scene.objects if scene is not None else None)
        # Object and Instancer attributes: name -> (K, 4) per object row (SceneArrays.object_attributes).
        self.object_attributes = dict(getattr(scene, "object_attributes", ()) or ())
        self.set_camera(scene.camera if scene is not None else Camera())

    def set_objects(self, objects: np.ndarray | None) -> None:
        """The object table (SceneArrays.objects); again when objects move (Renderer.update_instances)."""
        # Without an object table every triangle is in one object at the origin.
        self.objects = object_row(np.eye(4))[None] if objects is None else objects
        # Cycles' shadow terminator frequency multiplier per object row, 1 / (1 - shading offset / 2)
        # (scene/object.cpp), or None when no object has a Shading Offset (mixture_eval.terminator_shift).
        offset = self.objects[:, OBJ_SHADING_OFFSET] if self.objects.shape[1] > OBJ_SHADING_OFFSET else None
        self.terminator = None if offset is None or not (offset > 0).any() else \
            (F32(1.0) / (F32(1.0) - F32(0.5) * np.clip(offset, 0.0, 1.0))).astype(F32)
        # The object rows scaled unevenly, where tangent-space normal maps are combined in object space, or None.
        linear = self.objects[:, OBJ_WORLD_LINEAR:OBJ_WORLD_LINEAR + 9].reshape(-1, 3, 3).astype(np.float64)
        uneven = normals.uneven_scale(linear)
        self._uneven = uneven if uneven.any() else None

    def uneven_linear(self, prim: np.ndarray):
        """(hits, world_from_object, object_from_world) of the hits on triangles prim whose objects are scaled
        unevenly ((k,), (k, 3, 3) float64 each), or None where there are none (normals.normal_map's uneven)."""
        if self._uneven is None:
            return None
        rows = self.object_rows(prim)
        hits = np.flatnonzero(self._uneven[rows])
        if not len(hits):
            return None
        r = rows[hits]
        m = self.objects[r, OBJ_WORLD_LINEAR:OBJ_WORLD_LINEAR + 9].reshape(-1, 3, 3).astype(np.float64)
        a = self.objects[r, OBJ_FROM_WORLD:OBJ_FROM_WORLD + 12].reshape(-1, 3, 4)[:, :, :3].astype(np.float64)
        return hits, m, a

    def attribute(self, name: str, prim: np.ndarray) -> np.ndarray | None:
        """(n, 3, C) per-corner values of an attribute on triangles prim, None when no mesh has it."""
        return None if self.triangles is None else self.triangles.attribute(name, prim)

    def object_attribute(self, name: str, prim: np.ndarray) -> np.ndarray | None:
        """(n, 4) RGBA values of an object attribute at triangles prim, None when no object has it."""
        table = self.object_attributes.get(name)
        return None if table is None else np.take(table, self.object_rows(prim), axis=0)

    def object_rows(self, prim: np.ndarray) -> np.ndarray:
        """(n,) rows of objects for triangles prim."""
        rows = None if self.triangles is None else self.triangles.object_rows(prim)
        return np.zeros(len(prim), np.int32) if rows is None else rows

    def set_camera(self, camera: Camera) -> None:
        """The camera the Camera and Window coordinates are taken in."""
        eye, rotation = camera_frame(camera)
        self.camera_eye, self.camera_rotation = eye.astype(F32), rotation.astype(F32)
        self.camera_kind = camera.kind
        self.view_plane = view_plane(camera)


class Shading:
    """The scene's shaders, ready to be evaluated at hits."""

    def __init__(self, materials: Materials, textures: list[Texture], scene=None, triangles=None):
        # A material with only a Volume output has an invisible surface, the boundary of its medium: rays
        # and shadow rays go straight through it (Cycles' SD_HAS_ONLY_VOLUME), as through a white
        # Transparent BSDF (the integrator does not count them as transparent bounces).
        self.shaders = tuple(replace(s, closures=(VOLUME_BOUNDARY,)) if s.volume_only else s
                             for s in materials.shaders)
        self.textures = textures
        self.data = ShadingData(textures, scene, triangles)
        world = getattr(scene, "world", None)
        # Whether a Light Path node reads the last bounce's lobe: the integrator tracks it only then.
        self.reads_lobes = any(reads_lobes(s.program) for s in self.shaders) or (
            world is not None and world.program is not None and reads_lobes(world.program))
        # Whether a material's program traces rays (Ambient Occlusion, Bevel, Raycast): the integrator then hands its
        # surface vertices' keys to the programs; a Bevel also reads the path's smallest BSDF pdf.
        kinds = {op.kind for s in self.shaders if s.program is not None for op in s.program.ops}
        self.traces = bool(kinds & {"ShaderNodeAmbientOcclusion", "ShaderNodeBevel", "ShaderNodeRaycast"})
        self.bevels = "ShaderNodeBevel" in kinds
        # Whether a material reads the rays' footprint at indirect hits (Bump, Wireframe's Pixel Size): only then does
        # the integrator widen it after rough bounces (RenderSettings.widen_differentials), which costs an evaluation
        # of every closure per bounce.
        self.reads_footprint = bool(kinds & {"ShaderNodeBump", "ShaderNodeWireframe"})
        self.emissive = np.array([_may_emit(s.closures) for s in self.shaders], bool)
        # Emission that depends on more than the material: a texture, or layers above it (Principled).
        self.emission_varies = np.array([_emission_varies(s.closures) for s in self.shaders], bool)
        self.transparent = np.array([any(nodes.may_be_transparent(c) for c in s.closures) for s in self.shaders],
                                    bool)
        # Which materials shadow rays pass: the transparent ones, unless Transparent Shadows is off and the
        # material has no volume (Cycles' SD_HAS_TRANSPARENT_SHADOW, scene/shader.cpp); the others stop them.
        self.shadow_transparent = self.transparent & np.array(
            [s.transparent_shadow or bool(s.volume) or s.volume_only for s in self.shaders], bool)
        # Transparency sums (transparency): the transparent closures of materials shadow rays pass without a
        # portal, batched as _batches does (kind, then the material's first, second, ... closure of that
        # kind); materials with a portal one by one.
        has_portal = [any(c.kind == "PORTAL" for c in s.closures) for s in self.shaders]
        self._portal_materials = [m for m, s in enumerate(self.shaders)
                                  if has_portal[m] and self.shadow_transparent[m]]
        self._transparent_batches = _transparent_batches(
            [() if has_portal[m] or not self.shadow_transparent[m] else
             tuple(c for c in s.closures if nodes.may_be_transparent(c)) for m, s in enumerate(self.shaders)])
        self.transmissive = np.array([any(nodes.may_transmit(c) for c in s.closures) for s in self.shaders], bool)
        self.has_holdout = any(c.kind == "HOLDOUT" for s in self.shaders for c in s.closures)
        self.has_portal = any(c.kind == "PORTAL" for s in self.shaders for c in s.closures)
        self._set_normals = [(m, s.set_normal) for m, s in enumerate(self.shaders) if s.set_normal is not None]
        # Whether a Christensen-Burley closure is made: it turns diffuse after a diffuse bounce, so the integrator
        # then tracks the path's labels (PathState.lobes).
        self.burley = any(c.option("subsurface_method") == "BURLEY" for s in self.shaders for c in s.closures)
        # Whether any hit has more than one lobe to choose from (a Principled BSDF, a Mix, a delta lobe).
        self.layered = np.array([_mixes_lobes(s.closures) for s in self.shaders], bool)
        self.mixes_lobes = bool(self.layered.any())
        self.needs_uv = any(p.texture >= 0 for s in self.shaders for c in s.closures for p in c.params())
        # Plain diffuse closures (a Diffuse BSDF of roughness 0, no Mix above it, no other input) are made
        # for all hits at once from a colour table: most materials of most scenes are only that.
        self._plain = [_plain_diffuse(s.closures) for s in self.shaders]
        self._is_plain = np.array([p is not None for p in self._plain], bool)
        self._plain_color = np.array([_as_channels(np.asarray(p.value, F32), 3) if p is not None else np.zeros(3, F32)
                                      for p in self._plain], F32).T.copy()  # (3, M)
        self._rest = [tuple(c for c in s.closures if p is None or c.kind != "DIFFUSE")
                      for s, p in zip(self.shaders, self._plain)]
        self._has_rest = np.array([bool(r) for r in self._rest], bool)
        # The rest is built by kind: closures of one kind and options from all materials become one batch over
        # all their hits (one Principled stack per wave, not one per material; _batches).
        self._batches, self._alone = _batches(self._rest, [s.bump_map_correction for s in self.shaders])
        self._alone_lists = [(m, cs) for m, cs in enumerate(self._alone) if cs]
        self._emitting = _batches([tuple(c for c in s.closures if nodes.may_emit(c)) if self.emissive[m] else ()
                                   for m, s in enumerate(self.shaders)], [s.bump_map_correction for s in self.shaders])
        self._emitting = (self._emitting[0], [(m, cs) for m, cs in enumerate(self._emitting[1]) if cs])
        # Per texture: mean R, G, B and alpha over the image (alpha 1 for images without one), made when an
        # emission estimate first asks for it.
        self._texture_means: dict[int, np.ndarray] = {}

    # ---------------------------------------------------------------- per wave
    def surface(self, hit, closures: bool = True) -> SurfaceShading:
        """Evaluate every hit's material (hit: interaction.SurfaceHit)."""
        n = len(hit)
        wo = tuple(-c for c in hit.d)
        if self._set_normals and not hit.normal_set:
            self._set_normal(hit)
        builder = ClosureBuilder(n, hit.ns, wo) if closures else None
        emission = np.zeros((3, n), F32)
        holdout = np.zeros(n, F32)
        if closures and self._is_plain.any():
            self._plain_closures(hit, builder)
        hits_of = _material_hits(hit.mat, len(self.shaders))
        # Only the emission (for the light sampler): the emitting closures alone, batched as the closures are.
        batches, per_material = (self._batches, self._alone_lists) if closures else self._emitting
        for members in batches:
            segments = [(m, c, hits_of(m)) for m, c in members]
            segments = [s for s in segments if len(s[2])]
            if segments:
                self._build_batch(segments, hit, wo, builder, emission, holdout)
        for m, closure_list in per_material:
            idx = hits_of(m)
            if not len(idx):
                continue
            ctx = Context(self, hit, idx, wo, self.shaders[m].bump_map_correction, material=m)
            for closure in closure_list:
                out = nodes.build(closure, ctx, self._mix_weight(closure, ctx), builder)
                _collect(out, idx, emission, holdout)
        closure_set = builder.finish() if closures else None
        if closure_set is not None and self.data.terminator is not None:
            closure_set.terminator = np.take(self.data.terminator, self.data.object_rows(hit.prim))
        return SurfaceShading(closure_set, emission, holdout)

    def _set_normal(self, hit) -> None:
        """Cycles' SetNormal: where a material has a set normal (Shader.set_normal), it becomes the hits' shading
        normal before the material is evaluated, so its closures, its other nodes, light sampling and the passes all
        read it (sd->N after the bump shader). Evaluated by a run of its own at the hits' normal as it was."""
        hits_of = _material_hits(hit.mat, len(self.shaders))
        for m, ref in self._set_normals:
            idx = hits_of(m)
            if len(idx):
                normal = ProgramRun(self.shaders[m].program, HitInputs(self.data, hit, idx), OPS).value(ref)
                for k in range(3):
                    hit.ns[k][idx] = normal[:, k]
        hit.normal_set = True

    def aov(self, hit, name: str, channels: int) -> np.ndarray:
        """(channels, n) the hits' value of the AOV `name` (its Color input for channels 3, its Value for 1),
        0 for materials without that AOV Output (as Cycles leaves the pass)."""
        out = np.zeros((channels, len(hit)), F32)
        for m, idx in _by_material(hit.mat):
            for aov_name, colour, value in self.shaders[m].aovs:
                if aov_name == name:
                    sub = _Sub(hit, idx)
                    sub.material = m
                    out[:, idx] = np.reshape(self.param(colour if channels == 3 else value, sub, channels),
                                             (channels, -1))
        return out

    def _build_batch(self, segments, hit, wo, builder, emission, holdout) -> None:
        """One closure kind over the hits of several materials at once: inputs stitched per material. A
        batch whose hits this wave are all of one material is that material's closure, built as it is (no
        stitching: inputs read straight from its program)."""
        if len(segments) == 1:
            m, closure, idx = segments[0]
            ctx = Context(self, hit, idx, wo, self.shaders[m].bump_map_correction, material=m)
            _collect(nodes.build(closure, ctx, self._mix_weight(closure, ctx), builder), idx, emission, holdout)
            return
        idx, pieces = _side_by_side(segments)
        batch = _BatchClosure(pieces)
        ctx = Context(self, hit, idx, wo, self.shaders[segments[0][0]].bump_map_correction)
        weight = np.concatenate([self._mix_weight(c, _Sub(hit, ctx.idx[lo:hi], m)) for c, lo, hi, m in batch.pieces])
        _collect(nodes.build(batch, ctx, weight, builder), idx, emission, holdout)

    def _plain_closures(self, hit, builder) -> None:
        """Lambert closures of every hit on a plain diffuse material: the colour table, times the texture."""
        idx = np.flatnonzero(np.take(self._is_plain, hit.mat))
        if not len(idx):
            return
        mat = np.take(hit.mat, idx)
        color = np.take(self._plain_color, mat, axis=1)
        textured = [(m, p) for m, p in enumerate(self._plain) if p is not None and p.texture >= 0]
        for m, p in textured:
            sel = np.flatnonzero(mat == m)
            if len(sel):
                tex = self.textures[p.texture]
                u, v = finite_uv(np.take(hit.u, idx[sel]), np.take(hit.v, idx[sel]))
                color[:, sel] *= _as_channels(_lookup(tex, p, u, v), 3)
        builder.add(LAMBERT, idx, color)

    def transparency(self, hit) -> np.ndarray:
        """(3, N) float32: the share of light that passes straight through each hit (transparent
        shadows): the sum of its Transparent closures, Principled alpha included. A Ray Portal stops shadow
        rays, except at a hit that also has a transparent closure: there Cycles' shadow rays pass the sum
        of both (the portal's weight joins the transparency it sums, shade_shadow.h). Materials whose
        Transparent Shadows is off pass nothing (shadow_transparent).

        Materials without a portal are summed batch by batch across materials (_transparent_batches), as
        their closures are built: a shadow ray crossing many masked materials pays one pass per kind."""
        n = len(hit)
        wo = tuple(-c for c in hit.d)
        out = np.zeros((3, n), F32)
        hits_of = _material_hits(hit.mat, len(self.shaders))
        for members in self._transparent_batches:
            segments = [(m, c, hits_of(m)) for m, c in members]
            segments = [s for s in segments if len(s[2])]
            if not segments:
                continue
            idx, pieces = _side_by_side(segments)
            single = len(pieces) == 1
            closure = pieces[0][0] if single else _BatchClosure(pieces)
            ctx = Context(self, hit, idx, wo, self.shaders[segments[0][0]].bump_map_correction,
                          material=segments[0][0] if single else -1)
            weight = np.concatenate([self._mix_weight(c, _Sub(hit, ctx.idx[lo:hi], m)) for c, lo, hi, m in pieces])
            out[:, idx] += nodes.transparency(closure, ctx, weight)
        for m in self._portal_materials:
            idx = hits_of(m)
            if not len(idx):
                continue
            ctx = Context(self, hit, idx, wo, self.shaders[m].bump_map_correction, material=m)
            passed = np.zeros((3, len(idx)), F32)
            made = np.zeros(len(idx), bool)
            portals = [c for c in self.shaders[m].closures if c.kind == "PORTAL"]
            for closure in self.shaders[m].closures:
                if nodes.may_be_transparent(closure):
                    t = nodes.transparency(closure, ctx, self._mix_weight(closure, ctx))
                    passed += t
                    made |= np.abs(t.mean(axis=0)) >= CUTOFF
            for closure in portals:
                passed += np.where(made, portal_weight(closure, ctx, self._mix_weight(closure, ctx)), ZERO)
            out[:, idx] += passed
        return out

    def mean_emission(self, mat: np.ndarray) -> np.ndarray:
        """(3, n) emitted radiance of materials mat, textures averaged over the image and layers taken
        at normal incidence: an estimate of an emitter's power, for light selection."""
        out = np.zeros((3, len(mat)), F32)
        for m, idx in _by_material(mat):
            for closure in self.shaders[m].closures:
                value = nodes.mean_emission(closure, self._mean_param)
                if value is not None:
                    out[:, idx] += np.asarray(value, F32)[:, None] * self._mean_factor(closure)
        return out

    # ---------------------------------------------------------------- inputs
    def param(self, p, ctx, channels: int) -> np.ndarray:
        """A Param at the context's hits: (n,) for channels 1, (3, n) for 3. A colour feeding a float
        input becomes its luminance; a float feeding a colour input is grey, as Blender converts them.
        A BatchParam is evaluated piece by piece, over each material's hits."""
        n = len(ctx.idx)
        if isinstance(p, BatchParam):
            # Constants in one repeat; textured and linked pieces over their own hits (a link through its
            # material's program).
            values = np.stack([_as_channels(np.asarray(q.value, F32), channels) for q, _, _, _ in p.pieces], axis=1)
            out = np.repeat(values, [hi - lo for _, lo, hi, _ in p.pieces], axis=1)
            for piece, lo, hi, m in p.pieces:
                if piece.varies:
                    out[:, lo:hi] = self.param(piece, _Sub(ctx.hit, ctx.idx[lo:hi], m), channels).reshape(channels, -1)
            return out[0] if channels == 1 else out
        if p.link is not None:
            value = self.program_run(ctx.material, ctx.hit, ctx.idx).value(p.link)
            if channels == 1:
                return value if value.ndim == 1 else luminance(value)
            return np.ascontiguousarray(value.T if value.ndim == 2 else np.broadcast_to(value, (3, n)), F32)
        value = _as_channels(np.asarray(p.value, F32), channels)[:, None]
        if p.texture >= 0:
            tex = self.textures[p.texture]
            u, v = finite_uv(ctx.take(ctx.hit.u), ctx.take(ctx.hit.v))
            value = value * _as_channels(_lookup(tex, p, u, v), channels)
        else:
            value = np.broadcast_to(value, (channels, n))
        return np.ascontiguousarray(value[0] if channels == 1 else value, F32)

    def program_run(self, material: int, hit, idx: np.ndarray) -> ProgramRun:
        """The material's program over the hits idx of a wave (made once per wave and set of hits)."""
        cached = hit.programs.get(material)
        if cached is not None and (cached[0] is idx or (len(cached[0]) == len(idx) and np.array_equal(cached[0], idx))):
            return cached[1]
        run = ProgramRun(self.shaders[material].program, HitInputs(self.data, hit, idx), OPS)
        hit.programs[material] = (idx, run)
        return run

    def _mean_param(self, p: Param, channels: int) -> np.ndarray:
        """A Param's value averaged over its texture: (channels,)."""
        value = _as_channels(np.asarray(p.value, F32), channels)
        if p.texture >= 0:
            mean = self._texture_means.get(p.texture)
            if mean is None:
                mean = self._texture_means[p.texture] = self.textures[p.texture].means()
            looked = mean[3:4] if p.alpha else mean[p.channel:p.channel + 1] if p.channel >= 0 else mean[:3]
            value = value * _as_channels(looked, channels)
        return value

    def _mix_weight(self, closure: Closure, ctx) -> np.ndarray:
        """(n,) product of the Mix Shader factors above the closure."""
        weight = np.ones(len(ctx.idx), F32)
        for p, second in closure.factors:
            fac = np.clip(self.param(p, ctx, 1), 0.0, 1.0)
            weight = weight * (fac if second else F32(1.0) - fac)
        return weight

    def _mean_factor(self, closure: Closure) -> float:
        weight = 1.0
        for p, second in closure.factors:
            fac = float(np.clip(self._mean_param(p, 1)[0], 0.0, 1.0))
            weight *= fac if second else 1.0 - fac
        return weight


def _lookup(tex, p: Param, u, v) -> np.ndarray:
    """(1 or 3, n): the texture's alpha, one channel of its colour, or its colour, at u, v."""
    if p.alpha:
        return tex.lookup_alpha(u, v)[None]
    color = tex.lookup(u, v, unassociate=p.unassociate)
    return color[p.channel:p.channel + 1] if p.channel >= 0 else color


class _Sub:
    """Some hits of a context, of one material (-1: none, for inputs that are no program's), for evaluating
    inputs."""
    __slots__ = ("hit", "idx", "material")

    def __init__(self, hit, idx, material: int = -1):
        self.hit, self.idx, self.material = hit, idx, material

    def take(self, a):
        return np.take(a, self.idx)


class _BatchClosure:
    """Closures of one kind and options from several materials, seen by the node builders as one closure
    whose inputs vary from piece to piece of the batch's hits."""

    def __init__(self, pieces):
        self.pieces = pieces                     # (closure, lo, hi, material)
        first = pieces[0][0]
        self.kind, self.options, self.factors = first.kind, first.options, ()
        self._inputs: dict = {}

    def input(self, name: str):
        if name not in self._inputs:
            self._inputs[name] = self._stitch(name)
        return self._inputs[name]

    def _stitch(self, name: str):
        params = [c.input(name) for c, _, _, _ in self.pieces]
        if all(p is None for p in params):
            return None
        default = Param.of(DEFAULTS[self.kind][name]) if name in DEFAULTS[self.kind] else None
        params = [p if p is not None else default for p in params]
        # One value for all (often: the node's default), unless a piece is a program's: a link names an
        # output of its own material's program.
        own = [p for p in params if not isinstance(p, Param) or p.link is not None]
        if not own and all(p == params[0] for p in params[1:]):
            return params[0]
        return BatchParam([(p, lo, hi, m) for p, (_, lo, hi, m) in zip(params, self.pieces)])

    def option(self, name: str, default=None):
        return self.pieces[0][0].option(name, default)


def _batches(rest, bump_corrections):
    """Group the closures left to build by (kind, options, bump map correction): closures of every kind but
    hair batch across materials, their inputs (constants, textures, programs' outputs, normal maps) evaluated
    per material and the closures built once over all their hits: a wave of many textured materials
    pays one Principled stack, not one per material. A Tangent input keeps its closure with its material,
    and so does a hair closure whose inputs vary (its builder reads the Param itself). A batch holds at most
    one closure of each material (a material's second Diffuse goes into a second batch): the hits of a batch
    must be distinct, since the builder and the emission sum index by hit. Returns (batches: lists of
    (material, closure)), closures built alone per material)."""
    keyed: dict = {}
    alone = [[] for _ in rest]
    for m, closures in enumerate(rest):
        seen: dict = {}
        for c in closures:
            varies = any(not isinstance(p, Param) or p.varies for _, p in c.inputs)
            if c.input("Tangent") is None and not (varies and c.kind in _SOLO_KINDS):
                key = (c.kind, c.options, bump_corrections[m])
                seen[key] = seen.get(key, -1) + 1
                keyed.setdefault(key + (seen[key],), []).append((m, c))
            else:
                alone[m].append(c)
    return list(keyed.values()), [tuple(a) for a in alone]


def _side_by_side(segments):
    """The hits of segments [(material, closure, hit indices)] side by side: (hit indices, pieces [(closure, lo,
    hi, material)] of that array)."""
    idx = np.concatenate([s[2] for s in segments])
    bounds = np.cumsum([0] + [len(s[2]) for s in segments])
    return idx, [(c, lo, hi, m) for (m, c, _), lo, hi in zip(segments, bounds[:-1], bounds[1:])]


def _transparent_batches(closures) -> list:
    """Lists of (material, closure): the transparent closures of all materials grouped by kind, a material's
    k-th closure of a kind in the k-th list of that kind (a batch's hits must be distinct)."""
    keyed: dict = {}
    for m, cs in enumerate(closures):
        seen: dict = {}
        for c in cs:
            seen[c.kind] = seen.get(c.kind, -1) + 1
            keyed.setdefault((c.kind, seen[c.kind]), []).append((m, c))
    return list(keyed.values())


# Kinds whose builders read their inputs' Params themselves (hair_nodes: a linked Random against the curve's own).
_SOLO_KINDS = ("HAIR", "PRINCIPLED_HAIR")


def _material_hits(mat: np.ndarray, count: int):
    """hits_of(m): the indices of the hits on material m (ascending). One sort of the wave serves them
    all once a few materials have been asked for; before that, a scan per material is cheaper."""
    state = {"asked": 0, "order": None}

    def hits_of(m):
        if state["order"] is None:
            state["asked"] += 1
            if state["asked"] <= 3:
                return np.flatnonzero(mat == m)
            state["order"] = np.argsort(mat, kind="stable")
            sizes = np.bincount(mat, minlength=count)
            state["ends"] = np.cumsum(sizes)
            state["starts"] = state["ends"] - sizes
        return state["order"][state["starts"][m]:state["ends"][m]]
    return hits_of


def _collect(out, idx, emission, holdout) -> None:
    if out.emission is not None:
        emission[:, idx] += out.emission
    if out.holdout is not None:
        holdout[idx] += out.holdout


def _by_material(mat: np.ndarray):
    """(material, hit indices) for every material present, indices ascending."""
    if len(mat) == 0:
        return
    order = np.argsort(mat, kind="stable")
    sorted_mat = mat[order]
    cuts = np.flatnonzero(np.diff(sorted_mat)) + 1
    for chunk in np.split(order, cuts):
        yield int(mat[chunk[0]]), chunk


def _as_channels(value: np.ndarray, channels: int) -> np.ndarray:
    """(1 or 3, ...) values as `channels` rows: luminance for colour -> float, grey for float -> colour."""
    if len(value) == channels:
        return value
    if channels == 1:
        return luminance(np.moveaxis(value, 0, -1))[None].astype(F32)
    return np.repeat(value[:1], 3, axis=0)


def _plain_diffuse(closures):
    """The Color Param of a material's plain Diffuse BSDF (roughness 0, no Mix factor, no other input),
    or None."""
    diffuse = [c for c in closures if c.kind == "DIFFUSE"]
    if len(diffuse) != 1 or diffuse[0].factors:
        return None
    c = diffuse[0]
    rough = c.input("Roughness")
    color = c.input("Color")
    if any(name not in ("Color", "Roughness") for name, _ in c.inputs) or (
            rough is not None and (rough.varies or rough.value[0] >= 1e-5)) or (
            color is not None and color.link is not None):
        return None
    return color or Param.of(DEFAULTS["DIFFUSE"]["Color"])


def _mixes_lobes(closures) -> bool:
    bsdfs = [c for c in closures if c.kind not in ("EMISSION", "HOLDOUT")]
    return len(bsdfs) > 1 or any(c.kind != "DIFFUSE" for c in bsdfs)


def _may_emit(closures) -> bool:
    return any(nodes.may_emit(c) for c in closures)


def _emission_varies(closures) -> bool:
    return any(nodes.may_emit(c) and nodes.emission_varies(c) for c in closures)
