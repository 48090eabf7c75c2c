"""Subsurface scattering, Ambient Occlusion and Bevel against Cycles, in one process (issue 38's benchmark):
equal-time RMSE against a converged Cycles image on a backlit subsurface head (Suzanne, skin-like Principled
subsurface, Random Walk and Christensen-Burley) and on a scene whose materials use the Ambient Occlusion and
Bevel nodes (a rock darkened in its crevices by AO through a Color Ramp, a metal box with bevelled edges).

    .venv313/bin/python bench/shading.py [--quick] [--refresh]

Both engines through bpy.ops.render.render, the benchmark's Cycles settings (CPU, no clamping, box filter,
light tree on), 2 threads; the engines take turns. References are cached in bench/results/ (their noise is
measured by two half renders and taken out of the figures).
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import import_ember  # noqa: E402

import_ember()
import bpy  # noqa: E402

from bench import vs_cycles  # noqa: E402
from bench.volumes import RESULTS_DIR, _empty_scene, _light, _world, equal_time  # noqa: E402
from bench.vs_cycles import FULL, out, record_stats  # noqa: E402


def _principled(name, **inputs):
    material = bpy.data.materials.new(name)
    node = material.node_tree.nodes["Principled BSDF"]
    for key, value in inputs.items():
        node.inputs[key].default_value = value
    return material, node


def _add(ob, material, smooth=True):
    ob.data.materials.append(material)
    if smooth:
        for polygon in ob.data.polygons:
            polygon.use_smooth = True


def subsurface_scene(size, method="RANDOM_WALK"):
    """Suzanne (subdivided twice) with skin-like subsurface, backlit by an area light, a dim fill world."""
    scene = _empty_scene(size)
    _world(scene, (0.05, 0.06, 0.08))
    bpy.ops.mesh.primitive_monkey_add(size=1.6, location=(0.0, 0.0, 1.5))
    head = bpy.context.object
    modifier = head.modifiers.new("Subdivision", "SUBSURF")
    modifier.levels = modifier.render_levels = 2
    material, node = _principled("Skin", **{"Base Color": (0.8, 0.55, 0.45, 1.0), "Subsurface Weight": 1.0,
                                            "Subsurface Radius": (1.0, 0.35, 0.2), "Subsurface Scale": 0.15,
                                            "Roughness": 0.45})
    node.subsurface_method = method
    _add(head, material)
    head.rotation_euler = (0.0, 0.0, math.radians(-20))
    _light(scene, "AREA", (0.6, 2.2, 2.4), 300, rotation=(math.radians(-120), 0.0, math.radians(15)), size=0.6)
    _light(scene, "POINT", (-2.5, -2.0, 2.5), 60, size=0.3)
    return scene


def ao_bevel_scene(size):
    """A rock (a displaced icosphere) whose colour is AO through a Color Ramp, and a metal box whose edges are
    rounded by a Bevel node's normal, on a floor, under a sun and a sky-blue world."""
    scene = _empty_scene(size)
    _world(scene, (0.35, 0.45, 0.65))
    bpy.ops.mesh.primitive_plane_add(size=12.0)
    _add(bpy.context.object, _principled("Floor", **{"Base Color": (0.5, 0.5, 0.5, 1.0)})[0], smooth=False)
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=4, radius=0.9, location=(-0.9, 0.3, 0.8))
    rock = bpy.context.object
    texture = bpy.data.textures.new("Lumps", "CLOUDS")
    texture.noise_scale = 0.45
    displace = rock.modifiers.new("Displace", "DISPLACE")
    displace.texture, displace.strength = texture, 0.5
    material, node = _principled("Rock", **{"Roughness": 0.8})
    tree = material.node_tree
    ao = tree.nodes.new("ShaderNodeAmbientOcclusion")
    ao.inputs["Distance"].default_value = 0.6
    ramp = tree.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.05, 0.04, 0.03, 1.0)
    ramp.color_ramp.elements[1].color = (0.6, 0.5, 0.4, 1.0)
    tree.links.new(ao.outputs["AO"], ramp.inputs["Fac"])
    tree.links.new(ramp.outputs["Color"], node.inputs["Base Color"])
    _add(rock, material)
    bpy.ops.mesh.primitive_cube_add(size=1.2, location=(1.0, -0.3, 0.6))
    box = bpy.context.object
    material, node = _principled("Metal", **{"Base Color": (0.9, 0.75, 0.5, 1.0), "Metallic": 1.0,
                                             "Roughness": 0.3})
    bevel = material.node_tree.nodes.new("ShaderNodeBevel")
    bevel.inputs["Radius"].default_value = 0.08
    material.node_tree.links.new(bevel.outputs["Normal"], node.inputs["Normal"])
    _add(box, material, smooth=False)
    _light(scene, "SUN", (0, 0, 5), 3.0, rotation=(0.6, 0.2, 0.8))
    return scene


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small images, short budgets (a smoke test)")
    parser.add_argument("--refresh", action="store_true", help="render the references again")
    args = parser.parse_args()
    bpy.app.handlers.render_stats.append(record_stats)
    # References of at least four times the samples either engine reaches in the longest budget (Cycles reaches
    # 2,000-8,000 spp in 20 s here): below that their own noise, taken out of the figures, is as large as the
    # renders' and the ratio is noise (equal_time flags it).
    size, budgets, reference = (48, (2.0,), 256) if args.quick else (96, (5.0, 20.0), 16384)
    start, load = time.perf_counter(), os.getloadavg()[0]
    # Christensen-Burley's head renders four times as fast: its reference takes four times the samples.
    for method, label, scale in (("RANDOM_WALK", "Random Walk", 1), ("BURLEY", "Christensen-Burley", 4)):
        equal_time(subsurface_scene(size, method), f"subsurface_{method.lower()}",
                   f"backlit subsurface head ({label})", reference * scale, budgets, FULL, args.refresh)
    equal_time(ao_bevel_scene(size), "ao_bevel", "rock darkened by AO, bevelled metal box", reference, budgets,
               FULL, args.refresh)
    out(f"\nload average {load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end; "
        f"{time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    vs_cycles.RESULTS_DIR = RESULTS_DIR
    main()
