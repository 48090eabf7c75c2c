"""The Attribute node's Object, Instancer and View Layer types: a custom property or an RNA path read as an
RGBA value, where Blender looks for it.

Blender's rules (blenkernel/intern/object_dupli.cc: find_property_rgba, BKE_object_dupli_find_rgba_attribute,
BKE_view_layer_find_rgba_attribute), which Cycles' sync calls (intern/cycles/blender/object.cpp
lookup_instance_property for Object and Instancer, shader.cpp resolve_view_layer_attributes for View Layer):

- On one owner, a custom property of that name first; only when there is none, the name as an RNA path. A float,
  int or boolean reads (v, v, v, 1); a float or int array of at most 4 items fills (0, 0, 0, 1) from the front;
  anything else (strings, groups, pointers, longer arrays) is not found there.
- Object: the object, then its data (the mesh). Instancer: for an instance, its particle system's settings,
  then the instancer object, then the object and its data. View Layer: the view layer, the scene, the world.
- Found nowhere: (0, 0, 0, 0).
"""
from __future__ import annotations

import numpy as np

import re

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


def instancer_attribute(inst, ob, name: str) -> tuple:
    """An Instancer attribute of a depsgraph instance (read while the instance is valid): its particle
    system's settings, the instancer, then the object and its data. Geometry Nodes instance attributes,
    which Blender checks after the particle settings, are not reachable from Python: not read."""
    owners = []
    if inst is not None and inst.is_instance:
        system = getattr(inst, "particle_system", None)
        if system is not None:
            owners.append(system.settings)
        owners.append(inst.parent)
    return first_found((*owners, ob, getattr(ob, "data", None)), name)


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
