"""Procedural triangle meshes as plain arrays, for tests, benchmarks and examples.

Each builder returns (positions (T, 3, 3) float32, normals (T, 3, 3) float32) in world space,
triangles wound counter-clockwise seen from the side the normals point to.
"""
from __future__ import annotations

import numpy as np


def uv_sphere(segments: int = 24, radius: float = 1.0, center=(0.0, 0.0, 0.0), smooth: bool = True,
              inward: bool = False):
    """A closed UV sphere. Normals point out (or in), smooth or flat."""
    theta = np.linspace(0.0, np.pi, segments + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, 2 * segments + 1)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    v = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
    a, b, c, d = v[:-1, :-1], v[1:, :-1], v[1:, 1:], v[:-1, 1:]
    tris = np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3),
                           np.stack([a, c, d], -2).reshape(-1, 3, 3)])
    # Drop the slivers collapsed at the poles.
    area = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    tris = tris[area > 1e-9]
    if inward:
        tris = tris[:, ::-1]
    normals = tris.copy() if smooth else np.repeat(_face_normals(tris)[:, None], 3, axis=1)
    if inward and smooth:
        normals = -normals
    positions = tris * radius + np.asarray(center)
    return positions.astype(np.float32), normals.astype(np.float32)


def quad(corner, edge_u, edge_v):
    """A parallelogram corner + s*edge_u + t*edge_v, facing edge_u x edge_v."""
    c, eu, ev = (np.asarray(x, np.float64) for x in (corner, edge_u, edge_v))
    tris = np.array([[c, c + eu, c + eu + ev], [c, c + eu + ev, c + ev]])
    normals = np.repeat(_face_normals(tris)[:, None], 3, axis=1)
    return tris.astype(np.float32), normals.astype(np.float32)


def subdivided_quad(corner, edge_u, edge_v, n: int):
    """quad() split into an n x n grid (2 n^2 triangles)."""
    c, eu, ev = (np.asarray(x, np.float64) for x in (corner, edge_u, edge_v))
    s = np.arange(n) / n
    i, j = np.meshgrid(s, s, indexing="ij")
    base = c + i[..., None] * eu + j[..., None] * ev
    du, dv = eu / n, ev / n
    p00, p10, p11, p01 = base, base + du, base + du + dv, base + dv
    tris = np.concatenate([np.stack([p00, p10, p11], -2).reshape(-1, 3, 3),
                           np.stack([p00, p11, p01], -2).reshape(-1, 3, 3)])
    normals = np.repeat(_face_normals(tris)[:, None], 3, axis=1)
    return tris.astype(np.float32), normals.astype(np.float32)


def box(lo, hi, inward: bool = False, subdivisions: int = 1):
    """An axis-aligned box from corner lo to corner hi, faces pointing out (or in)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    x, y, z = hi - lo
    ex, ey, ez = np.array([x, 0, 0]), np.array([0, y, 0]), np.array([0, 0, z])
    faces = [(lo, ey, ex), (lo + ez, ex, ey),      # -z, +z
             (lo, ex, ez), (lo + ey, ez, ex),      # -y, +y
             (lo, ez, ey), (lo + ex, ey, ez)]      # -x, +x
    parts = [subdivided_quad(c, (v if inward else u), (u if inward else v), subdivisions) for c, u, v in faces]
    return (np.concatenate([p for p, _ in parts]), np.concatenate([n for _, n in parts]))


def merge(*meshes):
    """Concatenate meshes; returns positions, normals and per-triangle mesh index (T,) int32."""
    positions = np.concatenate([m[0] for m in meshes])
    normals = np.concatenate([m[1] for m in meshes])
    ids = np.concatenate([np.full(len(m[0]), i, np.int32) for i, m in enumerate(meshes)])
    return positions, normals, ids


def _face_normals(tris: np.ndarray) -> np.ndarray:
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """world_from_camera (4, 4) for a Blender camera (looks down local -Z, +Y up) at eye facing target."""
    eye, target, up = (np.asarray(x, np.float64) for x in (eye, target, up))
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, np.cross(back, right), back, eye
    return m


def cornell_box(width: int = 256, height: int = 256, light_size: float = 0.5, light_radiance: float = 15.0,
                wall_subdivisions: int = 6, sphere_segments: int = 12, light_height: float = 1.99):
    """A Cornell-like box (2 units wide, about 1k triangles): white, red and green diffuse walls, a smooth
    diffuse sphere, a downward emissive square of side light_size under the ceiling, black world.
    Returns a SceneArrays."""
    from .scene import Camera, Materials, SceneArrays, World
    s = wall_subdivisions
    walls = [
        subdivided_quad((-1, -1, 0), (0, 2, 0), (2, 0, 0), s),     # floor, facing +z
        subdivided_quad((-1, -1, 2), (2, 0, 0), (0, 2, 0), s),     # ceiling, facing -z
        subdivided_quad((-1, 1, 0), (0, 0, 2), (2, 0, 0), s),      # back wall, facing -y
        subdivided_quad((-1, -1, 0), (0, 0, 2), (0, 2, 0), s),     # left wall (red), facing +x
        subdivided_quad((1, -1, 0), (0, 2, 0), (0, 0, 2), s),      # right wall (green), facing -x
    ]
    h = light_size / 2
    light = quad((-h, -h, light_height), (0, 2 * h, 0), (2 * h, 0, 0))    # facing -z
    sphere = uv_sphere(sphere_segments, 0.45, (0.3, 0.25, 0.45))
    positions, normals, part = merge(*walls, light, sphere)
    # materials: 0 white, 1 red, 2 green, 3 light, 4 sphere
    material_of_part = np.array([0, 0, 0, 1, 2, 3, 4], np.int32)
    albedo = np.array([[0.73, 0.73, 0.73], [0.65, 0.05, 0.05], [0.12, 0.45, 0.15], [0.0, 0.0, 0.0],
                       [0.6, 0.6, 0.6]], np.float32)
    emission = np.zeros((5, 3), np.float32)
    emission[3] = light_radiance
    t = len(positions)
    camera = Camera(world_from_camera=look_at((0, -3.9, 1.0), (0, 0, 1.0)), fov_rad=np.radians(39.3),
                    width=width, height=height, clip_start=0.01, clip_end=100.0)
    return SceneArrays(positions=positions, normals=normals, uvs=np.zeros((t, 3, 2), np.float32),
                       material_ids=material_of_part[part],
                       materials=Materials.diffuse(albedo, emission=emission),
                       world=World(color=np.zeros(3, np.float32)), camera=camera)
