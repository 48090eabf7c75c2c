"""Ember against Cycles on real content: published glTF sample models imported with Blender's glTF importer
and lit as a user would light them (bench/real_scenes.py says which models, how they are lit and where to
get them), in one process, both engines through bpy.ops.render.render.

Both engines render with Blender's default settings, which are Cycles' (light tree on, Clamp Indirect 10,
Filter Glossy 1, 12 / 4 / 4 / 12 bounces, Blackman-Harris 1.5 px), adaptive sampling and denoising off,
--threads threads, the same width, height and samples. Volume shaders are disconnected in both (Ember has
none yet; with them the comparison would measure that difference, not noise or speed). Per scene:

  time      wall time of the render call at --samples spp (export, sync, BVH and images included) and the
            time per sample without the start-up (slope of wall time from a 1-spp render), each engine's,
            and Ember / Cycles;
  variance  per-sample variance: the pixels' variance over --seeds renders of --variance-samples spp each,
            times spp, over the image; Ember / Cycles, and the equal-time RMSE ratio it implies at the
            engines' per-sample times, sqrt(variance ratio x Ember's time per sample / Cycles');
  rmse      RMSE against a converged Cycles image (--reference-samples spp in two halves, cached in
            bench/results/; its own noise is taken out) after --budget seconds of each engine
            (time_limit on both), Ember / Cycles, and each image mean against the reference's.

    .venv/bin/python bench/real_content.py [--models DIR] [--quick] [--only NAME ...] [--skip-rmse]
                                           [--json PATH]

The full run takes about 45 minutes the first time (references) and 22 later on the 2-core machine;
--quick (80x60, few samples, short references) about 6. Figures go to stdout and to
bench/results/real_content[_quick].json. Ratios are measured in one run, the engines taking turns, so that
the shared machine's load hits both alike; the load average is printed at the start and the end.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import sys
import time
from dataclasses import asdict, dataclass, replace

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import ROOT, import_ember, median  # noqa: E402

import_ember()
import bpy  # noqa: E402

from bench import real_scenes  # noqa: E402
from bench.corpus_render import map_cycles_settings  # noqa: E402
from bench.vs_cycles import memory_mb, measured_render, out, own_rate, record_stats  # noqa: E402

RESULTS_DIR = os.path.join(ROOT, "bench", "results")
UNLIMITED_SAMPLES = 1 << 16
REFERENCE_SEEDS = (1001, 1002)


@dataclass(frozen=True)
class Config:
    width: int = 160
    height: int = 120
    samples: int = 128
    threads: int = 2
    repeats: int = 3                 # timed renders per engine at `samples` and at 1 (medians): one render of
    #                                  each moved the ratio by 20% on the shared machine
    variance_samples: int = 32
    seeds: int = 4
    reference_samples: int = 2048
    budget_s: float = 10.0


FULL = Config()
QUICK = replace(FULL, width=80, height=60, samples=16, repeats=1, variance_samples=8, seeds=3,
                reference_samples=256, budget_s=2.0)
ENGINES = ("CYCLES", "EMBER")


# ---------------------------------------------------------------- configuring and rendering
def prepare(scene, cfg: Config) -> int:
    """Both engines at Blender's defaults with the bench's samples, threads and switches; volume shaders
    disconnected. Returns how many volume links were removed."""
    render = scene.render
    render.threads_mode, render.threads = "FIXED", cfg.threads
    c = scene.cycles
    c.device, c.use_adaptive_sampling, c.use_denoising, c.use_animated_seed = "CPU", False, False, False
    map_cycles_settings(scene)
    e = scene.ember
    e.use_adaptive_sampling, e.use_denoising, e.use_animated_seed = False, False, False
    return _drop_volumes()


def _drop_volumes() -> int:
    removed = 0
    for mat in bpy.data.materials:
        tree = mat.node_tree
        if tree is None:
            continue
        for link in list(tree.links):
            if link.to_node.bl_idname == "ShaderNodeOutputMaterial" and link.to_socket.name == "Volume":
                tree.links.remove(link)
                removed += 1
    return removed


def render(scene, engine: str, samples: int, seed: int = 0, time_limit: float = 0.0, keep_image: bool = False):
    scene.render.engine = engine
    settings = scene.cycles if engine == "CYCLES" else scene.ember
    settings.samples, settings.seed, settings.time_limit = samples, seed, time_limit
    return measured_render(scene, keep_image)


# ---------------------------------------------------------------- the three parts
def timing(scene, cfg: Config) -> dict:
    """Wall time at cfg.samples and at 1 spp, interleaved; time per sample without the start-up."""
    runs = {e: {"full": [], "one": []} for e in ENGINES}
    for _ in range(cfg.repeats):
        for engine in ENGINES:
            runs[engine]["full"].append(render(scene, engine, cfg.samples))
            runs[engine]["one"].append(render(scene, engine, 1))
    pixels = cfg.width * cfg.height
    result = {}
    for engine in ENGINES:
        wall_n = median([r.wall_s for r in runs[engine]["full"]])
        wall_1 = median([r.wall_s for r in runs[engine]["one"]])
        per_sample = max(wall_n - wall_1, 1e-9) / max(cfg.samples - 1, 1)
        own = [own_rate(r, pixels) for r in runs[engine]["full"]]
        result[engine] = {"wall_s": wall_n, "wall_1spp_s": wall_1, "per_sample_s": per_sample,
                          "startup_s": wall_1 - per_sample,
                          "own_paths_per_s": median(own) if all(own) else None}
    e, c = result["EMBER"], result["CYCLES"]
    result["wall_ratio"] = e["wall_s"] / c["wall_s"]
    result["per_sample_ratio"] = e["per_sample_s"] / c["per_sample_s"]
    for engine, label in (("CYCLES", "Cycles"), ("EMBER", "Ember ")):
        x = result[engine]
        out(f"  time   {label} {x['wall_s']:6.2f} s at {cfg.samples} spp, {x['per_sample_s'] * 1e3:7.1f} ms per "
            f"sample + {x['startup_s']:5.2f} s start-up")
    out(f"  time   Ember / Cycles {result['wall_ratio']:.2f}x (per sample, without start-up "
        f"{result['per_sample_ratio']:.2f}x)")
    return result


def variance(scene, cfg: Config, per_sample_s: dict | None) -> dict:
    """Per-sample variance over cfg.seeds renders per engine, the engines taking turns seed by seed."""
    images = {e: [] for e in ENGINES}
    for seed in range(100, 100 + cfg.seeds):
        for engine in ENGINES:
            images[engine].append(render(scene, engine, cfg.variance_samples, seed=seed, keep_image=True).image)
    result = {}
    for engine in ENGINES:
        grey = np.stack(images[engine]).mean(axis=-1)
        per_pixel = grey.var(axis=0, ddof=1) * cfg.variance_samples
        # Standard error from the spread of the seeds' own squared deviations (the delta method on the mean).
        n = cfg.seeds
        deviations = ((grey - grey.mean(axis=0)) ** 2).mean(axis=(1, 2)) * cfg.variance_samples * n / (n - 1)
        result[engine] = {"variance": float(per_pixel.mean()),
                          "variance_standard_error": float(deviations.std(ddof=1) / math.sqrt(n)),
                          "mean": float(grey.mean())}
    e, c = result["EMBER"], result["CYCLES"]
    ratio = e["variance"] / c["variance"] if c["variance"] > 0 else math.inf
    rel = math.hypot(e["variance_standard_error"] / max(e["variance"], 1e-30),
                     c["variance_standard_error"] / max(c["variance"], 1e-30))
    result["ratio"], result["ratio_standard_error"] = ratio, ratio * rel
    expected = None
    if per_sample_s:
        expected = math.sqrt(ratio * per_sample_s["EMBER"] / per_sample_s["CYCLES"])
    result["expected_equal_time_rmse_ratio"] = expected
    out(f"  noise  variance per sample: Cycles {c['variance']:.4g} +- {c['variance_standard_error']:.2g}, "
        f"Ember {e['variance']:.4g} +- {e['variance_standard_error']:.2g}; Ember / Cycles {ratio:.2f} +- "
        f"{ratio * rel:.2f}" + (f"; equal-time RMSE ratio it implies {expected:.2f}" if expected else ""))
    return result


def reference(scene, name: str, cfg: Config, models_dir: str, refresh: bool):
    """The converged Cycles image (H, W, 3) float64 and the MSE its own noise adds, cached."""
    spec = real_scenes.BY_NAME[name]
    digest = hashlib.sha1()
    for path in (real_scenes.__file__, __file__):
        with open(path, "rb") as f:
            digest.update(f.read())
    digest.update(str(os.path.getsize(real_scenes.model_path(spec, models_dir))).encode())
    path = os.path.join(RESULTS_DIR, f"real_reference_{name}_{cfg.width}x{cfg.height}_{cfg.reference_samples}spp_"
                                     f"blender{bpy.app.version_string}_{digest.hexdigest()[:10]}.npz")
    if os.path.exists(path) and not refresh:
        data = np.load(path)
        return data["image"], float(data["noise_mse"]), True
    start = time.perf_counter()
    halves = [render(scene, "CYCLES", cfg.reference_samples // 2, seed=seed, keep_image=True).image
              for seed in REFERENCE_SEEDS]
    image = (halves[0] + halves[1]) / 2
    noise_mse = float(np.mean((halves[0] - halves[1]) ** 2) / 4)   # variance of the mean of the two halves
    os.makedirs(RESULTS_DIR, exist_ok=True)
    np.savez_compressed(path, image=image, noise_mse=noise_mse, seconds=time.perf_counter() - start)
    return image, noise_mse, False


def equal_time(scene, name: str, cfg: Config, models_dir: str, refresh: bool) -> dict:
    ref, noise_mse, cached = reference(scene, name, cfg, models_dir, refresh)
    result = {"reference_noise_rmse": math.sqrt(noise_mse), "reference_cached": cached}
    pixels = cfg.width * cfg.height
    for engine in ENGINES:
        run = render(scene, engine, UNLIMITED_SAMPLES, time_limit=cfg.budget_s, keep_image=True)
        mse = float(np.mean((run.image - ref) ** 2))
        result[engine] = {"rmse": math.sqrt(max(mse - noise_mse, 0.0)), "samples": run.samples_done,
                          "wall_s": run.wall_s, "render_s": run.render_s, "paths_per_s": own_rate(run, pixels),
                          "mean_vs_reference": float(run.image.mean() / max(ref.mean(), 1e-30) - 1.0)}
    e, c = result["EMBER"], result["CYCLES"]
    result["rmse_ratio"] = e["rmse"] / c["rmse"] if c["rmse"] > 0 else math.inf
    for engine, label in (("CYCLES", "Cycles"), ("EMBER", "Ember ")):
        x = result[engine]
        out(f"  rmse   {label} {x['rmse']:.5f} after {cfg.budget_s:g} s ({x['samples']} spp, render call "
            f"{x['wall_s']:.1f} s), image mean {x['mean_vs_reference']:+.2%} vs the reference")
    out(f"  rmse   Ember / Cycles {result['rmse_ratio']:.2f} (reference {cfg.reference_samples} spp"
        f"{', cached' if cached else ''}, its own noise RMSE {math.sqrt(noise_mse):.5f} taken out)")
    return result


# ---------------------------------------------------------------- main

def run_scene(name: str, cfg: Config, args) -> dict:
    spec = real_scenes.BY_NAME[name]
    try:
        scene = real_scenes.build(name, args.models, cfg.width, cfg.height)
    except FileNotFoundError as err:
        out(f"\n== {name}: skipped: {err}")
        return {"scene": name, "skipped": str(err)}
    except RuntimeError as err:   # the importer failed (bpy 5.3's wheel lacks the Draco library Buggy needs)
        lines = [line.strip() for line in str(err).splitlines() if "Error" in line and "Traceback" not in line]
        reason = f"Blender could not import {spec.model}: {lines[-1] if lines else type(err).__name__}"
        out(f"\n== {name}: skipped: {reason}")
        return {"scene": name, "skipped": reason}
    volumes = prepare(scene, cfg)
    out(f"\n== {name}: {spec.title}; {real_scenes.triangle_count():,} triangles"
        + (f"; {volumes} volume shader(s) disconnected" if volumes else ""))
    for engine in ENGINES:   # one-off costs: kernels, imports, image caches
        render(scene, engine, 1)
    row = {"scene": name, "title": spec.title, "volumes_disconnected": volumes}
    row["time"] = timing(scene, cfg)
    per_sample = {e: row["time"][e]["per_sample_s"] for e in ENGINES}
    if not args.skip_variance:
        row["variance"] = variance(scene, cfg, per_sample)
    if not args.skip_rmse:
        row["rmse"] = equal_time(scene, name, cfg, args.models, args.refresh_reference)
    row["memory_mb"] = memory_mb()
    return row


def summary(rows: list, cfg: Config) -> None:
    out(f"\n| Scene | Ember / Cycles time at {cfg.samples} spp | per sample | variance per sample | "
        f"equal-time RMSE ({cfg.budget_s:g} s) | implied by the variance |")
    out("| --- | --- | --- | --- | --- | --- |")
    for row in rows:
        if "skipped" in row:
            out(f"| {row['scene']} | skipped | | | | |")
            continue
        t, v, r = row["time"], row.get("variance"), row.get("rmse")
        cells = [f"{t['wall_ratio']:.2f}x", f"{t['per_sample_ratio']:.2f}x",
                 f"{v['ratio']:.2f} +- {v['ratio_standard_error']:.2f}" if v else "-",
                 f"{r['rmse_ratio']:.2f}" if r else "-",
                 f"{v['expected_equal_time_rmse_ratio']:.2f}" if v and v["expected_equal_time_rmse_ratio"] else "-"]
        out(f"| {row['scene']} | " + " | ".join(cells) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default=real_scenes.DEFAULT_MODELS_DIR,
                    help="folder holding the models (see bench/real_scenes.py)")
    ap.add_argument("--quick", action="store_true", help="a smoke run: 80x60, few samples, short references")
    ap.add_argument("--only", nargs="+", choices=[s.name for s in real_scenes.SCENES], help="these scenes only")
    ap.add_argument("--skip-variance", action="store_true")
    ap.add_argument("--skip-rmse", action="store_true")
    ap.add_argument("--refresh-reference", action="store_true", help="re-render the cached Cycles references")
    ap.add_argument("--json", help="where to write the figures (default bench/results/real_content[_quick].json)")
    args = ap.parse_args()
    cfg = QUICK if args.quick else FULL
    bpy.app.handlers.render_stats.append(record_stats)
    load_start = os.getloadavg()
    start = time.perf_counter()
    out(f"Ember vs Cycles on real content, Blender {bpy.app.version_string}, {cfg.width}x{cfg.height}, "
        f"{cfg.threads} threads, {os.cpu_count()} cores, load average {load_start[0]:.2f}"
        f"{' [quick]' if args.quick else ''}; models from {args.models}")
    rows = [run_scene(name, cfg, args) for name in (args.only or [s.name for s in real_scenes.SCENES])]
    summary(rows, cfg)
    load_end = os.getloadavg()
    report = {"quick": args.quick, "config": asdict(cfg), "blender": bpy.app.version_string,
              "cpu_count": os.cpu_count(), "load_average_start": load_start, "load_average_end": load_end,
              "seconds": time.perf_counter() - start, "scenes": rows}
    path = args.json or os.path.join(RESULTS_DIR, "real_content_quick.json" if args.quick else "real_content.json")
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as f:
        json.dump(report, f, indent=1)
    out(f"\nload average {load_start[0]:.2f} at the start, {load_end[0]:.2f} at the end; "
        f"{report['seconds']:.0f} s in all; figures in {os.path.relpath(path, ROOT)}")


if __name__ == "__main__":
    main()
