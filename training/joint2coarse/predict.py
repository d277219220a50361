"""Joint2Coarse at test time: a whole clip at once, or one frame at a time for the GUI."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from core.body.colliders import DEFAULT_MARGIN_M, push_out_of_capsules
from core.errors import InputError
from core.strain import StretchLimit, limit_stretch, stretch_limit
from training.joint2coarse.body_model import BodyResidualModel
from training.joint2coarse.config import PREDICTION_STRETCH, PREDICTION_SWEEPS
from training.joint2coarse.descriptor import (
    NUM_JOINTS,
    check_joint_inputs,
    descriptor_from_history,
    from_output_frame,
    heading_rotations,
    motion_descriptors,
    tilt_rotvecs,
    to_output_frame,
)
from training.joint2coarse.model import Joint2CoarseNet


def prediction_stretch_limit(rest: np.ndarray, faces: np.ndarray) -> StretchLimit:
    """The strain limit a project's proxy (``rest`` (V, 3) ``proxy/positions.obj``, ``faces``
    (F, 3)) puts on Joint2Coarse's predictions: :data:`PREDICTION_STRETCH`,
    :data:`PREDICTION_SWEEPS`."""
    return stretch_limit(rest, faces, PREDICTION_STRETCH, PREDICTION_SWEEPS)


def _run_net(net: Joint2CoarseNet, desc: np.ndarray) -> np.ndarray:
    """(B, D) float32 descriptors -> (B, Vc, 3) float32 output-frame vertices, eval mode."""
    if isinstance(net, BodyResidualModel):
        return net.predict(desc)
    was_training = net.training
    if was_training:
        net.eval()
    try:
        with torch.inference_mode():
            return net(torch.from_numpy(np.ascontiguousarray(desc, np.float32))).numpy()
    finally:
        if was_training:
            net.train()


def predict_proxy(
    net: Joint2CoarseNet,
    joints: np.ndarray,
    root_rotations: np.ndarray,
    *,
    capsules: np.ndarray | None = None,
    radii: np.ndarray | None = None,
    margin: float = DEFAULT_MARGIN_M,
    batch_size: int = 1024,
    source: str = "",
    stretch: StretchLimit | None = None,
) -> np.ndarray:
    """Proxy vertices for a whole clip.

    Parameters
    ----------
    net : Joint2CoarseNet
        Trained network (:func:`training.joint2coarse.load_model`).
    joints : (T, 20, 3) float32
        World joint positions, root then CANONICAL_JOINTS (:func:`joint2coarse_inputs`).
    root_rotations : (T, 3, 3) float32
        World rotation of the root joint.
    capsules : (T, K, 2, 3) float, optional
        Body capsules to push vertices out of (off when None).
    radii : (K,) float, optional
        Capsule radii; required with ``capsules``.
    margin : float
        Metres kept outside the capsules.
    batch_size : int
        Frames per network call (memory bound only; results do not depend on it).
    source : str
        Clip name for error messages.
    stretch : StretchLimit, optional
        Shorten the edges the network stretched past it (:func:`core.strain.limit_stretch`,
        :func:`prediction_stretch_limit`), before the push out of the capsules; off when None.

    Returns
    -------
    (T, Vc, 3) float32 world positions.
    """
    check_joint_inputs(joints, root_rotations, source)
    if stretch is not None and len(stretch.edges) and stretch.edges.max() >= net.n_vertices:
        raise InputError(
            f"the stretch limit's mesh is not the model's {net.n_vertices}-vertex proxy"
        )
    if (capsules is None) != (radii is None):
        raise InputError("capsules and radii go together", source or None)
    cfg = net.config
    desc, origin, heading = motion_descriptors(joints, root_rotations, cfg.window, cfg.stride)
    tilt, follow = tilt_rotvecs(root_rotations, heading), net.follow_weights()
    out = np.empty((len(desc), net.n_vertices, 3), np.float32)
    for start in range(0, len(desc), batch_size):
        sl = slice(start, start + batch_size)
        local = _run_net(net, desc[sl])
        out[sl] = from_output_frame(local, origin[sl], heading[sl], tilt[sl], follow)
    if stretch is not None:
        out = limit_stretch(out, stretch).astype(np.float32)
    if capsules is not None:
        out = push_out_of_capsules(out, capsules, radii, margin)
    return out


def reconstruct_proxy(
    net: Joint2CoarseNet, proxy: np.ndarray, joints: np.ndarray, root_rotations: np.ndarray
) -> np.ndarray:
    """The shape autoencoder's reconstruction of known proxy shapes (no motion encoder).

    Its error against ``proxy`` shows what the decoder reaches from the shape encoder's latent,
    which the motion encoder was trained to hit: where it is large, the shapes lie outside what
    the network learnt from its training clips, and a better motion encoder alone would not
    help (a strict bound would need the best latent, not the encoder's).

    Parameters
    ----------
    proxy : (T, Vc, 3) float
        World proxy vertices (a simulation).
    joints : (T, 20, 3) float32, root_rotations : (T, 3, 3) float32
        The clip's joints (:func:`joint2coarse_inputs`): they give each frame's root frame.

    Returns
    -------
    (T, Vc, 3) float32 world positions.
    """
    if isinstance(net, BodyResidualModel):
        raise InputError("our Joint2Coarse has no shape autoencoder to reconstruct with")
    proxy = np.asarray(proxy)
    t = check_joint_inputs(joints, root_rotations)
    if proxy.shape != (t, net.n_vertices, 3):
        raise InputError(f"proxy must be ({t}, {net.n_vertices}, 3), got {proxy.shape}")
    origin = np.asarray(joints, np.float64)[:, 0]
    heading = heading_rotations(root_rotations)
    frame = (origin, heading, tilt_rotvecs(root_rotations, heading), net.follow_weights())
    local = to_output_frame(proxy, *frame).reshape(t, -1).astype(np.float32)
    was_training = net.training
    net.eval()
    try:
        with torch.inference_mode():
            z = net.normalise_vertices(torch.from_numpy(local))
            out = net.denormalise_vertices(net.shape_decoder(net.shape_encoder(z))).numpy()
    finally:
        net.train(was_training)
    return from_output_frame(out, *frame).astype(np.float32)


class FrozenForward:
    """A network's eval-mode forward (descriptor -> output-frame vertices) as plain matrix products.

    Takes a copy of the motion encoder's and the decoder's weights (as ``(in, out)`` matrices
    in the layout a one-frame product reads fastest) and folds the output denormalisation into
    the last product: ``clamp(z) * std + mean`` is ``clamp(z * std + mean, mean - c * std,
    mean + c * std)``, so the last matrix (the output basis, or the full last layer) is scaled
    by ``std`` and ``mean`` becomes its bias. No module calls, no dropout layers, and one-frame
    calls write into preallocated buffers. Equals ``net(desc)`` in eval mode up to float32
    rounding (the slow, obvious reference the tests compare it with). Later training of
    ``net`` is not seen.

    Parameters
    ----------
    net : Joint2CoarseNet
    dtype : torch.dtype
        Dtype of the weight copies (``torch.bfloat16``: half the bytes to read; normalisation
        and the output bias stay float32).
    """

    def __init__(self, net: Joint2CoarseNet, dtype: torch.dtype = torch.float32):
        cfg = net.config
        with torch.no_grad():
            layers = [
                m for m in (*net.motion_encoder, *net.shape_decoder) if isinstance(m, nn.Linear)
            ]
            basis = net.shape_decoder[-1] if net.n_basis else None
            if basis is None:  # the decoder's last Linear is the output product
                *layers, last = layers
                out_w, out_b = last.weight.T, last.bias
            else:
                out_w, out_b = basis.basis, torch.zeros_like(net.vert_mean)
            std, mean = net.vert_std, net.vert_mean
            self.dtype = dtype
            self.weights = [_one_row_layout(m.weight.T, dtype) for m in layers]
            self.biases = [m.bias.to(dtype).clone() for m in layers]
            # Layers not followed by a ReLU: the motion encoder's last (the latent) and, with a
            # basis, the decoder's last (the coefficients).
            n_motion = sum(isinstance(m, nn.Linear) for m in net.motion_encoder)
            self.linear_ends = {n_motion - 1, len(layers) - 1 if basis is not None else -1}
            self.out_weight = _one_row_layout(out_w * std, dtype)
            self.out_bias = (out_b * std + mean).clone()
            self.out_low = (mean - cfg.clamp_z * std).clone()
            self.out_high = (mean + cfg.clamp_z * std).clone()
            self.desc_mean = net.desc_mean.clone()
            self.desc_std = net.desc_std.clone()
        self.clamp_z = cfg.clamp_z
        self.n_vertices = net.n_vertices
        self._one = [torch.empty(1, w.shape[1], dtype=dtype) for w in self.weights]
        self._one_out = torch.empty(1, self.out_weight.shape[1])

    def __call__(self, desc: torch.Tensor) -> torch.Tensor:
        """(B, D) float32 descriptors -> (B, Vc * 3) float32 output-frame vertices, flattened.

        With B = 1 the result is a preallocated buffer, overwritten by the next one-frame call.
        """
        one = len(desc) == 1
        x = ((desc - self.desc_mean) / self.desc_std).clamp_(-self.clamp_z, self.clamp_z)
        x = x.to(self.dtype)
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            x = torch.addmm(b, x, w, out=self._one[i]) if one else torch.addmm(b, x, w)
            if i not in self.linear_ends:
                x.relu_()
        if self.dtype == torch.float32:
            out = self._one_out if one else None
            y = torch.addmm(self.out_bias, x, self.out_weight, out=out)
        else:
            y = (x @ self.out_weight).float().add_(self.out_bias)
        return torch.minimum(torch.maximum(y, self.out_low, out=y), self.out_high, out=y)


class _BodyForward:
    """:class:`FrozenForward`'s call for our model: (B, D) float32 tensor -> (B, Vc * 3)."""

    def __init__(self, net: BodyResidualModel):
        self.net = net

    def __call__(self, desc: torch.Tensor) -> torch.Tensor:
        return torch.from_numpy(self.net.predict(desc.numpy()).reshape(len(desc), -1))


def _one_row_layout(weight: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """An (in, out) matrix for ``addmm(bias, x, weight)``, copied to ``dtype`` and laid out the
    way a one-row product runs fastest on CPU (measured on AVX2, torch 2.13): row-major for
    float32, column-major for bfloat16 (row-major bfloat16 is up to 10 times slower)."""
    w = weight.detach().to(dtype)
    return w.contiguous().clone() if dtype == torch.float32 else w.T.contiguous().T


class Joint2CoarseStream:
    """Joint2Coarse one frame at a time, for live use.

    Keeps a ring buffer of the joint history the descriptor samples (``(K - 1) * stride + 1``
    frames), so each call costs one descriptor and one network pass, whatever the clip length.
    Frame i of a stream equals frame i of :func:`predict_proxy` on the same clip (up to float32
    rounding). The network runs as a :class:`FrozenForward`: a copy of its weights taken now,
    so later training of ``net`` is not seen (make a new stream to see it).

    Parameters
    ----------
    net : Joint2CoarseNet
    radii : (K,) float, optional
        Capsule radii; when given, :meth:`push` takes that frame's capsules and pushes out.
    margin : float
        Metres kept outside the capsules.
    bfloat16 : bool
        Run the motion encoder and decoder on a bfloat16 copy of their weights (normalisation
        stays float32): half the memory traffic, so lower latency on CPUs where a frame is
        bound by reading the weights and that have bfloat16 arithmetic; results then differ
        from :func:`predict_proxy` by bfloat16 rounding.
    stretch : StretchLimit, optional
        As :func:`predict_proxy`'s: each frame's edges shortened before the push out.
    """

    def __init__(
        self,
        net: Joint2CoarseNet,
        radii: np.ndarray | None = None,
        margin: float = DEFAULT_MARGIN_M,
        bfloat16: bool = False,
        stretch: StretchLimit | None = None,
    ):
        self.net = net
        self.stretch = stretch
        if isinstance(net, BodyResidualModel):  # already plain matrix products
            self.forward = _BodyForward(net)
        else:
            self.forward = FrozenForward(net, torch.bfloat16 if bfloat16 else torch.float32)
        self._follow = net.follow_weights()
        cfg = net.config
        self._stride = cfg.stride
        self._samples = cfg.num_samples
        self._length = (self._samples - 1) * self._stride + 1
        self._ring = np.zeros((self._length, NUM_JOINTS - 1, 3), np.float64)
        self._offsets = self._stride * np.arange(self._samples)
        self.radii = None if radii is None else np.asarray(radii, np.float64)
        self.margin = margin
        self.frame_index = 0
        """Frames pushed since the start (or the last :meth:`reset`)."""

    def reset(self) -> None:
        """Start a new clip: the next frame is frame 0."""
        self.frame_index = 0

    def push(
        self,
        joints: np.ndarray,
        root_rotation: np.ndarray,
        capsules: np.ndarray | None = None,
    ) -> np.ndarray:
        """Add one frame and return its proxy.

        Parameters
        ----------
        joints : (20, 3) float
            World joint positions of this frame, root first.
        root_rotation : (3, 3) float
        capsules : (K, 2, 3) float, optional
            This frame's capsules; required when the stream was made with ``radii``.

        Returns
        -------
        (Vc, 3) float32 world positions.
        """
        joints = np.asarray(joints, np.float64)
        root_rotation = np.asarray(root_rotation, np.float64)
        ok = joints.shape == (NUM_JOINTS, 3) and root_rotation.shape == (3, 3)
        if not (ok and np.isfinite(joints).all() and np.isfinite(root_rotation).all()):
            check_joint_inputs(joints[None], root_rotation[None], "stream frame")  # says why
        if (capsules is None) != (self.radii is None):
            raise InputError("pass capsules exactly when the stream was made with radii")
        i = self.frame_index
        self._ring[i % self._length] = joints[1:]
        slots = np.maximum(i - self._offsets, 0) % self._length
        origin = joints[None, 0]
        heading = heading_rotations(root_rotation[None])
        desc = descriptor_from_history(self._ring[slots][None], origin, heading)
        with torch.inference_mode():
            local = self.forward(torch.from_numpy(desc)).numpy().reshape(1, -1, 3)
        tilt = tilt_rotvecs(root_rotation[None], heading)
        world = from_output_frame(local, origin, heading, tilt, self._follow)
        world = world.astype(np.float32)[0]
        self.frame_index = i + 1
        if self.stretch is not None:
            world = limit_stretch(world, self.stretch).astype(np.float32)
        if capsules is not None:
            world = push_out_of_capsules(world, capsules, self.radii, self.margin)
        return world
