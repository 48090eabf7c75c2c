"""Baking with Ember: RenderEngine.bake, which Blender's bake operator (Render Properties > Bake, or
bpy.ops.object.bake) calls once per image of the object it bakes.

Blender does the rest, as for Cycles (editors/object/object_bake_api.cc): it rasterises the object's UV map
into texels and, for Selected to Active, casts rays from the active object's surface (or its cage, pushed out
by the extrusion) to find the selected objects' surface behind each texel, and calls the engine once per
selected object with the texels that landed on it; afterwards it turns baked normals into the chosen Normal
Space with the chosen swizzle, converts colours to the image's colour space, and fills the margin. The
engine reads each texel's triangle and barycentrics from the result Blender hands it (render/intern/engine.cc,
render_result_from_bake: the BakePrimitive and BakeDifferential passes) and writes the bake into its Combined
pass, as Cycles' Blender session does (intern/cycles/blender/session.cpp, BlenderSession::bake). The scene is
exported as for a render; kernels/bake.py turns texels into paths and says what each bake type records.
"""
from __future__ import annotations

import itertools
import traceback

import numpy as np

from ..kernels import Renderer
from ..kernels.bake import GUIDES, KINDS, BakeJob, BakeTexels, bake as bake_texels, object_triangles
from .export import ExportCancelled, ExportError, export_scene
from .session import cancel_requested, render_settings, render_threads

# Each image of a bake needs its own result layer: Blender finds the image a result belongs to by its name.
_LAYERS = itertools.count()
# The bakes Cycles denoises when Render Properties > Sampling > Denoise is on: those whose pass supports denoising
# (scene/pass.cpp support_denoise: Combined and the Shadow Catcher pass; blender/session.cpp bake_setup_pass turns
# the denoiser off for the others).
DENOISED_BAKES = ("COMBINED", "SHADOW")
# The denoiser's input passes (Sampling > Denoise > Passes) -> the bake's guides (kernels/bake.py GUIDES).
_GUIDES = {"RGB": (), "RGB_ALBEDO": GUIDES[:1], "RGB_ALBEDO_NORMAL": GUIDES}


class BakeError(Exception):
    """The bake cannot go on; the message is one line for the user."""


def bake(engine, depsgraph, obj, pass_type: str, pass_filter: int, width: int, height: int) -> None:
    """Bake `obj` (the active object, or one selected object of Selected to Active) into the image of width x
    height texels Blender is baking; errors go to engine.report, never out of here."""
    # The layer is named: Blender reads an unnamed one from a null string and crashes (Blender 5.0 and 5.3).
    result = engine.begin_result(0, 0, width, height, layer=f"Ember bake {next(_LAYERS)}")
    done = False
    try:
        done = _bake(engine, depsgraph, obj, pass_type, pass_filter, result, width, height)
    except BakeError as err:
        engine.report({"ERROR"}, f"Ember: {err}")
    except ExportCancelled:
        pass
    except Exception as err:  # a bug of Ember's: one line; an escaping error would crash Blender
        traceback.print_exc()
        engine.report({"ERROR"}, f"Ember: internal error, bake abandoned: {type(err).__name__}: {err}")
    finally:
        engine.end_result(result, cancel=not done)


def _bake(engine, depsgraph, obj, pass_type: str, pass_filter: int, result, width: int, height: int) -> bool:
    if pass_type not in KINDS:
        raise BakeError(f"cannot bake '{pass_type}' (it bakes {', '.join(k.title() for k in KINDS)})")
    scene = depsgraph.scene
    should_stop = lambda: bool(engine.test_break()) or cancel_requested()  # noqa: E731
    ids, u, v, differentials, seed = read_texels(result, width * height)
    use_camera = scene.render.bake.view_from == "ACTIVE_CAMERA"
    if use_camera and scene.camera is None:
        raise BakeError("Bake > View From > Active Camera, but the scene has no camera")
    # The camera's frame is the image's only when the bake looks from it.
    key = (depsgraph.as_pointer(), obj.name, use_camera, (width, height) if use_camera else None)
    kept = getattr(engine, "_ember_bake", None)
    if kept is None or kept.key != key:
        drop_scene(engine)
        kept = engine._ember_bake = _scene_for(engine, depsgraph, obj, key, use_camera, width, height, should_stop)
    triangles = kept.triangles
    if len(ids) and ids.max() >= len(triangles):
        raise BakeError(f"object '{obj.name}': Blender baked triangle {int(ids.max())}, but its mesh has "
                        f"{len(triangles)} (a modifier that Ember and Blender's bake evaluate differently?)")
    prim = np.where(ids >= 0, np.take(triangles, np.maximum(ids, 0)) if len(triangles) else -1, -1)
    texels = BakeTexels(prim, u, v, differentials, width, height, seed)
    settings = render_settings(scene, None)
    engine.update_stats("", f"Ember: baking {pass_type.title()}, {settings.samples} samples")
    ember = scene.ember
    denoise = bool(ember.use_denoising) and pass_type in DENOISED_BAKES
    guides = dict.fromkeys(_GUIDES.get(ember.denoising_input_passes, GUIDES)) if denoise else None
    baked = bake_texels(kept.renderer, texels, BakeJob(pass_type, int(pass_filter), use_camera), settings,
                        should_stop, engine.update_progress, guides=guides)
    if should_stop():
        return False
    if denoise:
        denoise_bake(engine, baked, texels, pass_type, guides, ember, render_threads(scene.render), should_stop)
        if should_stop():
            return False
    combined = result.layers[0].passes["Combined"]
    c = combined.channels
    combined.rect.foreach_set(np.ascontiguousarray(baked[:, :c], np.float32).ravel())
    return True


def denoise_bake(engine, baked: np.ndarray, texels: BakeTexels, pass_type: str, guides: dict, ember, threads: int,
                 should_stop) -> bool:
    """Denoise a bake's colour in place, as Cycles denoises a bake (its film is the image of texels, denoised as a
    render's: src/integrator/denoiser_oidn.cpp) with the scene's quality, prefilter and passes: the texels of the
    object guided by their Denoising Albedo and Normal; a Shadow bake (Cycles' Shadow Catcher pass) with the
    stand-in albedo Cycles gives that pass, and 1 where no texel is baked (the pass reads 1 where nothing split),
    a Combined bake 0 there. Alpha is the bake's. A failure keeps the bake as it is, with a warning. True when
    denoised."""
    from .denoise import denoise
    from .film_denoise import STAND_IN_ALBEDO
    shape = (texels.height, texels.width, 3)
    blank = texels.prim < 0
    colour = baked[:, :3].copy()
    if pass_type == "SHADOW":
        colour[blank] = 1.0
    albedo, normal = guides.get("denoising_albedo"), guides.get("denoising_normal")
    noise_free = ()
    if albedo is not None and pass_type == "SHADOW":
        albedo, noise_free = np.full_like(albedo, STAND_IN_ALBEDO), ("albedo",)
    engine.update_stats("", f"Ember: denoising the bake ({ember.denoising_quality.title()})")
    try:
        clean = denoise(colour.reshape(shape), None if albedo is None else albedo.reshape(shape),
                        None if normal is None else normal.reshape(shape), quality=ember.denoising_quality,
                        prefilter=ember.denoising_prefilter, threads=threads, noise_free=noise_free,
                        progress=lambda fraction: not should_stop())
    except Exception as err:  # the library missing, OIDN's own error: the bake stays as baked
        engine.report({"WARNING"}, f"Ember: denoising failed, the bake is not denoised: {type(err).__name__}: {err}")
        return False
    if clean is None:
        return False
    clean = clean.reshape(-1, 3)
    if not np.isfinite(clean).all() or (not np.any(clean > 0) and np.any(colour > 0)):
        engine.report({"WARNING"}, "Ember: denoising gave non-finite or black texels, the bake is not denoised")
        return False
    baked[~blank, :3] = clean[~blank]
    return True


class _BakeScene:
    """The scene a bake exported and built, kept by its engine for the object's next image (each UDIM tile and
    each material's image is a call of its own: Blender's RE_bake_engine)."""

    def __init__(self, key, renderer, triangles):
        self.key, self.renderer, self.triangles = key, renderer, triangles


def _scene_for(engine, depsgraph, obj, key, use_camera: bool, width: int, height: int, should_stop) -> _BakeScene:
    engine.update_stats("", "Ember: exporting scene")
    try:
        exported = export_scene(depsgraph, width=width, height=height, should_stop=should_stop,
                                need_camera=use_camera, bake=True)
    except ExportError as err:
        raise BakeError(str(err)) from None
    for line in exported.warnings:
        engine.report({"WARNING"}, f"Ember: {line}")
    row = object_row(exported.index.instance_keys, obj.name)
    if row is None:
        raise BakeError(f"object '{obj.name}' has no triangles Ember renders (is it visible to any ray?)")
    engine.update_stats("", "Ember: building the scene")
    try:
        renderer = Renderer(exported.scene, render_threads(depsgraph.scene.render), processes=False)
    except ValueError as err:
        raise BakeError(f"invalid scene data: {err}") from None
    return _BakeScene(key, renderer, object_triangles(exported.scene, renderer.scene, row))


def drop_scene(engine) -> None:
    """Close the scene a bake kept (when its engine is freed, or another bake begins)."""
    try:
        kept = getattr(engine, "_ember_bake", None)
        if kept is not None:
            engine._ember_bake = None
    except ReferenceError:   # an engine whose RNA is gone: what it kept goes with it
        return
    if kept is not None:
        kept.renderer.close()


def read_texels(result, count: int):
    """(triangle numbers in the object's mesh (-1: not the object's), u, v, (count, 4) differentials, seeds or
    None) of the texels Blender hands over in the bake result's passes."""
    passes = {p.name: p for p in result.layers[0].passes}
    primitive = _pass_values(passes["BakePrimitive"], count)
    if primitive.shape[1] == 3:     # Blender 4.x and 5.x: u, v, triangle
        u, v, ids = primitive[:, 0], primitive[:, 1], primitive[:, 2].copy().view(np.int32)
        seed = None
    else:                           # older: seed, triangle, u, v
        seed, ids = primitive[:, 0].copy().view(np.uint32), primitive[:, 1].copy().view(np.int32)
        u, v = primitive[:, 2], primitive[:, 3]
    differentials = _pass_values(passes["BakeDifferential"], count)
    if "BakeSeed" in passes:        # baking to a colour attribute: each corner's vertex
        seed = _pass_values(passes["BakeSeed"], count)[:, 0].copy().view(np.uint32)
    ids = ids.astype(np.int64)
    blank = ids < 0
    u, v = np.where(blank, 0.0, u).astype(np.float32), np.where(blank, 0.0, v).astype(np.float32)
    return ids, u, v, np.where(blank[:, None], 0.0, differentials).astype(np.float32), seed


def _pass_values(render_pass, count: int) -> np.ndarray:
    values = np.empty(count * render_pass.channels, np.float32)
    render_pass.rect.foreach_get(values)
    return values.reshape(count, render_pass.channels)


def object_row(instance_keys, name: str) -> int | None:
    """The object table row of the object named `name` (its own, not an instance of it elsewhere), or the row
    of the first instance it makes (a curve or text object's mesh); None when it has none."""
    keys = list(instance_keys or ())
    for row, key in enumerate(keys):
        if key[0] == name and not key[1]:
            return row
    for row, key in enumerate(keys):
        if name in (key[0], key[1]):
            return row
    return None
