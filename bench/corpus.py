"""Ember against Cycles on .blend files other people made, each rendered as saved.

    .venv/bin/python bench/corpus.py FOLDER [-r] [-o OUT] [--samples 32] [--long-side 160] [--seed 0]
                                            [--threads 2] [--timeout 600] [--only SUBSTRING]
                                            [--set PATH=VALUE ...]

Every .blend in FOLDER (with -r, in its subfolders too, each named by its path under FOLDER) is rendered by each engine in a fresh process (bench/corpus_render.py): its own
camera, scene and frame, the long side scaled to --long-side pixels, equal samples, seeds and bounces,
the file's clamping and Filter Glossy for both (Ember takes the file's Cycles settings where it has them,
and the ones it lacks are printed), no denoising or adaptive sampling, --threads threads. A crash, an
error or a hang (--timeout seconds per file and engine) is reported for that file and the run goes on.
The .blend files are opened, never saved.

Each engine renders twice, with seeds --seed and --seed + 1: the two renders' spread is the engine's own
noise. Per file the tool prints
  - the image-mean difference, Ember / Cycles - 1, with its standard error;
  - over 8x8-pixel blocks, the 90th percentile of |Ember - Cycles| / (Cycles' noise in the block: the
    standard deviation of one Cycles render's block mean). With both estimates the mean of two renders
    and equal noise, it is |N(0, 1)|: about 1.64. Blocks without noise in either engine that agree to
    0.1% (a plain background) are left out, and counted apart;
  - Ember's noise over Cycles' (the square root of the ratio of their summed block variances), the time
    ratio (of the mean wall time of bpy.ops.render.render over the two renders: export, build and
    render, not the process start), Ember's warnings and the Cycles settings Ember lacks;
  - a verdict: 'beyond noise' when the 90th percentile of the blocks' differences over the noise of the
    difference (both engines' noise) exceeds 2.5, or the whole image's difference exceeds 4 standard
    errors;
and writes OUT/<file>.png (a path's folders joined by _): Cycles | Ember | a heat map of the blocks' differences over their noise (red:
Ember brighter, blue: darker; full colour at 5 standard errors) over a dim copy of the Cycles image.
The images are shown with the sRGB curve, not the file's view transform. At the end: a markdown table
(also OUT/summary.md) to paste into an issue.

To find the cause of a difference, --set PATH=VALUE changes a scene setting in both engines' processes
before anything else (Ember then takes it over like the file's own), e.g. --set cycles.diffuse_bounces=1024
to take a Cycles limit Ember lacks out of the comparison; reduce the file itself (hide objects, swap
materials) in copies of it.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import signal
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from dataclasses import dataclass, field

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RENDERER = os.path.join(ROOT, "bench", "corpus_render.py")
BLOCK = 8
# A block's noise is never taken below this fraction of its brightness: a region without noise (a plain
# background) compares at float precision otherwise, and any rounding would count as a difference.
NOISE_FLOOR_RELATIVE = 1e-3
P90_LIMIT = 2.5      # |N(0, 1)| has its 90th percentile at 1.64
WHOLE_Z_LIMIT = 4.0
HEAT_FULL_Z = 5.0
WARNING_LINE = re.compile(r"^Ember \| Frame -?\d+ \| Warning: (.*)$")
ERROR_LINE = re.compile(r"^(?:Error|ERROR)\W+(.*Ember.*)$")


# ====================================================================== running the engines
@dataclass
class EngineRun:
    """One engine's renders of one file, or why there are none."""
    images: np.ndarray | None = None        # (seeds, H, W, 4) float32, row 0 at the top
    seconds: list = field(default_factory=list)
    meta: dict = field(default_factory=dict)
    error: str | None = None
    warnings: list = field(default_factory=list)
    errors: list = field(default_factory=list)


def blend_files(folder: str, only: str | None = None, recursive: bool = False) -> list[str]:
    """The .blend files in folder (and its subfolders with recursive), sorted by their path under it; only: those
    whose name contains it."""
    if recursive:
        names = sorted(os.path.relpath(os.path.join(root, n), folder) for root, _, files in os.walk(folder)
                       for n in files if n.lower().endswith(".blend"))
    else:
        names = sorted(n for n in os.listdir(folder) if n.lower().endswith(".blend"))
    return [os.path.join(folder, n) for n in names if only is None or only.lower() in os.path.basename(n).lower()]


def file_label(path: str, folder: str) -> str:
    """A file's name in the reports: its path under the folder (its name alone when it lies in the folder)."""
    return os.path.relpath(path, folder).replace(os.sep, "/")


def parse_reports(stdout: str) -> tuple[list[str], list[str]]:
    """Ember's warnings and errors in a render's output, each once, in order."""
    warnings, errors = {}, {}
    for line in stdout.splitlines():
        line = line.strip()
        if m := WARNING_LINE.match(line):
            warnings.setdefault(m.group(1), None)
        elif m := ERROR_LINE.match(line):
            errors.setdefault(m.group(1), None)
    return list(warnings), list(errors)


def render_file(path: str, engine: str, args, workdir: str) -> EngineRun:
    """Run bench/corpus_render.py in its own process (and process group, so a hang is killed whole)."""
    out = os.path.join(workdir, f"{engine.lower()}.npz")
    command = [sys.executable, RENDERER, path, out, "--engine", engine, "--seeds", str(args.seed),
               str(args.seed + 1), "--samples", str(args.samples), "--long-side", str(args.long_side),
               "--threads", str(args.threads)] + [f"--set={item}" for item in args.set]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        stdout, stderr = proc.communicate(timeout=args.timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        return EngineRun(error=f"no result after {args.timeout:g} s: stopped")
    warnings, errors = parse_reports(stdout)
    if proc.returncode < 0:
        return EngineRun(error=f"crashed ({signal.Signals(-proc.returncode).name})", warnings=warnings, errors=errors)
    if not os.path.exists(out):
        tail = (stderr.strip().splitlines() or ["no output"])[-1]
        return EngineRun(error=f"exit status {proc.returncode}: {tail}", warnings=warnings, errors=errors)
    with np.load(out) as data:
        if "error" in data:
            return EngineRun(error=str(data["error"]), warnings=warnings, errors=errors)
        return EngineRun(images=data["images"], seconds=[float(s) for s in data["seconds"]],
                         meta=json.loads(str(data["meta"])), warnings=warnings, errors=errors)


# ====================================================================== comparing
@dataclass
class Comparison:
    """Ember's renders against Cycles' (see the module docstring for what each figure means)."""
    mean_relative: float          # Ember / Cycles - 1 over the whole image
    mean_relative_se: float       # its standard error
    p90_over_cycles_noise: float  # 90th percentile over blocks of |difference| / Cycles' noise
    p90_z: float                  # the same over the noise of the difference (both engines)
    noise_ratio: float            # Ember's noise / Cycles'
    block_z: np.ndarray           # (H // 8, W // 8) signed difference / its noise
    blocks_counted: int           # blocks in the percentiles
    blocks_equal: int             # blocks left out: noise-free in both engines and equal to the noise floor

    @property
    def whole_z(self) -> float:
        if self.mean_relative_se > 0:
            return self.mean_relative / self.mean_relative_se
        return 0.0 if self.mean_relative == 0 else float("inf")

    @property
    def beyond_noise(self) -> bool:
        return self.p90_z > P90_LIMIT or abs(self.whole_z) > WHOLE_Z_LIMIT


def grey(images: np.ndarray) -> np.ndarray:
    """(R, H, W, >=3) -> (R, H, W) float64 mean of RGB."""
    return images[..., :3].astype(np.float64).mean(axis=-1)


def block_sums(x: np.ndarray, block: int = BLOCK) -> np.ndarray:
    """(..., H, W) -> (..., H // block, W // block) sums (partial blocks at the edges dropped)."""
    h, w = x.shape[-2] // block * block, x.shape[-1] // block * block
    x = x[..., :h, :w]
    return x.reshape(*x.shape[:-2], h // block, block, w // block, block).sum(axis=(-3, -1))


def pixel_variance(renders: np.ndarray) -> np.ndarray:
    """(R, H, W) replicate renders -> (H, W) variance of one render's pixel (ddof 1)."""
    return renders.var(axis=0, ddof=1)


def noise_ratio(variance_ember: float, variance_cycles: float) -> float:
    """Ember's noise over Cycles' from their summed variances; 1 when neither has any."""
    if variance_cycles > 0:
        return float(np.sqrt(variance_ember / variance_cycles))
    return 1.0 if variance_ember == 0 else float("inf")


def compare(cycles: np.ndarray, ember: np.ndarray) -> Comparison:
    """cycles, ember : (R, H, W, 4) replicate renders with different seeds, R >= 2 each."""
    c, e = grey(cycles), grey(ember)
    rc, re_ = len(c), len(e)
    n = BLOCK * BLOCK
    mean_c, mean_e = c.mean(axis=0), e.mean(axis=0)
    var_c, var_e = pixel_variance(c), pixel_variance(e)
    # Noise of one render's block mean: pixels are independent (each has its own sample sequence).
    block_var_c, block_var_e = block_sums(var_c) / n**2, block_sums(var_e) / n**2
    block_c = block_sums(mean_c) / n
    difference = block_sums(mean_e) / n - block_c
    floor = (NOISE_FLOOR_RELATIVE * np.abs(block_c)) ** 2 + 1e-30
    sigma_c = np.sqrt(np.maximum(block_var_c, floor))
    sigma_diff = np.sqrt(np.maximum(block_var_c / rc + block_var_e / re_, floor))
    block_z = difference / sigma_diff
    # A noise-free block (a plain background) that agrees says nothing about the renders: counting it would
    # pull the percentiles toward 0 in proportion to how much of the frame is empty.
    equal = (block_var_c / rc + block_var_e / re_ <= floor) & (difference**2 <= floor)
    counted = ~equal if (~equal).any() else np.ones_like(equal)
    whole_c, whole_e = mean_c.mean(), mean_e.mean()
    pixels = c.shape[1] * c.shape[2]
    # Floored as the blocks are: two noise-free images (a plain background) that differ by float rounding agree.
    whole_se = max(np.sqrt(var_c.sum() / rc + var_e.sum() / re_) / pixels, NOISE_FLOOR_RELATIVE * abs(mean_c.mean()))
    if whole_c > 0:
        mean_relative, mean_relative_se = whole_e / whole_c - 1.0, whole_se / whole_c
    else:  # a black Cycles image (nothing the camera sees is lit): Ember's must be black too
        mean_relative, mean_relative_se = (0.0 if whole_e == 0 else float("inf")), 0.0
    return Comparison(
        mean_relative=float(mean_relative), mean_relative_se=float(mean_relative_se),
        p90_over_cycles_noise=float(np.percentile((np.abs(difference) / sigma_c)[counted], 90)),
        p90_z=float(np.percentile(np.abs(block_z)[counted], 90)),
        noise_ratio=noise_ratio(block_var_e.sum(), block_var_c.sum()),
        block_z=block_z, blocks_counted=int(counted.sum()), blocks_equal=int(equal.sum()))


# ====================================================================== pictures
def to_display(linear: np.ndarray) -> np.ndarray:
    """Linear RGB (H, W, 3) -> sRGB-encoded uint8."""
    x = np.clip(np.nan_to_num(linear, nan=0.0, posinf=1.0), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(srgb * 255).astype(np.uint8)


def heat_map(block_z: np.ndarray, backdrop: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: the blocks' signed z (red: Ember brighter, blue: darker) over a dim grey backdrop
    (H, W, 3 uint8, the Cycles image)."""
    h, w = backdrop.shape[:2]
    base = backdrop.astype(np.float64).mean(axis=-1, keepdims=True) / 255 * 0.35
    heat = np.repeat(base, 3, axis=-1)
    strength = np.clip(block_z / HEAT_FULL_Z, -1.0, 1.0)
    per_pixel = np.kron(strength, np.ones((BLOCK, BLOCK)))
    bh, bw = per_pixel.shape
    region = heat[:bh, :bw]
    region[..., 0] += np.clip(per_pixel, 0, None)
    region[..., 2] += np.clip(-per_pixel, 0, None)
    region[..., 1] += 0.25 * np.abs(per_pixel) ** 2   # a brighter core where the difference is largest
    return np.round(np.clip(heat, 0, 1) * 255).astype(np.uint8)


def side_by_side(cycles: np.ndarray, ember: np.ndarray, block_z: np.ndarray, gap: int = 2) -> np.ndarray:
    """Cycles | Ember | heat map, (H, 3 W + 2 gap, 3) uint8, from the renders' means (H, W, 3) linear."""
    left, middle = to_display(cycles), to_display(ember)
    spacer = np.full((left.shape[0], gap, 3), 255, np.uint8)
    return np.concatenate([left, spacer, middle, spacer, heat_map(block_z, left)], axis=1)


def write_png(path: str, rgb: np.ndarray) -> None:
    """An 8-bit RGB PNG of (H, W, 3) uint8, row 0 at the top."""
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[row].tobytes() for row in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))


# ====================================================================== one file, the table
@dataclass
class FileResult:
    name: str
    saved_by: str = "?"
    size: tuple = ()
    comparison: Comparison | None = None
    time_ratio: float = float("nan")
    warnings: list = field(default_factory=list)
    lacking: list = field(default_factory=list)
    mapped: dict = field(default_factory=dict)
    missing_images: int = 0
    camera_added: bool = False
    failure: str | None = None
    png: str | None = None

    @property
    def verdict(self) -> str:
        if self.failure:
            return "failed"
        return "beyond noise" if self.comparison.beyond_noise else "within noise"


def failures_of(cycles: EngineRun, ember: EngineRun) -> list[str]:
    """Why the two runs cannot be compared, if they cannot."""
    failures = [f"{name}: {run.error}" for name, run in (("Cycles", cycles), ("Ember", ember)) if run.error]
    if failures:
        return failures
    bad = int((~np.isfinite(ember.images[..., :3])).any(axis=-1).sum())
    if bad:
        return [f"Ember: {bad} pixels are not finite numbers"]
    if cycles.images.shape != ember.images.shape:
        return [f"the engines' images differ in size: {cycles.images.shape} and {ember.images.shape}"]
    if min(cycles.images.shape[1:3]) < BLOCK:
        return [f"the image is under {BLOCK} pixels high or wide: raise --long-side"]
    return []


def compare_file(path: str, args) -> FileResult:
    result = FileResult(file_label(path, args.folder))
    with tempfile.TemporaryDirectory() as workdir:
        cycles = render_file(path, "CYCLES", args, workdir)
        ember = render_file(path, "EMBER", args, workdir)
    result.warnings = ember.warnings + [f"error: {e}" for e in ember.errors]
    meta = ember.meta or cycles.meta
    result.saved_by, result.size = meta.get("saved_by", "?"), tuple(meta.get("size", ()))
    result.lacking, result.mapped = ember.meta.get("lacking", []), ember.meta.get("mapped", {})
    result.missing_images = len(meta.get("missing_images", []))
    result.camera_added = bool(meta.get("camera_added"))
    failures = failures_of(cycles, ember)
    if failures:
        result.failure = "; ".join(failures)
        return result
    result.comparison = compare(cycles.images, ember.images)
    result.time_ratio = float(np.mean(ember.seconds) / np.mean(cycles.seconds))
    mean_c, mean_e = (run.images[..., :3].astype(np.float64).mean(axis=0) for run in (cycles, ember))
    result.png = os.path.join(args.output, os.path.splitext(result.name)[0].replace("/", "_") + ".png")
    write_png(result.png, side_by_side(mean_c, mean_e, result.comparison.block_z))
    return result


def report_lines(r: FileResult, samples: int) -> list[str]:
    size = "x".join(map(str, r.size)) if r.size else "?"
    lines = [f"{r.name} (saved by Blender {r.saved_by}, {size} px, {samples} spp x 2 seeds per engine)"]
    if r.camera_added:
        lines.append("  saved without a camera: seen by one added to frame it (bench/corpus_render.py frame_camera)")
    if r.failure:
        lines.append(f"  FAILED: {r.failure}")
    else:
        c = r.comparison
        lines += [f"  image mean: Ember/Cycles - 1 = {c.mean_relative:+.2%} (standard error {c.mean_relative_se:.2%})",
                  f"  {c.blocks_counted} 8x8 blocks ({c.blocks_equal} more noise-free and equal): 90th percentile of "
                  f"|difference| / Cycles' noise = {c.p90_over_cycles_noise:.2f} (no difference: about 1.64); over "
                  f"the difference's noise {c.p90_z:.2f}",
                  f"  Ember's noise / Cycles' = {c.noise_ratio:.2f}; time Ember / Cycles = {r.time_ratio:.1f}"]
    if r.mapped:
        lines.append("  Ember uses the file's " + ", ".join(f"{k}={v}" for k, v in r.mapped.items()))
    lines.append("  Ember lacks: " + (", ".join(r.lacking) if r.lacking else "nothing the file sets"))
    if r.missing_images:
        lines.append(f"  images missing from the file's folder: {r.missing_images} "
                     f"(both engines render them as missing)")
    lines.append(f"  Ember's warnings ({len(r.warnings)})" + (":" if r.warnings else ""))
    lines += [f"    - {w}" for w in r.warnings]
    lines.append(f"  verdict: {r.verdict}" + (f"  -> {r.png}" if r.png else ""))
    return lines


def summary_table(results: list[FileResult], args) -> str:
    head = (f"Ember vs Cycles on {len(results)} .blend files as saved: long side {args.long_side} px, "
            f"{args.samples} spp x 2 seeds per engine, {args.threads} threads, no denoising or adaptive sampling.\n"
            f"p90 = 90th percentile over 8x8 blocks of |Ember - Cycles| / Cycles' noise (about 1.64 when they "
            f"agree); p90 both = the same over the difference's noise (both engines'); verdict: beyond noise when "
            f"p90 both > {P90_LIMIT} or the image mean differs by more than {WHOLE_Z_LIMIT:g} standard errors.\n"
            + (f"Settings changed in both engines: {', '.join(args.set)}.\n" if args.set else "") + "\n")
    rows = ["| file | Blender | mean Ember/Cycles - 1 | p90 | p90 both | noise E/C | time E/C | warnings | Ember lacks "
            "| verdict |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        lacks = ", ".join(r.lacking) or "-"
        if r.failure:
            rows.append(f"| {r.name} | {r.saved_by} | - | - | - | - | - | {len(r.warnings)} | {lacks} | "
                        f"failed: {r.failure.replace('|', '/')} |")
            continue
        c = r.comparison
        rows.append(f"| {r.name} | {r.saved_by} | {c.mean_relative:+.2%} ± {c.mean_relative_se:.2%} | "
                    f"{c.p90_over_cycles_noise:.2f} | {c.p90_z:.2f} | {c.noise_ratio:.2f} | {r.time_ratio:.1f} | "
                    f"{len(r.warnings)} | "
                    f"{lacks} | {r.verdict} |")
    notes = [f"- {r.name}: " + "; ".join(r.warnings) for r in results if r.warnings]
    return head + "\n".join(rows) + ("\n\nEmber's warnings:\n" + "\n".join(notes) if notes else "") + "\n"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description="Render every .blend in a folder with Cycles and Ember, as "
                                                 "saved, and compare them.")
    parser.add_argument("folder", help="folder holding .blend files")
    parser.add_argument("-r", "--recursive", action="store_true",
                        help="also the .blend files in its subfolders (a collection of repositories, each file "
                             "beside the images it links: they are opened where they lie), named by their path")
    parser.add_argument("-o", "--output", default=os.path.join("out", "corpus"),
                        help="where the side-by-side PNGs and summary.md go (default: out/corpus)")
    parser.add_argument("--samples", type=int, default=32, help="samples per pixel of each render (default 32)")
    parser.add_argument("--long-side", type=int, default=160, help="long side of the image in pixels (default 160)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first render; the second uses seed + 1")
    parser.add_argument("--threads", type=int, default=2, help="render threads (default 2)")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per file and engine (default 600)")
    parser.add_argument("--only", help="only files whose name contains this")
    parser.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                        help="for investigations: change a scene setting in both engines before anything else "
                             "(Ember then takes it over like the file's own), e.g. cycles.diffuse_bounces=1024; "
                             "repeatable")
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if not os.path.isdir(args.folder):
        print(f"corpus: error: no such folder: {args.folder}", file=sys.stderr)
        return 2
    if args.samples < 1 or args.long_side < 8 or args.threads < 1 or args.timeout <= 0:
        print("corpus: error: --samples and --threads must be at least 1, --long-side at least 8, --timeout "
              "positive", file=sys.stderr)
        return 2
    files = blend_files(args.folder, args.only, args.recursive)
    if not files:
        print(f"corpus: error: no .blend files in {args.folder}", file=sys.stderr)
        return 2
    os.makedirs(args.output, exist_ok=True)
    results, start = [], time.perf_counter()
    for path in files:
        result = compare_file(path, args)
        results.append(result)
        print("\n".join(report_lines(result, args.samples)), flush=True)
    table = summary_table(results, args)
    with open(os.path.join(args.output, "summary.md"), "w") as f:
        f.write(table)
    print(f"\n{table}\n{len(files)} files in {time.perf_counter() - start:.0f} s; images in {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
