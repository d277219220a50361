"""Neural renderer speed: ms per frame for raster + features + network, streaming playback.

Usage: ``python benchmarks/renderer_speed.py [--sizes 128 256 512] [--presets cpu paper]
[--threads 1 2] [--frames 12] [--device cpu]``

The measurement lives in :mod:`app.bench.render` (``dng bench render``, which also takes a
trained project and writes JSON): a synthetic skirt proxy (about 2k vertices) sways over a
flat background; the camera frames it as in the data set. Each frame is one streaming
``NeuralRenderer.render`` call (random weights: speed does not depend on them) after a
Joint2Coarse streaming step; ``raster+feat`` times the scene build, rasterization and feature
maps alone; ``network`` is the rest. Prints one row per (preset, size, threads), the crop size
and the load average (the machine may be shared).
"""

from __future__ import annotations

import argparse
import os

from app.bench.render import HEADER, WARMUP, format_row, measure, synthetic_setup


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[128, 256, 512])
    p.add_argument("--presets", nargs="+", default=["cpu", "paper"])
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    p.add_argument("--frames", type=int, default=12, help="timed frames (after 2 warm-up)")
    p.add_argument("--resolution", type=int, default=64, help="proxy columns (2k vertices)")
    p.add_argument("--device", default="cpu")
    args = p.parse_args()

    setup = synthetic_setup(args.frames + WARMUP, args.resolution)
    print(f"proxy: {setup.proxy.shape[1]} vertices, {len(setup.faces)} faces; device {args.device}")
    print(f"load average before: {os.getloadavg()[0]:.2f} (cores: {os.cpu_count()})")
    print(HEADER)
    measure(
        setup, args.presets, args.sizes, args.threads, args.device,
        report=lambda r: print(format_row(r), flush=True),
    )  # fmt: skip


if __name__ == "__main__":
    main()
