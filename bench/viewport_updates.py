"""Incremental viewport updates (issue 14): the time from moving an object to the viewport's first new
frame, with the incremental update against a full export of the scene, in one run.

    .venv/bin/python bench/viewport_updates.py [--triangles 1000000] [--moves 3] [--pixel-size 4]

The scene: a mesh of --triangles triangles (bench/big_scenes.py's bumpy sphere), a small cube beside it,
a sun and a world, seen by the factory startup file's 3D view (1574x954) at one film pixel per
--pixel-size screen pixels, rendered by a ViewportRender on 2 threads as Blender's view_update drives it
(the depsgraph_update_post handler stands in for Blender calling view_update). Each move sets the cube's
location; the clock runs from the edit until:
  main     view_update returns (the time Blender's UI is blocked),
  preview  the worker publishes the restart's quick low-resolution frame,
  sample   the first full-resolution sample is published.
"full" is the same viewport with every update answered by a full export (what view_update did before
incremental updates): a new export of every mesh and a new Renderer (BVHs and tables). Medians of --moves
moves each; the ratio is full / incremental.

The price: the viewport exports every mesh as an instance (so that moving one is a new transform), and
instanced triangles trace slower than triangles copied into world space (closest hits go through 16-ray
packets, hits are placed by their instance's matrix). "trace" is the best of 3 renders of 4 samples at
the film's size, the viewport's export against a final render's, on the same Renderer code.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from types import SimpleNamespace

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import import_ember, median  # noqa: E402

import_ember()
import bpy  # noqa: E402

from bench.big_scenes import build  # noqa: E402
from ember.engine import viewport as vp  # noqa: E402
from ember.engine.export import export_scene  # noqa: E402
from ember.kernels import Renderer, RenderSettings  # noqa: E402

THREADS = 2
TIMEOUT_S = 600.0


class FullExportViewport(vp.ViewportRender):
    """The viewport without incremental updates: every content update is a full export."""

    def _update(self, depsgraph, parts, settings) -> bool:
        return False


def stand_ins(pixel_size: int):
    """The factory 3D view as view_update's context, and an engine that answers what the viewport asks."""
    area = next(a for a in bpy.data.screens["Layout"].areas if a.type == "VIEW_3D")
    context = SimpleNamespace(space_data=area.spaces.active, region_data=area.spaces.active.region_3d,
                              region=next(r for r in area.regions if r.type == "WINDOW"))
    engine = SimpleNamespace(get_preview_pixel_size=lambda scene: pixel_size,
                             update_stats=lambda *args: None, tag_redraw=lambda: None)
    return engine, context


def wait_for(session, generation: int, samples: int) -> float:
    """perf_counter() when the session has published a frame of `generation` with `samples` full samples."""
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        frame = session.snapshot()
        if frame is not None and frame.generation >= generation and frame.samples_done >= samples:
            return time.perf_counter()
        if session.error:
            raise RuntimeError(session.error)
        time.sleep(0.001)
    raise TimeoutError("the viewport published no frame")


def measure(viewport_class, cube, engine, context, moves: int) -> dict:
    """Median seconds from a move of the cube to each milestone, and the first (full) export's."""
    viewport = viewport_class(THREADS)
    session = viewport.session

    def handler(scene, depsgraph):
        viewport.view_update(engine, context, depsgraph)

    try:
        start = time.perf_counter()
        viewport.view_update(engine, context, bpy.context.evaluated_depsgraph_get())
        first = wait_for(session, session.generation, 1) - start
        times = {"main": [], "preview": [], "sample": []}
        bpy.app.handlers.depsgraph_update_post.append(handler)
        try:
            for k in range(moves):
                wait_for(session, session.generation, 1)
                start = time.perf_counter()
                cube.location.x = 1.6 + 0.1 * (k + 1)
                bpy.context.evaluated_depsgraph_get()           # Blender evaluates, then calls view_update
                times["main"].append(time.perf_counter() - start)
                generation = session.generation
                times["preview"].append(wait_for(session, generation, 0) - start)
                times["sample"].append(wait_for(session, generation, 1) - start)
        finally:
            bpy.app.handlers.depsgraph_update_post.remove(handler)
        return {"first export": first, **{name: median(values) for name, values in times.items()}}
    finally:
        viewport.free()


def trace_seconds(instance_everything: bool, width: int, height: int) -> float:
    """Best of 3 renders of 4 samples of the scene as the viewport (or a final render) exports it."""
    exported = export_scene(bpy.context.evaluated_depsgraph_get(), width=width, height=height,
                            instance_everything=instance_everything)
    with Renderer(exported.scene, THREADS) as renderer:
        renderer.render(RenderSettings(samples=1))   # warm up (lazily built tables)
        times = []
        for seed in range(3):
            start = time.perf_counter()
            renderer.render(RenderSettings(samples=4, seed=seed))
            times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--triangles", type=int, default=1_000_000)
    parser.add_argument("--moves", type=int, default=3)
    parser.add_argument("--pixel-size", type=int, default=4)
    args = parser.parse_args()

    scene = build("mesh", args.triangles, 0)
    scene.ember.preview_samples = 4
    scene.ember.use_adaptive_sampling = False
    bpy.ops.mesh.primitive_cube_add(size=0.3, location=(1.6, 0.0, 0.0))
    cube = bpy.context.object
    engine, context = stand_ins(args.pixel_size)
    width, height = vp.film_size(context.region.width, context.region.height, args.pixel_size)
    print(f"{args.triangles / 1e6:g}M-triangle mesh + a 12-triangle cube that moves; film {width}x{height}, "
          f"{THREADS} threads, {os.cpu_count()} cores; median of {args.moves} moves")
    results = {"incremental": measure(vp.ViewportRender, cube, engine, context, args.moves),
               "full": measure(FullExportViewport, cube, engine, context, args.moves)}
    print(f"{'':14}{'incremental':>12}{'full':>10}{'ratio':>8}")
    for name in ("main", "preview", "sample"):
        inc, full = results["incremental"][name], results["full"][name]
        print(f"{'move -> ' + name:14}{inc:11.3f}s{full:9.3f}s{full / inc:7.1f}x")
    print(f"(first full export to its first sample: {results['incremental']['first export']:.2f} s)")
    instanced, plain = trace_seconds(True, width, height), trace_seconds(False, width, height)
    print(f"trace 4 samples: every mesh instanced (viewport) {instanced:.3f} s, copied (final render) "
          f"{plain:.3f} s: {instanced / plain:.2f}x")


if __name__ == "__main__":
    main()
