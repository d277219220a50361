"""Joint2Coarse inference speed on CPU: streaming latency per frame and batched throughput.

Usage: ``python benchmarks/joint2coarse_speed.py [--vertices 2000] [--frames 600]
[--threads 1 2] [--output-basis 256 0] [--model paper ours] [--mirror] [--members N]``

Our model (``model=ours``: the proxy skinned to the body plus a residual network) is timed
first, streaming and batched, on a synthetic skirt of ``--vertices`` with a random residual of
the config's ``residual_widths`` (``--residual-widths``; none: the linear residual) onto
``residual_basis`` principal components, ``--members`` networks side by side
(``residual_members``); with ``--mirror``, as trained with mirrored clips: it predicts
symmetrically (two passes a frame).

Times the paper-sized network (widths at full size for 2048+ vertices) with random weights
(speed does not depend on what the weights are) and output frames that follow the hips' tilt
(``tilt_follow``: a rotation per vertex per frame), once per ``--output-basis`` (default: the
config's, then 0, the paper's full last layer), with 1 and then 2
threads: streaming (:class:`Joint2CoarseStream`, float32 and bfloat16) and batched
(:func:`predict_proxy`). Prints median and 95th percentile milliseconds per frame, both wall
clock and the thread's CPU time (which other processes on a busy machine inflate less), the
load average around each measurement, and whether streaming meets the 2 ms target (issue #6:
default config, 1 thread, float32, median wall clock). Then times a few training steps of
each stage.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import replace

import numpy as np
import torch

from core.body.shape import BodyShape
from training.joint2coarse import (
    Joint2CoarseClip,
    Joint2CoarseConfig,
    Joint2CoarseStream,
    predict_proxy,
    train_joint2coarse,
)
from training.joint2coarse.augment import mirror_map
from training.joint2coarse.body_model import BodyResidualModel, body_rig, feature_count
from training.joint2coarse.config import FEATURE_FRAMES, MODELS, RESIDUAL_FRAMES
from training.joint2coarse.descriptor import joint2coarse_inputs
from training.joint2coarse.model import Joint2CoarseNet
from training.joint2coarse.synthetic import rest_skirt, skirt_faces, synthetic_clip, synthetic_walk

#: Streaming latency target of issue #6 (milliseconds per frame, median, 1 thread).
TARGET_MS = 2.0


def _load() -> str:
    return f"load {os.getloadavg()[0]:.2f}/{os.cpu_count()} CPUs"


def _summary(wall_s: np.ndarray, cpu_s: np.ndarray) -> str:
    w, c = wall_s * 1e3, cpu_s * 1e3
    return (
        f"median {np.median(w):.3f} ms/frame, p95 {np.percentile(w, 95):.3f} ms "
        f"(CPU time: median {np.median(c):.3f}, p95 {np.percentile(c, 95):.3f} ms)"
    )


def time_stream(net: Joint2CoarseNet, joints, root_rot, bfloat16: bool) -> tuple:
    """Wall and thread-CPU seconds of every :meth:`Joint2CoarseStream.push` over the clip."""
    stream = Joint2CoarseStream(net, bfloat16=bfloat16)
    for f in range(50):  # warm-up
        stream.push(joints[f], root_rot[f])
    stream.reset()
    wall, cpu = np.empty(len(joints)), np.empty(len(joints))
    for f in range(len(joints)):
        t0, c0 = time.perf_counter(), time.thread_time()
        stream.push(joints[f], root_rot[f])
        wall[f], cpu[f] = time.perf_counter() - t0, time.thread_time() - c0
    return wall, cpu


def time_batch(net: Joint2CoarseNet, joints, root_rot, batch: int, repeats: int = 5) -> tuple:
    """Wall and thread-CPU seconds per frame of each of ``repeats`` :func:`predict_proxy` runs."""
    predict_proxy(net, joints[:batch], root_rot[:batch], batch_size=batch)
    wall, cpu = np.empty(repeats), np.empty(repeats)
    for r in range(repeats):
        t0, c0 = time.perf_counter(), time.thread_time()
        predict_proxy(net, joints, root_rot, batch_size=batch)
        wall[r], cpu[r] = time.perf_counter() - t0, time.thread_time() - c0
    return wall / len(joints), cpu / len(joints)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vertices", type=int, default=2000, help="proxy vertex count Vc")
    parser.add_argument("--frames", type=int, default=600, help="frames of the test clip")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument(
        "--output-basis", type=int, nargs="+", default=[Joint2CoarseConfig().output_basis, 0],
        help="output basis sizes to compare (0: the full last layer); default: the config's, 0",
    )  # fmt: skip
    parser.add_argument(
        "--encoder-widths", type=int, nargs="+", default=None,
        help="shape encoder widths (decoder mirrors them); default: the paper's",
    )  # fmt: skip
    parser.add_argument(
        "--model", nargs="+", default=["paper", "ours"], choices=MODELS,
        help="models to time (ours: the skinned base and the residual, model=ours)",
    )  # fmt: skip
    parser.add_argument(
        "--residual-widths", type=int, nargs="*", default=None,
        help="ours: hidden widths of the residual (none given: linear); default: the config's",
    )  # fmt: skip
    parser.add_argument(
        "--mirror", action="store_true",
        help="ours: trained with mirrored clips (mirror=true), so it predicts symmetrically: "
        "the motion and its mirror each frame",
    )  # fmt: skip
    parser.add_argument(
        "--members", type=int, default=1,
        help="ours: residual networks folded into one (residual_members)",
    )  # fmt: skip
    parser.add_argument(
        "--feature-frame", default="heading", choices=FEATURE_FRAMES,
        help="ours: the frame of the residual's motion features (feature_frame)",
    )  # fmt: skip
    parser.add_argument(
        "--residual-frame", default="hips", choices=RESIDUAL_FRAMES,
        help="ours: the frame the residual is predicted in (residual_frame)",
    )  # fmt: skip
    parser.add_argument(
        "--train-steps", type=int, default=20,
        help="also time this many training steps per stage (0: skip)",
    )  # fmt: skip
    args = parser.parse_args()
    if args.members < 1:
        parser.error(f"--members must be at least 1, got {args.members}")

    base = Joint2CoarseConfig()
    if args.encoder_widths:
        base = replace(base, encoder_widths=tuple(args.encoder_widths))
    if args.residual_widths is not None:
        base = replace(base, residual_widths=tuple(args.residual_widths))
    base = replace(
        base,
        residual_members=args.members,
        feature_frame=args.feature_frame,
        residual_frame=args.residual_frame,
    )
    joints, root_rot = joint2coarse_inputs(synthetic_walk(args.frames, seed=0))
    print(f"{_load()} before; torch {torch.__version__}, {args.frames} frames per measurement")
    verdict = None
    if "ours" in args.model:
        net = _ours(base, args.vertices, args.mirror)
        print(
            f"== model=ours: Vc={net.n_vertices}, descriptor {net.descriptor_dim}, "
            f"{len(net.arrays['feat_mean'])} residual features, hidden widths "
            f"{base.residual_widths or 'none (linear)'}"
            + (f" x {base.residual_members} members" if base.residual_widths else "")
            + (", symmetric (mirror=true)" if args.mirror else "")
            + f", features in the {base.feature_frame} frame, residual in the "
            f"{base.residual_frame} frame"
        )
        for threads in args.threads:
            torch.set_num_threads(threads)
            wall, cpu = time_stream(net, joints, root_rot, False)
            print(f"  threads={threads} streaming: {_summary(wall, cpu)}, {_load()}")
            if threads == 1:
                ms = float(np.median(wall)) * 1e3
                met = "MET" if ms < TARGET_MS else "NOT met"
                print(f"  target {TARGET_MS} ms/frame (1 thread, streaming, median): {met}")
            wall, cpu = time_batch(net, joints, root_rot, 256)
            print(f"  threads={threads} batched (batch 256): {_summary(wall, cpu)}, {_load()}")
    if "paper" not in args.model:
        return
    for k in args.output_basis:
        config = replace(base, output_basis=k)
        torch.manual_seed(0)
        net = Joint2CoarseNet(config, args.vertices, config.num_samples * 57).eval()
        # Output frames that follow the hips' tilt, as a trained default model has (the tilt
        # costs a per-vertex rotation per frame; random weights would leave it off).
        net.follow.copy_(torch.linspace(config.tilt_follow, 0.0, args.vertices))
        params = sum(p.numel() for p in net.motion_encoder.parameters())
        params += sum(p.numel() for p in net.shape_decoder.parameters())
        params += sum(b.numel() for b in net.shape_decoder.buffers())
        name = f"output_basis={k}" + (
            " (default)" if k == Joint2CoarseConfig().output_basis else ""
        )
        print(
            f"== {name}: Vc={args.vertices}, descriptor {net.descriptor_dim}, shape widths "
            f"{config.shape_widths(args.vertices)}, basis {net.n_basis}, "
            f"{params / 1e6:.2f} M inference weights ({params * 4 / 2**20:.1f} MiB float32)"
        )
        for threads in args.threads:
            torch.set_num_threads(threads)
            for half in (False, True):
                wall, cpu = time_stream(net, joints, root_rot, half)
                kind = "bfloat16" if half else "float32"
                print(f"  threads={threads} streaming {kind}: {_summary(wall, cpu)}, {_load()}")
                if threads == 1 and not half and k == Joint2CoarseConfig().output_basis:
                    verdict = float(np.median(wall)) * 1e3
            for batch in (64, 256):
                wall, cpu = time_batch(net, joints, root_rot, batch)
                print(
                    f"  threads={threads} batched (batch {batch}): {_summary(wall, cpu)}, "
                    f"{1 / np.median(wall):.0f} frames/s, {_load()}"
                )
    if verdict is not None:
        met = "MET" if verdict < TARGET_MS else "NOT met"
        print(
            f"target {TARGET_MS} ms/frame (default config, 1 thread, float32 streaming, median): "
            f"{met} at {verdict:.3f} ms ({_load()})"
        )
    if args.train_steps:
        for k in args.output_basis:
            _time_training(
                replace(base, output_basis=k), args.vertices, args.train_steps, args.threads[0]
            )


def _ours(base: Joint2CoarseConfig, n_vertices: int, mirror: bool) -> BodyResidualModel:
    """Our model for a synthetic skirt of about ``n_vertices`` vertices, with a random residual
    of the config's ``residual_widths``, ``residual_members`` and ``residual_basis`` (speed does
    not depend on its values); with ``mirror``,
    the skirt's mirror map (the symmetric prediction)."""
    around = 100
    rings = max(2, round(n_vertices / around))
    skirt = rest_skirt(rings, around)
    config = replace(base, model="ours")
    weights, rest_joints, rest_vertices = body_rig(BodyShape(), skirt, config.skin_fade)
    d = config.num_samples * 57
    k = feature_count(config, d)
    rng = np.random.default_rng(0)
    arrays = {
        "weights": weights, "rest_joints": rest_joints, "rest_vertices": rest_vertices,
        "feat_mean": np.zeros(k), "feat_std": np.ones(k),
    }  # fmt: skip
    width, n = k + 1, config.residual_members
    for i, w in enumerate(config.residual_widths):  # members side by side (dense: as fast)
        arrays[f"hidden{i}"] = rng.normal(0.0, width**-0.5, (width, n * w)).astype(np.float32)
        width = n * w + 1
    out = 3 * len(skirt)
    if config.residual_widths:  # onto the principal components and the mean residual
        arrays["basis"] = rng.normal(0.0, 0.1, (config.residual_basis + 1, out)).astype(np.float32)
        out = config.residual_basis + 1
    arrays["coef"] = rng.normal(0.0, 1e-3, (width, out)).astype(np.float32)
    if mirror:
        m = mirror_map(skirt, skirt_faces(rings, around))
        arrays["mirror_corners"], arrays["mirror_barycentric"] = m.corners, m.barycentric
        config = replace(config, mirror=True)
    return BodyResidualModel(config, d, arrays)


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
            f"threads={threads} training, output_basis={base.output_basis}, Vc={rings * around}, batch "
            f"{config.batch_size}, stage {stage}: {per * 1e3:.1f} ms/step"
        )


if __name__ == "__main__":
    main()
