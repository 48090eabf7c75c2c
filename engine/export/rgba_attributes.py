"""The Attribute node's Object, Instancer and View Layer types: a custom property or an RNA path read as an
RGBA value, where Blender looks for it.

Blender's rules (blenkernel/intern/object_dupli.cc: find_property_rgba, BKE_object_dupli_find_rgba_attribute,
BKE_view_layer_find_rgba_attribute), which Cycles' sync calls (intern/cycles/blender/object.cpp
lookup_instance_property for Object and Instancer, shader.cpp resolve_view_layer_attributes for View Layer):

- Geometry Nodes instances: the attribute of that name on the instance domain of the instances that placed
  them (object_dupli.cc find_geonode_attribute_rgba), read through Object.evaluated_geometry() (InstanceAttributes).
- On one owner, a custom property of that name first; only when there is none, the name as an RNA path. A float,
  int or boolean reads (v, v, v, 1); a float or int array of at most 4 items fills (0, 0, 0, 1) from the front;
  anything else (strings, groups, pointers, longer arrays) is not found there.
- Object: the object, then its data (the mesh). Instancer: for an instance, its particle system's settings,
  its geometry-nodes instance attribute, then the instancer object, then the object and its data. View Layer: the
  view layer, the scene, the world.
- Found nowhere: (0, 0, 0, 0).
"""
from __future__ import annotations

import re

import numpy as np

from .mesh import attribute_values

NOT_FOUND = (0.0, 0.0, 0.0, 0.0)
# RNA_path_resolve drops a trailing array index: the path names the whole array property.
_INDEX = re.compile(r"\[\s*\d+\s*\]$")


def property_rgba(owner, name: str) -> tuple | None:
    """The RGBA value of a custom property or RNA path on owner (an ID or a struct such as a view layer);
    None when it is not there or does not convert."""
    if owner is None or not name:
        return None
    try:
        custom = owner[name]
    except (KeyError, TypeError, AttributeError):
        custom = _MISSING
    if custom is not _MISSING:
        return _rgba(custom)
    path = _INDEX.sub("", name) if _INDEX.search(name) else name
    try:
        value = owner.path_resolve(path)
    except (ValueError, TypeError, AttributeError):
        return None
    return _rgba(value)


_MISSING = object()


def _rgba(value) -> tuple | None:
    """A property value as Blender converts it (find_property_rgba), or None."""
    if isinstance(value, bool):
        v = 1.0 if value else 0.0
        return (v, v, v, 1.0)
    if isinstance(value, (int, float)):
        v = float(value)
        return (v, v, v, 1.0)
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or hasattr(value, "keys"):
        return None
    try:
        items = list(value)
    except TypeError:
        return None
    if not 0 < len(items) <= 4 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in items):
        return None
    out = [0.0, 0.0, 0.0, 1.0]
    out[:len(items)] = [float(v) for v in items]
    return tuple(out)


def first_found(owners, name: str) -> tuple:
    """The value on the first owner that has it, NOT_FOUND if none does."""
    for owner in owners:
        value = property_rgba(owner, name)
        if value is not None:
            return value
    return NOT_FOUND


def object_attribute(ob, name: str) -> tuple:
    """An Object attribute: on the object, then on its data."""
    return first_found((ob, getattr(ob, "data", None)), name)


def instancer_attribute(inst, ob, name: str, instances: "InstanceAttributes | None" = None) -> tuple:
    """An Instancer attribute of a depsgraph instance (read while the instance is valid): its particle
    system's settings, its geometry-nodes instance attribute (instances: the export's InstanceAttributes), the
    instancer, then the object and its data."""
    if inst is None or not inst.is_instance:
        return first_found((ob, getattr(ob, "data", None)), name)
    system = getattr(inst, "particle_system", None)
    if system is not None:
        value = property_rgba(system.settings, name)
        if value is not None:
            return value
    if instances is not None:
        value = instances.value(inst, name)
        if value is not None:
            return value
    return first_found((inst.parent, ob, getattr(ob, "data", None)), name)


class InstanceAttributes:
    """The attributes geometry nodes put on the instance domain of an instancer's instances (Store Named
    Attribute on instances, Molecular Nodes' colours), as Blender's find_geonode_attribute_rgba reads them for an
    Attribute node of type Instancer. Python reaches a depsgraph instance's instancer (inst.parent) and, through
    Object.evaluated_geometry(), its instances with their transforms and attributes, but not which of them an
    instance is: that is found by its world matrix, the instancer's times the instance's transform (instances of
    instances, placed by two transforms, are not matched: `unmatched` counts them, and they read what the
    instancer and the object hold). One table per instancer, read once per export."""

    def __init__(self):
        self._tables: dict = {}
        self._last = (None, None)   # (instancer pointer, matrix bytes) of the instance last asked, its index
        self.unmatched = 0
        self.unreachable = 0        # instancers with geometry nodes but no Object.evaluated_geometry()

    def value(self, inst, name: str) -> tuple | None:
        table = self._table(inst.parent)
        if table is None:
            return None
        matrix = np.array(inst.matrix_world, np.float64)
        key = (inst.parent.as_pointer(), matrix.tobytes())
        if key != self._last[0]:   # each of an instance's names asks in turn: match it once
            index = table.index_of(matrix)
            self._last = (key, index)
            if index is None:
                self.unmatched += 1
        index = self._last[1]
        return None if index is None or name not in table.names else table.rgba(name, index)

    def _table(self, parent):
        if parent is None:
            return None
        key = parent.as_pointer()
        if key not in self._tables:
            self._tables[key] = _InstanceTable.of(parent)
            if evaluated_geometry(parent) is None and any(m.type == "NODES" for m in getattr(parent, "modifiers", ())):
                self.unreachable += 1   # geometry nodes' instances, which this Blender's Python does not reach
        return self._tables[key]


class _InstanceTable:
    """One instancer's instances: their world matrices (sorted by x of the translation for lookups) and their
    instance-domain attributes, read as RGBA when first asked."""

    def __init__(self, geometry, cloud, world: np.ndarray):
        self.geometry = geometry   # keeps the instances' point cloud (owned by the geometry set) alive
        self.cloud = cloud
        self.world = world
        self.names = {a.name for a in cloud.attributes if not a.name.startswith(".")} - _BUILTIN
        self._x_order = np.argsort(world[:, 0, 3], kind="stable")
        self._xs = world[self._x_order, 0, 3]
        self._values: dict = {}
        self._last = -1

    @classmethod
    def of(cls, parent):
        geometry = evaluated_geometry(parent)
        if geometry is None:
            return None
        try:
            geometry = geometry()
            cloud = geometry.instances_pointcloud()
        except (RuntimeError, ReferenceError, TypeError):   # an Empty instancing a collection has no geometry
            return None
        if cloud is None or not len(cloud.points) or "instance_transform" not in cloud.attributes:
            return None
        n = len(cloud.points)
        flat = np.empty(16 * n, np.float32)
        cloud.attributes["instance_transform"].data.foreach_get("value", flat)
        local = flat.reshape(n, 4, 4).transpose(0, 2, 1).astype(np.float64)   # stored by columns
        return cls(geometry, cloud, np.matmul(np.array(parent.matrix_world, np.float64)[None], local))

    def index_of(self, matrix: np.ndarray) -> int | None:
        """The instance whose world matrix is `matrix` (to float32 precision): the one after the last found
        first (Blender lists an instancer's instances in order), else a search by the translation's x."""
        tolerance = 1e-5 * (1.0 + np.abs(matrix).max())
        for guess in (self._last, self._last + 1):
            if 0 <= guess < len(self.world) and np.abs(self.world[guess] - matrix).max() <= tolerance:
                self._last = guess
                return guess
        x = matrix[0, 3]
        lo, hi = np.searchsorted(self._xs, x - tolerance), np.searchsorted(self._xs, x + tolerance, side="right")
        for candidate in self._x_order[lo:hi]:
            if np.abs(self.world[candidate] - matrix).max() <= tolerance:
                self._last = int(candidate)
                return self._last
        return None

    def rgba(self, name: str, index: int) -> tuple:
        if name not in self._values:
            self._values[name] = _attribute_rgba(self.cloud.attributes[name], len(self.world))
        return tuple(float(v) for v in self._values[name][index])


def evaluated_geometry(parent):
    """The instancer's Object.evaluated_geometry, or None where this Blender's Python has none."""
    return getattr(parent, "evaluated_geometry", None)


# Instance-domain attributes Blender keeps for itself.
_BUILTIN = {"instance_transform", "position"}


def _attribute_rgba(attribute, n: int) -> np.ndarray:
    """(n, 4) an attribute's values (mesh.attribute_values) converted to a colour as Blender's attribute conversions
    do (lookup_or_default<ColorGeometry4f>): a scalar v is (v, v, v, 1), a vector (x, y, z, 1), a 2D vector
    (x, y, 0, 1), a colour itself; other types read (0, 0, 0, 0)."""
    out = np.zeros((n, 4), np.float32)
    values = attribute_values(None, attribute)
    if values is None:
        return out
    width = values.shape[1]
    if width == 4:
        return values
    out[:, :3 if width == 1 else width] = values
    out[:, 3] = 1.0
    return out


def particle_values(inst, outputs, time: float) -> dict:
    """{Particle Info output: RGBA} for outputs (kernels.shading.input_ops.PARTICLE_OUTPUTS names) of a depsgraph
    instance, as Cycles' sync_dupli_particle stores them: the particle persistent_id[0] of the instance's
    particle system (its index; Age is the scene's time, `time`, less its birth time; Location, Velocity and
    Angular Velocity its state), read once. An instance of no particle system, or of a child particle (Cycles
    keeps none), reads Cycles' zero particle: all 0, and Random the hash of index 0. A scalar fills r, g, b."""
    from ...kernels.shading.hash import hash_uint2_to_float
    system = getattr(inst, "particle_system", None) if inst is not None and inst.is_instance else None
    index = int(inst.persistent_id[0]) if system is not None else 0
    particle = system.particles[index] if system is not None and index < len(system.particles) else None
    if particle is None:
        index = 0
    scalars = {"Index": float(index),
               "Random": float(hash_uint2_to_float(np.uint32(index), np.uint32(0))[0])}
    if particle is not None:
        scalars.update({"Age": time - float(particle.birth_time), "Lifetime": float(particle.lifetime),
                        "Size": float(particle.size)})
    out = {}
    for name in outputs:
        if name in scalars:
            out[name] = (scalars[name],) * 3 + (1.0,)
        elif particle is None:
            out[name] = (0.0, 0.0, 0.0, 1.0)
        else:
            out[name] = tuple(float(c) for c in getattr(particle, name.lower().replace(" ", "_"))) + (1.0,)
    return out


def view_layer_attribute(scene, view_layer, name: str) -> tuple:
    """A View Layer attribute: on the view layer, the scene, then the scene's world."""
    return first_found((view_layer, scene, getattr(scene, "world", None)), name)
