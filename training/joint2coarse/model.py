"""Joint2Coarse networks: shape autoencoder, motion encoder, normalisation, save and load."""

from __future__ import annotations

import os
from pathlib import Path

import torch
from torch import nn

from core.errors import InputError
from core.fileio import atomic_path
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


class Joint2CoarseNet(nn.Module):
    """Shape autoencoder + motion encoder, with the normalisation statistics as buffers.

    Parameters
    ----------
    config : Joint2CoarseConfig
    n_vertices : int
        Proxy vertex count Vc.
    descriptor_dim : int
        Motion descriptor length D (``config.num_samples * 57``).

    Buffers ``desc_mean``, ``desc_std`` are (D,) float32; ``vert_mean``, ``vert_std`` are
    (Vc * 3,) float32, per coordinate of root-frame vertices. They travel in the state dict.
    """

    def __init__(self, config: Joint2CoarseConfig, n_vertices: int, descriptor_dim: int):
        super().__init__()
        self.config = config
        self.n_vertices = n_vertices
        self.descriptor_dim = descriptor_dim
        out = 3 * n_vertices
        widths = config.shape_widths(n_vertices)
        self.shape_encoder = mlp(out, widths, config.latent_dim, config.dropout)
        self.shape_decoder = mlp(config.latent_dim, widths[::-1], out, config.dropout)
        self.motion_encoder = mlp(
            descriptor_dim, config.motion_widths, config.latent_dim, config.dropout
        )
        self.register_buffer("desc_mean", torch.zeros(descriptor_dim))
        self.register_buffer("desc_std", torch.ones(descriptor_dim))
        self.register_buffer("vert_mean", torch.zeros(out))
        self.register_buffer("vert_std", torch.ones(out))

    def set_statistics(self, desc_mean, desc_std, vert_mean, vert_std) -> None:
        """Copy normalisation statistics in (array-likes of the buffer shapes)."""
        for name, value in (
            ("desc_mean", desc_mean), ("desc_std", desc_std),
            ("vert_mean", vert_mean), ("vert_std", vert_std),
        ):  # fmt: skip
            buf = getattr(self, name)
            buf.copy_(torch.as_tensor(value, dtype=buf.dtype).reshape(buf.shape))

    def normalise_descriptor(self, desc: torch.Tensor) -> torch.Tensor:
        """(B, D) float32 metres -> clamped z-scores."""
        z = (desc - self.desc_mean) / self.desc_std
        return z.clamp(-self.config.clamp_z, self.config.clamp_z)

    def normalise_vertices(self, verts: torch.Tensor) -> torch.Tensor:
        """(B, Vc * 3) float32 root-frame metres -> z-scores (not clamped: training targets)."""
        return (verts - self.vert_mean) / self.vert_std

    def denormalise_vertices(self, z: torch.Tensor) -> torch.Tensor:
        """(B, Vc * 3) z-scores -> (B, Vc, 3) root-frame metres, z clamped first."""
        z = z.clamp(-self.config.clamp_z, self.config.clamp_z)
        return (z * self.vert_std + self.vert_mean).reshape(len(z), self.n_vertices, 3)

    def forward(self, desc: torch.Tensor) -> torch.Tensor:
        """Motion descriptors (B, D) float32 -> root-frame proxy vertices (B, Vc, 3) float32."""
        latent = self.motion_encoder(self.normalise_descriptor(desc))
        return self.denormalise_vertices(self.shape_decoder(latent))


def save_model(net: Joint2CoarseNet, path: str | os.PathLike) -> None:
    """Write an inference model file (config, sizes, weights, statistics), atomically."""
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
    if not path.is_file():
        raise InputError("no Joint2Coarse model file here", path)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many kinds on corrupt files
        raise InputError(f"cannot read Joint2Coarse model: {exc}", path) from None
    if not isinstance(payload, dict) or payload.get("format") != MODEL_FORMAT:
        raise InputError(f"not a Joint2Coarse model file (expected format {MODEL_FORMAT})", path)
    return net_from_payload(payload, path)


def net_from_payload(payload: dict, path: str | os.PathLike | None = None) -> Joint2CoarseNet:
    """Build the network a saved payload (model file or training checkpoint) describes."""
    config = Joint2CoarseConfig.from_dict(payload["config"])
    net = Joint2CoarseNet(config, int(payload["n_vertices"]), int(payload["descriptor_dim"]))
    try:
        net.load_state_dict(payload["state_dict"])
    except RuntimeError as exc:
        raise InputError(
            f"Joint2Coarse weights do not fit the stored config: {exc}", path
        ) from None
    return net.eval()
