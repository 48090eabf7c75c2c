"""Adaptive subdivision: a mesh whose last modifier is a Subdivision Surface with Adaptive Subdivision on is diced
per camera, as Cycles does, instead of read at the modifier's levels.

What Blender and Cycles 5.x do (intern/cycles/blender/util.h object_subdivision_modifier, mesh.cpp
create_subd_mesh, sync.cpp; source/blender/modifiers/intern/MOD_subsurf.cc): the option is the modifier's own
(`use_adaptive_subdivision`, no Experimental feature set since 5.0); it counts when that modifier is the last
of the stack and enabled for the render (Show in Viewport for the viewport). Blender then leaves the
subdivision to the engine: the evaluated mesh keeps its base (cage) mesh, which Python reads as
`GeometrySet.from_evaluated_object(ob).mesh_base` (everything else sees the mesh subdivided at the levels).
Cycles dices the cage with DiagSplit to a rate of Pixel Size x the scene's Dicing Rate (Render, or Viewport in
the viewport; at least 0.1 px) seen from the scene's Dicing Camera (else the render camera) at the frame's
resolution, with Offscreen Scale outside the view and at most 2^Max Subdivisions segments per patch edge; in
Object space to Edge Length x Dicing Rate in object units. Catmull-Clark evaluates the limit surface with the
modifier's Boundary Smooth and edge creases; Simple the bilinear patches. True displacement then moves the
diced vertices (engine/export/displacement.py), as Cycles' GeometryManager::displace does.

subdivision/ holds the geometry (cage, limit surface, DiagSplit, EdgeDice); this module reads Blender and makes
a LocalMesh of the triangles with what the export reads of meshes (attributes, tangents, normals for
displacement): AdaptiveMesh. Cycles interpolates attributes over the patches linearly (UV maps of
Catmull-Clark surfaces smoothly, with UV Smooth); here every attribute, UVs included, is interpolated
linearly, and Catmull-Clark surfaces with edge creases are not diced (a warning names the object; the mesh
Blender evaluates at the render levels is rendered).
"""
from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np

from .camera import export_camera
from .mesh import (OBJECT_ATTRIBUTE_KINDS, LocalMesh, attribute_values, read_values, sphere_uvs,
                   triangle_normals, triangle_tangents)
from . import mesh_topology
from .subdivision.cage import Cage, bilinear, bilinear_corners
from .subdivision.dice import Tessellation, dice
from .subdivision.dicing import DicingCamera
from .subdivision import refine
from .subdivision.refine import Unsupported
from .subdivision.split import DiagSplit
from .subdivision.surface import CatmullClarkSurface, LinearSurface

# Cycles' scene defaults (intern/cycles/blender/addon/properties.py), for a scene without Cycles' settings.
DEFAULTS = {"dicing_rate": 1.0, "preview_dicing_rate": 8.0, "max_subdivisions": 12, "offscreen_dicing_scale": 4.0}
MIN_PIXEL_RATE = 0.1


def adaptive_modifier(ob, preview: bool):
    """The modifier Cycles dices `ob` by (the last of its stack, a Subdivision Surface with Adaptive
    Subdivision, enabled for this kind of render), or None."""
    modifiers = getattr(ob, "modifiers", None)
    if not modifiers:
        return None
    last = modifiers[-1]
    if last.type != "SUBSURF" or not getattr(last, "use_adaptive_subdivision", False):
        return None
    return last if (last.show_viewport if preview else last.show_render) else None


class Dicing:
    """What the adaptive objects of one export share: the scene's settings and the dicing camera (made on
    first use: an export without adaptive objects reads nothing more)."""

    def __init__(self, depsgraph, camera_ob, width: int, height: int):
        scene = depsgraph.scene_eval
        self.preview = depsgraph.mode == "VIEWPORT"
        settings = getattr(scene, "cycles", None)

        def setting(name):
            return getattr(settings, name, DEFAULTS[name]) if settings is not None else DEFAULTS[name]
        self.rate = float(setting("preview_dicing_rate" if self.preview else "dicing_rate"))
        self.max_level = int(setting("max_subdivisions"))
        self.offscreen = float(setting("offscreen_dicing_scale"))
        chosen = getattr(settings, "dicing_camera", None) if settings is not None else None
        self._camera_ob = chosen.evaluated_get(depsgraph) if chosen is not None else camera_ob
        self._scene, self._size = scene, (width, height)
        self._camera = None

    @property
    def camera(self) -> DicingCamera:
        if self._camera is None:
            camera = export_camera(self._camera_ob, self._scene, *self._size, [])
            self._camera = DicingCamera(camera, self.offscreen)
        return self._camera

    def dices(self, ob) -> bool:
        """Whether `ob` is one Cycles would dice (tessellate() may still decline it, with a warning)."""
        return adaptive_modifier(ob, self.preview) is not None

    def tessellate(self, ob, warnings: list[str], poll=None) -> "AdaptiveMesh | None":
        """The diced mesh of an object Cycles would dice, or None (not such an object, or not dicable here:
        then a warning names it and the mesh Blender evaluates is rendered). poll() is called as faces are
        split (it raises to cancel)."""
        modifier = adaptive_modifier(ob, self.preview)
        if modifier is None:
            _check_experimental(ob, self._scene, warnings)
            return None
        geometry = bpy.types.GeometrySet.from_evaluated_object(ob)
        base = geometry.mesh_base or geometry.mesh
        if base is None or len(base.polygons) == 0:
            return None
        if base.is_editmode:
            # Its mesh then lists only the edit mesh's layers (mesh.readable_mesh), and a full copy would be the
            # subdivided mesh.
            warnings.append(f"Object '{ob.name}' is in Edit Mode: adaptive subdivision is diced in Object Mode, "
                            f"here the mesh Blender evaluates is rendered")
            return None
        cage = read_cage(base)
        simple = modifier.subdivision_type == "SIMPLE"
        if not simple and modifier.use_creases and _has_creases(base):
            warnings.append(f"Object '{ob.name}': adaptive subdivision of edge or vertex creases is not supported, "
                            f"the mesh Blender evaluates at the render levels is rendered")
            return None
        try:
            surface = LinearSurface(cage, _vertex_normals(base)) if simple else \
                CatmullClarkSurface(cage, modifier.boundary_smooth == "PRESERVE_CORNERS")
        except Unsupported as err:
            warnings.append(f"Object '{ob.name}': adaptive subdivision: {err}, the mesh Blender evaluates at the "
                            f"render levels is rendered")
            return None
        if modifier.adaptive_space == "OBJECT":
            rate, camera = float(modifier.adaptive_object_edge_length) * self.rate, None
        else:
            rate, camera = max(MIN_PIXEL_RATE, float(modifier.adaptive_pixel_size) * self.rate), self.camera
        split = DiagSplit(cage, surface, rate, self.max_level, camera, np.array(ob.matrix_world)).run(poll)
        uv_smooth = "NONE" if simple else modifier.uv_smooth
        return AdaptiveMesh(base, geometry, cage, dice(split, surface), simple, uv_smooth,
                            modifier.boundary_smooth == "PRESERVE_CORNERS", ob.name, warnings)


def _check_experimental(ob, scene, warnings: list[str]) -> None:
    """Blender 4.x's adaptive subdivision (the object's Cycles setting under the Experimental feature set, a
    last Subdivision Surface modifier) is not diced: say so."""
    modifiers = getattr(ob, "modifiers", None)
    if not modifiers or modifiers[-1].type != "SUBSURF" or hasattr(modifiers[-1], "use_adaptive_subdivision"):
        return
    if getattr(getattr(ob, "cycles", None), "use_adaptive_subdivision", False) and \
            getattr(getattr(scene, "cycles", None), "feature_set", "") == "EXPERIMENTAL":
        warnings.append(f"Object '{ob.name}': adaptive subdivision is diced from Blender 5.0 on (the modifier's "
                        f"option); here the mesh Blender evaluates is rendered")


def read_cage(mesh) -> Cage:
    """The cage of a base mesh (object space)."""
    v, f, c = len(mesh.vertices), len(mesh.polygons), len(mesh.loops)
    positions = read_values(mesh.attributes["position"].data, "vector", 3 * v, np.float32)
    sizes = read_values(mesh.polygons, "loop_total", f, np.int32)
    corner_verts = read_values(mesh.attributes[".corner_vert"].data, "value", c, np.int32)
    return Cage.from_faces(positions.astype(np.float64), sizes, corner_verts)


def _vertex_normals(mesh) -> np.ndarray:
    return read_values(mesh.vertex_normals, "vector", 3 * len(mesh.vertices), np.float32).reshape(-1, 3)


def _has_creases(mesh) -> bool:
    for name in ("crease_edge", "crease_vert"):
        attr = mesh.attributes.get(name)
        if attr is not None and len(attr.data):
            values = read_values(attr.data, "value", len(attr.data), np.float32)
            if values.any():
                return True
    return False


def uv_surface(cage: Cage, uvs: np.ndarray, uv_smooth: str, keep_corners: bool) -> CatmullClarkSurface | None:
    """The Catmull-Clark surface of a UV map (uvs (C, 2) per face corner) with the modifier's UV Smooth, or None
    for UV Smooth None (linear). Cycles refines a UV map as OpenSubdiv's face-varying data (subd/osd.cpp): a
    mesh of its own, one vertex per distinct value of each vertex (merge_smooth_fvar), its seams boundaries,
    with the interpolation blender/util.h maps UV Smooth to; its kept corners here (OpenSubdiv's fvarLevel.cpp):
    Keep Boundaries (FVAR_LINEAR_BOUNDARIES, the default) every boundary value, so seams and boundaries stay
    straight; Keep Corners (CORNERS_ONLY) the values of one face; Keep Corners, Junctions (CORNERS_PLUS1) also
    the values of a vertex with three values or more; Keep Corners, Junctions, Concave (CORNERS_PLUS2) also
    the ends of seams inside the mesh and both values of a vertex with two when one is a corner; All
    (LINEAR_NONE) only the corners Boundary Smooth keeps.
    Raises refine.Unsupported where the map's mesh is not one these rules cover."""
    if uv_smooth == "NONE":
        return None
    values = np.asarray(uvs, np.float32) + np.float32(0.0)          # -0 is 0, as Cycles' == has it
    keys = np.concatenate([cage.corner_verts[:, None], values.view(np.int32).astype(np.int64)], axis=1)
    unique, ids = np.unique(keys, axis=0, return_inverse=True)
    vertex = unique[:, 0]
    points = np.zeros((len(unique), 3))
    points[:, :2] = unique[:, 1:].astype(np.int32).view(np.float32)
    mesh = Cage(points, cage.face_starts, cage.face_sizes, ids.reshape(-1).astype(np.int64))
    faces, boundary = refine.cage_valence(mesh)
    edge = boundary > 0
    corner = edge & (faces == 1)
    if uv_smooth == "PRESERVE_BOUNDARIES":
        kept = edge
    elif uv_smooth == "SMOOTH_ALL":
        kept = corner & keep_corners
    else:
        kept = corner
        if uv_smooth != "PRESERVE_CORNERS":
            kept = kept | (edge & (np.bincount(vertex, minlength=len(cage.positions))[vertex] >= 3))
        if uv_smooth == "PRESERVE_CORNERS_JUNCTIONS_AND_CONCAVE":
            values = np.bincount(vertex, minlength=len(cage.positions))
            inner = refine.cage_valence(cage)[1] == 0
            with_corner = np.bincount(vertex[corner], minlength=len(cage.positions)) > 0
            kept = kept | (edge & inner[vertex] & (values[vertex] == 1)) | (edge & (values[vertex] == 2)
                                                                             & with_corner[vertex])
    return CatmullClarkSurface(mesh, kept=kept)


def _face_values(mesh, name: str, dtype) -> np.ndarray | None:
    attr = mesh.attributes.get(name)
    if attr is None:
        return None
    return read_values(attr.data, "value", len(mesh.polygons), dtype)


@dataclass
class AdaptiveMesh:
    """A diced mesh: `local` its triangles (object space, before displacement), and what the export reads of
    meshes, as engine/export/mesh.py and displacement.BlenderMesh read an evaluated Blender mesh."""
    base: object            # the base bpy Mesh (valid while `geometry` is held)
    geometry: object        # the GeometrySet holding it
    cage: Cage
    tessellation: Tessellation
    simple: bool
    uv_smooth: str          # the modifier's UV Smooth ("NONE" for Simple subdivision)
    keep_corners: bool      # Boundary Smooth "Keep Corners"
    name: str
    warnings: list

    def __post_init__(self):
        tess, cage = self.tessellation, self.cage
        self.patches = cage.patches()
        self._uv_surfaces = {}
        t = len(tess.triangles)
        self.triangle_face = self.patches.face[tess.triangle_patch]
        vertices = tess.positions.astype(np.float32)
        corners = tess.triangles.reshape(-1).astype(np.int32)
        smooth = self._smooth_faces()[self.triangle_face]
        uv_layer = next((uv for uv in self.base.uv_layers if uv.active_render), None)
        uvs = self._uv_values(uv_layer).astype(np.float32) if uv_layer is not None else \
            np.broadcast_to(np.zeros((1, 2), np.float32), (3 * t, 2))
        slots = _face_values(self.base, "material_index", np.int32)
        slots = slots[self.triangle_face] if slots is not None else np.zeros(t, np.int32)
        # Cycles shades smooth faces by the vertex normals of the dicing, flat ones by their triangles.
        if not smooth.any():
            rows, index, self.vertex_rows = triangle_normals(vertices, corners), np.repeat(np.arange(t), 3), None
        else:
            flat = np.flatnonzero(~smooth)
            rows = np.concatenate([tess.normals.astype(np.float32), triangle_normals(vertices, corners)[flat]])
            index = corners.astype(np.int64).reshape(t, 3)
            index[flat] = (len(vertices) + np.arange(len(flat)))[:, None]
            self.vertex_rows = len(vertices)
        self.local = LocalMesh(vertices=vertices, corners=corners, normal_rows=rows.astype(np.float32),
                               normal_index=index.reshape(-1).astype(np.uint32), uvs=uvs, slots=slots)

    # ------------------------------------------------------------ what the export reads
    def vertex_normals(self) -> np.ndarray:
        """(V, 3) float32 the diced vertices' normals (the displacement's direction)."""
        return self.tessellation.normals.astype(np.float32)

    def flat_triangles(self, t: int) -> np.ndarray:
        return ~self._smooth_faces()[self.triangle_face]

    def tangents(self, local: LocalMesh, uv_maps: tuple, object_name: str, warnings: list[str]) -> np.ndarray:
        """(T*3, 4) tangents of the UV map uv_maps names, each triangle's UV gradient (Cycles runs MikkTSpace
        over the diced triangles)."""
        wanted = uv_maps[0]
        layer = self.base.uv_layers.get(wanted) if wanted else \
            next((uv for uv in self.base.uv_layers if uv.active_render), None)
        if layer is None and wanted:
            warnings.append(f"Object '{object_name}': no UV map '{wanted}' for its normal map or tangent, "
                            f"left unperturbed")
            return np.zeros((3 * local.triangle_count, 4), np.float32)
        warnings.append(f"Object '{object_name}': tangents of adaptive subdivision are each triangle's UV gradient "
                        f"(not MikkTSpace)")
        uvs = sphere_uvs(local.positions) if layer is None else self._uv_values(layer)
        return triangle_tangents(local.positions, local.normals, uvs)

    def attributes(self, names: tuple, object_name: str, warnings: list[str]) -> dict:
        """{name: (T*3, C) float32} per triangle corner, for the names node programs read (mesh.read_attributes'
        names), interpolated over the patches from the base mesh."""
        out = {}
        for name in names:
            kind, _, key = name.partition(":")
            if kind in OBJECT_ATTRIBUTE_KINDS:
                continue
            if kind == "geom":
                values = self._geometry_attribute(key)
                if values is not None:
                    out[name] = values.astype(np.float32)
                continue
            if kind == "uv":
                layer = self.base.uv_layers.get(key)
                if layer is not None:
                    out[name] = self._uv_values(layer).astype(np.float32)
                continue
            colors = self.base.color_attributes
            if kind == "color":
                attr = colors.get(key) if key else (colors[colors.render_color_index]
                                                    if 0 <= colors.render_color_index < len(colors) else None)
            else:
                attr = self.base.attributes.get(key)
            if attr is None:
                continue
            values = attribute_values(self.base, attr)
            if values is None or attr.domain not in ("POINT", "CORNER", "FACE"):
                warnings.append(f"Object '{object_name}': attribute '{key}' ({attr.data_type}, {attr.domain}) is "
                                f"not supported, reads zero")
                continue
            out[name] = self._domain_values(values, attr.domain).astype(np.float32)
        return out

    # ------------------------------------------------------------ interpolation
    def _smooth_faces(self) -> np.ndarray:
        """(F,) bool: faces Cycles shades smooth (create_mesh: !sharp_face, all of them for Simple subdivision
        of a mesh with corner normals)."""
        sharp = _face_values(self.base, "sharp_face", bool)
        if sharp is None or (self.simple and self.base.normals_domain == "CORNER"):
            return np.ones(self.cage.face_count, bool)
        return ~sharp

    def _uv_values(self, layer) -> np.ndarray:
        """(T*3, 2) a UV map at the triangle corners: smoothed as UV Smooth says, else linearly."""
        uvs = read_values(layer.uv, "vector", 2 * len(self.base.loops), np.float32).reshape(-1, 2)
        if layer.name not in self._uv_surfaces:
            try:
                self._uv_surfaces[layer.name] = uv_surface(self.cage, uvs, self.uv_smooth, self.keep_corners)
            except Unsupported as err:
                self.warnings.append(f"Object '{self.name}': UV map '{layer.name}' is interpolated linearly over "
                                     f"adaptive subdivision ({err} in it)")
                self._uv_surfaces[layer.name] = None
        surface = self._uv_surfaces[layer.name]
        if surface is None:
            return self._corner_values(uvs)
        tess = self.tessellation
        return surface.positions(np.repeat(tess.triangle_patch, 3), tess.corner_uv.reshape(-1, 2))[:, :2]

    def _corner_values(self, loop_values: np.ndarray) -> np.ndarray:
        """(T*3, C) per triangle corner: a face-corner attribute at the corners' patch (u, v)."""
        tess = self.tessellation
        corners = bilinear_corners(self.cage, self.patches, loop_values)
        patch = np.repeat(tess.triangle_patch, 3)
        return bilinear(corners[patch], tess.corner_uv.reshape(-1, 2))

    def _vertex_values(self, loop_values: np.ndarray) -> np.ndarray:
        """(T*3, C) per triangle corner: a vertex attribute (given per face corner) at each diced vertex's
        (patch, u, v), as Cycles interpolates vertex attributes when it sets the vertex."""
        tess = self.tessellation
        corners = bilinear_corners(self.cage, self.patches, loop_values)
        used = tess.vertex_patch >= 0
        per_vertex = np.zeros((len(tess.vertex_patch), loop_values.shape[1]))
        per_vertex[used] = bilinear(corners[tess.vertex_patch[used]], tess.vertex_uv[used])
        return per_vertex[tess.triangles.reshape(-1)]

    def _domain_values(self, values: np.ndarray, domain: str) -> np.ndarray:
        if domain == "FACE":
            return np.repeat(values[self.triangle_face], 3, axis=0)
        if domain == "POINT":
            return self._vertex_values(values[self.cage.corner_verts])
        return self._corner_values(values)

    def _geometry_attribute(self, key: str) -> np.ndarray | None:
        local = self.local
        if key == "undisplaced_position":
            return np.concatenate([local.positions, np.ones((len(local.corners), 1), np.float32)], axis=1)
        if key == "undisplaced_normal":
            if bpy.app.version >= (5, 2, 0):
                return local.normals
            return self.tessellation.normals[local.corners]
        edges = read_values(self.base.edges, "vertices", 2 * len(self.base.edges), np.int32)
        if key == "pointiness":
            per_vertex = mesh_topology.pointiness(self.cage.positions.astype(np.float32), _vertex_normals(self.base),
                                                  edges)
            return self._vertex_values(per_vertex[self.cage.corner_verts][:, None])
        if key == "random_per_island":
            first = self.cage.corner_verts[self.cage.face_starts]
            per_face = mesh_topology.random_per_island(len(self.cage.positions), edges, first)
            return np.repeat(per_face[self.triangle_face], 3)[:, None]
        return None
