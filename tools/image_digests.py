#!/usr/bin/env python3.11
"""Print a digest of the images of a few kernel scenes, to prove that a refactor leaves images bit for bit.

    .venv/bin/python tools/image_digests.py > before.txt   # on the old code
    .venv/bin/python tools/image_digests.py | diff before.txt -   # on the new code: no output

The scenes cover every sampling mode, emissive triangles, Blender lights of each kind, an HDRI world, a
texture and the transparent film, and (exported through bpy) bench/scenes.py's row of Principled spheres:
metal, plastic, glass, coat, sheen, once with every data and light pass and Cryptomatte. Small images and
few samples: it runs in a few seconds.
"""
from __future__ import annotations

import hashlib
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import import_ember  # noqa: E402

import_ember()
from ember.kernels import Lights, RenderSettings, World, render  # noqa: E402
from ember.kernels.scene import LIGHT_KINDS, Materials  # noqa: E402
from ember.kernels.shapes import cornell_box  # noqa: E402


def digest(image: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(image, np.float32).tobytes()).hexdigest()[:16]


def lights() -> Lights:
    kinds = ["POINT", "SPOT", "SUN", "RECT", "DISK"]
    n = len(kinds)
    frame = np.repeat(np.diag([1.0, 1.0, 1.0]).astype(np.float32)[None], n, axis=0)
    return Lights(kind=np.array([LIGHT_KINDS[k] for k in kinds], np.int32),
                  position=np.array([[0.3, 0.1, 1.8], [-0.4, 0.2, 1.7], [0, 0, 0], [0.0, 0.4, 1.9],
                                     [-0.5, -0.3, 1.9]], np.float32),
                  frame=frame, radiance=np.full((n, 3), 2.0, np.float32),
                  radius=np.array([0.05, 0.0, 0, 0, 0], np.float32),
                  size=np.array([[0, 0], [0, 0], [0, 0], [0.3, 0.2], [0.25, 0.25]], np.float32),
                  spot_cos=np.array([[0, 0], [0.8, 0.9], [0, 0], [0, 0], [0, 0]], np.float32),
                  sun_half_angle=np.array([0, 0, 0.05, 0, 0], np.float32))


def textured(scene):
    tex = np.random.default_rng(3).random((8, 8, 3), dtype=np.float32)
    albedo = [[0.73, 0.73, 0.73], [0.65, 0.05, 0.05], [0.12, 0.45, 0.15], [0.0, 0.0, 0.0], [0.6, 0.6, 0.6]]
    emission = np.zeros((5, 3), np.float32)
    emission[3] = 15.0
    mats = Materials.diffuse(albedo, albedo_texture=[0, -1, -1, -1, -1], emission=emission)
    uvs = np.random.default_rng(4).random(scene.uvs.shape, dtype=np.float32)
    return type(scene)(**{**scene.__dict__, "materials": mats, "textures": (tex,), "texture_srgb": (True,),
                          "uvs": uvs})


def cases():
    base = cornell_box(40, 40)
    hdri = np.random.default_rng(5).random((16, 32, 3), dtype=np.float32) * 3
    sky = World(color=np.zeros(3, np.float32), hdri=hdri, strength=1.0)
    for mode in ("NEE_MIS", "COSINE", "LECTURE"):
        yield f"cornell {mode}", base, RenderSettings(samples=4, mode=mode, max_bounces=4)
    yield "cornell lights", type(base)(**{**base.__dict__, "lights": lights()}), RenderSettings(samples=4)
    yield "cornell hdri", type(base)(**{**base.__dict__, "world": sky}), RenderSettings(samples=4, max_bounces=3)
    yield "cornell textured", textured(base), RenderSettings(samples=4)
    yield "cornell transparent", type(base)(**{**base.__dict__, "world": sky}), \
        RenderSettings(samples=2, transparent_background=True, seed=7)


def materials():
    """The Principled sphere row of bench/vs_cycles.py, exported from Blender."""
    import bpy

    from bench import scenes
    from ember.engine.export import export_scene
    scenes.materials_scene(48, 32)
    exported = export_scene(bpy.context.evaluated_depsgraph_get(), width=48, height=32)
    yield "materials", exported.scene, RenderSettings(samples=4, max_bounces=6)
    yield "materials small waves", exported.scene, RenderSettings(samples=4, max_bounces=6, wave_size=512)
    yield "materials passes", exported.scene, RenderSettings(samples=4, max_bounces=6, passes=PASSES,
                                                             cryptomatte=("object", "material"))


# Every pass but the Vector pass (which needs a scene with motion) and the adaptive noise estimate.
PASSES = ("depth", "position", "object_index", "material_index", "normal", "uv", "denoising_albedo",
          "denoising_normal", "denoising_depth", "mist", "emission", "environment", "diffuse_direct",
          "diffuse_indirect", "diffuse_color", "glossy_direct", "glossy_indirect", "glossy_color",
          "transmission_direct", "transmission_indirect", "transmission_color")


def main() -> None:
    for name, scene, settings in (*cases(), *materials()):
        result = render(scene, settings, threads=2)
        print(f"{name:24s} {digest(result.image)}  mean {result.image[..., :3].mean():.6f}")
        for extra in settings.passes:
            print(f"  pass {extra:20s} {digest(result.film.resolve_pass(extra))}")
        for kind in settings.cryptomatte:
            print(f"  cryptomatte {kind:13s} {digest(result.film.resolve_crypto(kind))}")


if __name__ == "__main__":
    main()
