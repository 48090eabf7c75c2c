"""Run by tests/test_extension.py in fresh interpreters (python -I -S), as a render farm's worker runs
Blender: one process installs Ember, the others render a saved .blend the way `blender -b` does.

    python -I -S farm_worker_child.py SITE_DIR MODE WORK_DIR [PACKAGE_ZIP]

MODE install: install and enable the package, save the preferences (what
    `blender --command extension install-file -r user_default -e PACKAGE` does once per worker);
    then build the test scene (engine Cycles) and save it as WORK_DIR/scene.blend.
MODE worker: load the saved preferences, as `blender -b` does, open scene.blend, pick Ember (-E EMBER) and
    render frame 1 to its output path (-f 1).
MODE factory: the same after Blender's factory settings, as `blender --factory-startup -b` starts.
Prints one JSON line starting with RESULT:.
"""
from __future__ import annotations

import json
import os
import sys

SITE_DIR, MODE, WORK_DIR = sys.argv[1:4]
sys.path.append(SITE_DIR)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
MODULE = "bl_ext.user_default.ember"


def main() -> dict:
    import bpy
    blend = os.path.join(WORK_DIR, "scene.blend")
    if MODE == "install":
        bpy.ops.extensions.package_install_files(filepath=sys.argv[4], repo="user_default", enable_on_install=True)
        bpy.ops.wm.save_userpref()
        import extension_install_child as scenes
        scene = scenes.build_scene(bpy)
        scene.render.engine = "CYCLES"
        scene.render.filepath = "//frames/f_####"
        scene.render.image_settings.file_format = "OPEN_EXR"
        scene.render.image_settings.color_depth = "32"
        bpy.ops.wm.save_as_mainfile(filepath=blend)
        return {"enabled": MODULE in bpy.context.preferences.addons}
    if MODE == "worker":
        bpy.ops.wm.read_userpref()
    else:
        bpy.ops.wm.read_factory_settings()
    result = {"ember_enabled": MODULE in bpy.context.preferences.addons}
    bpy.ops.wm.open_mainfile(filepath=blend)
    scene = bpy.context.scene
    try:
        scene.render.engine = "EMBER"
        result["engine"] = scene.render.engine
    except TypeError as err:   # not an engine Blender knows: -E EMBER fails the same way
        result["engine"] = None
        result["error"] = str(err).splitlines()[0]
        return result
    scene.ember.samples = 8
    scene.ember.pixel_filter_type, scene.ember.use_denoising = "BOX", False
    # -f 1 renders one frame of an animation: the output path gets the frame number.
    scene.frame_start = scene.frame_end = 1
    bpy.ops.render.render(animation=True)
    out = bpy.path.abspath(scene.render.frame_path(frame=1))
    result["output"] = out
    result["written"] = os.path.exists(out)
    if result["written"]:
        import numpy as np
        image = bpy.data.images.load(out, check_existing=False)
        w, h = image.size
        pixels = np.empty(w * h * 4, np.float32)
        image.pixels.foreach_get(pixels)
        rgb = pixels.reshape(h, w, 4)[::-1, :, :3]
        result["sky_rgb"] = rgb[:4].reshape(-1, 3).mean(axis=0).tolist()
    return result


if __name__ == "__main__":
    print("RESULT:" + json.dumps(main()), flush=True)
