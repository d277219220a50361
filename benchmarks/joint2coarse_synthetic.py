"""Joint2Coarse accuracy on the synthetic skirt: does each stage help, and on unseen motion?

Usage: ``python benchmarks/joint2coarse_synthetic.py [--frames 600] [--steps 1500 1500 800]``

Trains on two synthetic walks (``training.joint2coarse.synthetic``; last 15 % of each held
out), then predicts a third walk it never saw. Prints the per-vertex error (mean and 95th
percentile, mm) of the mean-shape baseline and of the model after each stage, on validation
frames and on the unseen walk (the motion-stage model is saved aside to compare with the
fine-tuned one), and how far the bfloat16 stream strays from float32.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from training.joint2coarse import (
    Joint2CoarseClip,
    Joint2CoarseConfig,
    Joint2CoarseStream,
    heading_rotations,
    predict_proxy,
    to_root_frame,
    train_joint2coarse,
    vertex_errors,
)
from training.joint2coarse.synthetic import synthetic_clip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=600, help="frames per training walk")
    parser.add_argument("--steps", type=int, nargs=3, default=[1500, 1500, 800],
                        help="autoencoder, motion and fine-tune steps")  # fmt: skip
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    clips = [Joint2CoarseClip(*synthetic_clip(args.frames, s), name=f"walk-{s}") for s in (0, 1)]
    test_joints, test_rot, test_proxy = synthetic_clip(args.frames, seed=5)
    config = Joint2CoarseConfig(
        window=16, stride=2, encoder_widths=(256, 128, 64), latent_dim=16,
        motion_widths=(256, 128, 64), min_width=16, width_reference_vertices=120,
        batch_size=64, autoencoder_steps=args.steps[0], motion_steps=args.steps[1],
        finetune_steps=args.steps[2], seed=args.seed, eval_every=250, checkpoint_every=500,
    )  # fmt: skip
    print(f"{len(clips)} walks x {args.frames} frames, Vc={clips[0].proxy.shape[1]}, {config}")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        no_ft = train_joint2coarse(clips, Path(tmp) / "a", replace(config, finetune_steps=0),
                                   progress=False)  # fmt: skip
        res = train_joint2coarse(clips, Path(tmp) / "b", config, progress=False)
        print(f"trained twice in {time.perf_counter() - t0:.1f} s")
    print(f"validation, mean shape baseline: {res.baseline.mean_mm:.2f} mm mean, "
          f"{res.baseline.p95_mm:.2f} mm p95")  # fmt: skip
    for stage, e in res.stage_errors.items():
        print(f"validation after {stage}: {e.mean_mm:.2f} mm mean, {e.p95_mm:.2f} mm p95")
    local = to_root_frame(test_proxy, test_joints[:, 0], heading_rotations(test_rot))
    mean = res.net.vert_mean.numpy().reshape(1, -1, 3)
    e = vertex_errors(np.broadcast_to(mean, local.shape), local)
    print(f"unseen walk, mean shape baseline: {e.mean_mm:.2f} mm mean, {e.p95_mm:.2f} mm p95")
    for name, r in (("motion stage only", no_ft), ("with fine-tune", res)):
        pred = predict_proxy(r.net, test_joints, test_rot)
        e = vertex_errors(pred, test_proxy)
        print(f"unseen walk, {name}: {e.mean_mm:.2f} mm mean, {e.p95_mm:.2f} mm p95")
    stream = Joint2CoarseStream(res.net, bfloat16=True)
    half = np.stack([stream.push(j, r) for j, r in zip(test_joints, test_rot)])
    e = vertex_errors(half, pred)
    print(f"bfloat16 stream vs float32 batch: {e.mean_mm:.3f} mm mean, {e.max_mm:.3f} mm max")


if __name__ == "__main__":
    main()
