"""Joint2Coarse accuracy on the synthetic skirt: does each stage help, and on unseen motion?

Usage: ``python benchmarks/joint2coarse_synthetic.py [--frames 600] [--steps 1500 1500 800]
[--output-basis K] [--rings 6 --around 20] [--paper-widths]``

Trains on two synthetic walks (``training.joint2coarse.synthetic``; last 15 % of each held
out), then predicts a third walk it never saw. Prints the per-vertex error (mean and 95th
percentile, mm) of the mean-shape baseline and of the model after each stage, on validation
frames and on the unseen walk (the motion-stage model is saved aside to compare with the
fine-tuned one), and how far the float32 and bfloat16 streams stray from batch prediction.
``--output-basis`` (default: the config's) compares the output basis with the full last
layer (0); ``--rings``/``--around`` size the skirt (20 x 100 = 2000 vertices);
``--paper-widths`` uses the paper's network sizes instead of the small ones.
"""

from __future__ import annotations

import argparse
import os
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
    tilt_rotvecs,
    to_output_frame,
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
    parser.add_argument("--output-basis", type=int, default=Joint2CoarseConfig().output_basis,
                        help="output basis size (0: the full last layer)")  # fmt: skip
    parser.add_argument("--rings", type=int, default=6, help="skirt vertex rings")
    parser.add_argument("--around", type=int, default=20, help="skirt vertices per ring")
    parser.add_argument("--paper-widths", action="store_true",
                        help="the paper's network sizes (default: small ones for 120 vertices)")  # fmt: skip
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    size = {"rings": args.rings, "around": args.around}
    clips = [
        Joint2CoarseClip(*synthetic_clip(args.frames, s, **size), name=f"walk-{s}") for s in (0, 1)
    ]
    test_joints, test_rot, test_proxy = synthetic_clip(args.frames, seed=5, **size)
    schedule = dict(
        batch_size=64, autoencoder_steps=args.steps[0], motion_steps=args.steps[1],
        finetune_steps=args.steps[2], seed=args.seed, eval_every=250, checkpoint_every=500,
        output_basis=args.output_basis,
    )  # fmt: skip
    if args.paper_widths:
        config = Joint2CoarseConfig(**schedule)
    else:
        config = Joint2CoarseConfig(
            window=16, stride=2, encoder_widths=(256, 128, 64), latent_dim=16,
            motion_widths=(256, 128, 64), min_width=16, width_reference_vertices=120, **schedule,
        )  # fmt: skip
    print(f"{len(clips)} walks x {args.frames} frames, Vc={clips[0].proxy.shape[1]}, {config}")
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
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
    heading = heading_rotations(test_rot)
    frame = (test_joints[:, 0], heading, tilt_rotvecs(test_rot, heading), res.net.follow_weights())
    local = to_output_frame(test_proxy, *frame)
    mean = res.net.vert_mean.numpy().reshape(1, -1, 3)
    e = vertex_errors(np.broadcast_to(mean, local.shape), local)
    print(f"unseen walk, mean shape baseline: {e.mean_mm:.2f} mm mean, {e.p95_mm:.2f} mm p95")
    if res.net.n_basis:  # the best any prediction through the basis can do
        b = res.net.shape_decoder[-1].basis.numpy().astype(np.float64)
        b = b[(b**2).sum(1) > 0]
        b /= np.linalg.norm(b, axis=1, keepdims=True)  # orthonormal rows: a projection
        std = res.net.vert_std.numpy().astype(np.float64)
        z = (local.reshape(len(local), -1) - mean.reshape(1, -1)) / std
        floor = (z @ b.T @ b) * std + mean.reshape(1, -1)
        e = vertex_errors(floor.reshape(local.shape), local)
        print(
            f"unseen walk projected onto the {res.net.n_basis}-component output basis: "
            f"{e.mean_mm:.2f} mm mean, {e.p95_mm:.2f} mm p95 (the floor of the basis)"
        )
    for name, r in (("motion stage only", no_ft), ("with fine-tune", res)):
        pred = predict_proxy(r.net, test_joints, test_rot)
        e = vertex_errors(pred, test_proxy)
        print(f"unseen walk, {name}: {e.mean_mm:.2f} mm mean, {e.p95_mm:.2f} mm p95")
    for half in (False, True):
        stream = Joint2CoarseStream(res.net, bfloat16=half)
        frames = np.stack([stream.push(j, r) for j, r in zip(test_joints, test_rot)])
        e = vertex_errors(frames, pred)
        print(
            f"{'bfloat16' if half else 'float32'} stream vs float32 batch: "
            f"{e.mean_mm:.4f} mm mean, {e.max_mm:.4f} mm max"
        )


if __name__ == "__main__":
    main()
