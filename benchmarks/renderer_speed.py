"""Neural renderer speed: ms per frame for raster + features + network, streaming playback.

Usage: ``python benchmarks/renderer_speed.py [--sizes 128 256 512] [--presets cpu paper]
[--threads 1 2] [--frames 12] [--device cpu]``

A synthetic skirt proxy (about 2k vertices) sways over a cylinder body; the camera frames the
body so the garment covers about as much of the image as in the data set. Each frame is one
``NeuralRenderer.render`` call (random weights: speed does not depend on them), which
rasterizes the proxy, makes UV and motion-feature maps, samples the texture, encodes frame t
once (t-1's latent is reused), decodes and pastes over the background. ``raster+feat`` times
the scene build, rasterization and feature maps alone; ``network`` is the rest. Prints one row
per (preset, size, threads), the crop size and the load average (the machine may be shared).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from core.camera import crop_camera, make_camera
from core.features import joint_window
from training.renderer import PRESETS, FrameState, NeuralRenderer, RenderNet, synthetic_scene


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[128, 256, 512])
    p.add_argument("--presets", nargs="+", default=["cpu", "paper"])
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    p.add_argument("--frames", type=int, default=12, help="timed frames (after 2 warm-up)")
    p.add_argument("--resolution", type=int, default=64, help="proxy columns (2k vertices)")
    p.add_argument("--device", default="cpu")
    args = p.parse_args()

    n = args.frames + 2
    scene = synthetic_scene(n, resolution=args.resolution, seed=0)
    print(f"proxy: {scene.proxy.shape[1]} vertices, {len(scene.faces)} faces; device {args.device}")
    print(f"load average before: {os.getloadavg()[0]:.2f} (cores: {os.cpu_count()})")
    header = (
        f"{'preset':>6} {'size':>5} {'thr':>3} {'crop':>9} {'raster+feat':>11} "
        f"{'network':>8} {'total ms':>8} {'fps':>6} {'load':>5}"
    )
    print(header)
    for name in args.presets:
        for size in args.sizes:
            for threads in args.threads:
                torch.set_num_threads(threads)
                torch.manual_seed(0)
                r = NeuralRenderer(
                    RenderNet(PRESETS[name]), scene.faces, scene.uvs, device=args.device
                )
                cam = make_camera((0.0, 0.85, 2.2), (0.0, 0.75, 0.0), width=size, height=size)
                bg = np.full((size, size, 3), 200, np.uint8)
                frames = [
                    FrameState(scene.proxy[t], joint_window(scene.joints, t), bg) for t in range(n)
                ]
                total, feat = [], []
                for t, f in enumerate(frames):
                    t0 = time.perf_counter()
                    r.render(cam, f)
                    if args.device.startswith("cuda"):
                        torch.cuda.synchronize()
                    t1 = time.perf_counter()
                    # raster + features alone, on a fresh scene (as render does per new frame)
                    box = r.crop_box(cam, f)
                    crop = crop_camera(cam, box.x0, box.y0, box.width, box.height)
                    g = FrameState(f.vertices.copy(), f.window, bg)
                    t2 = time.perf_counter()
                    with torch.no_grad():
                        r.features(r._frame_data(g), crop)
                    t3 = time.perf_counter()
                    if t >= 2:
                        total.append(t1 - t0)
                        feat.append(t3 - t2)
                ms, fm = 1e3 * np.median(total), 1e3 * np.median(feat)
                print(
                    f"{name:>6} {size:>5} {threads:>3} {box.width:>4}x{box.height:<4} "
                    f"{fm:>11.1f} {ms - fm:>8.1f} {ms:>8.1f} {1e3 / ms:>6.1f} "
                    f"{os.getloadavg()[0]:>5.2f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
