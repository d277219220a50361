"""Where a streamed frame of the torch-only render path goes: wall time and launches per frame.

Plays a bundle (``dng export torch``) frame by frame as a viewer streams it
(:meth:`training.torchpath.TorchPlayer.render`, one camera, the clip's frames in order) and
prints, per bundle, window and size: the median ms of a whole streamed frame (background,
Joint2Coarse, rasterization, features, network, paste) and of Joint2Coarse alone; then, from
``torch.profiler`` over 10 more frames, the top-level torch operations per frame, the device
kernels and copies per frame (CUDA only) and the commonest runtime calls (``cudaLaunchKernel``,
``cudaStreamSynchronize``...). Needs only torch and numpy (it runs on a GPU machine beside the
bundle)::

    python benchmarks/torchpath_profile.py BUNDLE [BUNDLE ...] [--device cuda] \
        [--clip walk] [--sizes 256 512] [--windows crop full]

A frame whose time follows its launch count rather than its pixel count is bound by the host
issuing work, not by the GPU doing it.
"""

from __future__ import annotations

import argparse
import collections
import sys
import time

import numpy as np
import torch

from core.errors import InputError
from training.torchpath import TorchPlayer

#: Frames played before timing (allocator, kernel selection), timed, then profiled.
WARMUP, TIMED, PROFILED = 5, 40, 10


def profile_one(bundle: str, device: str, clip: str, size: int, window: str) -> dict:
    """The figures of the module docstring for one bundle, size and window."""
    from torch.profiler import ProfilerActivity, profile

    cuda = torch.device(device).type == "cuda"
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    player = TorchPlayer(bundle, device, window=window)
    player.set_clip(clip)
    n = player.num_frames
    if n < WARMUP + TIMED + PROFILED:
        raise InputError(
            f"clip {clip!r} has {n} frames; {WARMUP + TIMED + PROFILED} are played", bundle
        )
    cam = player.camera(0, size, size, azimuth_deg=30.0)

    def median_ms(fn, frames) -> float:
        times = []
        for t in frames:
            sync()
            t0 = time.perf_counter()
            fn(t)
            sync()
            times.append(time.perf_counter() - t0)
        return 1e3 * float(np.median(times))

    with torch.no_grad():
        for t in range(WARMUP):
            player.render(t, cam)
        timed = range(WARMUP, WARMUP + TIMED)
        frame_ms = median_ms(lambda t: player.render(t, cam), timed)
        j2c_ms = median_ms(lambda t: player.proxy([t]), timed)
        activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
        with profile(activities=activities) as prof:
            for t in range(WARMUP + TIMED, WARMUP + TIMED + PROFILED):
                player.render(t, cam)
            sync()
    events = prof.events()
    on_host = [e for e in events if e.device_type.name == "CPU"]
    ops = [e for e in on_host if e.name.startswith("aten::") and e.cpu_parent is None]
    kernels = [e for e in events if e.device_type.name == "CUDA"]
    runtime = collections.Counter(e.name for e in on_host if e.name.startswith("cuda"))
    return {
        "bundle": bundle,
        "device": device,
        "window": window,
        "size": size,
        "frame_ms": frame_ms,
        "joint2coarse_ms": j2c_ms,
        "ops_per_frame": len(ops) / PROFILED,
        "kernels_per_frame": len(kernels) / PROFILED,
        "runtime_calls_per_frame": {k: v / PROFILED for k, v in runtime.most_common(4)},
        "torch": torch.__version__,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("bundles", nargs="+", help="bundle files (dng export torch)")
    p.add_argument("--device", default="cuda")
    p.add_argument("--clip", default="walk", help="clip of the bundles to play")
    p.add_argument("--sizes", type=int, nargs="+", default=[256, 512])
    p.add_argument("--windows", nargs="+", default=["crop", "full"], choices=["crop", "full"])
    args = p.parse_args(argv)
    if torch.device(args.device).type == "cuda" and not torch.cuda.is_available():
        print("--device cuda: no CUDA GPU on this machine", file=sys.stderr)
        return 2
    print(f"{'bundle':>24} {'window':>6} {'size':>5} {'frame ms':>9} {'j2c ms':>7} "
          f"{'ops/frame':>9} {'kernels':>8}  runtime calls per frame")  # fmt: skip
    try:
        for bundle in args.bundles:
            for window in args.windows:
                for size in args.sizes:
                    r = profile_one(bundle, args.device, args.clip, size, window)
                    calls = ", ".join(
                        f"{k} {v:.0f}" for k, v in r["runtime_calls_per_frame"].items()
                    )
                    print(
                        f"{bundle.split('/')[-1][-24:]:>24} {window:>6} {size:>5} "
                        f"{r['frame_ms']:>9.2f} {r['joint2coarse_ms']:>7.2f} "
                        f"{r['ops_per_frame']:>9.0f} {r['kernels_per_frame']:>8.0f}  {calls}"
                    )
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"torch {torch.__version__}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
