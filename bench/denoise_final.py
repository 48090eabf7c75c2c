"""The final render's denoise through the command line: its time next to the render's, and the process's
peak memory with and without it.

    .venv/bin/python bench/denoise_final.py [--resolution 1920x1080 2000x2000] [--samples N]
                                            [--time-limit S] [--interrupt-after S] [--no-plain]

Each resolution renders the demo scene with `python -m ember render` in a child process, with the file's
settings (denoising on: HIGH quality, ACCURATE prefilter, albedo and normal, Cycles' defaults), and once
with --no-denoise (--no-plain skips it). Printed per run: the render's time (its own 'done' line), the
denoise's (from its first progress line to the 'done' line, which follows the denoise), the wall time, and
the child's peak resident memory (os.wait4's ru_maxrss). --time-limit renders with that limit (the fast
denoise); --interrupt-after sends Ctrl-C that many seconds into the denoise (peak memory of an image too
large to wait for: a tiled denoise reaches its peak in its first tile).
"""
from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DONE = re.compile(r"(done|stopped|cancelled): (\d+)/(\d+) samples in (?:(\d+):)?(\d+):([\d.]+)")


def seconds(match) -> float:
    hours, minutes, secs = match.group(4), match.group(5), match.group(6)
    return int(hours or 0) * 3600 + int(minutes) * 60 + float(secs)


def run(resolution: str, extra: list[str], interrupt_after: float | None) -> dict:
    """One render in a child process: its times (s) and peak RSS (GB)."""
    with tempfile.TemporaryDirectory() as tmp:
        command = [sys.executable, "-m", "ember", "render", "--resolution", resolution,
                   "-o", os.path.join(tmp, "frame.exr"), *extra]
        start = time.perf_counter()
        child = subprocess.Popen(command, stdout=subprocess.PIPE,
                                 stderr=subprocess.STDOUT, text=True)
        figures = {"denoise_start": None, "done_at": None, "render_s": None, "samples": "", "lines": []}
        for line in child.stdout:
            now = time.perf_counter() - start
            figures["lines"].append(line.rstrip())
            if "| Denoising" in line and figures["denoise_start"] is None:
                figures["denoise_start"] = now
                if interrupt_after is not None:
                    signal_at = now + interrupt_after
                    figures["signal_at"] = signal_at
            match = DONE.search(line)
            if match:
                figures["done_at"], figures["render_s"] = now, seconds(match)
                figures["samples"] = f"{match.group(2)}/{match.group(3)}"
            if figures.get("signal_at") is not None and now >= figures["signal_at"]:
                child.send_signal(signal.SIGINT)
                figures["signal_at"] = None
        _, status, usage = os.wait4(child.pid, 0)
        figures["wall_s"] = time.perf_counter() - start
        figures["status"] = os.waitstatus_to_exitcode(status)
        figures["peak_gb"] = usage.ru_maxrss * 1024 / 1e9     # Linux reports kB
        end = figures["done_at"] if figures["done_at"] is not None else figures["wall_s"]
        figures["denoise_s"] = end - figures["denoise_start"] if figures["denoise_start"] is not None else 0.0
        return figures


def show(label: str, f: dict) -> None:
    render = f"{f['render_s']:7.1f} s" if f["render_s"] is not None else "      -  "
    share = f["denoise_s"] / (f["denoise_s"] + f["render_s"]) if f["render_s"] and f["denoise_s"] else 0.0
    print(f"  {label:24s} samples {f['samples']:>9s}  render {render}  denoise {f['denoise_s']:7.1f} s "
          f"({share:4.0%} of both)  wall {f['wall_s']:7.1f} s  peak RSS {f['peak_gb']:5.2f} GB  exit {f['status']}",
          flush=True)
    if f["status"] == 130:   # interrupted: how far the denoise had come
        print("   ", next((line for line in reversed(f["lines"]) if "| Denoising" in line), ""))
    elif f["status"] != 0:
        print("\n".join(f["lines"][-5:]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", nargs="+", default=["1920x1080", "2000x2000"])
    ap.add_argument("--samples", type=int, help="samples per pixel (default: the demo's)")
    ap.add_argument("--time-limit", type=float, help="also render with this time limit")
    ap.add_argument("--interrupt-after", type=float, help="Ctrl-C this many seconds into the denoise")
    ap.add_argument("--no-plain", action="store_true", help="skip the --no-denoise run")
    args = ap.parse_args()
    extra = ["--samples", str(args.samples)] if args.samples else []
    print(f"python -m ember render (the demo scene), {os.cpu_count()} cores")
    for resolution in args.resolution:
        print(resolution)
        show("denoised (scene's)", run(resolution, extra, args.interrupt_after))
        if args.time_limit:
            show(f"time limit {args.time_limit:g} s", run(resolution, extra + ["--time-limit", str(args.time_limit)],
                                                          args.interrupt_after))
        if not args.no_plain:
            show("--no-denoise", run(resolution, extra + ["--no-denoise"], None))


if __name__ == "__main__":
    main()
