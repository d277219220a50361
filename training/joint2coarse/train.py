"""Training Joint2Coarse: data split, three stages, atomic resumable checkpoints, loss log.

Stages (DESIGN, "The method"):

1. ``autoencoder``: shape encoder + decoder on normalised output-frame proxy vertices (vertex L2;
   the output frame is the root frame tilted per vertex, ``config.tilt_follow``);
   the decoder's output basis (``config.output_basis``) is set from the training shapes first.
2. ``motion``: motion encoder onto the frozen shape latent of each frame (latent L2).
3. ``finetune``: motion encoder + decoder end to end on vertex L2 (skipped when 0 steps).

A run writes three files into ``out_dir``: the training checkpoint (everything a resumed run
needs: weights, optimiser, RNG states, stage, step, epoch and the current shuffle), the loss log
(CSV) and, when every stage is done, the inference model file. Re-running with the same data and
config continues from the last checkpoint and ends with the same weights as an uninterrupted run.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from core.errors import InputError
from core.fileio import atomic_path
from training.csvlog import append_rows, truncate_rows
from training.joint2coarse.augment import MirrorMap, mirror_motion
from training.joint2coarse.body_model import fit_body_residual
from training.joint2coarse.config import Joint2CoarseConfig
from training.joint2coarse.descriptor import (
    check_joint_inputs,
    follow_weights,
    motion_descriptors,
    tilt_rotvecs,
    to_output_frame,
    to_root_frame,
)
from training.joint2coarse.metrics import VertexErrors
from training.joint2coarse.model import (
    Joint2CoarseNet,
    net_from_payload,
    save_model,
    stored_config,
)
from training.loop import read_checkpoint

#: Format tag of a training checkpoint.
CHECKPOINT_FORMAT = "joint2coarse-train/1"
#: File names inside a training folder.
CHECKPOINT_NAME = "joint2coarse_train.pt"
MODEL_NAME = "joint2coarse.pt"
LOG_NAME = "joint2coarse_loss.csv"
#: Training stages, in order.
STAGES = ("autoencoder", "motion", "finetune")
LOG_COLUMNS = ("step", "stage", "epoch", "train_loss", "val_loss", "val_mean_mm")


@dataclass(frozen=True)
class Joint2CoarseClip:
    """One training pair: a motion and the proxy simulated under it.

    Attributes
    ----------
    joints : (T, 20, 3) float32
        World joint positions, root then CANONICAL_JOINTS (:func:`joint2coarse_inputs`).
    root_rotations : (T, 3, 3) float32
        World rotation of the root joint.
    proxy : (T, Vc, 3) float32
        Simulated proxy vertices, world positions.
    name : str
        Where the pair came from (cache file), named in error messages.
    """

    joints: np.ndarray
    root_rotations: np.ndarray
    proxy: np.ndarray
    name: str = ""

    def __post_init__(self) -> None:
        t = check_joint_inputs(self.joints, self.root_rotations, self.name)
        p = np.asarray(self.proxy)
        if p.ndim != 3 or p.shape[2] != 3 or p.shape[1] == 0:
            raise InputError(f"proxy cache must be (T, Vc, 3), got {p.shape}", self.name or None)
        if p.shape[0] != t:
            raise InputError(
                f"proxy cache has {p.shape[0]} frames but the motion has {t}", self.name or None
            )
        if not np.isfinite(p).all():
            raise InputError("proxy cache contains NaN or infinite values", self.name or None)

    @property
    def num_frames(self) -> int:
        return len(self.joints)


@dataclass(frozen=True)
class Joint2CoarseData:
    """Descriptors and output-frame vertices, split into training and validation frames.

    Attributes
    ----------
    train_desc, val_desc : (N, D) float32
    train_verts, val_verts : (N, Vc * 3) float32
        Proxy vertices in their frame's output frames
        (:func:`~training.joint2coarse.descriptor.to_output_frame`), flattened.
    n_vertices : int
    follow : (Vc,) float32
        Each vertex's share of the root's tilt in its output frame (all 0: the root frame).
    """

    train_desc: np.ndarray
    train_verts: np.ndarray
    val_desc: np.ndarray
    val_verts: np.ndarray
    n_vertices: int
    follow: np.ndarray

    def fingerprint(self) -> str:
        """SHA-256 of the arrays: a resumed run must train on exactly the same data."""
        h = hashlib.sha256()
        for a in (self.train_desc, self.train_verts, self.val_desc, self.val_verts, self.follow):
            h.update(str(a.shape).encode())
            h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()


def split_frames(num_frames: int, val_fraction: float) -> int:
    """Frames of a clip used for training; the rest (its end, contiguous) is validation."""
    n_val = int(round(num_frames * val_fraction))
    if val_fraction > 0 and num_frames >= 2:
        n_val = max(n_val, 1)
    return max(num_frames - n_val, 1)


def prepare_data(clips: Sequence[Joint2CoarseClip], config: Joint2CoarseConfig) -> Joint2CoarseData:
    """Descriptors and output-frame targets of every clip, split per clip (last frames held out).

    The output frames' follow weights (:func:`follow_weights`) come from the height of each
    vertex in the root frame, averaged over the training frames of every clip.
    """
    if not clips:
        raise InputError("Joint2Coarse needs at least one (motion, proxy cache) pair")
    n_vertices = clips[0].proxy.shape[1]
    frames = []  # per clip: descriptors, origin, heading, tilt, training frame count
    height_sum, height_count = np.zeros(n_vertices), 0
    for clip in clips:
        if clip.proxy.shape[1] != n_vertices:
            raise InputError(
                f"proxy cache has {clip.proxy.shape[1]} vertices, the first clip has {n_vertices}",
                clip.name or None,
            )
        desc, origin, heading = motion_descriptors(
            clip.joints, clip.root_rotations, config.window, config.stride
        )
        n_train = split_frames(clip.num_frames, config.val_fraction)
        rooted = to_root_frame(clip.proxy[:n_train], origin[:n_train], heading[:n_train])
        height_sum += rooted[..., 1].sum(0)
        height_count += n_train
        frames.append((desc, origin, heading, tilt_rotvecs(clip.root_rotations, heading), n_train))
    follow = np.zeros(n_vertices, np.float32)
    if config.tilt_follow > 0:
        follow = follow_weights(height_sum / height_count, config.tilt_follow)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("td", "tv", "vd", "vv")}
    for clip, (desc, origin, heading, tilt, n_train) in zip(clips, frames):
        local = to_output_frame(clip.proxy, origin, heading, tilt, follow)
        local = local.reshape(len(desc), -1).astype(np.float32)
        parts["td"].append(desc[:n_train])
        parts["tv"].append(local[:n_train])
        parts["vd"].append(desc[n_train:])
        parts["vv"].append(local[n_train:])
    return Joint2CoarseData(
        train_desc=np.concatenate(parts["td"]),
        train_verts=np.concatenate(parts["tv"]),
        val_desc=np.concatenate(parts["vd"]),
        val_verts=np.concatenate(parts["vv"]),
        n_vertices=n_vertices,
        follow=follow,
    )


def normalisation_statistics(
    data: Joint2CoarseData, std_floor: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-coordinate mean and std (floored) of training descriptors and vertices, float32."""
    out = []
    for a in (data.train_desc, data.train_verts):
        a = a.astype(np.float64)
        out += [a.mean(0).astype(np.float32), np.maximum(a.std(0), std_floor).astype(np.float32)]
    return out[0], out[1], out[2], out[3]


@dataclass(frozen=True)
class Joint2CoarseTrainResult:
    """What a finished training run produced.

    Attributes
    ----------
    net : Joint2CoarseNet
        The final network, eval mode.
    model_path, log_path, checkpoint_path : Path
    stage_errors : dict[str, VertexErrors]
        Validation error after each stage: ``autoencoder`` is the reconstruction of the true
        shape (a floor for the rest), ``motion`` and ``finetune`` are motion -> proxy. Empty
        when there are no validation frames.
    baseline : VertexErrors or None
        Validation error of the mean training shape placed in each frame's root frame.
    resumed_at_step : int
        Step the run resumed from (0 for a fresh run).
    """

    net: Joint2CoarseNet
    model_path: Path
    log_path: Path
    checkpoint_path: Path
    stage_errors: dict[str, VertexErrors]
    baseline: VertexErrors | None
    resumed_at_step: int


def _errors_mm(pred: np.ndarray, ref: np.ndarray) -> VertexErrors:
    e = np.linalg.norm((pred - ref).reshape(len(ref), -1, 3).astype(np.float64), axis=-1) * 1e3
    return VertexErrors(float(e.mean()), float(np.percentile(e, 95)), float(e.max()))


class _Trainer:
    """The state of one run; kept as an object so checkpoints capture all of it."""

    def __init__(self, data: Joint2CoarseData, config: Joint2CoarseConfig, out_dir: Path) -> None:
        self.data = data
        self.config = config
        self.checkpoint_path = out_dir / CHECKPOINT_NAME
        self.model_path = out_dir / MODEL_NAME
        self.log_path = out_dir / LOG_NAME
        self.fingerprint = data.fingerprint()
        self.stage_steps = (config.autoencoder_steps, config.motion_steps, config.finetune_steps)
        d = data.train_desc.shape[1]
        torch.manual_seed(config.seed)
        self.net = Joint2CoarseNet(config, data.n_vertices, d)
        self.net.set_statistics(*normalisation_statistics(data, config.std_floor))
        self.net.follow.copy_(torch.from_numpy(data.follow))
        self.shuffle = torch.Generator().manual_seed(config.seed + 1)
        self.td = torch.from_numpy(data.train_desc)
        self.tx = self.net.normalise_vertices(torch.from_numpy(data.train_verts))
        self.net.set_output_basis(self.tx.numpy())
        self.vd = torch.from_numpy(data.val_desc)
        self.vx = self.net.normalise_vertices(torch.from_numpy(data.val_verts))
        self.stage = 0
        self.stage_step = 0
        self.step = 0
        self.epoch = 0
        self.perm = torch.randperm(len(self.td), generator=self.shuffle)
        self.pos = 0
        self.optimizer: torch.optim.Optimizer | None = None
        self.latents: torch.Tensor | None = None
        self.stage_errors: dict[str, list[float]] = {}
        self.pending_rows: list[list] = []
        self.loss_sum = 0.0
        self.loss_count = 0
        self.resumed_at_step = 0

    # -- stages ------------------------------------------------------------------------------

    def _stage_parameters(self, stage: int) -> list[torch.nn.Parameter]:
        n = self.net
        if stage == 0:
            return [*n.shape_encoder.parameters(), *n.shape_decoder.parameters()]
        if stage == 1:
            return list(n.motion_encoder.parameters())
        return [*n.motion_encoder.parameters(), *n.shape_decoder.parameters()]

    def _begin_stage(self) -> None:
        lr = self.config.finetune_learning_rate if self.stage == 2 else self.config.learning_rate
        self.optimizer = torch.optim.RMSprop(self._stage_parameters(self.stage), lr=lr)
        self.latents = None
        if self.stage == 1:  # targets: the frozen shape latent of each training frame
            self.net.eval()
            with torch.no_grad():
                self.latents = self.net.shape_encoder(self.tx)

    def _loss(self, stage: int, desc: torch.Tensor, x: torch.Tensor, idx=None) -> torch.Tensor:
        n = self.net
        if stage == 0:
            return torch.mean((n.shape_decoder(n.shape_encoder(x)) - x) ** 2)
        z = n.motion_encoder(n.normalise_descriptor(desc))
        if stage == 1:
            target = self.latents[idx] if idx is not None else n.shape_encoder(x)
            return torch.mean((z - target) ** 2)
        return torch.mean((n.shape_decoder(z) - x) ** 2)

    def _prediction(self, stage: int, desc: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Normalised vertex prediction of the stage's path (eval mode, no grad)."""
        n = self.net
        if stage == 0:
            z = n.shape_encoder(x)
        else:
            z = n.motion_encoder(n.normalise_descriptor(desc))
        return n.shape_decoder(z).clamp(-self.config.clamp_z, self.config.clamp_z)

    def validate(self, stage: int) -> tuple[float, VertexErrors] | None:
        if len(self.vd) == 0:
            return None
        self.net.eval()
        with torch.no_grad():
            loss = float(self._loss(stage, self.vd, self.vx))
            pred = (
                self._prediction(stage, self.vd, self.vx) * self.net.vert_std + self.net.vert_mean
            )
        return loss, _errors_mm(pred.numpy(), self.data.val_verts)

    def _next_batch(self) -> torch.Tensor:
        b = min(self.config.batch_size, len(self.perm))
        if self.pos + b > len(self.perm):
            self.perm = torch.randperm(len(self.td), generator=self.shuffle)
            self.pos = 0
            self.epoch += 1
        idx = self.perm[self.pos : self.pos + b]
        self.pos += b
        return idx

    def train_step(self) -> float:
        idx = self._next_batch()
        self.net.train()
        loss = self._loss(self.stage, self.td[idx], self.tx[idx], idx)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return float(loss.detach())

    # -- log and checkpoints -------------------------------------------------------------------

    def log_row(self, evaluate: bool) -> tuple[float, float | None]:
        train = self.loss_sum / max(self.loss_count, 1)
        self.loss_sum, self.loss_count = 0.0, 0
        val_loss = val_mm = ""
        if evaluate and (v := self.validate(self.stage)) is not None:
            val_loss, val_mm = f"{v[0]:.6g}", f"{v[1].mean_mm:.4f}"
        self.pending_rows.append(
            [self.step, STAGES[self.stage], self.epoch, f"{train:.6g}", val_loss, val_mm]
        )
        return train, (float(val_mm) if val_mm else None)

    def flush_log(self) -> None:
        append_rows(self.log_path, LOG_COLUMNS, self.pending_rows)
        self.pending_rows = []

    def truncate_log(self) -> None:
        """Drop log rows written after the checkpoint a resumed run starts from."""
        truncate_rows(self.log_path, LOG_COLUMNS, self.step)

    def save_checkpoint(self) -> None:
        self.flush_log()
        payload = {
            "format": CHECKPOINT_FORMAT,
            "config": self.config.to_dict(),
            "n_vertices": self.net.n_vertices,
            "descriptor_dim": self.net.descriptor_dim,
            "fingerprint": self.fingerprint,
            "state_dict": self.net.state_dict(),
            "optimizer": None if self.optimizer is None else self.optimizer.state_dict(),
            "stage": self.stage,
            "stage_step": self.stage_step,
            "step": self.step,
            "epoch": self.epoch,
            "perm": self.perm,
            "pos": self.pos,
            "torch_rng": torch.get_rng_state(),
            "shuffle_rng": self.shuffle.get_state(),
            "stage_errors": self.stage_errors,
            "loss_sum": self.loss_sum,
            "loss_count": self.loss_count,
        }
        with atomic_path(self.checkpoint_path) as tmp:
            torch.save(payload, tmp)

    def load_checkpoint(self) -> None:
        path = self.checkpoint_path
        payload = read_checkpoint(
            path, CHECKPOINT_FORMAT, "Joint2Coarse",
            [("fingerprint", self.fingerprint, "different training data")],
        )  # fmt: skip
        if stored_config(payload, path) != self.config:  # older files lack newer fields
            raise InputError(
                "checkpoint was made with a different config: use a new folder or delete it", path
            )
        self.net.load_state_dict(net_from_payload(payload, path).state_dict())
        self.stage = int(payload["stage"])
        self.stage_step = int(payload["stage_step"])
        self.step = self.resumed_at_step = int(payload["step"])
        self.epoch = int(payload["epoch"])
        self.perm = payload["perm"]
        self.pos = int(payload["pos"])
        self.stage_errors = payload["stage_errors"]
        self.loss_sum = float(payload["loss_sum"])
        self.loss_count = int(payload["loss_count"])
        torch.set_rng_state(payload["torch_rng"])
        self.shuffle.set_state(payload["shuffle_rng"])
        if self.stage < len(STAGES):
            self._begin_stage()
            if payload["optimizer"] is not None:
                self.optimizer.load_state_dict(payload["optimizer"])
        self.truncate_log()


def mirrored_clips(
    clips: Sequence[Joint2CoarseClip], mirror: MirrorMap | None
) -> list[Joint2CoarseClip]:
    """``clips`` followed by each one's left-right mirror (:mod:`training.joint2coarse.augment`),
    named ``NAME (mirrored)``; refused for a garment that is not symmetric
    (:meth:`~training.joint2coarse.augment.MirrorMap.check`)."""
    if mirror is None:
        raise InputError(
            "Joint2Coarse with mirror=true needs the proxy's mirror map (augment.mirror_map)"
        )
    mirror.check()
    out = list(clips)
    for clip in clips:
        if clip.proxy.shape[1] != len(mirror.corners):
            raise InputError(
                f"the mirror map has {len(mirror.corners)} vertices, the proxy cache "
                f"{clip.proxy.shape[1]}",
                clip.name or None,
            )
        joints, root_rotations = mirror_motion(clip.joints, clip.root_rotations)
        proxy = mirror.reflect(clip.proxy).astype(np.float32)
        out.append(Joint2CoarseClip(joints, root_rotations, proxy, f"{clip.name} (mirrored)"))
    return out


def train_joint2coarse(
    clips: Sequence[Joint2CoarseClip],
    out_dir: str | os.PathLike,
    config: Joint2CoarseConfig | None = None,
    *,
    progress: bool = True,
    callback: Callable[[int, str, float], None] | None = None,
    rig: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    mirror: MirrorMap | None = None,
) -> Joint2CoarseTrainResult:
    """Train Joint2Coarse on (motion, proxy cache) pairs, resuming from ``out_dir`` if possible.

    Parameters
    ----------
    clips : sequence of Joint2CoarseClip
        All with the same proxy vertex count.
    out_dir : path
        Gets the checkpoint, the loss log and the model file. A checkpoint already there from
        the same config and data is resumed; one from anything else raises :class:`InputError`.
    config : Joint2CoarseConfig, optional
        The paper's defaults when None.
    progress : bool
        Show a tqdm progress bar.
    callback : callable(step, stage, loss), optional
        Called after every optimisation step (the GUI's hook; raising from it stops the run,
        which then resumes from the last checkpoint).
    rig : (weights, rest_joints, rest_vertices), optional
        :func:`~training.joint2coarse.body_model.body_rig` of the proxy; required by
        ``config.model == "ours"`` (fitted in closed form: no steps, no checkpoint).
    mirror : MirrorMap, optional
        :func:`~training.joint2coarse.augment.mirror_map` of the proxy; required by
        ``config.mirror``, which adds every clip's mirror (:func:`mirrored_clips`).

    Returns
    -------
    Joint2CoarseTrainResult
    """
    # Here, not at module level: the torch-only render path (training.torchpath) imports
    # this package, and a machine with only torch and numpy has no tqdm.
    from tqdm.auto import tqdm

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cfg = config or Joint2CoarseConfig()
    if cfg.mirror:
        clips = mirrored_clips(clips, mirror)
    if cfg.model == "ours":
        return _train_ours(clips, out_dir, cfg, rig, mirror)
    data = prepare_data(clips, cfg)
    # Our own RNG stream: initial weights, dropout and shuffling never touch the caller's.
    with torch.random.fork_rng(devices=[]):
        tr = _Trainer(data, cfg, out_dir)
        if tr.checkpoint_path.is_file():
            tr.load_checkpoint()
        else:
            tr._begin_stage()
            with contextlib.suppress(FileNotFoundError):
                tr.log_path.unlink()
        bar = tqdm(
            total=cfg.total_steps, initial=tr.step, disable=not progress, desc="joint2coarse"
        )
        with bar:
            while tr.stage < len(STAGES):
                n_steps = tr.stage_steps[tr.stage]
                while tr.stage_step < n_steps:
                    loss = tr.train_step()
                    tr.stage_step += 1
                    tr.step += 1
                    tr.loss_sum += loss
                    tr.loss_count += 1
                    done = tr.stage_step == n_steps
                    if tr.step % cfg.log_every == 0 or done:
                        train, val_mm = tr.log_row(tr.step % cfg.eval_every == 0 or done)
                        post = {"stage": STAGES[tr.stage], "loss": f"{train:.4g}"}
                        if val_mm is not None:
                            post["val_mm"] = f"{val_mm:.2f}"
                        bar.set_postfix(post, refresh=False)
                    bar.update(1)
                    if not done and tr.step % cfg.checkpoint_every == 0:
                        tr.save_checkpoint()
                    if callback is not None:
                        callback(tr.step, STAGES[tr.stage], loss)
                v = tr.validate(tr.stage)
                if v is not None:
                    e = v[1]
                    tr.stage_errors[STAGES[tr.stage]] = [e.mean_mm, e.p95_mm, e.max_mm]
                tr.stage += 1
                tr.stage_step = 0
                if tr.stage < len(STAGES):
                    tr._begin_stage()
                else:
                    tr.optimizer = None
                tr.save_checkpoint()
    tr.net.eval()
    save_model(tr.net, tr.model_path)
    baseline = None
    if len(data.val_verts):
        mean = tr.net.vert_mean.numpy()[None]
        baseline = _errors_mm(np.broadcast_to(mean, data.val_verts.shape), data.val_verts)
    errors = {k: VertexErrors(*v) for k, v in tr.stage_errors.items()}
    return Joint2CoarseTrainResult(
        net=tr.net,
        model_path=tr.model_path,
        log_path=tr.log_path,
        checkpoint_path=tr.checkpoint_path,
        stage_errors=errors,
        baseline=baseline,
        resumed_at_step=tr.resumed_at_step,
    )


def _train_ours(
    clips: Sequence[Joint2CoarseClip],
    out_dir: Path,
    cfg: Joint2CoarseConfig,
    rig: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
    mirror: MirrorMap | None,
) -> Joint2CoarseTrainResult:
    """Fit our model (:func:`fit_body_residual`) on the heading-frame training frames (with
    ``config.mirror``, the model keeps the mirror map and predicts symmetrically); the log
    gets one row with the held-out frames' error, its stage ``residual`` (the network) or
    ``ridge`` (the linear residual)."""
    if rig is None:
        raise InputError("our Joint2Coarse (model=ours) needs the proxy's body rig (body_rig)")
    data = prepare_data(clips, replace(cfg, tilt_follow=0.0))  # ours predicts in the heading frame
    model = fit_body_residual(cfg, data.train_desc, data.train_verts, rig, mirror)
    model_path, log_path = out_dir / MODEL_NAME, out_dir / LOG_NAME
    save_model(model, model_path)
    errors, baseline = {}, None
    stage = "residual" if cfg.residual_widths else "ridge"
    row = [cfg.residual_steps if cfg.residual_widths else 0, stage, 0, "", "", ""]
    if len(data.val_verts):
        pred = model.predict(data.val_desc).reshape(len(data.val_desc), -1)
        errors[stage] = _errors_mm(pred, data.val_verts)
        row[-1] = f"{errors[stage].mean_mm:.4f}"
        mean = data.train_verts.mean(0, keepdims=True)
        baseline = _errors_mm(np.broadcast_to(mean, data.val_verts.shape), data.val_verts)
    with contextlib.suppress(FileNotFoundError):
        log_path.unlink()
    append_rows(log_path, LOG_COLUMNS, [row])
    return Joint2CoarseTrainResult(
        net=model,
        model_path=model_path,
        log_path=log_path,
        checkpoint_path=out_dir / CHECKPOINT_NAME,
        stage_errors=errors,
        baseline=baseline,
        resumed_at_step=0,
    )
