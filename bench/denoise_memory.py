"""The memory a tiled denoise takes, by image size: flat once an image is tiled.

    .venv/bin/python bench/denoise_memory.py [--sizes 1024 2160 4000 8000] [--quality HIGH] [--tiles 2]

Each size runs in a child process: denoise.denoise_image over a synthetic square image (noise around a
gradient, albedo and normal, every window made when read and every tile dropped when written, so that
nothing but the denoise holds memory), stopped through its progress callback once --tiles tiles are written
(every window of an image is at most the size of its largest ones, so the peak is reached by then). Printed:
the child's peak resident memory above what it held with OIDN loaded and its device made, and the number
of tiles. --whole also runs, to its end, OIDN over the whole arrays (tile_pixels above the image's size:
OIDN then tiles by itself, as Ember's denoise did before it tiled), whose inputs and outputs are whole.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def child(size: int, quality: str, tiles: int, whole: bool) -> None:
    sys.path.insert(0, ROOT)
    from bench.common import import_ember
    import_ember()
    import numpy as np
    from ember.engine import denoise as dn

    def peak_kb() -> int:
        with open("/proc/self/status") as status:
            return next(int(line.split()[1]) for line in status if line.startswith("VmHWM"))

    def window(name, rows, cols):
        rng = np.random.default_rng(rows.start * 7919 + cols.start)
        shape = (rows.stop - rows.start, cols.stop - cols.start, 3)
        base = {"color": 1.0, "albedo": 0.5, "normal": 0.0}[name]
        return (base + 0.3 * rng.standard_normal(shape)).astype(np.float32)

    dn.available()
    dn._device(0, None)
    start = peak_kb()
    written = []
    if whole:
        images = [window(name, slice(0, size), slice(0, size)) for name in ("color", "albedo", "normal")]
        dn.denoise(*images, quality=quality, tile_pixels=size * size)
    else:
        dn.denoise_image(window, size, size, lambda rows, cols, tile: written.append(1),
                         aux=("albedo", "normal"), quality=quality, progress=lambda fraction: len(written) < tiles)
    print(json.dumps({"peak_gb": (peak_kb() - start) * 1024 / 1e9, "tiles": len(written)}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1024, 2160, 4000, 8000])
    ap.add_argument("--quality", default="HIGH")
    ap.add_argument("--tiles", type=int, default=2, help="tiles written before the denoise is stopped")
    ap.add_argument("--whole", action="store_true", help="also the untiled denoise over whole arrays")
    ap.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        size, quality, tiles, whole = args.child
        return child(int(size), quality, int(tiles), whole == "1")
    print(f"denoise_image, {args.quality} quality, ACCURATE prefilter, albedo + normal, stopped after "
          f"{args.tiles} tiles; peak RSS above the loaded library")
    for size in args.sizes:
        for whole in ((False, True) if args.whole else (False,)):
            out = subprocess.run([sys.executable, __file__, "--child", str(size), args.quality, str(args.tiles),
                                  "1" if whole else "0"], capture_output=True, text=True)
            if out.returncode:
                print(f"  {size}x{size}: failed: {out.stderr.strip().splitlines()[-1:]}")
                continue
            figures = json.loads(out.stdout.strip().splitlines()[-1])
            label = "whole arrays (untiled)" if whole else f"tiled, {figures['tiles']} tiles written"
            print(f"  {size:5d}x{size:<5d} {label:26s} peak +{figures['peak_gb']:5.2f} GB", flush=True)


if __name__ == "__main__":
    main()
