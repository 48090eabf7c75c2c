"""Export: the one place that reads Blender data for a render.

An evaluated depsgraph becomes a kernels.SceneArrays of plain numpy arrays, and nothing from bpy outlives
the call (as Cycles' sync: sync once, snapshot, let go). It never reads bpy.context, since a final render
runs on a job thread: everything comes from the depsgraph.

    result = export_scene(depsgraph, engine.camera_override)
    for line in result.warnings:
        engine.report({'WARNING'}, line)
    scene = result.scene.validate().scene

mesh.py reads geometry, materials.py shader nodes and images, world.py the world, camera.py the camera.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

from ...kernels import SceneArrays
from .camera import export_camera, render_region, render_resolution
from .lights import export_lights
from .materials import DEFAULT_ALBEDO, MaterialTable
from .mesh import export_geometry
from .world import export_world

__all__ = ["DEFAULT_ALBEDO", "ExportError", "ExportResult", "export_scene", "render_region",
           "render_resolution"]


@dataclass
class ExportResult:
    """A scene ready for the kernel, and what the export could not honour.

    scene : not validated yet; call scene.validate().
    warnings : one line each, without duplicates, for RenderEngine.report({'WARNING'}, ...).
    seconds : export wall time.
    triangle_count : triangles exported (before validate() drops degenerate ones).
    instance_count : object instances that contributed triangles (plain objects count as one each).
    """
    scene: SceneArrays
    warnings: list[str]
    seconds: float
    triangle_count: int
    instance_count: int


class ExportError(Exception):
    """The scene cannot be rendered at all; the message is one user-facing line."""


def export_scene(depsgraph, camera_override=None, *, width=None, height=None) -> ExportResult:
    """Read an evaluated depsgraph into a SceneArrays.

    camera_override : a camera object to use instead of the scene's (RenderEngine.camera_override).
    width, height : full frame in pixels; by default the scene's resolution x percentage / 100.
    Raises ExportError when there is no camera.
    """
    start = time.perf_counter()
    scene = depsgraph.scene_eval
    camera_ob = camera_override or scene.camera
    if camera_ob is None:
        raise ExportError("Scene has no camera")
    default_width, default_height = render_resolution(scene)
    warnings: list[str] = []
    camera = export_camera(camera_ob.evaluated_get(depsgraph), scene,
                           default_width if width is None else width,
                           default_height if height is None else height, warnings)
    materials = MaterialTable(warnings)
    geometry = export_geometry(depsgraph, materials, warnings)
    world = export_world(scene.world, warnings)
    lights = export_lights(depsgraph, warnings)
    arrays = SceneArrays(positions=geometry.positions, normals=geometry.normals, uvs=geometry.uvs,
                         material_ids=geometry.material_ids, materials=materials.to_kernel(),
                         textures=materials.textures, texture_srgb=materials.texture_srgb, world=world,
                         camera=camera, lights=lights)
    return ExportResult(scene=arrays, warnings=list(dict.fromkeys(warnings)),
                        seconds=time.perf_counter() - start, triangle_count=len(geometry.material_ids),
                        instance_count=geometry.instance_count)
