"""Joint2Coarse networks: shape autoencoder, motion encoder, normalisation, save and load."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from torch import nn

from core.errors import InputError
from core.fileio import atomic_path, read_torch_payload
from training.joint2coarse.body_model import body_model_from_state
from training.joint2coarse.config import Joint2CoarseConfig

#: Format tag of a saved model file.
MODEL_FORMAT = "joint2coarse-model/1"


def mlp(in_dim: int, widths: tuple[int, ...], out_dim: int, dropout: float) -> nn.Sequential:
    """Linear -> ReLU -> Dropout for each hidden width, then a plain Linear to ``out_dim``."""
    layers: list[nn.Module] = []
    prev = in_dim
    for w in widths:
        layers += [nn.Linear(prev, w), nn.ReLU()]
        if dropout > 0:
            layers.append(nn.Dropout(dropout))
        prev = w
    layers.append(nn.Linear(prev, out_dim))
    return nn.Sequential(*layers)


class OutputBasis(nn.Module):
    """Fixed linear basis: coefficients (B, K) -> ``coefficients @ basis`` (B, N).

    The basis (K, N) float32 is a buffer (saved with the weights, never trained); it starts at
    zero and is set by :meth:`Joint2CoarseNet.set_output_basis`.
    """

    def __init__(self, n_components: int, n_outputs: int):
        super().__init__()
        self.register_buffer("basis", torch.zeros(n_components, n_outputs))

    def forward(self, coefficients: torch.Tensor) -> torch.Tensor:
        return coefficients @ self.basis


def principal_basis(data: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` leading principal directions of ``data`` (its rows are samples), as rows, each
    scaled by the data's RMS along it, so the coefficients of the data are about unit size.

    The directions are those of the uncentred second moment ``data.T @ data``: for z-scored
    data (mean zero) that is the PCA. Unit-size coefficients are what the decoder's last layer
    learns easily (as it does the unit-variance z-scores of a full last layer); unscaled, the
    leading coefficients are tens of units and training is slower and less accurate. Computed in
    float64 from a thin SVD, or from the eigen decomposition of ``data.T @ data`` when there are
    more samples than coordinates. Each row's largest entry is made positive, so the result does
    not depend on the LAPACK sign choice. Rows beyond the data's rank are (about) zero; rows
    beyond ``min(N, D)`` exactly zero.

    The decomposition runs in torch, not numpy: numpy's LAPACK result changes with its BLAS
    thread count (``OMP_NUM_THREADS``), which no setting of ours controls, and a different basis
    trains a different Joint2Coarse. torch's follows ``torch.set_num_threads``, which the
    pipeline pins (``torch_threads``), so a seed gives the same model whatever the environment
    says.

    Parameters
    ----------
    data : (N, D) float
    k : int

    Returns
    -------
    (k, D) float32 with orthogonal rows, in decreasing order of norm (the RMS).
    """
    x = torch.as_tensor(np.asarray(data, np.float64))
    n, d = x.shape
    if n > d:
        power, vecs = torch.linalg.eigh(x.T @ x)  # ascending
        rows = vecs.flip(1)[:, :k].T.numpy()
        rms = np.sqrt(np.maximum(power.flip(0)[:k].numpy(), 0.0) / n)
    else:
        _, sv, vh = torch.linalg.svd(x, full_matrices=False)
        rows, rms = vh[:k].numpy(), sv[:k].numpy() / np.sqrt(n)
    peak = np.argmax(np.abs(rows), axis=1)
    rows = rows * np.sign(rows[np.arange(len(rows)), peak])[:, None]
    out = np.zeros((k, d), np.float32)
    out[: len(rows)] = rows * rms[:, None]
    return out


class Joint2CoarseNet(nn.Module):
    """Shape autoencoder + motion encoder, with the normalisation statistics as buffers.

    Parameters
    ----------
    config : Joint2CoarseConfig
    n_vertices : int
        Proxy vertex count Vc.
    descriptor_dim : int
        Motion descriptor length D (``config.num_samples * 57``).

    With an output basis (``config.basis_size(n_vertices)`` K > 0) the shape decoder's last
    layer predicts K coefficients and ends in an :class:`OutputBasis` (K, Vc * 3), set from the
    training shapes by :meth:`set_output_basis`. Either way ``shape_decoder`` maps a latent to
    (B, Vc * 3) normalised vertices.

    Buffers ``desc_mean``, ``desc_std`` are (D,) float32; ``vert_mean``, ``vert_std`` are
    (Vc * 3,) float32, per coordinate of output-frame vertices; ``follow`` is (Vc,) float32, the
    share of the root's tilt each vertex's output frame takes (:meth:`follow_weights`). They
    travel in the state dict.
    """

    def __init__(self, config: Joint2CoarseConfig, n_vertices: int, descriptor_dim: int):
        super().__init__()
        self.config = config
        self.n_vertices = n_vertices
        self.descriptor_dim = descriptor_dim
        out = 3 * n_vertices
        widths = config.shape_widths(n_vertices)
        self.shape_encoder = mlp(out, widths, config.latent_dim, config.dropout)
        self.n_basis = config.basis_size(n_vertices)
        if self.n_basis:
            self.shape_decoder = mlp(config.latent_dim, widths[::-1], self.n_basis, config.dropout)
            self.shape_decoder.append(OutputBasis(self.n_basis, out))
        else:
            self.shape_decoder = mlp(config.latent_dim, widths[::-1], out, config.dropout)
        self.motion_encoder = mlp(
            descriptor_dim, config.motion_widths, config.latent_dim, config.dropout
        )
        self.register_buffer("desc_mean", torch.zeros(descriptor_dim))
        self.register_buffer("desc_std", torch.ones(descriptor_dim))
        self.register_buffer("vert_mean", torch.zeros(out))
        self.register_buffer("vert_std", torch.ones(out))
        self.register_buffer("follow", torch.zeros(n_vertices))

    def follow_weights(self) -> np.ndarray | None:
        """(Vc,) float64 copy of the ``follow`` buffer, or None when it is all zero (every
        vertex in the root frame: :func:`~training.joint2coarse.descriptor.to_output_frame`)."""
        w = self.follow.detach().numpy().astype(np.float64)
        return w if w.any() else None

    def set_statistics(self, desc_mean, desc_std, vert_mean, vert_std) -> None:
        """Copy normalisation statistics in (array-likes of the buffer shapes)."""
        for name, value in (
            ("desc_mean", desc_mean), ("desc_std", desc_std),
            ("vert_mean", vert_mean), ("vert_std", vert_std),
        ):  # fmt: skip
            buf = getattr(self, name)
            buf.copy_(torch.as_tensor(value, dtype=buf.dtype).reshape(buf.shape))

    def set_output_basis(self, normalised_vertices: np.ndarray) -> None:
        """Set the output basis to the principal directions of training shapes.

        Parameters
        ----------
        normalised_vertices : (N, Vc * 3) float
            Training shapes as :meth:`normalise_vertices` gives them (z-scores: the space the
            training loss measures, so the basis keeps what the loss cares about most). See
            :func:`principal_basis`.
        """
        if self.n_basis:
            basis = principal_basis(normalised_vertices, self.n_basis)
            self.shape_decoder[-1].basis.copy_(torch.from_numpy(basis))

    def normalise_descriptor(self, desc: torch.Tensor) -> torch.Tensor:
        """(B, D) float32 metres -> clamped z-scores."""
        z = (desc - self.desc_mean) / self.desc_std
        return z.clamp(-self.config.clamp_z, self.config.clamp_z)

    def normalise_vertices(self, verts: torch.Tensor) -> torch.Tensor:
        """(B, Vc * 3) float32 output-frame metres -> z-scores (not clamped: training targets)."""
        return (verts - self.vert_mean) / self.vert_std

    def denormalise_vertices(self, z: torch.Tensor) -> torch.Tensor:
        """(B, Vc * 3) z-scores -> (B, Vc, 3) output-frame metres, z clamped first."""
        z = z.clamp(-self.config.clamp_z, self.config.clamp_z)
        return (z * self.vert_std + self.vert_mean).reshape(len(z), self.n_vertices, 3)

    def forward(self, desc: torch.Tensor) -> torch.Tensor:
        """Motion descriptors (B, D) float32 -> output-frame proxy vertices (B, Vc, 3) float32."""
        latent = self.motion_encoder(self.normalise_descriptor(desc))
        return self.denormalise_vertices(self.shape_decoder(latent))


def save_model(net: Joint2CoarseNet, path: str | os.PathLike) -> None:
    """Write an inference model file (config, sizes, weights, statistics), atomically; ours
    (a :class:`~training.joint2coarse.body_model.BodyResidualModel`) too."""
    payload = {
        "format": MODEL_FORMAT,
        "config": net.config.to_dict(),
        "n_vertices": net.n_vertices,
        "descriptor_dim": net.descriptor_dim,
        "state_dict": net.state_dict(),
    }
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def load_model(path: str | os.PathLike) -> Joint2CoarseNet:
    """Read a file written by :func:`save_model`; the network comes back in eval mode."""
    path = Path(path)
    return net_from_payload(read_torch_payload(path, MODEL_FORMAT, "Joint2Coarse model"), path)


def stored_config(payload: dict, path: str | os.PathLike | None = None) -> Joint2CoarseConfig:
    """The config of a saved payload; files from before ``output_basis``, ``tilt_follow`` or
    ``mirror`` existed read them as 0 / false (what those files were trained with)."""
    data = payload.get("config")
    if not isinstance(data, dict):
        raise InputError("Joint2Coarse file has no config", path)
    data = {"output_basis": 0, "tilt_follow": 0.0, "mirror": False, **data}
    try:
        return Joint2CoarseConfig.from_dict(data)
    except (InputError, TypeError) as exc:
        raise InputError(f"Joint2Coarse file has an unusable config: {exc}", path) from None


def net_from_payload(payload: dict, path: str | os.PathLike | None = None) -> Joint2CoarseNet:
    """Build the network a saved payload (model file or training checkpoint) describes (ours,
    ``config.model == "ours"``, comes back as a
    :class:`~training.joint2coarse.body_model.BodyResidualModel`)."""
    config = stored_config(payload, path)
    if config.model == "ours":
        state = payload.get("state_dict")
        if not isinstance(state, dict):
            raise InputError("Joint2Coarse model file has no weights", path)
        return body_model_from_state(config, int(payload["descriptor_dim"]), state, path)
    net = Joint2CoarseNet(config, int(payload["n_vertices"]), int(payload["descriptor_dim"]))
    state = payload["state_dict"]
    if isinstance(state, dict) and "follow" not in state:  # written before the buffer existed
        state = {**state, "follow": net.follow.clone()}
    try:
        net.load_state_dict(state)
    except RuntimeError as exc:
        raise InputError(
            f"Joint2Coarse weights do not fit the stored config: {exc}", path
        ) from None
    return net.eval()
