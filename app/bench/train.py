"""``dng bench train``: neural-renderer training speed: steps per second, peak memory, and the
share of each step spent waiting for data.

Each row trains the renderer of a preset (random initial weights) for a few steps with the
studio's own training step (``training.adversarial.AdversarialTrainer.train_step``: generator,
temporal discriminator, L1, feature matching, GAN; the perceptual loss when its VGG file is
there; ``--precision``, by default bf16 on CUDA and fp32 on the CPU), fed as the trainers are
(``training.loader.batches``: a ``torch.utils.data.DataLoader`` with ``--workers`` processes and
pinned memory on CUDA), batches copied to the device without blocking.

The batches are **synthetic**: random tensors of exactly the shapes of the data set's samples
(frames t-1, t, t+1 of UV (2), motion features (95), proxy mask, target, background and target
mask at the given size); speed does not depend on the pixel values. Two distinct samples are
made once and served in turn, so "waiting" (the time a step spends in ``next(loader)`` and the
copy to the device; on CUDA the GPU is idle then, as each step ends by reading its losses back)
is the cost of *feeding* those shapes: collating in the workers, passing the batch to the
trainer's process, pinning it and copying it. It is a floor of the real data set's, whose
workers also rasterize the proxy, interpolate its motion features and decode the images.

``--motion`` picks how the samples carry the motion features, as the trainers do: ``pixels``
(the (3, 95, H, W) map the loader makes: the trainers on the CPU) or ``vertices`` (per-vertex
features of a :data:`VERTICES`-vertex proxy with each pixel's corner ids and weights,
interpolated on the device inside the timed step: the trainers on CUDA,
:func:`training.loader.for_device`); ``auto`` is the trainers' choice for ``--device``.

Rows name the device and the torch version; peak memory is CUDA's ``max_memory_allocated`` on
a GPU and the process's peak resident size on the CPU.
"""

from __future__ import annotations

import argparse
import functools
import itertools
import json
import os
import resource
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from app.bench import add_output_arguments
from app.bench.render import device_name
from core.errors import InputError
from core.fileio import write_json

HELP = "renderer training: steps/s, peak memory and the share of each step waiting for data"
#: Steps run before timing (allocator, cuDNN autotuning, worker start-up).
WARMUP = 2
#: Smallest image the temporal discriminator takes (three stride-2 4x4 convs, two more 4x4).
MIN_SIZE = 32
#: Proxy vertices of the synthetic samples' per-vertex motion features (about the synthetic
#: skirt's, ``dng bench render``).
VERTICES = 2000
MOTION_FORMS = ("auto", "pixels", "vertices")


class ShapeDataset:
    """Random samples of the data set's shapes (see the module docstring).

    Parameters
    ----------
    length : samples; size : image side (pixels); motion_channels : C of the motion features
    vertices : None for the (3, C, H, W) motion map, or the proxy's vertex count for the
        per-vertex form (:data:`training.renderer.data.VERTEX_MOTION_KEYS`)
    distinct : samples made (served in turn)
    """

    def __init__(
        self,
        length: int,
        size: int,
        motion_channels: int = 95,
        seed: int = 0,
        distinct: int = 2,
        vertices: int | None = None,
    ):
        import torch

        from training.renderer.data import SAMPLE_KEYS

        self.length, self.size = length, size
        channels = {k: motion_channels if c is None else c for k, c in SAMPLE_KEYS.items()}
        if vertices is not None:
            del channels["motion"]
        self.samples = []
        for i in range(min(distinct, length)):
            g = torch.Generator().manual_seed(seed + i)
            sample = {}
            for k, c in channels.items():
                t = torch.rand(3, c, size, size, generator=g)
                sample[k] = (t > 0.3).float() if k.endswith("mask") else t
            if vertices is not None:
                w = torch.rand(3, 3, size, size, generator=g)
                sample["motion_corners"] = torch.randint(
                    vertices, (3, 3, size, size), generator=g, dtype=torch.int32
                )
                sample["motion_weights"] = w / w.sum(1, keepdim=True) * sample["proxy_mask"]
                sample["vertex_motion"] = torch.rand(3, vertices, motion_channels, generator=g)
            self.samples.append(sample)

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, i: int) -> dict:
        """Sample ``i``: one of the distinct samples (made once, served in turn)."""
        if not 0 <= i < self.length:
            raise IndexError(f"sample {i} of {self.length}")
        return self.samples[i % len(self.samples)]


def measure_one(
    preset: str,
    size: int,
    batch: int,
    device: str,
    steps: int,
    workers: int,
    out_dir,
    precision: str = "auto",
    motion: str = "auto",
) -> dict:
    """Train ``steps`` timed steps (after :data:`WARMUP`); one row."""

    import torch

    from training.loader import batches
    from training.renderer import PRESETS
    from training.renderer.train import collate_samples, renderer_trainer

    cuda = str(device).startswith("cuda")
    dev = torch.device(device)
    config = replace(PRESETS[preset], batch_size=batch, precision=precision)
    n = batch * (steps + WARMUP)
    if motion == "auto":
        motion = "vertices" if cuda else "pixels"
    vertices = VERTICES if motion == "vertices" else None
    data = ShapeDataset(n, size, config.motion_channels, vertices=vertices)
    trainer = renderer_trainer(data, config, out_dir, device=dev, steps=steps + WARMUP)
    feed = batches(
        data, trainer.order, steps + WARMUP, batch,
        functools.partial(collate_samples, motion_channels=config.motion_channels),
        workers=workers, pin_memory=cuda,
    )  # fmt: skip
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    if cuda:
        torch.cuda.reset_peak_memory_stats(dev)
    waits, totals = [], []
    for step in range(steps + WARMUP):
        sync()
        t0 = time.perf_counter()
        item, trainer.order = next(feed)
        batch_dev = item.to(dev, non_blocking=True)
        t1 = time.perf_counter()
        trainer.train_step(batch_dev)
        trainer.step += 1
        sync()
        t2 = time.perf_counter()
        if step >= WARMUP:
            waits.append(t1 - t0)
            totals.append(t2 - t0)
    if cuda:
        peak = torch.cuda.max_memory_allocated(dev) / 2**20
    else:
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    step_s = float(np.mean(totals))
    return {
        "preset": preset,
        "size": size,
        "batch": batch,
        "workers": workers,
        "device": str(device),
        "device_name": device_name(device),
        "torch": torch.__version__,
        "data": "synthetic (two samples of the data set's shapes, served in turn)",
        "precision": trainer.precision,
        "motion": motion,
        "perceptual": trainer.perceptual is not None,
        "steps": steps,
        "ms_per_step": 1e3 * step_s,
        "steps_per_s": 1.0 / step_s,
        "images_per_s": batch / step_s,
        "wait_share": float(np.sum(waits) / np.sum(totals)),
        "peak_memory_mib": peak,
        "peak_memory_kind": "cuda max_memory_allocated" if cuda else "process peak RSS",
        "load_average": os.getloadavg()[0],
    }


HEADER = (
    f"{'preset':>7} {'size':>5} {'batch':>5} {'wkr':>3} {'prec':>4} {'motion':>8} {'ms/step':>8} "
    f"{'steps/s':>7} {'img/s':>6} {'wait':>6} {'peak MiB':>9} {'load':>5}  device / torch"
)


def format_row(r: dict) -> str:
    return (
        f"{r['preset']:>7} {r['size']:>5} {r['batch']:>5} {r['workers']:>3} "
        f"{r['precision']:>4} {r['motion']:>8} {r['ms_per_step']:>8.1f} {r['steps_per_s']:>7.2f} "
        f"{r['images_per_s']:>6.2f} {r['wait_share']:>6.1%} {r['peak_memory_mib']:>9.0f} "
        f"{r['load_average']:>5.2f}  {r['device_name']} / torch {r['torch']}"
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from training.renderer.config import PRECISIONS

    add_output_arguments(parser)
    parser.add_argument("--device", default="cpu", help="cpu or cuda[:i]")
    parser.add_argument(
        "--preset", default=None, help="renderer preset (default: cpu on CPU, paper on CUDA)"
    )
    parser.add_argument(
        "--size", type=int, default=None, help="image side (default: 128 on CPU, 512 on CUDA)"
    )
    parser.add_argument(
        "--batch", type=int, nargs="+", default=None,
        help="batch sizes (default: 2 on CPU, 2 4 8 on CUDA)",
    )  # fmt: skip
    parser.add_argument("--steps", type=int, default=None, help="timed steps (default 4 / 20)")
    parser.add_argument("--workers", type=int, default=2, help="DataLoader worker processes")
    parser.add_argument(
        "--precision", nargs="+", default=["auto"], choices=PRECISIONS,
        help="training arithmetic (RendererConfig.precision; auto: bf16 on CUDA, fp32 on CPU)",
    )  # fmt: skip
    parser.add_argument(
        "--motion", nargs="+", default=["auto"], choices=MOTION_FORMS,
        help="how samples carry the motion features: pixels (the loader's map), vertices "
        "(interpolated on the device); auto: vertices on CUDA, pixels on CPU",
    )  # fmt: skip


def run(args: argparse.Namespace) -> int:

    import torch

    from training.renderer import PRESETS

    cuda = args.device.startswith("cuda")
    if cuda and not torch.cuda.is_available():
        raise InputError("--device cuda: no CUDA GPU on this machine")
    preset = args.preset or ("paper" if cuda else "cpu")
    if preset not in PRESETS:
        raise InputError(f"unknown preset {preset!r}; choose from {', '.join(PRESETS)}")
    size = args.size or (512 if cuda else 128)
    batches = args.batch or ([2, 4, 8] if cuda else [2])
    steps = args.steps or (20 if cuda else 4)
    stride = PRESETS[preset].stride
    if size % stride or size < max(stride, MIN_SIZE) or steps < 1 or min(batches) < 1:
        raise InputError(
            f"--size must be a multiple of the network's stride {stride} and at least "
            f"{MIN_SIZE} (the discriminator's window); --steps and --batch at least 1"
        )
    if args.workers < 0:
        raise InputError("--workers must be at least 0")
    say = (lambda *a: None) if args.json else print
    say(f"device {args.device}; synthetic batches of the data set's shapes")
    say(HEADER)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for motion, precision, b in itertools.product(args.motion, args.precision, batches):
            row = measure_one(
                preset, size, b, args.device, steps, args.workers, Path(tmp), precision, motion
            )
            rows.append(row)
            say(format_row(row))
    table = {"bench": "train", "device": args.device, "torch": torch.__version__, "rows": rows}
    out = Path(args.out)
    write_json(out / "train.json", table)
    if args.json:
        print(json.dumps(table, indent=2))
    else:
        print(f"wrote {out / 'train.json'}")
    return 0
