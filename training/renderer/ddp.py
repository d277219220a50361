"""Multi-process training under torchrun (DistributedDataParallel; gloo on CPU, nccl on CUDA).

::

    python -m torch.distributed.run --standalone --nproc_per_node 2 -m training.renderer.ddp \\
        --out runs/renderer --preset cpu --dataset mypackage.data:make_dataset

``--dataset module:function`` names a callable returning the map-style data set (called with no
arguments in every process); ``--synthetic N`` uses N frames of the built-in synthetic scene
instead (a smoke run). ``--dump-weights`` writes each rank's final weights to
``out/rank{r}_weights.pt`` (used by the test that checks all ranks agree).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from pathlib import Path

import torch
import torch.distributed as dist

from core.errors import InputError
from core.fileio import atomic_path
from training.renderer.config import preset
from training.renderer.train import train_renderer


def _dataset(args):
    if args.dataset:
        mod, _, fn = args.dataset.partition(":")
        if not fn:
            raise InputError(f"--dataset must be module:function, got {args.dataset!r}")
        return getattr(importlib.import_module(mod), fn)()
    from training.renderer.data import SyntheticDataset, synthetic_scene

    cfg = preset(args.preset)
    return SyntheticDataset(synthetic_scene(args.synthetic), cfg.image_size, args.cameras)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", required=True, help="output folder (rank 0 writes)")
    p.add_argument("--preset", default="cpu", help="renderer config preset")
    p.add_argument("--steps", type=int, default=None, help="override the preset's steps")
    p.add_argument("--dataset", default="", help="module:function returning the data set")
    p.add_argument("--synthetic", type=int, default=6, help="frames of the synthetic scene")
    p.add_argument("--cameras", type=int, default=2, help="synthetic cameras per frame")
    p.add_argument("--device", default="auto", help="cpu, cuda or auto")
    p.add_argument("--threads", type=int, default=1, help="torch threads per process (CPU)")
    p.add_argument("--dump-weights", action="store_true", help="write each rank's weights")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    use_cuda = args.device == "cuda" or (args.device == "auto" and torch.cuda.is_available())
    local = int(os.environ.get("LOCAL_RANK", 0))
    if use_cuda:
        torch.cuda.set_device(local)
        device = torch.device("cuda", local)
    else:
        device = torch.device("cpu")
    distributed = "WORLD_SIZE" in os.environ
    if distributed:
        dist.init_process_group("nccl" if use_cuda else "gloo")
    try:
        cfg = preset(args.preset)
        result = train_renderer(
            _dataset(args), args.out, cfg, device=device, steps=args.steps, progress=local == 0
        )
        if args.dump_weights:
            rank = dist.get_rank() if distributed else 0
            state = {
                "generator": result.net.state_dict(),
                "discriminator": result.discriminator.state_dict(),
            }
            with atomic_path(Path(args.out) / f"rank{rank}_weights.pt") as tmp:
                torch.save(state, tmp)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    finally:
        if distributed:
            dist.destroy_process_group()
    return 0


if __name__ == "__main__":
    sys.exit(main())
