"""Training the baselines: each kind is a configuration of the one adversarial trainer
(:mod:`training.adversarial`, the same step, schedule, guard, checkpoints and log as our
renderer's), plus the model file the evaluation loads.

One step: the generator renders frame t; with a discriminator, the discriminator's loss on
(real, fake) inputs from :meth:`BaselineModel.disc_inputs` and the generator's loss
``w_l1 L1 + w_perceptual perceptual + w_fm FM + w_gan GAN + extra_weight regulariser`` are
computed against the same (pre-update) discriminator, then both optimisers step; a non-finite
loss or gradient skips the whole step (the log's ``skipped`` column).

A run writes into ``out_dir``: ``<kind>_train.pt`` (resumable: weights, optimisers, sample
order, RNG, counters), ``<kind>_loss.csv`` and, at the end, ``<kind>.pt`` (config + generator
weights, what :func:`load_baseline` reads). Re-running with the same data, config and step
budget resumes and ends with the same weights as an uninterrupted run (CPU).

Benchmark: ``python -m training.baselines --bench [KIND ...]`` times training steps of the
``cpu`` presets at 128 px, batch 2, on one thread.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn
from tqdm.auto import tqdm

from core.errors import InputError
from core.fileio import atomic_path
from training.adversarial import AdversarialTrainer, RunFiles, dataset_fingerprint
from training.baselines.common import BaselineConfig, BaselineModel, RendererAdapter
from training.baselines.dnr import DNR_GAN_PRESETS, DNR_PRESETS, DeferredNeuralRenderer, DNRConfig
from training.baselines.pix2pix import PIX2PIX_PRESETS, Pix2Pix, Pix2PixConfig
from training.loader import batches, for_device
from training.loop import run_steps

KINDS = ("pix2pix", "dnr", "dnr-gan")
PRESETS: dict[str, dict[str, BaselineConfig]] = {
    "pix2pix": PIX2PIX_PRESETS,
    "dnr": DNR_PRESETS,
    "dnr-gan": DNR_GAN_PRESETS,
}
CHECKPOINT_FORMAT = "baseline-train/1"
MODEL_FORMAT = "baseline-model/1"
LOG_COLUMNS = (
    "step", "epoch", "loss_g", "l1", "pyramid", "detail", "gradient", "perceptual", "fm", "gan_g", "extra",
    "loss_d", "skipped", "seconds",
)  # fmt: skip


def _check_kind(kind: str) -> None:
    if kind not in KINDS:
        raise InputError(f"unknown baseline {kind!r}; choose from {list(KINDS)}")


def preset(kind: str, name: str = "cpu") -> BaselineConfig:
    """The named preset (``cpu``, ``tiny``) of a baseline kind."""
    _check_kind(kind)
    if name not in PRESETS[kind]:
        raise InputError(f"unknown {kind} preset {name!r}; choose from {sorted(PRESETS[kind])}")
    return PRESETS[kind][name]


def build_model(config: BaselineConfig) -> BaselineModel:
    """A fresh model for a config (its ``baseline`` names the kind)."""
    if isinstance(config, Pix2PixConfig):
        return Pix2Pix(config)
    if isinstance(config, DNRConfig):
        return DeferredNeuralRenderer(config)
    raise InputError(f"not a baseline config: {type(config).__name__}")


def _config_from(kind: str, data: dict) -> BaselineConfig:
    cls = Pix2PixConfig if kind == "pix2pix" else DNRConfig
    return cls.from_dict({"adam_eps": 1e-8, **data})  # files from before it: torch's default


@dataclass(frozen=True)
class BaselineTrainResult:
    """What a finished run produced.

    Attributes
    ----------
    kind : the baseline; model : BaselineModel (eval mode); discriminator : module or None
    model_path, log_path, checkpoint_path : Path
    resumed_at_step : step the run resumed from (0 when fresh)
    skipped_steps : steps skipped by the NaN/inf guard (whole run)
    perceptual : whether the perceptual loss was on
    steps : steps of this run
    """

    kind: str
    model: BaselineModel
    discriminator: nn.Module | None
    model_path: Path
    log_path: Path
    checkpoint_path: Path
    resumed_at_step: int
    skipped_steps: int
    perceptual: bool
    steps: int


def save_baseline(path: str | os.PathLike, model: BaselineModel) -> None:
    """Write the model file (kind, config, generator weights), atomically."""
    payload = {
        "format": MODEL_FORMAT,
        "kind": model.config.baseline,
        "config": model.config.to_dict(),
        "generator": model.state_dict(),
    }
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def load_baseline(path: str | os.PathLike, device: str | torch.device = "cpu") -> BaselineModel:
    """A trained baseline (eval mode) from ``<kind>.pt`` (or a training checkpoint).

    ``model.render(batch_dict) -> (B, 3, H, W)`` renders frame t.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("baseline model file not found", path)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise InputError(f"cannot read baseline model: {exc}", path) from None
    if not isinstance(payload, dict) or payload.get("format") not in (
        MODEL_FORMAT,
        CHECKPOINT_FORMAT,
    ):
        raise InputError(f"not a baseline model ({MODEL_FORMAT})", path)
    kind = payload.get("kind")
    if kind not in KINDS:
        raise InputError(f"unknown baseline kind {kind!r}", path)
    try:
        config = _config_from(kind, payload["config"])
    except (InputError, TypeError) as exc:
        raise InputError(f"bad stored config: {exc}", path) from None
    model = build_model(config)
    try:
        model.load_state_dict(payload["generator"])
    except RuntimeError as exc:
        raise InputError(f"weights do not match the stored config: {exc}", path) from None
    return model.to(device).eval()


def load_for_evaluation(path: str | os.PathLike, device: str | torch.device = "cpu"):
    """Our renderer (``renderer.pt``, wrapped in :class:`RendererAdapter`) or a baseline,
    by the file's format: either way an object with ``render(batch_dict) -> (B, 3, H, W)``."""
    path = Path(path)
    if not path.is_file():
        raise InputError("model file not found", path)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise InputError(f"cannot read model: {exc}", path) from None
    fmt = payload.get("format") if isinstance(payload, dict) else None
    if isinstance(fmt, str) and fmt.startswith("renderer-"):
        from training.renderer.train import load_model

        _, net, _ = load_model(path)
        return RendererAdapter(net.to(device))
    return load_baseline(path, device)


def collate_samples(samples: list[dict]) -> dict[str, torch.Tensor]:
    """Samples of the data set -> one batch (in a DataLoader worker when there are any)."""
    try:
        return torch.utils.data.default_collate(samples)
    except (RuntimeError, TypeError) as exc:
        raise InputError(f"data set items do not collate: {exc}") from None


def baseline_trainer(
    kind: str, dataset, config: BaselineConfig, out_dir: Path, steps: int, device: torch.device
) -> AdversarialTrainer:
    """The :class:`training.adversarial.AdversarialTrainer` of a ``kind`` run: the model (its
    own :class:`training.adversarial.Method`) and its discriminator seeded by ``config.seed``,
    its files in ``out_dir``."""
    torch.manual_seed(config.seed)
    model = build_model(config).to(device)
    files = RunFiles(
        checkpoint=out_dir / f"{kind}_train.pt",
        log=out_dir / f"{kind}_loss.csv",
        log_columns=LOG_COLUMNS,
        format=CHECKPOINT_FORMAT,
        what="baseline",
        identity=(
            ("kind", kind, "another baseline"),
            ("config", config.to_dict(), "a different config"),
            ("fingerprint", dataset_fingerprint(dataset), "different training data"),
            ("steps", steps, "a different step budget"),
        ),
    )
    return AdversarialTrainer(
        model, model.make_discriminator(), model, config, files,
        n_samples=len(dataset), batch_size=config.batch_size, steps=steps, device=device,
    )  # fmt: skip


def feed(tr: AdversarialTrainer, dataset, steps: int, workers: int = 0):
    """The next ``steps`` checked batches of a baseline run and the sample order after each
    (:func:`training.loader.batches`)."""
    for item, order in batches(
        for_device(dataset, tr.device), tr.order, steps, tr.config.batch_size, collate_samples,
        workers=workers, pin_memory=tr.device.type == "cuda",
    ):  # fmt: skip
        yield tr.net.check(item, ("target",)), order


def train_baseline(
    kind: str,
    dataset,
    out_dir: str | os.PathLike,
    config: BaselineConfig | None = None,
    *,
    steps: int | None = None,
    progress: bool = True,
    device: str | torch.device = "cpu",
    callback: Callable[[int, dict[str, float] | None], None] | None = None,
    workers: int = 0,
) -> BaselineTrainResult:
    """Train a baseline, resuming from ``out_dir`` when a matching checkpoint is there.

    Parameters
    ----------
    kind : one of ``KINDS`` ("pix2pix", "dnr", "dnr-gan")
    dataset : map-style data set of samples (renderer samples + ``proxy_shading`` for pix2pix)
    out_dir : gets ``<kind>_train.pt``, ``<kind>_loss.csv`` and ``<kind>.pt``; a checkpoint
        made with another config, data or budget raises :class:`InputError`
    config : the kind's config (its ``cpu`` preset when None); must train ``kind``
    steps : steps of this run (``config.steps`` when None)
    progress : show a tqdm bar
    device : "cpu" or "cuda[:i]"
    callback : called after each step with (step, losses or None if skipped); raising from it
        stops the run, which resumes from the last checkpoint
    workers : DataLoader worker processes that load batches ahead (:func:`training.loader.
        batches`); 0 loads each in this process. The batches, hence the weights, are the same.

    Returns
    -------
    BaselineTrainResult
    """
    _check_kind(kind)
    cfg = config if config is not None else preset(kind, "cpu")
    if not isinstance(cfg, BaselineConfig) or cfg.baseline != kind:
        got = getattr(cfg, "baseline", type(cfg).__name__)
        raise InputError(f"config trains {got!r}, not {kind!r}")
    n_steps = cfg.steps if steps is None else int(steps)
    if n_steps < 0:
        raise InputError(f"steps must be >= 0, got {n_steps}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with torch.random.fork_rng(devices=[]):
        tr = baseline_trainer(kind, dataset, cfg, out_dir, n_steps, torch.device(device))
        tr.start()
        if cfg.w_perceptual > 0 and tr.perceptual is None and tr.step < n_steps:
            tqdm.write(f"{kind}: perceptual loss off (no VGG19 weights file in config.vgg_path)")
        with tqdm(total=n_steps, initial=tr.step, disable=not progress, desc=kind) as bar:
            run_steps(
                tr, feed(tr, dataset, n_steps - tr.step, workers), n_steps, bar, name=kind,
                log_every=cfg.log_every, checkpoint_every=cfg.checkpoint_every,
                postfix=lambda m: {"g": f"{m['loss_g']:.4g}", "skipped": tr.skipped},
                callback=callback, say=tqdm.write,
            )  # fmt: skip
    tr.net.eval()
    model_path = out_dir / f"{kind}.pt"
    save_baseline(model_path, tr.net)
    return BaselineTrainResult(
        kind=kind,
        model=tr.net,
        discriminator=tr.disc,
        model_path=model_path,
        log_path=tr.files.log,
        checkpoint_path=tr.files.checkpoint,
        resumed_at_step=tr.resumed_at_step,
        skipped_steps=tr.skipped,
        perceptual=tr.perceptual is not None,
        steps=n_steps,
    )


# --------------------------------------------------------------------------------------------
# Benchmark of the cpu presets


def synthetic_batch(size: int, batch: int = 2, seed: int = 0) -> dict[str, torch.Tensor]:
    """A random batch with every sample key (B, 3, C, H, W) float32 (benchmarks, tests)."""
    g = torch.Generator().manual_seed(seed)
    mask = (torch.rand(batch, 3, 1, size, size, generator=g) > 0.5).float()
    return {
        "uv": torch.rand(batch, 3, 2, size, size, generator=g) * mask,
        "motion": torch.rand(batch, 3, 95, size, size, generator=g) * mask,
        "proxy_mask": mask,
        "target": torch.rand(batch, 3, 3, size, size, generator=g),
        "background": torch.rand(batch, 3, 3, size, size, generator=g),
        "target_mask": mask,
        "proxy_shading": torch.rand(batch, 3, 1, size, size, generator=g) * mask,
    }


def bench(kind: str, steps: int = 10, warmup: int = 3) -> tuple[float, float]:
    """(median wall-clock, median process CPU) seconds of a training step of ``kind``'s cpu
    preset (128 px, batch 2, random data, the calling thread settings). With one thread the CPU
    time is what the step costs on an idle machine; the wall time grows with other work."""
    cfg = preset(kind, "cpu")

    class _Data:
        def __init__(self):
            b = synthetic_batch(cfg.image_size, 4)
            self.items = [{k: v[i] for k, v in b.items()} for i in range(4)]

        def __len__(self):
            return len(self.items)

        def __getitem__(self, i):
            return self.items[i]

    with tempfile.TemporaryDirectory() as d:
        data = _Data()
        tr = baseline_trainer(kind, data, cfg, Path(d), steps, torch.device("cpu"))
        batches_ = feed(tr, data, warmup + steps)
        for _ in range(warmup):
            tr.train_step(next(batches_)[0])
        wall, cpu = [], []
        for _ in range(steps):
            t0, c0 = time.perf_counter(), time.process_time()
            tr.train_step(next(batches_)[0])
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
    return sorted(wall)[steps // 2], sorted(cpu)[steps // 2]


def main(argv: list[str] | None = None) -> int:

    p = argparse.ArgumentParser(description="Time the baselines' cpu presets (one thread).")
    p.add_argument("--bench", nargs="*", default=list(KINDS), metavar="KIND")
    p.add_argument("--steps", type=int, default=10)
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    for kind in args.bench or KINDS:
        wall, cpu = bench(kind, args.steps)
        print(
            f"{kind}: {cpu * 1000:.0f} ms CPU, {wall * 1000:.0f} ms wall per step (medians; "
            "cpu preset, 128 px, batch 2, 1 thread)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
