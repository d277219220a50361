"""The one adversarial trainer: our neural renderer and every baseline are configurations of it.

A run trains a generator (and, unless the method is L1-only, a PatchGAN discriminator) with the
same step, schedule, guard, checkpoints, resume and log, whatever the method. What a method
brings is a :class:`Method`: how its generator is called on a batch, the ground truth at frame t,
what its discriminator sees and its own regulariser. :class:`AdversarialTrainer` does the rest.

One step:

1. both learning rates follow :func:`training.schedule.lr_scale` (constant, then a linear fall
   from ``lr_decay_from``);
2. the generator renders frame t (under ``precision``'s autocast; everything after it runs in
   float32);
3. the discriminator's loss on ``method.disc_inputs(batch, fake.detach())`` (real and fake
   halves in one pass, its backward);
4. the generator's loss ``w_l1 L1 + w_pyramid pyramid + w_detail detail + w_gradient
   gradient + w_perceptual perceptual + w_fm FM + w_gan GAN + extra_weight extra`` against the
   same (pre-update) discriminator, with its parameters frozen; feature matching compares with
   the real half's activations of step 3 (pix2pixHD's way: one discriminator pass fewer than a
   separate pass over the real inputs);
5. a non-finite loss or gradient (on any process, under torchrun) skips the whole step;
   otherwise the discriminator, then the generator step (Adam, fused on CPU and CUDA).

Checkpoints (``format``, what must match to resume, the weights, optimisers, scalers and
:meth:`training.loop.AdversarialRun.run_state`) are written atomically by rank 0; a resumed
run ends with the same weights as an uninterrupted one (CPU).
"""

from __future__ import annotations

import contextlib
import hashlib
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import torch
import torch.distributed as dist
from torch import nn
from torch.nn import functional as F

from core.errors import InputError
from core.fileio import atomic_path
from training.csvlog import append_rows, truncate_rows
from training.loop import AdversarialRun, read_checkpoint
from training.losses import (
    detail_energy_l1,
    feature_matching,
    gan_d_loss,
    gan_g_loss,
    gradient_similarity_loss,
    load_perceptual,
    pyramid_l1,
)
from training.schedule import lr_scale, set_lr

#: Every loss a step computes, in log order (a trainer's log keeps the ones its columns name).
LOSSES = (
    "loss_g", "l1", "pyramid", "detail", "gradient", "perceptual", "fm", "gan_g", "extra",
    "loss_d",
)  # fmt: skip


class GanConfig(Protocol):
    """The config fields the trainer reads (``RendererConfig`` and every ``BaselineConfig``
    have them)."""

    lr_g: float
    lr_d: float
    betas: tuple[float, float]
    adam_eps: float
    texture_lr_scale: float
    lr_decay_from: float
    gan_mode: str
    w_l1: float
    w_pyramid: float
    w_detail: float
    w_gradient: float
    w_perceptual: float
    w_fm: float
    w_gan: float
    vgg_path: str
    vgg_channels: tuple[int, ...]
    seed: int


class Method(Protocol):
    """What a method brings to the trainer.

    ``generate(net, batch) -> (fake (B, 3, H, W), aux)``: the generator (``net`` is it, or its
    DistributedDataParallel wrapper) on a batch; ``target(batch) -> (B, 3, H, W)``: the ground
    truth at frame t; ``disc_inputs(batch, fake) -> (real (B', C, H, W), fake (B', C, H, W))``:
    what the discriminator sees; ``extra_loss(batch, aux)``: the method's own regulariser
    (unweighted scalar), weighted by ``extra_weight``.
    """

    extra_weight: float

    def generate(self, net: nn.Module, batch) -> tuple[torch.Tensor, object]: ...

    def target(self, batch) -> torch.Tensor: ...

    def disc_inputs(self, batch, fake: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]: ...

    def extra_loss(self, batch, aux) -> torch.Tensor: ...


@dataclass(frozen=True)
class RunFiles:
    """Where a run keeps its checkpoint and log, and what its checkpoint must match.

    checkpoint, log : the resumable checkpoint and the CSV loss log
    log_columns : the log's columns (``step``, ``epoch``, losses of :data:`LOSSES`,
        ``skipped``, ``seconds``)
    format, what : the checkpoint's format string and the name its errors use
    identity : ``(key, value, what differs)`` stored in the checkpoint and checked on resume
    extra : stored, not checked
    """

    checkpoint: Path
    log: Path
    log_columns: tuple[str, ...]
    format: str
    what: str
    identity: tuple[tuple[str, object, str], ...]
    extra: dict = field(default_factory=dict)


def dataset_fingerprint(dataset) -> str:
    """SHA-256 of the data set's length and its first and last samples (cheap, catches a
    different data set in a resumed folder); InputError for an empty data set."""
    if len(dataset) == 0:
        raise InputError("data set is empty: nothing to train on")
    h = hashlib.sha256(str(len(dataset)).encode())
    for i in sorted({0, len(dataset) - 1}):
        s = dataset[i]
        for k in sorted(s):
            t = torch.as_tensor(s[k]).float().contiguous()
            h.update(k.encode() + str(tuple(t.shape)).encode() + t.numpy().tobytes())
    return h.hexdigest()


def world_size() -> int:
    """Processes of the run: torchrun's world size, 1 without a process group."""
    return dist.get_world_size() if dist.is_available() and dist.is_initialized() else 1


def adam(params: Iterable, lr: float, betas, eps: float, device: torch.device):
    """Adam over parameters or parameter groups, fused on CPU and CUDA (several times faster
    than the per-tensor loop on a large neural texture)."""
    fused = device.type in ("cpu", "cuda")
    return torch.optim.Adam(list(params), lr=lr, betas=tuple(betas), eps=eps, fused=fused)


def generator_groups(generator: nn.Module, lr: float, texture_lr_scale: float) -> list[dict]:
    """The generator's trainable parameters as Adam's groups: the neural texture's
    (``texture.*``, where the generator has one) at ``lr * texture_lr_scale``, the rest at
    ``lr``; each group's ``lr_scale`` is what :func:`~training.schedule.set_lr` keeps."""
    named = [(n, p) for n, p in generator.named_parameters() if p.requires_grad]
    texture = [p for n, p in named if n.startswith("texture.")]
    rest = [p for n, p in named if not n.startswith("texture.")]
    groups = [(rest, 1.0), (texture, texture_lr_scale)]
    return [{"params": ps, "lr": lr * s, "lr_scale": s} for ps, s in groups if ps]


class AdversarialTrainer(AdversarialRun):
    """The state of one run (so a checkpoint captures all of it) and its step.

    Parameters
    ----------
    generator, discriminator : the networks, built by the caller after seeding (None: the
        method is L1-only, no GAN or FM)
    method : :class:`Method`
    config : :class:`GanConfig`
    files : :class:`RunFiles`
    n_samples, batch_size, steps : the data set's length, samples per step and process, the
        run's step budget
    device : where the networks train
    precision : the generator's arithmetic (``fp32``, ``bf16`` or ``fp16``; fp16 with loss
        scaling); the discriminator and the losses always run in float32

    The generator's parameters that require grad train (fine-tuning freezes the others).

    Under torchrun (an initialised process group) the networks are wrapped in
    DistributedDataParallel and only rank 0 writes files.
    """

    def __init__(
        self,
        generator: nn.Module,
        discriminator: nn.Module | None,
        method: Method,
        config: GanConfig,
        files: RunFiles,
        *,
        n_samples: int,
        batch_size: int,
        steps: int,
        device: torch.device,
        precision: str = "fp32",
    ):
        self.net, self.disc, self.method, self.config, self.files = (
            generator, discriminator, method, config, files
        )  # fmt: skip
        self.device = device
        self.steps = steps
        self.distributed = dist.is_available() and dist.is_initialized()
        self.rank = dist.get_rank() if self.distributed else 0
        self.world = world_size()
        if n_samples < batch_size * self.world:
            processes = f" x {self.world} processes" if self.world > 1 else ""
            raise InputError(
                f"data set has {n_samples} samples, fewer than one batch ({batch_size}{processes})"
            )
        self.net.to(device)
        self.g_params = [p for p in generator.parameters() if p.requires_grad]
        self.opt_g = adam(
            generator_groups(generator, config.lr_g, config.texture_lr_scale),
            config.lr_g, config.betas, config.adam_eps, device,
        )  # fmt: skip
        self.opt_d = None
        if discriminator is not None:
            discriminator.to(device)
            self.opt_d = adam(
                discriminator.parameters(), config.lr_d, config.betas, config.adam_eps, device
            )
        self.precision = precision
        self.amp = precision != "fp32"
        scaled = precision == "fp16"  # bfloat16 has float32's range: no loss scaling
        self.scaler_g = torch.amp.GradScaler("cuda", enabled=scaled)
        self.scaler_d = torch.amp.GradScaler("cuda", enabled=scaled)
        self.perceptual = (
            load_perceptual(config.vgg_path, config.vgg_channels)
            if config.w_perceptual > 0
            else None
        )
        if self.perceptual is not None:
            self.perceptual.to(device)
        if self.distributed:
            ids = [device.index] if device.type == "cuda" else None
            ddp = torch.nn.parallel.DistributedDataParallel
            self.g_ddp = ddp(generator, device_ids=ids)
            self.d_ddp = None if discriminator is None else ddp(discriminator, device_ids=ids)
        else:
            self.g_ddp, self.d_ddp = generator, discriminator
        losses = tuple(c for c in files.log_columns if c in LOSSES)
        super().__init__(n_samples, config.seed, losses)

    # -- one step ------------------------------------------------------------------------------

    def _autocast(self):
        if self.amp:
            dtype = torch.bfloat16 if self.precision == "bf16" else torch.float16
            return torch.autocast(self.device.type, dtype=dtype)
        return contextlib.nullcontext()

    def train_step(self, batch) -> dict[str, float] | None:
        """One step (the module docstring); the losses, or None when the guard skipped it."""
        cfg, method, disc = self.config, self.method, self.disc
        scale = lr_scale(self.step, self.steps, cfg.lr_decay_from)
        set_lr(self.opt_g, cfg.lr_g * scale)
        set_lr(self.opt_d, cfg.lr_d * scale)
        self.net.train()
        real_t = method.target(batch)
        with self._autocast():
            fake, aux = method.generate(self.g_ddp, batch)
        fake = fake.float()
        self.opt_g.zero_grad(set_to_none=True)
        zero = fake.new_zeros(())
        loss_d, gan, fm = zero, zero, zero
        if disc is not None:
            disc.train()
            self.opt_d.zero_grad(set_to_none=True)
            real_in, fake_in = method.disc_inputs(batch, fake.detach())
            logits, feats = self.d_ddp(torch.cat([real_in, fake_in]))
            # The real half's activations, of the same (pre-update) discriminator that feature
            # matching compares with: reused, not recomputed.
            feats_r = [f[: len(real_in)].detach().float() for f in feats]
            lr, lf = logits.float().chunk(2)
            loss_d = gan_d_loss(lr, lf, cfg.gan_mode)
            self.scaler_d.scale(loss_d).backward()
            # The generator's loss through the plain discriminator (its gradients not wanted).
            for p in disc.parameters():
                p.requires_grad_(False)
            try:
                _, fake_in = method.disc_inputs(batch, fake)
                logits_f, feats_f = disc(fake_in)
                gan = gan_g_loss(logits_f.float(), cfg.gan_mode)
                if cfg.w_fm > 0:
                    fm = feature_matching([f.float() for f in feats_f], feats_r)
            finally:
                for p in disc.parameters():
                    p.requires_grad_(True)
        l1 = F.l1_loss(fake, real_t)
        pyramid = pyramid_l1(fake, real_t) if cfg.w_pyramid > 0 else zero
        detail = detail_energy_l1(fake, real_t) if cfg.w_detail > 0 else zero
        gradient = gradient_similarity_loss(fake, real_t) if cfg.w_gradient > 0 else zero
        perc = self.perceptual(fake, real_t) if self.perceptual is not None else zero
        extra = method.extra_loss(batch, aux) if method.extra_weight > 0 else zero
        loss_g = (
            cfg.w_l1 * l1
            + cfg.w_pyramid * pyramid
            + cfg.w_detail * detail
            + cfg.w_gradient * gradient
            + cfg.w_perceptual * perc
            + cfg.w_fm * fm
            + cfg.w_gan * gan
            + method.extra_weight * extra
        )
        self.scaler_g.scale(loss_g).backward()
        if not self._finite(loss_g, loss_d):
            self.opt_g.zero_grad(set_to_none=True)
            if self.opt_d is not None:
                self.opt_d.zero_grad(set_to_none=True)
            return None
        if self.opt_d is not None:
            self.scaler_d.step(self.opt_d)
            self.scaler_d.update()
        self.scaler_g.step(self.opt_g)
        self.scaler_g.update()
        values = dict(
            zip(LOSSES, (loss_g, l1, pyramid, detail, gradient, perc, fm, gan, extra, loss_d))
        )
        return {k: float(values[k].detach()) for k in self.losses}

    def _finite(self, loss_g: torch.Tensor, loss_d: torch.Tensor) -> bool:
        """Whether both losses and every gradient are finite, on every process (fp16's scalers
        skip non-finite steps themselves, so only the losses are checked there)."""
        finite = torch.isfinite(loss_g) & torch.isfinite(loss_d)
        if not self.scaler_g.is_enabled():
            params = [*self.g_params, *(self.disc.parameters() if self.disc is not None else ())]
            grads = [p.grad for p in params if p.grad is not None]
            if grads:
                finite = finite & torch.stack([g.isfinite().all() for g in grads]).all()
        finite = finite.to(torch.int32)
        if self.distributed:
            dist.all_reduce(finite, op=dist.ReduceOp.MIN)
        return bool(finite)

    # -- log and checkpoints -------------------------------------------------------------------

    def off_losses(self) -> set[str]:
        off = {"fm", "gan_g", "loss_d"} if self.disc is None else set()
        off |= {"pyramid"} if self.config.w_pyramid <= 0 else set()
        off |= {"detail"} if self.config.w_detail <= 0 else set()
        off |= {"gradient"} if self.config.w_gradient <= 0 else set()
        return off | ({"perceptual"} if self.perceptual is None else set())

    def _modules(self) -> dict[str, object | None]:
        """The checkpoint's keys of everything with a state dict."""
        return {
            "generator": self.net,
            "discriminator": self.disc,
            "opt_g": self.opt_g,
            "opt_d": self.opt_d,
            "scaler_g": self.scaler_g,
            "scaler_d": self.scaler_d,
        }

    def flush_log(self) -> None:
        if self.rank == 0:
            append_rows(self.files.log, self.files.log_columns, self.pending_rows)
        self.pending_rows = []

    def save_checkpoint(self) -> None:
        """Flush the log; rank 0 writes the checkpoint atomically."""
        self.flush_log()
        if self.rank != 0:
            return
        payload = {
            "format": self.files.format,
            **{key: value for key, value, _ in self.files.identity},
            **self.files.extra,
            **{k: None if m is None else m.state_dict() for k, m in self._modules().items()},
            **self.run_state(),
        }
        with atomic_path(self.files.checkpoint) as tmp:
            torch.save(payload, tmp)

    def load_checkpoint(self) -> None:
        """Resume from the checkpoint (InputError naming it when it was made otherwise); log
        rows written after it are dropped."""
        payload = read_checkpoint(
            self.files.checkpoint, self.files.format, self.files.what, list(self.files.identity)
        )
        for key, module in self._modules().items():
            if module is not None and payload.get(key) is not None:
                module.load_state_dict(payload[key])
        self.restore_run_state(payload)
        if self.rank == 0:
            truncate_rows(self.files.log, self.files.log_columns, self.step)

    def start(self) -> None:
        """Resume when the checkpoint is there; otherwise a fresh log."""
        if self.files.checkpoint.is_file():
            self.load_checkpoint()
        elif self.rank == 0:
            with contextlib.suppress(FileNotFoundError):
                self.files.log.unlink()
