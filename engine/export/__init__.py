"""Export: the one place that reads Blender data for a render.

An evaluated depsgraph becomes a kernels.SceneArrays of plain numpy arrays, and nothing from bpy outlives
the call (as Cycles' sync: sync once, snapshot, let go). It never reads bpy.context, since a final render
runs on a job thread: everything comes from the depsgraph.

    result = export_scene(depsgraph, engine.camera_override)
    for line in result.warnings:
        engine.report({'WARNING'}, line)
    scene = result.scene.validate().scene

geometry.py exports the meshes (mesh.py reads one, instances.py decides and names instances), materials.py
the material table, world.py the world, lights.py the lights, camera.py the camera; node trees are walked
by graph.py and sockets.py and compiled to programs by nodes.py, images loaded by images.py; updates.py
classifies what a depsgraph update changed and reads those parts again (the viewport's incremental updates).
"""
from __future__ import annotations

import dataclasses
import functools

import os
import re
import time
from dataclasses import dataclass

import bpy
import numpy as np

from ...kernels import Camera, SceneArrays
from ...kernels.cryptomatte import hash_names
from ...kernels.memory import small_pages, trim_heap
from ...kernels.scene.objects import ALL_RAYS
from .adaptive import Dicing
from .camera import export_camera, render_region, render_resolution
from .culling import Culling
from .geometry import export_geometry
from .images import shader_images, texture_limit
from .light_groups import group_table, object_groups
from .light_linking import light_links, link_table
from .lights import export_lights
from .materials import DEFAULT_ALBEDO, MaterialTable
from .deform import deform_fields, vector_deform_fields
from .motion import scene_motion, vector_fields
from .rgba_attributes import view_layer_attribute
from .updates import ExportIndex, export_index
from .world import export_layer_world

__all__ = ["DEFAULT_ALBEDO", "ExportCancelled", "ExportError", "ExportResult", "export_scene", "render_region",
           "render_resolution"]
# A Blender-relative path inside a warning: '//' up to a closing bracket, quote or the end.
_RELATIVE_PATH = re.compile(r"(?<![:/\w])//[^)'\"]*")


@dataclass
class ExportResult:
    """A scene ready for the kernel, and what the export could not honour.

    scene : not validated yet; call scene.validate().
    warnings : one line each, without duplicates, for RenderEngine.report({'WARNING'}, ...).
    seconds : export wall time.
    triangle_count : triangles exported, instanced ones counted once per instance (before validate() drops
        degenerate ones).
    instance_count : object instances that contributed triangles (plain objects count as one each).
    """
    scene: SceneArrays
    warnings: list[str]
    seconds: float
    triangle_count: int
    instance_count: int
    crypto_names: dict | None = None   # Cryptomatte kind -> the names its ids hash (the manifests)
    index: ExportIndex | None = None   # what names the rows of the scene (partial exports: updates.py)


class ExportError(Exception):
    """The scene cannot be rendered at all; the message is one user-facing line."""


class ExportCancelled(Exception):
    """should_stop() returned True during the export (Esc, or Ctrl-C on the command line)."""


def object_visibility(per_row: list | None) -> np.ndarray | None:
    """SceneArrays.object_visibility from the object rows' instance_visibility(), None when every row is seen
    by every ray and none is a holdout (the kernel then skips every visibility test)."""
    if not per_row or all(v == ALL_RAYS for v in per_row):
        return None
    return np.array(per_row, np.uint8)


@small_pages()
def export_scene(depsgraph, camera_override=None, *, width=None, height=None, should_stop=None,
                 motion=None, vector=None, instance_everything: bool = False, mesh_cache=None,
                 need_camera: bool = True, bake: bool = False, viewport: bool = False) -> ExportResult:
    """Read an evaluated depsgraph into a SceneArrays.

    camera_override : a camera object to use instead of the scene's (RenderEngine.camera_override).
    width, height : full frame in pixels; by default the scene's resolution x percentage / 100.
    should_stop : polled while objects are read (a few times a second at most); ExportCancelled when
        it returns True.
    motion : motion.MotionSamples (motion.sample_motion) for motion blur, or None.
    instance_everything : every mesh a prototype placed by its instances, even when used once (the
        viewport, whose moved objects then only change their transforms: updates.py).
    mesh_cache : geometry.MeshCache keeping meshes between the frames of an animation (Persistent Data), or None.
    need_camera : False for a bake, which sees no camera unless it bakes from it (a default one stands in).
    bake : the export is a bake's (View Layer > Filter > Surfaces off leaves the meshes in, as Cycles' bake).
    viewport : the export is the viewport's: no Simplify > Culling (its view moves), Simplify's viewport Texture Limit.
    Raises ExportError when there is no camera and one is needed.
    """
    start = time.perf_counter()
    scene = depsgraph.scene_eval
    camera_ob = camera_override or scene.camera
    if camera_ob is None and need_camera:
        raise ExportError("Scene has no camera")
    default_width, default_height = render_resolution(scene)
    warnings: list[str] = []
    if getattr(getattr(scene, "cycles", None), "use_fast_gi", False):
        own = sorted({ob.name for ob in depsgraph.objects
                      if getattr(getattr(ob.original, "cycles", None), "ao_distance", 0.0)})
        if own:
            warnings.append(f"Fast GI: the AO Distance of object{'s' if len(own) > 1 else ''} {', '.join(own[:5])}"
                            f"{' ...' if len(own) > 5 else ''} is not applied (the world's is)")
    cycles = getattr(scene, "cycles", None)
    if scene.render.use_simplify and getattr(cycles, "texture_resolution_render", 1.0) != 1.0:
        warnings.append(f"Simplify > Texture Resolution {scene.cycles.texture_resolution_render:g} is not applied: "
                        f"textures render at their own size (or the Texture Limit)")
    width = default_width if width is None else width
    height = default_height if height is None else height
    camera = Camera() if camera_ob is None else \
        export_camera(camera_ob.evaluated_get(depsgraph), scene, width, height, warnings)
    layer_attribute = functools.partial(view_layer_attribute, scene, depsgraph.view_layer_eval)
    materials = MaterialTable(warnings, layer_attribute, scene.frame_current,
                              override=depsgraph.view_layer_eval.material_override)
    materials.images.limit = texture_limit(scene, viewport)
    poll = Poller(should_stop)
    links = link_table(depsgraph)
    warnings.extend(links.warnings)
    groups = group_table(depsgraph.view_layer)
    with materials.images:   # the scene's image files are decoded on threads while the meshes are read
        materials.images.prefetch(shader_images(
            [m.node_tree for m in depsgraph.ids if isinstance(m, bpy.types.Material)]
            + [scene.world.node_tree if scene.world is not None else None]
            + [getattr(light, "node_tree", None) for light in depsgraph.ids if isinstance(light, bpy.types.Light)]))
        geometry = export_geometry(depsgraph, materials, warnings, poll,
                                   moving=frozenset(motion.objects) | frozenset(motion.meshes)
                                   if motion is not None else frozenset(),
                                   motion=motion, surfaces=bake or bool(depsgraph.view_layer_eval.use_solid),
                                   culling=Culling(scene, camera) if not viewport and not bake and camera_ob is not None
                                   else None,
                                   instance_everything=instance_everything, cache=mesh_cache, links=links,
                                   light_groups=groups,
                                   dicing=None if camera_ob is None else
                                   Dicing(depsgraph, camera_ob.evaluated_get(depsgraph), width, height))
        world = export_layer_world(depsgraph, warnings, materials.images, layer_attribute)
        lights = export_lights(depsgraph, warnings, poll, links, groups, materials.images, layer_attribute)
    crypto_names = {"object": [k[0] for k in geometry.instance_keys or []],
                    "asset": list(geometry.instance_assets or []), "material": list(materials.names)}
    arrays = SceneArrays(positions=geometry.positions, normals=geometry.normals, uvs=geometry.uvs,
                         material_ids=geometry.material_ids, materials=materials.to_kernel(),
                         textures=materials.textures, texture_srgb=materials.texture_srgb, world=world,
                         camera=camera, lights=lights, tangents=geometry.tangents,
                         attributes=geometry.attributes, objects=geometry.objects, object_ids=geometry.object_ids,
                         crypto_ids={kind: hash_names(names) for kind, names in crypto_names.items()},
                         instances=geometry.instances, volumes=geometry.volumes,
                         object_attributes=geometry.object_attributes,
                         object_visibility=object_visibility(geometry.instance_visibility),
                         light_links=light_links(geometry.instance_links),
                         curves=geometry.curves, points=geometry.points, shape_instances=geometry.shape_instances,
                         light_groups=object_groups(geometry.instance_groups, groups.world(scene.world))
                         if groups.used else None,
                         **(dict(bvh_vertices=geometry.bvh[0], bvh_indices=geometry.bvh[1]) if geometry.bvh else {}),
                         **scene_motion(motion, geometry),
                         **deform_fields(motion, geometry, warnings),
                         **vector_fields(vector, geometry, camera.world_from_camera),
                         **vector_deform_fields(vector, geometry, warnings))
    if motion is not None:
        warnings.extend(motion.warnings)
        if motion.camera is not None or motion.camera_fov is not None:
            arrays = dataclasses.replace(arrays, camera=dataclasses.replace(camera, motion=motion.camera,
                                                                            fov_motion=motion.camera_fov))
    trim_heap()   # the export's temporaries (per-mesh reads, corner gathers) go back to the system
    return ExportResult(scene=arrays, warnings=list(dict.fromkeys(absolute_paths(w) for w in warnings)),
                        seconds=time.perf_counter() - start,
                        triangle_count=len(geometry.material_ids) + (geometry.instances.triangle_total
                                                                     if geometry.instances is not None else 0),
                        instance_count=geometry.instance_count, crypto_names=crypto_names,
                        index=export_index(geometry, materials, links.signature()))


class Poller:
    """Calls should_stop at most every interval_s (Blender's test_break is cheap, but an export may
    visit millions of instances) and raises ExportCancelled when it returns True."""

    def __init__(self, should_stop=None, interval_s: float = 0.05):
        self._should_stop = should_stop
        self._interval = interval_s
        self._next = 0.0

    def __call__(self) -> None:
        if self._should_stop is None:
            return
        now = time.perf_counter()
        if now >= self._next:
            self._next = now + self._interval
            if self._should_stop():
                raise ExportCancelled()


def absolute_paths(line: str) -> str:
    """A warning with its Blender-relative paths ('//textures/a.png') made absolute."""
    return _RELATIVE_PATH.sub(lambda m: os.path.normpath(bpy.path.abspath(m.group(0))), line)
