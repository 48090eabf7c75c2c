"""Geometry: one module per primitive type, how it is put into Embree and what a hit on it yields, and the
instances that place prototypes of any type.

    triangles.py   the triangle table (corner, edges, normals, UVs per triangle, gathered per hit) and
                   barycentric interpolation; Embree gets triangles as indexed meshes (kernels/accel.py)
    curves.py      curves: Embree's buffers (Catmull-Rom keys with the ends repeated), what a hit yields
    points.py      points: Embree's sphere points, what a hit yields
    primitives.py  curves and points numbered after the triangles, and the table that answers for all of them
    instances.py   prototypes placed by transforms (Embree's two-level BVH), their boxes, the scene's extent,
                   the emissive triangles of instances, the flattened copy of an instanced scene

A new primitive type is a module beside these: docs/architecture.md (Where new content goes) says what it
provides.
"""
from .instances import (apply_matrices, emissive_instanced, extent, flatten_instances, instance_boxes,
                        lights_of, normal_matrices, prototype_boxes, scene_extent, uniform_scales)
from .triangles import (DEFERRED_ROWS, E1, E2, N0, N1, N2, NG, P0, UV0, UV1, UV2, TriangleTable, interpolate_uv)

__all__ = ["DEFERRED_ROWS", "E1", "E2", "N0", "N1", "N2", "NG", "P0", "UV0", "UV1", "UV2", "TriangleTable",
           "apply_matrices", "emissive_instanced", "extent", "flatten_instances", "instance_boxes",
           "interpolate_uv", "lights_of", "normal_matrices", "prototype_boxes", "scene_extent", "uniform_scales"]
