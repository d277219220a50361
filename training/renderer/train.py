"""Training the neural renderer: GAN training loop, atomic resumable checkpoints, CSV log,
preview PNGs, NaN/inf guard, torchrun (DDP) and the two fine-tuning modes.

One step (DESIGN, "The method"): the generator renders R_t from frames t and t-1; the
discriminator sees consecutive-frame pairs ``[R_t, I_{t-1}]`` and ``[I_{t+1}, R_t]`` (fake) and
``[I_t, I_{t-1}]``, ``[I_{t+1}, I_t]`` (real); the generator's loss is
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

import contextlib
import functools
import hashlib
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch.nn import functional as F

from core.errors import InputError
from core.fileio import atomic_path
from core.shading import contact_sheet, write_png
from training.csvlog import append_rows, truncate_rows
from training.loader import batches
from training.loop import AdversarialRun, read_checkpoint, run_steps
from training.losses import feature_matching, gan_d_loss, gan_g_loss, load_perceptual
from training.renderer.config import RendererConfig
from training.renderer.data import CUR, NEXT, PREV, RenderBatch
from training.renderer.model import PatchDiscriminator, RenderNet, background_finetune_parameters
from training.schedule import lr_scale, set_lr

CHECKPOINT_FORMAT = "renderer-train/1"
MODEL_FORMAT = "renderer-model/1"
CHECKPOINT_NAME = "renderer_train.pt"
MODEL_NAME = "renderer.pt"
LOG_NAME = "renderer_loss.csv"
PREVIEW_DIR = "previews"
LOG_COLUMNS = (
    "step", "epoch", "loss_g", "l1", "perceptual", "fm", "gan_g", "loss_d", "skipped", "seconds",
)  # fmt: skip
#: What a run trains: everything, or (background fine-tuning) the last decoder layers, the
#: refinement blocks and the discriminator.
TRAINABLE = ("all", "background")


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
    # Files written before ``lr_decay_from`` existed were trained at constant rates: they read
    # as 1.0, so a fine-tune that starts from one keeps its schedule.
    config = RendererConfig.from_dict({"lr_decay_from": 1.0, **payload["config"]})
    net = RenderNet(config)
    try:
        net.load_state_dict(payload["generator"])
        disc = None
        if payload.get("discriminator") is not None:
            disc = PatchDiscriminator(config.disc_width)
            disc.load_state_dict(payload["discriminator"])
    except RuntimeError as exc:
        raise InputError(f"weights do not match the stored config: {exc}", path) from None
    return config, net.eval(), disc


def _architecture(config: RendererConfig) -> dict:
    keep = (
        "texture_sizes", "texture_channels", "motion_channels", "use_motion", "base_width",
        "max_width", "n_down", "decoder_features", "background_width", "disc_width",
        "skip_connections", "blend_output",
    )  # fmt: skip
    d = config.to_dict()
    return {k: d[k] for k in keep}


def dataset_fingerprint(dataset) -> str:
    """SHA-256 of the data set's length and its first and last samples (cheap, catches a
    different data set in a resumed folder)."""
    h = hashlib.sha256(str(len(dataset)).encode())
    for i in sorted({0, len(dataset) - 1}):
        s = dataset[i]
        for k in sorted(s):
            t = torch.as_tensor(s[k]).float().contiguous()
            h.update(k.encode() + str(tuple(t.shape)).encode() + t.numpy().tobytes())
    return h.hexdigest()


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


class _Trainer(AdversarialRun):
    """The state of one run, kept as an object so checkpoints capture all of it: the networks,
    optimisers, scalers and processes here, the rest in :class:`training.loop.AdversarialRun`."""

    def __init__(
        self,
        dataset,
        config: RendererConfig,
        out_dir: Path,
        *,
        device: torch.device,
        steps: int,
        init_from: Path | None,
        trainable: str,
    ):
        self.dataset = dataset
        self.config = config
        self.device = device
        self.steps = steps
        self.trainable = trainable
        self.out_dir = out_dir
        self.checkpoint_path = out_dir / CHECKPOINT_NAME
        self.model_path = out_dir / MODEL_NAME
        self.log_path = out_dir / LOG_NAME
        self.distributed = dist.is_available() and dist.is_initialized()
        self.rank = dist.get_rank() if self.distributed else 0
        self.world = dist.get_world_size() if self.distributed else 1
        if len(dataset) < config.batch_size * self.world:
            raise InputError(
                f"data set has {len(dataset)} samples, fewer than one global batch "
                f"({config.batch_size} x {self.world} processes)"
            )
        self.fingerprint = dataset_fingerprint(dataset)
        self.init_from = "" if init_from is None else str(init_from)
        torch.manual_seed(config.seed)
        self.net = RenderNet(config)
        self.disc = PatchDiscriminator(config.disc_width)
        if init_from is not None:
            cfg0, net0, disc0 = load_model(init_from)
            if _architecture(cfg0) != _architecture(config):
                raise InputError("model to fine-tune has a different architecture", init_from)
            self.net.load_state_dict(net0.state_dict())
            if disc0 is not None:
                self.disc.load_state_dict(disc0.state_dict())
        if trainable == "background":
            names = set(background_finetune_parameters(self.net))
            for n, p in self.net.named_parameters():
                p.requires_grad_(n in names)
        self.net.to(device)
        self.disc.to(device)
        self.g_params = [p for p in self.net.parameters() if p.requires_grad]
        # Fused Adam: several times faster than the per-tensor loop on a large neural texture.
        fused = device.type in ("cpu", "cuda")
        self.opt_g = torch.optim.Adam(
            self.g_params, lr=config.lr_g, betas=tuple(config.betas), fused=fused
        )
        self.opt_d = torch.optim.Adam(
            self.disc.parameters(), lr=config.lr_d, betas=tuple(config.betas), fused=fused
        )
        self.precision = config.resolved_precision(device.type)
        self.amp = self.precision != "fp32"
        scaled = self.precision == "fp16"  # bfloat16 has float32's range: no loss scaling
        self.scaler_g = torch.amp.GradScaler("cuda", enabled=scaled)
        self.scaler_d = torch.amp.GradScaler("cuda", enabled=scaled)
        self.perceptual = load_perceptual(config.vgg_path, config.vgg_channels)
        if self.perceptual is not None:
            self.perceptual.to(device)
        if self.distributed:
            ids = [device.index] if device.type == "cuda" else None
            self.g_ddp = torch.nn.parallel.DistributedDataParallel(self.net, device_ids=ids)
            self.d_ddp = torch.nn.parallel.DistributedDataParallel(self.disc, device_ids=ids)
        else:
            self.g_ddp, self.d_ddp = self.net, self.disc
        super().__init__(len(dataset), config.seed, LOG_COLUMNS[2:8])

    # -- one step ------------------------------------------------------------------------------

    def _autocast(self):
        """The generator's arithmetic (``config.precision``); the discriminator and the losses
        always run in float32."""
        if self.amp:
            dtype = torch.bfloat16 if self.precision == "bf16" else torch.float16
            return torch.autocast(self.device.type, dtype=dtype)
        return contextlib.nullcontext()

    def train_step(self, batch: RenderBatch) -> dict[str, float] | None:
        """One step; the losses, or None when the guard skipped it."""
        cfg = self.config
        scale = lr_scale(self.step, self.steps, cfg.lr_decay_from)
        set_lr(self.opt_g, cfg.lr_g * scale)
        set_lr(self.opt_d, cfg.lr_d * scale)
        self.net.train()
        self.disc.train()
        real_t = batch.target[:, CUR]
        prev, nxt = batch.target[:, PREV], batch.target[:, NEXT]
        with self._autocast():
            fake, _ = self.g_ddp(**batch.generator_inputs(cfg.use_motion))
        fake = fake.float()
        real_pairs = torch.cat([torch.cat([real_t, prev], 1), torch.cat([nxt, real_t], 1)])
        fd = fake.detach()
        fake_pairs_d = torch.cat([torch.cat([fd, prev], 1), torch.cat([nxt, fd], 1)])
        self.opt_d.zero_grad(set_to_none=True)
        self.opt_g.zero_grad(set_to_none=True)
        # The spectral-norm discriminator in float32 whatever the precision: its power
        # iteration is what low precision would make unstable.
        logits, _ = self.d_ddp(torch.cat([real_pairs, fake_pairs_d]))
        lr, lf = logits.float().chunk(2)
        loss_d = gan_d_loss(lr, lf, cfg.gan_mode)
        self.scaler_d.scale(loss_d).backward()

        # Generator: through the plain discriminator (its gradients are not wanted here).
        for p in self.disc.parameters():
            p.requires_grad_(False)
        try:
            fake_pairs = torch.cat([torch.cat([fake, prev], 1), torch.cat([nxt, fake], 1)])
            logits_f, feats_f = self.disc(fake_pairs)
            with torch.no_grad():
                _, feats_r = self.disc(real_pairs)
            l1 = F.l1_loss(fake, real_t)
            perc = (
                self.perceptual(fake, real_t) if self.perceptual is not None else fake.new_zeros(())
            )
            fm = feature_matching([f.float() for f in feats_f], [f.float() for f in feats_r])
            gan = gan_g_loss(logits_f.float(), cfg.gan_mode)
            loss_g = cfg.w_l1 * l1 + cfg.w_perceptual * perc + cfg.w_fm * fm + cfg.w_gan * gan
            self.scaler_g.scale(loss_g).backward()
        finally:
            for p in self.disc.parameters():
                p.requires_grad_(True)

        finite = torch.isfinite(loss_d) & torch.isfinite(loss_g)
        if not self.scaler_g.is_enabled():  # fp16's scalers skip non-finite steps themselves
            grads = [
                p.grad for p in (*self.g_params, *self.disc.parameters()) if p.grad is not None
            ]
            if grads:
                finite = finite & torch.stack([g.isfinite().all() for g in grads]).all()
        finite = finite.to(torch.int32)
        if self.distributed:
            dist.all_reduce(finite, op=dist.ReduceOp.MIN)
        if not bool(finite):
            self.opt_d.zero_grad(set_to_none=True)
            self.opt_g.zero_grad(set_to_none=True)
            return None
        self.scaler_d.step(self.opt_d)
        self.scaler_g.step(self.opt_g)
        self.scaler_d.update()
        self.scaler_g.update()
        return {
            "loss_g": float(loss_g.detach()),
            "l1": float(l1.detach()),
            "perceptual": float(perc.detach()),
            "fm": float(fm.detach()),
            "gan_g": float(gan.detach()),
            "loss_d": float(loss_d.detach()),
        }

    # -- log, previews, checkpoints ------------------------------------------------------------

    def off_losses(self) -> set[str]:
        return {"perceptual"} if self.perceptual is None else set()

    def flush_log(self) -> None:
        if self.rank == 0:
            append_rows(self.log_path, LOG_COLUMNS, self.pending_rows)
        self.pending_rows = []

    def truncate_log(self) -> None:
        """Drop log rows written after the checkpoint a resumed run starts from."""
        if self.rank == 0:
            truncate_rows(self.log_path, LOG_COLUMNS, self.step)

    def preview(self) -> None:
        if self.rank != 0:
            return
        batch = collate_samples([self.dataset[0]], self.config.motion_channels).to(self.device)
        self.net.eval()
        with torch.no_grad():
            fake, a = self.net(**batch.generator_inputs(self.config.use_motion))
        tiles = [_image(fake[0]), _image(batch.target[0, CUR]), _image(a[0].expand(3, -1, -1))]
        sheet = contact_sheet(tiles, ["prediction", "ground truth", "mask A"])
        write_png(self.out_dir / PREVIEW_DIR / f"step_{self.step:06d}.png", sheet)

    def save_checkpoint(self) -> None:
        self.flush_log()
        if self.rank != 0:
            return
        payload = {
            "format": CHECKPOINT_FORMAT,
            "config": self.config.to_dict(),
            "fingerprint": self.fingerprint,
            "steps": self.steps,
            "trainable": self.trainable,
            "init_from": self.init_from,
            "world": self.world,
            "generator": self.net.state_dict(),
            "discriminator": self.disc.state_dict(),
            "opt_g": self.opt_g.state_dict(),
            "opt_d": self.opt_d.state_dict(),
            "scaler_g": self.scaler_g.state_dict(),
            "scaler_d": self.scaler_d.state_dict(),
            **self.run_state(),
        }
        with atomic_path(self.checkpoint_path) as tmp:
            torch.save(payload, tmp)

    def load_checkpoint(self) -> None:
        payload = read_checkpoint(
            self.checkpoint_path, CHECKPOINT_FORMAT, "renderer",
            [("config", self.config.to_dict(), "a different config"),
             ("fingerprint", self.fingerprint, "different training data"),
             ("steps", self.steps, "a different step budget"),
             ("trainable", self.trainable, "a different fine-tuning mode"),
             ("world", self.world, "a different number of processes")],
        )  # fmt: skip
        self.net.load_state_dict(payload["generator"])
        self.disc.load_state_dict(payload["discriminator"])
        self.opt_g.load_state_dict(payload["opt_g"])
        self.opt_d.load_state_dict(payload["opt_d"])
        self.scaler_g.load_state_dict(payload["scaler_g"])
        self.scaler_d.load_state_dict(payload["scaler_d"])
        self.restore_run_state(payload)
        self.truncate_log()


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
    trainable : ``"all"`` or ``"background"`` (see :func:`finetune_background`)
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
        tr = _Trainer(
            dataset,
            cfg,
            out_dir,
            device=device,
            steps=n_steps,
            init_from=None if init_from is None else Path(init_from),
            trainable=trainable,
        )
        if tr.checkpoint_path.is_file():
            tr.load_checkpoint()
        elif tr.rank == 0:
            with contextlib.suppress(FileNotFoundError):
                tr.log_path.unlink()
        if tr.perceptual is None and tr.rank == 0 and tr.step < n_steps:
            tqdm.write("renderer: perceptual loss off (no VGG19 weights file in config.vgg_path)")
        bar = tqdm(
            total=n_steps, initial=tr.step, disable=not progress or tr.rank != 0, desc="renderer"
        )
        with bar:
            feed = batches(
                dataset, tr.order, n_steps - tr.step, cfg.batch_size,
                functools.partial(collate_samples, motion_channels=cfg.motion_channels),
                workers=workers, pin_memory=device.type == "cuda", world=tr.world, rank=tr.rank,
            )  # fmt: skip
            run_steps(
                tr, ((item.to(device, non_blocking=True), order) for item, order in feed),
                n_steps, bar, name="renderer", log_every=cfg.log_every,
                checkpoint_every=cfg.checkpoint_every,
                postfix=lambda m: {"g": f"{m['loss_g']:.4g}", "d": f"{m['loss_d']:.4g}",
                                   "skipped": tr.skipped},
                preview_every=cfg.preview_every, preview=tr.preview, callback=callback,
                say=tqdm.write if tr.rank == 0 else None,
            )  # fmt: skip
    tr.net.eval()
    if tr.rank == 0:
        save_model(tr.model_path, tr.net, tr.disc)
    if tr.distributed:
        dist.barrier()
    return RendererTrainResult(
        net=tr.net,
        discriminator=tr.disc,
        model_path=tr.model_path,
        log_path=tr.log_path,
        checkpoint_path=tr.checkpoint_path,
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
