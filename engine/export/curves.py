"""Reading curves in object space, as Cycles' Blender sync reads them (intern/cycles/blender/curves.cpp):

- Curves objects (new hair, geometry-nodes curves; export_hair_curves): positions, the `radius` attribute
  (0.005 where there is none), every curve on the object's first material slot, linear when the first curve
  is of poly type (else the scene's shape); Curves Info's Intercept (the length along the curve over its
  whole length, per key), Length and Random (the hash of the curve's number); the render UV, the first
  two-float attribute on curves; other attributes by name, per key or per curve; where Huang hair asks for
  them, the curves' normals (Curves.normals: Blender's curves_normals_point_domain_calc, as Cycles reads them).
- Hair particle systems of a mesh object (ObtainCacheParticleData, ExportCurveSegments): render steps
  (2^steps + 1 keys, more for spiral kink), the children where there are any (else the parents), each key
  where Blender's path cache has it (ParticleSystem.co_hair, world space, into the object's space), the radius
  along the strand from the particle settings' Root, Tip, Shape and Radius Scale (shaperadius), 0 at a closed
  tip; the material of the settings' slot; UVs and byte colours of the emitter where each strand grows
  (uv_on_emitter, mcol_on_emitter; colours sRGB to linear).

Placing curves in the world is engine/export/shapes.py.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import chain

import numpy as np

from ...kernels.shading.hair_nodes import CURVE_NORMAL
from ...kernels.shading.hash import hash_uint2_to_float
from ...kernels.textures import srgb_to_linear
from ..version import blender_version
from .mesh import OBJECT_ATTRIBUTE_KINDS, attribute_values

# Cycles' radius of curves without a radius attribute.
DEFAULT_RADIUS = 0.005
# The Blender whose Cycles stores vertex normals packed (2c62c712e, "Compress vertex normals with octahedral
# mapping", February 2026, after Cycles' 5.2 version bump): curves' normals are read back quantised, and the zero
# normals of particle hair as about +Z.
PACKED_NORMALS = (5, 2, 0)
# Blender's curve type of poly curves (CURVE_TYPE_POLY): Cycles renders them as linear curves.
CURVE_TYPE_POLY = 1


@dataclass(frozen=True)
class LocalCurves:
    """Curves in object space: keys (K, 4) float32 x, y, z, radius; offsets (C + 1,) int32; linear (poly type:
    Linear 3D Curves whatever the scene's shape); slots (C,) int32 material slot per curve; attributes
    {name: (K, n) per key or (C, n) per curve}; dropped: curves of fewer than two keys left out."""
    keys: np.ndarray
    offsets: np.ndarray
    linear: bool
    slots: np.ndarray
    attributes: dict
    dropped: int = 0

    @property
    def count(self) -> int:
        return len(self.offsets) - 1

    @property
    def segment_count(self) -> int:
        return len(self.keys) - self.count


def read_curves(data, names: tuple, object_name: str, warnings: list[str]) -> LocalCurves:
    """An evaluated Curves data-block in object space, with the attributes among `names`."""
    k, c = len(data.points), len(data.curves)
    offsets = np.zeros(c + 1, np.int32)
    keys = np.empty((k, 4), np.float32)
    if c:
        data.curve_offset_data.foreach_get("value", offsets)
        position = np.empty(3 * k, np.float32)
        data.attributes["position"].data.foreach_get("vector", position)
        keys[:, :3] = position.reshape(k, 3)
        radius = data.attributes.get("radius")
        if radius is not None and radius.domain == "POINT" and radius.data_type == "FLOAT":
            values = np.empty(k, np.float32)
            radius.data.foreach_get("value", values)
            keys[:, 3] = values
        else:
            keys[:, 3] = DEFAULT_RADIUS
    types = data.attributes.get("curve_type")
    linear = False
    if types is not None and c:
        first = np.empty(c, np.int8)
        types.data.foreach_get("value", first)
        linear = int(first[0]) == CURVE_TYPE_POLY
    attributes = {}
    for name in names:
        kind, _, key = name.partition(":")
        if kind in OBJECT_ATTRIBUTE_KINDS or kind in ("std", "geom"):
            continue
        attr = data.attributes.get(key) if kind != "color" or key else _render_color(data)
        if attr is None:
            continue
        values = attribute_values(data, attr) if attr.domain in ("POINT", "CURVE") else None
        if values is None:
            warnings.append(f"Object '{object_name}': attribute '{attr.name}' ({attr.data_type}, {attr.domain}) "
                            f"is not supported on curves, reads zero")
            continue
        attributes[name] = values
    if CURVE_NORMAL in names and k:
        normals = curve_normals(data, k)
        attributes[CURVE_NORMAL] = as_cycles_stores(normals) if blender_version() >= PACKED_NORMALS else normals
    uv = next((a for a in data.attributes if a.data_type == "FLOAT2" and a.domain == "CURVE"
               and not a.name.startswith(".")), None)
    if uv is not None:   # Cycles' "weak" render UV of curves: the first two-float attribute on them
        attributes["uv"] = attribute_values(data, uv)
    local = LocalCurves(keys, offsets, linear, np.zeros(c, np.int32), attributes)
    return _kept(with_standard(local, names), object_name, warnings)


def curve_normals(data, k: int) -> np.ndarray:
    """(K, 3) float32 Blender's normals of a Curves data-block's points (Curves.normals, made by
    curves_normals_point_domain_calc as Cycles' sync makes them). Blender makes that array when an iteration over
    the collection begins and frees it when the iteration ends, so foreach_get (which copies after ending it) and
    vectors kept past the loop read freed memory: each value is copied while the iteration is on it (about 4 us a
    key)."""
    return np.fromiter((x for v in data.normals for x in v.vector), np.float32, count=3 * k).reshape(k, 3)


def as_cycles_stores(normals: np.ndarray) -> np.ndarray:
    """(K, 3) float32 normals as Cycles from PACKED_NORMALS reads them back: each packed into two 16-bit
    octahedral coordinates and decoded, normalised (packed_normal in intern/cycles/util/types_normal.h). A zero
    normal comes back as about (0, 0, 1)."""
    n = np.asarray(normals, np.float32).reshape(-1, 3)
    mu, hmu = np.float32(65535.0), np.float32(32767.5)
    inv_l1 = np.float32(1.0) / (np.abs(n).sum(axis=1) + np.float32(1e-6))
    vx, vy = n[:, 0] * inv_l1, n[:, 1] * inv_l1
    wrap_x = (np.float32(1.0) - np.abs(vy)) * np.copysign(np.float32(1.0), vx)
    wrap_y = (np.float32(1.0) - np.abs(vx)) * np.copysign(np.float32(1.0), vy)
    below = n[:, 2] < 0
    vx, vy = np.where(below, wrap_x, vx), np.where(below, wrap_y, vy)
    dx = np.floor(np.clip(vx * hmu + (hmu + np.float32(0.5)), 0, mu))
    dy = np.floor(np.clip(vy * hmu + (hmu + np.float32(0.5)), 0, mu))
    nx = dx * np.float32(2.0 / 65535.0) - np.float32(1.0)
    ny = dy * np.float32(2.0 / 65535.0) - np.float32(1.0)
    nz = np.float32(1.0) - np.abs(nx) - np.abs(ny)
    t = np.maximum(-nz, np.float32(0.0))
    nx, ny = nx + np.copysign(t, -nx), ny + np.copysign(t, -ny)
    out = np.stack([nx, ny, nz], axis=1).astype(np.float32)
    return (out / np.sqrt(np.einsum("ij,ij->i", out, out))[:, None]).astype(np.float32)


def _render_color(data):
    colors = getattr(data, "color_attributes", None)
    if colors is None or not 0 <= colors.render_color_index < len(colors):
        return None
    return colors[colors.render_color_index]


def with_standard(local: LocalCurves, names: tuple, lengths: np.ndarray | None = None) -> LocalCurves:
    """The curves with the Curves Info attributes among names: "std:intercept" per key (0 to 1 along each curve
    by length), "std:length" per curve (object space), "std:curve_random" per curve (hash of its number)."""
    wanted = [n for n in ("std:intercept", "std:length", "std:curve_random") if n in names]
    if not wanted or not local.count:
        return local
    attributes = dict(local.attributes)
    if "std:intercept" in wanted or "std:length" in wanted:
        xyz = local.keys[:, :3]
        step = np.zeros(len(xyz), np.float32)
        step[1:] = np.sqrt(np.einsum("ij,ij->i", xyz[1:] - xyz[:-1], xyz[1:] - xyz[:-1]))
        step[local.offsets[:-1]] = 0.0          # no step into a curve's first key
        along = np.cumsum(step, dtype=np.float64)
        start = along[local.offsets[:-1]]
        curve_of_key = np.repeat(np.arange(local.count), np.diff(local.offsets))
        along = along - start[curve_of_key]
        length = along[local.offsets[1:] - 1]
        if "std:intercept" in wanted:
            total = length[curve_of_key]
            attributes["std:intercept"] = np.where(total > 0, along / np.where(total > 0, total, 1.0),
                                                   along).astype(np.float32)[:, None]
        if "std:length" in wanted:
            attributes["std:length"] = length.astype(np.float32)[:, None]
    if "std:curve_random" in wanted:
        index = np.arange(local.count, dtype=np.uint32)
        attributes["std:curve_random"] = hash_uint2_to_float(index, np.zeros(local.count, np.uint32)).astype(
            np.float32)[:, None]
    return LocalCurves(local.keys, local.offsets, local.linear, local.slots, attributes, local.dropped)


def _kept(local: LocalCurves, object_name: str, warnings: list[str]) -> LocalCurves:
    """The curves of two keys or more (a curve of one key has no segment to trace), with a warning for the rest."""
    sizes = np.diff(local.offsets)
    short = sizes < 2
    if not short.any():
        return local
    keep = np.flatnonzero(~short)
    key_rows = np.concatenate([np.arange(local.offsets[i], local.offsets[i + 1]) for i in keep]) if len(keep) \
        else np.zeros(0, np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes[keep])]).astype(np.int32)
    k = len(local.keys)
    attributes = {name: (v[key_rows] if len(v) == k and k != local.count else v[keep])
                  for name, v in local.attributes.items()}
    warnings.append(f"Object '{object_name}': {int(short.sum())} curves of a single point are not rendered")
    return LocalCurves(np.ascontiguousarray(local.keys[key_rows]), offsets, local.linear, local.slots[keep],
                       attributes, int(short.sum()))


# ---------------------------------------------------------------- hair particle systems
def hair_systems(ob, render: bool) -> list:
    """(modifier, particle system) of each hair system Cycles renders as curves: its modifier shown in this kind
    of render, settings of type Hair rendered as Path; none in Edit or Particle Edit mode."""
    if ob.type != "MESH" or getattr(ob, "mode", "OBJECT") in ("EDIT", "PARTICLE_EDIT"):
        return []
    out = []
    for mod in ob.modifiers:
        if mod.type != "PARTICLE_SYSTEM" or not (mod.show_render if render else mod.show_viewport):
            continue
        part = mod.particle_system.settings
        if part.type == "HAIR" and part.render_type == "PATH":
            out.append((mod, mod.particle_system))
    return out


def read_particle_hair(ob, systems: list, render: bool, slot_count: int, names: tuple, mesh,
                       object_name: str, warnings: list[str]) -> LocalCurves:
    """The strands of an evaluated mesh object's hair systems (hair_systems) in the object's space, one after
    another; mesh: its evaluated mesh (its UV maps and colours name the emitter's attributes)."""
    keys, offsets, slots = [], [0], []
    world_from_object = np.array(ob.matrix_world, np.float64)
    object_from_world = np.linalg.inv(world_from_object)
    uv_names = [layer.name for layer in mesh.uv_layers] if mesh is not None else []
    render_uv = next((i for i, layer in enumerate(mesh.uv_layers) if layer.active_render), None) \
        if mesh is not None else None
    colours = [a.name for a in mesh.color_attributes if a.data_type == "BYTE_COLOR" and a.domain == "CORNER"] \
        if mesh is not None else []
    wanted_uv, wanted_colour = _emitter_names(names, uv_names, colours)
    values: dict[str, list] = {}
    for mod, psys in systems:
        part = psys.settings
        steps = part.render_step if render else part.display_step
        count = (1 << steps) + 1 + (part.kink_extra_steps if part.kink == "SPIRAL" else 0)
        parents = len(psys.particles)
        children = len(psys.child_particles)
        if not render:
            children = int(children * part.display_percentage / 100.0)
        first = parents if part.child_type != "NONE" and children else 0
        total = parents + children if first else parents
        if total - first <= 0:
            continue
        numbers = range(first, total)
        co = psys.co_hair
        points = _floats((co(ob, particle_no=i, step=s) for i in numbers for s in range(count)),
                         3 * len(numbers) * count, np.float64).reshape(-1, count, 3)
        local = points @ object_from_world[:3, :3].T + object_from_world[:3, 3]
        step = np.zeros((len(local), count), np.float64)
        step[:, 1:] = np.linalg.norm(local[:, 1:] - local[:, :-1], axis=2)
        along = np.cumsum(step, axis=1)
        length = along[:, -1]
        time = np.where(length[:, None] > 0, along / np.where(length > 0, length, 1.0)[:, None], 0.0)
        scale = part.radius_scale * 0.5
        radius = _shape_radius(part.shape, scale * part.root_radius, scale * part.tip_radius, time)
        if part.use_close_tip:
            radius[:, -1] = 0.0
        block = np.empty((len(local), count, 4), np.float32)
        block[:, :, :3] = local
        block[:, :, 3] = radius
        keys.append(block.reshape(-1, 4))
        offsets.extend(offsets[-1] + count * np.arange(1, len(local) + 1))
        slots.append(np.full(len(local), min(max(part.material - 1, 0), max(slot_count - 1, 0)), np.int32))
        particle = psys.particles[0] if parents else None
        particles = psys.particles
        for name, index in wanted_uv.items():
            values.setdefault(name, []).append(_floats(
                (psys.uv_on_emitter(mod, particle=particles[i] if i < parents else particle, particle_no=i,
                                    uv_no=index) for i in numbers), 2 * len(numbers), np.float32).reshape(-1, 2))
        for name, index in wanted_colour.items():
            rgb = _floats((psys.mcol_on_emitter(mod, particle=particles[i] if i < parents else particle,
                                                particle_no=i, vcol_no=index) for i in numbers),
                          3 * len(numbers), np.float32).reshape(-1, 3)
            values.setdefault(name, []).append(np.concatenate([srgb_to_linear(rgb), np.ones((len(rgb), 1),
                                                                                          np.float32)], axis=1))
        if render_uv is not None and "uv" not in wanted_uv:
            values.setdefault("uv", []).append(_floats(
                (psys.uv_on_emitter(mod, particle=particles[i] if i < parents else particle, particle_no=i,
                                    uv_no=render_uv) for i in numbers), 2 * len(numbers), np.float32).reshape(-1, 2))
    if not keys:
        return LocalCurves(np.zeros((0, 4), np.float32), np.zeros(1, np.int32), False, np.zeros(0, np.int32), {})
    attributes = {name: np.concatenate(parts) for name, parts in values.items()
                  if sum(len(p) for p in parts) == len(offsets) - 1}
    keys = np.ascontiguousarray(np.concatenate(keys))
    if CURVE_NORMAL in names and blender_version() >= PACKED_NORMALS:
        # Cycles writes particle hair zero normals (ExportCurveSegments), which its packing reads back as ~+Z.
        zero = as_cycles_stores(np.zeros((1, 3), np.float32))
        attributes[CURVE_NORMAL] = np.repeat(zero, len(keys), axis=0)
    offsets = np.array(offsets, np.int32)
    # Generated coordinates: Cycles gives each strand its root's (kernels/shading/shape_ops.py).
    roots = np.ones((len(offsets) - 1, 4), np.float32)    # x, y, z and 1: the strand has a root
    roots[:, :3] = keys[offsets[:-1], :3]
    attributes["std:root"] = roots
    local = LocalCurves(keys, offsets, False, np.concatenate(slots), attributes)
    return with_standard(local, names)


def _floats(vectors, count: int, dtype) -> np.ndarray:
    """The components of a run of Blender vectors (co_hair's, uv_on_emitter's: `count` floats in all) end to
    end, read by np.fromiter: Blender's path cache answers one key per call, and building a tuple and a list
    of them besides cost as much again as the calls (1.0 s against 0.54 s for 100,000 keys)."""
    return np.fromiter(chain.from_iterable(vectors), dtype, count)


def _emitter_names(names: tuple, uv_names: list, colours: list) -> tuple[dict, dict]:
    """Which names hair reads from its emitter: {name: UV map number} ("uv" the render map, "uv:" and "attr:" a
    map by name), {name: colour number} ("color:" and "attr:" a byte corner colour by name), as Cycles' sync
    names the hair's UV and colour attributes after the mesh's."""
    uv, colour = {}, {}
    for name in names:
        kind, _, key = name.partition(":")
        if kind in ("uv", "attr") and key in uv_names:
            uv[name] = uv_names.index(key)
        elif kind in ("color", "attr") and key in colours:
            colour[name] = colours.index(key)
    return uv, colour


def _shape_radius(shape: float, root: float, tip: float, time: np.ndarray) -> np.ndarray:
    """Cycles' shaperadius: from root to tip along time in [0, 1], bent by Shape in [-1, 1]."""
    radius = 1.0 - time
    if shape < 0:
        radius = np.power(radius, 1.0 + shape)
    elif shape > 0:
        radius = np.power(radius, 1.0 / (1.0 - shape))
    return radius * (root - tip) + tip
