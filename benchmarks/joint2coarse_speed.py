"""Joint2Coarse inference speed on CPU: streaming latency per frame and batched throughput.

Usage: ``python benchmarks/joint2coarse_speed.py [--vertices 2000] [--frames 600]``

Times the paper-sized network (widths at full size for 2048+ vertices) with random weights:
speed does not depend on what the weights are. Runs under ``torch.inference_mode`` with 1 and
then 2 threads (streaming in float32 and bfloat16, batched in float32), then times a few
training steps of each stage; prints one line per measurement.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import replace

import numpy as np
import torch

from training.joint2coarse import (
    Joint2CoarseClip,
    Joint2CoarseConfig,
    Joint2CoarseStream,
    predict_proxy,
    train_joint2coarse,
)
from training.joint2coarse.descriptor import joint2coarse_inputs
from training.joint2coarse.model import Joint2CoarseNet
from training.joint2coarse.synthetic import synthetic_clip, synthetic_walk


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vertices", type=int, default=2000, help="proxy vertex count Vc")
    parser.add_argument("--frames", type=int, default=600, help="frames of the test clip")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument(
        "--encoder-widths", type=int, nargs="+", default=None,
        help="shape encoder widths (decoder mirrors them); default: the paper's",
    )  # fmt: skip
    parser.add_argument(
        "--train-steps", type=int, default=20,
        help="also time this many training steps per stage (0: skip)",
    )  # fmt: skip
    args = parser.parse_args()

    config = Joint2CoarseConfig()
    if args.encoder_widths:
        config = replace(config, encoder_widths=tuple(args.encoder_widths))
    torch.manual_seed(0)
    net = Joint2CoarseNet(config, args.vertices, config.num_samples * 57).eval()
    joints, root_rot = joint2coarse_inputs(synthetic_walk(args.frames, seed=0))
    params = sum(p.numel() for p in net.motion_encoder.parameters())
    params += sum(p.numel() for p in net.shape_decoder.parameters())
    print(f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    print(
        f"Vc={args.vertices} descriptor={net.descriptor_dim} "
        f"shape widths={config.shape_widths(args.vertices)} inference params={params}"
    )
    for threads in args.threads:
        torch.set_num_threads(threads)
        for half in (False, True):
            stream = Joint2CoarseStream(net, bfloat16=half)
            for f in range(50):  # warm-up
                stream.push(joints[f], root_rot[f])
            stream.reset()
            times = np.empty(args.frames)
            for f in range(args.frames):
                t0 = time.perf_counter()
                stream.push(joints[f], root_rot[f])
                times[f] = time.perf_counter() - t0
            ms = times * 1e3
            print(
                f"threads={threads} streaming {'bfloat16' if half else 'float32'}: "
                f"median {np.median(ms):.3f} ms/frame, p95 {np.percentile(ms, 95):.3f} ms, "
                f"min {ms.min():.3f} ms ({args.frames} frames)"
            )
        for batch in (64, 256):
            predict_proxy(net, joints[:batch], root_rot[:batch], batch_size=batch)
            best = np.inf
            for _ in range(3):
                t0 = time.perf_counter()
                predict_proxy(net, joints, root_rot, batch_size=batch)
                best = min(best, time.perf_counter() - t0)
            print(
                f"threads={threads} batched (batch {batch}): {best / args.frames * 1e3:.3f} ms/frame, "
                f"{args.frames / best:.0f} frames/s (best of 3, {args.frames} frames)"
            )
    print(f"load average after inference: {os.getloadavg()[0]:.2f}")
    if args.train_steps:
        _time_training(config, args.vertices, args.train_steps, args.threads[0])


def _time_training(base: Joint2CoarseConfig, n_vertices: int, steps: int, threads: int) -> None:
    """Milliseconds per step of each stage of ``base`` on a synthetic skirt of ~n_vertices."""
    torch.set_num_threads(threads)
    around = 100
    rings = max(2, round(n_vertices / around))
    clip = Joint2CoarseClip(*synthetic_clip(300, 0, rings=rings, around=around), name="skirt")
    big = 10**9
    config = replace(
        base, autoencoder_steps=steps, motion_steps=steps, finetune_steps=steps,
        eval_every=big, checkpoint_every=big, log_every=big,
    )  # fmt: skip
    stamps: dict[str, list[float]] = {}

    def tick(step: int, stage: str, loss: float) -> None:
        stamps.setdefault(stage, []).append(time.perf_counter())

    with tempfile.TemporaryDirectory() as tmp:
        train_joint2coarse([clip], tmp, config, progress=False, callback=tick)
    for stage, ts in stamps.items():
        per = (ts[-1] - ts[0]) / (len(ts) - 1)
        print(
            f"threads={threads} training, Vc={rings * around}, batch "
            f"{config.batch_size}, stage {stage}: {per * 1e3:.1f} ms/step"
        )


if __name__ == "__main__":
    main()
