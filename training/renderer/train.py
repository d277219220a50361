"""Training the neural renderer: our method's configuration of the one adversarial trainer
(:mod:`training.adversarial`: its step, schedule, NaN/inf guard, atomic resumable checkpoints,
CSV log and torchrun), preview PNGs and the two fine-tuning modes.

One step (DESIGN, "The method"): the generator renders R_t from frames t and t-1; the
discriminator sees consecutive-frame pairs ``[R_t, I_{t-1}]`` and ``[I_{t+1}, R_t]`` (fake) and
``[I_t, I_{t-1}]``, ``[I_{t+1}, I_t]`` (real) (:class:`RendererMethod`); the generator's loss is
``w_l1 * L1 + w_perceptual * perceptual + w_fm * FM + w_gan * GAN`` (10, 10, 5, 0.5). Both losses
are computed against the same (pre-update) discriminator, then both optimisers step, so a
non-finite loss or gradient skips the whole step (counted in the log's ``skipped`` column).

A run writes into ``out_dir``: ``renderer_train.pt`` (resumable: weights, optimisers, scalers,
sample order, RNG, counters), ``renderer_loss.csv``, ``previews/step_NNNNNN.png`` and, at the
end, ``renderer.pt`` (the model: config + generator + discriminator). Re-running with the same
data and config resumes and ends with the same weights as an uninterrupted run (CPU).

Under torchrun every process trains on its own ``batch_size`` samples (the global batch is
``batch_size * world_size``), gradients are averaged by DistributedDataParallel (gloo on CPU,
nccl on CUDA) and only rank 0 writes files.
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist

from core.errors import InputError
from core.fileio import atomic_path
from core.shading import contact_sheet, write_png
from training.adversarial import AdversarialTrainer, RunFiles, dataset_fingerprint, world_size
from training.loader import batches, for_device
from training.loop import run_steps
from training.renderer.config import RendererConfig
from training.renderer.data import CUR, NEXT, PREV, RenderBatch
from training.renderer.model import (
    PatchDiscriminator,
    RenderNet,
    background_finetune_parameters,
    relight_parameters,
    texture_colour_loss,
)

CHECKPOINT_FORMAT = "renderer-train/1"
MODEL_FORMAT = "renderer-model/1"
CHECKPOINT_NAME = "renderer_train.pt"
MODEL_NAME = "renderer.pt"
LOG_NAME = "renderer_loss.csv"
PREVIEW_DIR = "previews"
LOG_COLUMNS = (
    "step", "epoch", "loss_g", "l1", "pyramid", "detail", "gradient", "perceptual", "fm", "gan_g", "loss_d",
    "skipped", "seconds",
)  # fmt: skip
#: What a run trains: everything; (background fine-tuning) the last decoder layers, the
#: refinement blocks and the discriminator; or (relighting) the last two layers and the
#: discriminator (:func:`training.renderer.model.relight_parameters`).
TRAINABLE = ("all", "background", "relight")


@dataclass(frozen=True)
class RendererTrainResult:
    """What a finished run produced.

    Attributes
    ----------
    net : RenderNet (eval mode); discriminator : PatchDiscriminator
    model_path, log_path, checkpoint_path : Path
    resumed_at_step : step the run resumed from (0 when fresh)
    skipped_steps : steps skipped by the NaN/inf guard (over the whole run)
    perceptual : whether the perceptual loss was on
    steps : steps of this run
    """

    net: RenderNet
    discriminator: PatchDiscriminator
    model_path: Path
    log_path: Path
    checkpoint_path: Path
    resumed_at_step: int
    skipped_steps: int
    perceptual: bool
    steps: int


def save_model(
    path: str | os.PathLike, net: RenderNet, discriminator: PatchDiscriminator | None
) -> None:
    """Write the model file (config + weights), atomically."""
    payload = {
        "format": MODEL_FORMAT,
        "config": net.config.to_dict(),
        "generator": net.state_dict(),
        "discriminator": None if discriminator is None else discriminator.state_dict(),
    }
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def load_model(
    path: str | os.PathLike,
) -> tuple[RendererConfig, RenderNet, PatchDiscriminator | None]:
    """Read a model file (or a training checkpoint): (config, generator, discriminator)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("renderer model file not found", path)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise InputError(f"cannot read renderer model: {exc}", path) from None
    if not isinstance(payload, dict) or payload.get("format") not in (
        MODEL_FORMAT,
        CHECKPOINT_FORMAT,
    ):
        raise InputError(f"not a renderer model ({MODEL_FORMAT})", path)
    config = RendererConfig.from_stored(payload["config"])
    net = RenderNet(config)
    try:
        net.load_state_dict(payload["generator"])
        disc = None
        if payload.get("discriminator") is not None:
            disc = PatchDiscriminator(config.disc_width, disc_channels(config))
            disc.load_state_dict(payload["discriminator"])
    except RuntimeError as exc:
        raise InputError(f"weights do not match the stored config: {exc}", path) from None
    return config, net.eval(), disc


def _architecture(config: RendererConfig) -> dict:
    keep = (
        "texture_sizes", "texture_channels", "motion_channels", "use_motion", "base_width",
        "max_width", "n_down", "decoder_features", "background_width", "disc_width",
        "skip_connections", "blend_output", "use_temporal", "texture_readout", "background_guide",
    )  # fmt: skip
    d = config.to_dict()
    return {k: d[k] for k in keep}


def collate_samples(samples: list[dict], motion_channels: int) -> RenderBatch:
    """Samples of the data set -> one checked batch (in a DataLoader worker when there are
    any)."""
    try:
        for s in samples:
            RenderBatch.from_dict(s, motion_channels)
    except InputError as exc:
        raise InputError(f"data set item: {exc.problem}") from None
    batch = torch.utils.data.default_collate(samples)
    return RenderBatch.from_dict(batch, motion_channels)


def _image(t: torch.Tensor) -> np.ndarray:
    """(3, H, W) float in [0, 1] -> (H, W, 3) uint8."""
    a = t.detach().float().clamp(0, 1).permute(1, 2, 0).cpu().numpy()
    return (a * 255 + 0.5).astype(np.uint8)


def _needs_discriminator(config: RendererConfig) -> bool:
    """Whether a loss term looks at the discriminator: on L1 alone (the quick preset) its
    passes and updates would change no weight of the generator, so none is built."""
    return config.w_gan > 0 or config.w_fm > 0


def disc_channels(config: RendererConfig) -> int:
    """Input channels of the discriminator: a pair of consecutive RGB frames, or one frame
    without temporal conditioning (``use_temporal``)."""
    return 6 if config.use_temporal else 3


class RendererMethod:
    """Our renderer as a :class:`training.adversarial.Method`: the generator renders R_t from
    frames t and t-1 (:meth:`RenderBatch.generator_inputs`); the discriminator sees
    consecutive-frame pairs, ``[R_t, I_{t-1}]`` and ``[I_{t+1}, R_t]`` (fake), ``[I_t, I_{t-1}]``
    and ``[I_{t+1}, I_t]`` (real), or without ``temporal`` single frames, R_t against I_t. Its
    regulariser, weighted by ``w_texture`` (0: none), is DNR's on frame t's sampled texture."""

    def __init__(self, use_motion: bool, temporal: bool = True, w_texture: float = 0.0):
        self.use_motion = use_motion
        self.temporal = temporal
        self.extra_weight = w_texture

    def generate(self, net, batch: RenderBatch) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(R_t (B, 3, H, W), frame t's sampled texture (B, L * C, H, W), or None without the
        regulariser)."""
        if self.extra_weight <= 0:
            return net(**batch.generator_inputs(self.use_motion))[0], None
        rgb, _, texture = net(**batch.generator_inputs(self.use_motion), with_texture=True)
        return rgb, texture

    def target(self, batch: RenderBatch) -> torch.Tensor:
        return batch.target[:, CUR]

    def disc_inputs(
        self, batch: RenderBatch, fake: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(real, fake) pairs, each (2B, 6, H, W); single frames (B, 3, H, W) without
        ``temporal``."""
        real_t, prev, nxt = batch.target[:, CUR], batch.target[:, PREV], batch.target[:, NEXT]
        if not self.temporal:
            return real_t, fake
        real = torch.cat([torch.cat([real_t, prev], 1), torch.cat([nxt, real_t], 1)])
        return real, torch.cat([torch.cat([fake, prev], 1), torch.cat([nxt, fake], 1)])

    def extra_loss(self, batch: RenderBatch, aux) -> torch.Tensor:
        return texture_colour_loss(aux, batch.target[:, CUR], batch.proxy_mask[:, CUR])


def renderer_trainer(
    dataset,
    config: RendererConfig,
    out_dir: Path,
    *,
    device: torch.device,
    steps: int,
    init_from: Path | None = None,
    trainable: str = "all",
) -> AdversarialTrainer:
    """The :class:`training.adversarial.AdversarialTrainer` of a renderer run: the networks
    seeded by ``config.seed`` (weights from ``init_from`` when fine-tuning; only the
    background fine-tuning's parameters train when ``trainable == "background"``), its files in
    ``out_dir``."""
    torch.manual_seed(config.seed)
    net = RenderNet(config)
    disc = (
        PatchDiscriminator(config.disc_width, disc_channels(config))
        if _needs_discriminator(config)
        else None
    )
    if init_from is not None:
        cfg0, net0, disc0 = load_model(init_from)
        if _architecture(cfg0) != _architecture(config):
            raise InputError("model to fine-tune has a different architecture", init_from)
        net.load_state_dict(net0.state_dict())
        if disc0 is not None and disc is not None:
            disc.load_state_dict(disc0.state_dict())
    if trainable != "all":
        pick = background_finetune_parameters if trainable == "background" else relight_parameters
        names = set(pick(net))
        for n, p in net.named_parameters():
            p.requires_grad_(n in names)
    files = RunFiles(
        checkpoint=out_dir / CHECKPOINT_NAME,
        log=out_dir / LOG_NAME,
        log_columns=LOG_COLUMNS,
        format=CHECKPOINT_FORMAT,
        what="renderer",
        identity=(
            ("config", config.to_dict(), "a different config"),
            ("fingerprint", dataset_fingerprint(dataset), "different training data"),
            ("steps", steps, "a different step budget"),
            ("trainable", trainable, "a different fine-tuning mode"),
            ("world", world_size(), "a different number of processes"),
        ),
        extra={"init_from": "" if init_from is None else str(init_from)},
    )
    return AdversarialTrainer(
        net, disc, RendererMethod(config.use_motion, config.use_temporal, config.w_texture),
        config, files,
        n_samples=len(dataset), batch_size=config.batch_size, steps=steps, device=device,
        precision=config.resolved_precision(device.type),
    )  # fmt: skip


def _preview(tr: AdversarialTrainer, dataset, out_dir: Path) -> None:
    """A contact sheet of the prediction, the ground truth and the mask on the first sample
    (rank 0)."""
    if tr.rank != 0:
        return
    cfg = tr.config
    batch = collate_samples([dataset[0]], cfg.motion_channels).to(tr.device)
    tr.net.eval()
    with torch.no_grad():
        fake, a = tr.net(**batch.generator_inputs(cfg.use_motion))
    tiles = [_image(fake[0]), _image(batch.target[0, CUR]), _image(a[0].expand(3, -1, -1))]
    sheet = contact_sheet(tiles, ["prediction", "ground truth", "mask A"])
    write_png(out_dir / PREVIEW_DIR / f"step_{tr.step:06d}.png", sheet)


def train_renderer(
    dataset,
    out_dir: str | os.PathLike,
    config: RendererConfig | None = None,
    *,
    device: str | torch.device = "cpu",
    steps: int | None = None,
    init_from: str | os.PathLike | None = None,
    trainable: str = "all",
    progress: bool = True,
    callback: Callable[[int, dict[str, float] | None], None] | None = None,
    workers: int = 0,
) -> RendererTrainResult:
    """Train (or fine-tune) the neural renderer, resuming from ``out_dir`` when possible.

    Parameters
    ----------
    dataset : map-style data set of samples (see :mod:`training.renderer.data`)
    out_dir : gets the checkpoint, the log, previews and the model file. A checkpoint already
        there from the same config, data, budget and mode is resumed; any other raises
        :class:`InputError`.
    config : RendererConfig (the ``cpu`` preset when None)
    device : "cpu" or "cuda[:i]" (under torchrun, each process's own device)
    steps : steps of this run (``config.steps`` when None)
    init_from : a model file (or training checkpoint) whose weights start the run (fine-tuning)
    trainable : ``"all"``, ``"background"`` (see :func:`finetune_background`) or ``"relight"``
        (:func:`finetune_relight`)
    progress : show a tqdm bar (rank 0 only)
    callback : called after each step with (step, losses or None if skipped); raising from it
        stops the run, which resumes from the last checkpoint
    workers : DataLoader worker processes that load batches ahead (:func:`training.loader.
        batches`; pinned memory on CUDA); 0 loads each in this process. The batches, hence the
        weights, are the same either way.

    Returns
    -------
    RendererTrainResult
    """
    # Here, not at module level: the torch-only render path (training.torchpath) imports
    # this package, and a machine with only torch and numpy has no tqdm.
    from tqdm.auto import tqdm

    cfg = config or RendererConfig()
    if trainable not in TRAINABLE:
        raise InputError(f"trainable must be one of {TRAINABLE}, got {trainable!r}")
    n_steps = cfg.steps if steps is None else int(steps)
    if n_steps < 0:
        raise InputError(f"steps must be >= 0, got {n_steps}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    device = torch.device(device)
    with torch.random.fork_rng(devices=[]):
        tr = renderer_trainer(
            dataset, cfg, out_dir, device=device, steps=n_steps,
            init_from=None if init_from is None else Path(init_from), trainable=trainable,
        )  # fmt: skip
        tr.start()
        if cfg.w_perceptual > 0 and tr.perceptual is None and tr.rank == 0 and tr.step < n_steps:
            tqdm.write("renderer: perceptual loss off (no VGG19 weights file in config.vgg_path)")
        bar = tqdm(
            total=n_steps, initial=tr.step, disable=not progress or tr.rank != 0, desc="renderer"
        )
        with bar:
            feed = batches(
                for_device(dataset, device), tr.order, n_steps - tr.step, cfg.batch_size,
                functools.partial(collate_samples, motion_channels=cfg.motion_channels),
                workers=workers, pin_memory=device.type == "cuda", world=tr.world, rank=tr.rank,
            )  # fmt: skip
            run_steps(
                tr, ((item.to(device, non_blocking=True), order) for item, order in feed),
                n_steps, bar, name="renderer", log_every=cfg.log_every,
                checkpoint_every=cfg.checkpoint_every,
                postfix=lambda m: {"g": f"{m['loss_g']:.4g}", "d": f"{m['loss_d']:.4g}",
                                   "skipped": tr.skipped},
                preview_every=cfg.preview_every, preview=lambda: _preview(tr, dataset, out_dir),
                callback=callback,
                say=tqdm.write if tr.rank == 0 else None,
            )  # fmt: skip
    tr.net.eval()
    model_path = out_dir / MODEL_NAME
    if tr.rank == 0:
        save_model(model_path, tr.net, tr.disc)
    if tr.distributed:
        dist.barrier()
    return RendererTrainResult(
        net=tr.net,
        discriminator=tr.disc,
        model_path=model_path,
        log_path=tr.files.log,
        checkpoint_path=tr.files.checkpoint,
        resumed_at_step=tr.resumed_at_step,
        skipped_steps=tr.skipped,
        perceptual=tr.perceptual is not None,
        steps=n_steps,
    )


def finetune_body(
    model_path: str | os.PathLike,
    dataset,
    out_dir: str | os.PathLike,
    config: RendererConfig | None = None,
    *,
    steps: int | None = None,
    **kwargs,
) -> RendererTrainResult:
    """Fine-tune every parameter to a new body shape (same proxy motion, new backgrounds and
    targets), starting from a trained model. Default budget: ``config.body_finetune_fraction``
    (25%) of ``config.steps``. ``config`` defaults to the model's own."""
    cfg = config or load_model(model_path)[0]
    if steps is None:
        steps = max(1, math.ceil(cfg.body_finetune_fraction * cfg.steps))
    return train_renderer(dataset, out_dir, cfg, steps=steps, init_from=model_path, **kwargs)


def finetune_background(
    model_path: str | os.PathLike,
    dataset,
    out_dir: str | os.PathLike,
    config: RendererConfig | None = None,
    *,
    steps: int | None = None,
    **kwargs,
) -> RendererTrainResult:
    """Fine-tune to a new background / lighting from a few examples: only the last decoder
    layers, the refinement blocks and the discriminator train; the neural texture, encoder,
    SPADE block and background net stay bit-identical. Default budget:
    ``config.background_finetune_steps``."""
    cfg = config or load_model(model_path)[0]
    if steps is None:
        steps = cfg.background_finetune_steps
    return train_renderer(
        dataset, out_dir, cfg, steps=steps, init_from=model_path, trainable="background", **kwargs
    )


def finetune_relight(
    model_path: str | os.PathLike,
    dataset,
    out_dir: str | os.PathLike,
    config: RendererConfig | None = None,
    *,
    steps: int,
    **kwargs,
) -> RendererTrainResult:
    """Fine-tune to a new light from a few example renders (the paper's section (iv)): only the
    last two decoder layers (:func:`training.renderer.model.relight_parameters`) and the
    discriminator, when the model has one, train, for ``steps`` (the paper's about 100:
    ``pipeline.finetune.RELIGHT_STEPS``)."""
    cfg = config or load_model(model_path)[0]
    return train_renderer(
        dataset, out_dir, cfg, steps=steps, init_from=model_path, trainable="relight", **kwargs
    )
