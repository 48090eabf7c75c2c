"""Reading one evaluated point cloud (Point Cloud objects, the points geometry nodes make: Mesh to Points,
Distribute Points...) into object-space spheres, as Cycles' Blender sync reads them
(intern/cycles/blender/pointcloud.cpp, export_pointcloud): the position and `radius` attributes (0.01 where a
cloud has none), every point on the object's first material slot, Point Info's Random the hash of the point's
number, and the attributes node programs ask for by name. Placing clouds in the world is engine/export/shapes.py.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...kernels.shading.hash import hash_uint2_to_float
from .mesh import OBJECT_ATTRIBUTE_KINDS, attribute_values

# Cycles' radius of points whose cloud has no radius attribute.
DEFAULT_RADIUS = 0.01


@dataclass(frozen=True)
class LocalPoints:
    """One point cloud in object space: points (P, 4) float32 centre and radius; attributes {name: (P, C)}."""
    points: np.ndarray
    attributes: dict

    @property
    def count(self) -> int:
        return len(self.points)


def read_points(cloud, names: tuple, object_name: str, warnings: list[str]) -> LocalPoints:
    """An evaluated PointCloud's spheres and the attributes among `names` (the material table's names: "attr:",
    "color:", "uv:" look the name up among the cloud's attributes; "std:point_random" is Point Info's Random)."""
    n = len(cloud.points)
    out = np.empty((n, 4), np.float32)
    if n:
        position = np.empty(3 * n, np.float32)
        cloud.attributes["position"].data.foreach_get("vector", position)
        out[:, :3] = position.reshape(n, 3)
        radius = cloud.attributes.get("radius")
        if radius is not None and radius.domain == "POINT" and radius.data_type == "FLOAT":
            values = np.empty(n, np.float32)
            radius.data.foreach_get("value", values)
            out[:, 3] = values
        else:
            out[:, 3] = DEFAULT_RADIUS
    return LocalPoints(out, read_point_attributes(cloud, n, names, object_name, warnings))


def read_point_attributes(data, n: int, names: tuple, object_name: str, warnings: list[str]) -> dict:
    """{name: (n, C) float32} of the attributes among names on the POINT domain of `data` (a cloud)."""
    out = {}
    for name in names:
        kind, _, key = name.partition(":")
        if kind in OBJECT_ATTRIBUTE_KINDS or kind == "geom":
            continue
        if name == "std:point_random":
            index = np.arange(n, dtype=np.uint32)
            out[name] = hash_uint2_to_float(index, np.zeros(n, np.uint32)).astype(np.float32)[:, None]
            continue
        if kind == "std":
            continue
        attr = _named(data, kind, key)
        if attr is None:
            continue
        values = attribute_values(data, attr) if attr.domain == "POINT" else None
        if values is None:
            warnings.append(f"Object '{object_name}': attribute '{attr.name}' ({attr.data_type}, {attr.domain}) "
                            f"is not supported on points, reads zero")
            continue
        out[name] = values
    return out


def _named(data, kind: str, key: str):
    """The attribute a name stands for: by its name, or the render colour attribute for "color:"."""
    if kind == "color" and not key:
        colors = getattr(data, "color_attributes", None)
        if colors is None or not 0 <= colors.render_color_index < len(colors):
            return None
        return colors[colors.render_color_index]
    return data.attributes.get(key)
