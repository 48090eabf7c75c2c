"""Run by tests/test_extension.py in a fresh interpreter (python -I -S): install a built Ember package
into the Blender user resources named by BLENDER_USER_RESOURCES, render with it, disable and remove it.

    python -I -S extension_install_child.py SITE_DIR PACKAGE_ZIP WORK_DIR

SITE_DIR holds the packages Blender needs (bpy, numpy, ...) but no embreex. Prints one JSON line
starting with RESULT: what the parent test asserts on. Failures raise (non-zero exit, traceback).
"""
from __future__ import annotations

import json
import math
import os
import sys
import time

SITE_DIR, PACKAGE_ZIP, WORK_DIR = sys.argv[1:4]
sys.path.append(SITE_DIR)

MODULE = "bl_ext.user_default.ember"
WORLD_COLOR = (0.2, 0.4, 0.8)
PLANE_ALBEDO = 0.8


def embreex_importable() -> bool:
    import importlib.util
    return importlib.util.find_spec("embreex") is not None


def node_tree(bpy, owner):
    """A material's or world's node tree. Blender 4.x makes one only when asked (use_nodes, which 5.x
    deprecates: its materials and worlds always have one)."""
    if bpy.app.version < (5, 0, 0):
        owner.use_nodes = True
    return owner.node_tree


def build_scene(bpy):
    """Camera above a large diffuse plane under a uniform world: the top of the image is sky, the
    bottom plane, whose radiance is albedo x world."""
    scene = bpy.context.scene
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    scene.render.resolution_x, scene.render.resolution_y = 32, 24
    scene.render.resolution_percentage = 100
    scene.render.threads_mode = "FIXED"
    scene.render.threads = 2

    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    cam.location = (0.0, -6.0, 1.5)
    cam.rotation_euler = (math.radians(90.0 - math.degrees(math.atan2(0.5, 6.0))), 0.0, 0.0)
    scene.camera = cam

    mat = bpy.data.materials.new("Plane")
    tree = node_tree(bpy, mat)
    tree.nodes.clear()
    bsdf = tree.nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (PLANE_ALBEDO,) * 3 + (1.0,)
    tree.links.new(bsdf.outputs[0], tree.nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
    mesh = bpy.data.meshes.new("Plane")
    mesh.from_pydata([(-20, -20, 0), (20, -20, 0), (20, 20, 0), (-20, 20, 0)], [], [(0, 1, 2, 3)])
    mesh.materials.append(mat)
    scene.collection.objects.link(bpy.data.objects.new("Plane", mesh))

    world = bpy.data.worlds.new("World")
    scene.world = world
    tree = node_tree(bpy, world)
    tree.nodes.clear()
    bg = tree.nodes.new("ShaderNodeBackground")
    bg.inputs["Color"].default_value = WORLD_COLOR + (1.0,)
    bg.inputs["Strength"].default_value = 1.0
    tree.links.new(bg.outputs[0], tree.nodes.new("ShaderNodeOutputWorld").inputs["Surface"])
    return scene


def render_exr(bpy, scene, wave_size=None, processes=None):
    """Render with Ember to a linear EXR; return (H, W, 4) float32, row 0 at the top. wave_size: force
    the kernel's wave size (many waves); processes False: no worker processes."""
    import numpy as np
    schedule = sys.modules[MODULE + ".kernels.schedule"]
    if wave_size is not None:
        schedule.WAVE_SIZE = schedule.LAYERED_WAVE_SIZE = wave_size
    schedule.WORKER_START_S = 1e9 if processes is False else 1.5
    start_paths = schedule.WORKER_START_PATHS
    if processes is False:
        schedule.WORKER_START_PATHS = 1 << 60
    scene.render.engine = "EMBER"
    scene.ember.samples = 8
    # The checks are exact colours of flat regions: a one-pixel box and no denoiser, as the parity tests.
    scene.ember.pixel_filter_type, scene.ember.use_denoising = "BOX", False
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = os.path.join(WORK_DIR, "frame.exr")
    scene.render.use_file_extension = False
    bpy.ops.render.render(write_still=True)
    schedule.WORKER_START_PATHS = start_paths
    image = bpy.data.images.load(scene.render.filepath, check_existing=False)
    w, h = image.size
    pixels = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(pixels)
    bpy.data.images.remove(image)
    return pixels.reshape(h, w, 4)[::-1]


def engine_listed(bpy) -> bool:
    render = bpy.context.scene.render
    try:
        render.engine = "EMBER"
    except TypeError:
        return False
    return render.engine == "EMBER"


def main() -> dict:
    result = {"embreex_visible_before_install": embreex_importable()}
    import bpy
    resources = os.environ["BLENDER_USER_RESOURCES"]
    result["extensions_dir"] = bpy.utils.user_resource("EXTENSIONS")

    bpy.ops.extensions.package_install_files(filepath=PACKAGE_ZIP, repo="user_default", enable_on_install=True)
    result["enabled"] = MODULE in bpy.context.preferences.addons
    import embreex
    ember = sys.modules[MODULE]
    from importlib import import_module
    result["embreex_file"] = embreex.__file__
    result["ember_file"] = ember.__file__
    result["version"] = import_module(MODULE + ".engine.version").EMBER_VERSION
    result["checkout_ember_loaded"] = "ember" in sys.modules

    import numpy as np
    scene = build_scene(bpy)
    image = render_exr(bpy, scene)
    rgb = image[..., :3].astype(float)
    result["finite"] = bool(np.isfinite(image).all())
    result["sky_rgb"] = rgb[:4].reshape(-1, 3).mean(axis=0).tolist()
    result["plane_rgb"] = rgb[-4:].reshape(-1, 3).mean(axis=0).tolist()
    result["shape"] = list(image.shape)

    # Worker processes from the installed package (bl_ext.user_default.ember): the child imports it under
    # that name, with embreex from the bundled wheel. A render forced to use them is the same image.
    schedule = sys.modules[MODULE + ".kernels.schedule"]
    workers = sys.modules[MODULE + ".kernels.workers"]
    schedule.WORKER_START_PATHS, schedule.MIN_WAVE_PATHS = 1, 64
    scene.ember.use_adaptive_sampling = False
    plain = render_exr(bpy, scene, wave_size=64, processes=False)
    render_exr(bpy, scene, wave_size=64)   # starts a worker, which outlives this short render in the pool

    def pooled():
        deadline = time.monotonic() + 30.0
        while not workers.pooled() and time.monotonic() < deadline:
            time.sleep(0.05)
        return [w.process.pid for w in workers.pooled()]
    first = pooled()
    helped = render_exr(bpy, scene, wave_size=64)   # takes it from the pool: ready within the render
    result["worker_image_equal"] = bool(np.array_equal(plain, helped))
    result["worker_pids"] = first + pooled()
    workers.close_pool()

    package_dir = os.path.join(result["extensions_dir"], "user_default", "ember")
    result["package_dir_existed"] = os.path.isdir(package_dir)
    bpy.ops.preferences.addon_disable(module=MODULE)
    result["disabled"] = MODULE not in bpy.context.preferences.addons
    result["engine_after_disable"] = engine_listed(bpy)
    result["settings_after_disable"] = hasattr(bpy.types.Scene, "ember")

    repos = bpy.context.preferences.extensions.repos
    repo_index = next(i for i, repo in enumerate(repos) if repo.module == "user_default")
    bpy.ops.extensions.package_uninstall(repo_index=repo_index, pkg_id="ember")
    result["package_dir_after_uninstall"] = os.path.exists(package_dir)
    site_packages = os.path.join(result["extensions_dir"], ".local", "lib",
                                 f"python{sys.version_info[0]}.{sys.version_info[1]}", "site-packages")
    result["wheel_files_after_uninstall"] = sorted(os.listdir(site_packages)) if os.path.isdir(site_packages) else []
    result["resources"] = resources
    return result


if __name__ == "__main__":
    print("RESULT:" + json.dumps(main()), flush=True)
