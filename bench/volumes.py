"""Volumes against Cycles, in one process (issue 36's benchmark): equal-time RMSE against a converged Cycles
image on a smoke cloud (an OpenVDB density grid, written here with Blender's openvdb module, lit by a sun and
the sky) and on world fog crossed by two spot lights' beams; and the time to the first sample of a render of
a 256^3 VDB volume.

    .venv313/bin/python bench/volumes.py [--quick] [--refresh]

Both engines through bpy.ops.render.render at Blender's volume defaults (null scattering, Volume bounces 0),
the benchmark's Cycles settings otherwise (CPU, no clamping, box filter, light tree on), 2 threads; the
engines take turns. References are cached in bench/results/ (their noise is measured by two half renders and
taken out of the figures).
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import ROOT, import_ember, median  # noqa: E402

import_ember()
import bpy  # noqa: E402
import numpy as np  # noqa: E402

from bench import vs_cycles  # noqa: E402
from bench.vs_cycles import FULL, UNLIMITED_SAMPLES, out, record_stats, render  # noqa: E402
from ember.engine.export.volumes import openvdb_module  # noqa: E402

RESULTS_DIR = os.path.join(ROOT, "bench", "results")
CUBE_FACES = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]


def _mesh(name, verts, faces, material=None):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    ob = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(ob)
    if material is not None:
        mesh.materials.append(material)
    return ob


def _box(name, lo, hi, material=None):
    return _mesh(name, [(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])],
                 CUBE_FACES, material)


def _empty_scene(size):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    from ember import register
    try:
        register()
    except ValueError:
        pass
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    camera.location, camera.rotation_euler = (0.0, -5.0, 1.6), (math.radians(80), 0.0, 0.0)
    scene.camera = camera
    world = bpy.data.worlds.new("World")
    scene.world = world
    return scene


def _world(scene, colour, strength=1.0):
    tree = scene.world.node_tree
    background = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBackground")
    background.inputs["Color"].default_value = (*colour, 1.0)
    background.inputs["Strength"].default_value = strength
    return tree


def _light(scene, kind, location, energy, rotation=(0.0, 0.0, 0.0), size=0.1, spot=None):
    data = bpy.data.lights.new(kind, kind)
    data.energy = energy
    if kind == "SUN":
        data.angle = 0.05
    else:
        data.shadow_soft_size = size
    if spot is not None:
        data.spot_size = spot
    ob = bpy.data.objects.new(kind, data)
    scene.collection.objects.link(ob)
    ob.location, ob.rotation_euler = location, rotation


def write_cloud(path, resolution):
    """A cloud of fractal density (a sum of random sines shaped by a ball), resolution^3 voxels of 1/resolution
    scene units x 2.4, written as a VDB 'density' grid."""
    vdb = openvdb_module()
    rng = np.random.default_rng(5)
    axis = (np.arange(resolution, dtype=np.float32) - resolution / 2) / (resolution / 2)
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
    density = np.zeros_like(x)
    for octave in range(4):
        freq = 2.0 * 2 ** octave
        for _ in range(3):
            k = rng.normal(size=3).astype(np.float32)
            k *= freq / np.linalg.norm(k)
            density += np.sin(k[0] * x + k[1] * y + k[2] * z + rng.uniform(0, 6.3)) / 2 ** octave
    ball = np.clip(1.0 - (x * x + y * y + 1.4 * z * z), 0.0, None)
    density = np.clip(density * 0.35 + 1.2 * ball - 0.4, 0.0, None).astype(np.float32)
    grid = vdb.FloatGrid()
    grid.name = "density"
    grid.copyFromArray(density, ijk=(0, 0, 0))
    grid.transform = vdb.createLinearTransform(voxelSize=2.4 / resolution)
    vdb.write(str(path), grids=[grid])


def smoke_scene(size, vdb_path, density=6.0):
    scene = _empty_scene(size)
    _world(scene, (0.35, 0.45, 0.65))
    _mesh("Floor", [(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)], [(0, 1, 2, 3)])
    volume = bpy.data.volumes.new("Cloud")
    volume.filepath = str(vdb_path)
    ob = bpy.data.objects.new("Cloud", volume)
    scene.collection.objects.link(ob)
    ob.location = (-1.2, -1.2, 0.2)
    material = bpy.data.materials.new("Smoke")
    tree = material.node_tree
    tree.nodes.clear()
    node = tree.nodes.new("ShaderNodeVolumePrincipled")
    node.inputs["Density"].default_value = density
    node.inputs["Color"].default_value = (0.85, 0.85, 0.85, 1.0)
    tree.links.new(node.outputs[0], tree.nodes.new("ShaderNodeOutputMaterial").inputs["Volume"])
    volume.materials.append(material)
    _light(scene, "SUN", (0, 0, 5), 3.0, rotation=(0.6, 0.2, 0.8))
    return scene


def fog_scene(size):
    scene = _empty_scene(size)
    tree = _world(scene, (0.01, 0.012, 0.02))
    fog = tree.nodes.new("ShaderNodeVolumeScatter")
    fog.inputs["Density"].default_value = 0.06
    fog.inputs["Anisotropy"].default_value = 0.2
    tree.links.new(fog.outputs[0], next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputWorld")
                   .inputs["Volume"])
    _mesh("Floor", [(-8, -8, 0), (8, -8, 0), (8, 8, 0), (-8, 8, 0)], [(0, 1, 2, 3)])
    _box("Box", (-0.4, -0.4, 0.0), (0.4, 0.4, 0.8))
    _box("Pillar", (1.0, 0.8, 0.0), (1.3, 1.1, 2.0))
    _light(scene, "SPOT", (-1.5, -0.5, 3.2), 1200, rotation=(0.35, -0.35, 0.0), spot=0.7)
    _light(scene, "SPOT", (1.8, -1.0, 3.0), 900, rotation=(0.4, 0.45, 0.0), spot=0.5)
    return scene


def _reference(scene, name, samples, cfg, refresh):
    path = os.path.join(RESULTS_DIR, f"volumes_reference_{name}_{scene.render.resolution_x}_{samples}spp_"
                                     f"blender{bpy.app.version_string}.npz")
    if os.path.exists(path) and not refresh:
        data = np.load(path)
        return data["image"], float(data["noise_mse"]), True
    halves = [render(scene, "CYCLES", samples // 2, cfg, seed=seed, keep_image=True).image for seed in (101, 102)]
    image = (halves[0] + halves[1]) / 2
    noise_mse = float(np.mean((halves[0] - halves[1]) ** 2) / 4)   # the mean's own noise
    os.makedirs(RESULTS_DIR, exist_ok=True)
    np.savez_compressed(path, image=image, noise_mse=noise_mse)
    return image, noise_mse, False


def equal_time(scene, name, title, ref_samples, budgets, cfg, refresh):
    t0 = time.perf_counter()
    ref, noise_mse, cached = _reference(scene, name, ref_samples, cfg, refresh)
    out(f"\n== equal-time RMSE: {title}, {scene.render.resolution_x}^2 px, 2 threads; reference Cycles "
        f"{ref_samples} spp ({'cached' if cached else f'{time.perf_counter() - t0:.0f} s'}), its noise RMSE "
        f"{math.sqrt(noise_mse):.5f} taken out")
    for engine in ("CYCLES", "EMBER"):
        render(scene, engine, 1, cfg)   # warm-up
    rows = {}
    for budget in budgets:
        row = {}
        for engine in ("CYCLES", "EMBER"):
            run = render(scene, engine, UNLIMITED_SAMPLES, cfg, time_limit=budget, keep_image=True)
            mse = float(np.mean((run.image - ref) ** 2))
            row[engine] = {"rmse": math.sqrt(max(mse - noise_mse, 0.0)), "samples": run.samples_done,
                           "render_s": run.render_s, "mean": float(run.image.mean())}
        ratio = row["EMBER"]["rmse"] / row["CYCLES"]["rmse"]
        rows[budget] = (row, ratio)
        for engine in ("CYCLES", "EMBER"):
            x = row[engine]
            out(f"  {budget:4.0f} s  {engine.title():6s} RMSE {x['rmse']:.5f}, {x['samples']} spp, mean "
                f"{x['mean'] / ref.mean() - 1:+.2%} vs reference")
        out(f"  {budget:4.0f} s  ratio Ember / Cycles RMSE {ratio:.2f}")
        if max(row[e]["samples"] for e in row) * 4 > ref_samples:
            # The reference's own noise, taken out above, is then not small against the render's: the
            # difference of two noisy numbers of the same size, the ratio is not a measurement.
            out(f"  {budget:4.0f} s  NOT RELIABLE: a render took more than a quarter of the reference's samples")
    return rows


def first_sample(vdb_path, cfg, repeats):
    scene = smoke_scene(64, vdb_path)
    walls = {"CYCLES": [], "EMBER": []}
    for _ in range(repeats):
        for engine in ("CYCLES", "EMBER"):
            walls[engine].append(render(scene, engine, 1, cfg).wall_s)
    c, e = median(walls["CYCLES"]), median(walls["EMBER"])
    out(f"\n== time to first sample, 256^3 VDB cloud, 64^2 px, 1 spp (render call, median of {repeats}): "
        f"Cycles {c:.2f} s, Ember {e:.2f} s, ratio {e / c:.2f}x")
    return c, e


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small images, short budgets (a smoke test)")
    parser.add_argument("--refresh", action="store_true", help="render the references again")
    args = parser.parse_args()
    cfg = FULL
    bpy.app.handlers.render_stats.append(record_stats)
    size, budgets = (48, (2.0,)) if args.quick else (96, (5.0, 20.0))
    start, load = time.perf_counter(), os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        cloud = os.path.join(tmp, "cloud_128.vdb")
        write_cloud(cloud, 128)
        equal_time(smoke_scene(size, cloud), "smoke", "smoke cloud (128^3 VDB density, sun and sky)",
                   256 if args.quick else 4096, budgets, cfg, args.refresh)
        equal_time(fog_scene(size), "fog", "world fog crossed by two spot lights' beams",
                   256 if args.quick else 4096, budgets, cfg, args.refresh)
        big = os.path.join(tmp, "cloud_256.vdb")
        write_cloud(big, 128 if args.quick else 256)
        first_sample(big, cfg, 1 if args.quick else 3)
    out(f"\nload average {load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end; "
        f"{time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    vs_cycles.RESULTS_DIR = RESULTS_DIR
    main()
