"""Joint2Coarse at test time: a whole clip at once, or one frame at a time for the GUI."""

from __future__ import annotations

import copy

import numpy as np
import torch

from core.errors import InputError
from training.joint2coarse.collision import DEFAULT_MARGIN_M, push_out_of_capsules
from training.joint2coarse.descriptor import (
    NUM_JOINTS,
    check_joint_inputs,
    descriptor_from_history,
    from_root_frame,
    heading_rotations,
    motion_descriptors,
)
from training.joint2coarse.model import Joint2CoarseNet


def _run_net(net: Joint2CoarseNet, desc: np.ndarray) -> np.ndarray:
    """(B, D) float32 descriptors -> (B, Vc, 3) float32 root-frame vertices, eval mode."""
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

    Returns
    -------
    (T, Vc, 3) float32 world positions.
    """
    check_joint_inputs(joints, root_rotations, source)
    if (capsules is None) != (radii is None):
        raise InputError("capsules and radii go together", source or None)
    cfg = net.config
    desc, origin, heading = motion_descriptors(joints, root_rotations, cfg.window, cfg.stride)
    out = np.empty((len(desc), net.n_vertices, 3), np.float32)
    for start in range(0, len(desc), batch_size):
        sl = slice(start, start + batch_size)
        local = _run_net(net, desc[sl])
        out[sl] = from_root_frame(local, origin[sl], heading[sl])
    if capsules is not None:
        out = push_out_of_capsules(out, capsules, radii, margin)
    return out


class Joint2CoarseStream:
    """Joint2Coarse one frame at a time, for live use.

    Keeps a ring buffer of the joint history the descriptor samples (``(K - 1) * stride + 1``
    frames), so each call costs one descriptor and one network pass, whatever the clip length.
    Frame i of a stream equals frame i of :func:`predict_proxy` on the same clip. The network
    runs in eval mode; give the stream a network no other thread is training (a loaded model
    file, or a ``copy.deepcopy`` snapshot).

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
        bound by reading the weights; results then differ from :func:`predict_proxy` by
        bfloat16 rounding. The copy is taken now: later training of ``net`` is not seen.
    """

    def __init__(
        self,
        net: Joint2CoarseNet,
        radii: np.ndarray | None = None,
        margin: float = DEFAULT_MARGIN_M,
        bfloat16: bool = False,
    ):
        self.net = net
        self._half = None
        if bfloat16:
            self._half = (
                copy.deepcopy(net.motion_encoder).to(torch.bfloat16).eval(),
                copy.deepcopy(net.shape_decoder).to(torch.bfloat16).eval(),
            )
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
        check_joint_inputs(joints[None], root_rotation[None], "stream frame")
        if (capsules is None) != (self.radii is None):
            raise InputError("pass capsules exactly when the stream was made with radii")
        i = self.frame_index
        self._ring[i % self._length] = joints[1:]
        slots = np.maximum(i - self._offsets, 0) % self._length
        origin = joints[None, 0]
        heading = heading_rotations(root_rotation[None])
        desc = descriptor_from_history(self._ring[slots][None], origin, heading)
        local = self._forward(desc)
        world = from_root_frame(local, origin, heading).astype(np.float32)[0]
        self.frame_index = i + 1
        if capsules is not None:
            world = push_out_of_capsules(world, capsules, self.radii, self.margin)
        return world

    def _forward(self, desc: np.ndarray) -> np.ndarray:
        if self._half is None:
            return _run_net(self.net, desc)
        encoder, decoder = self._half
        with torch.inference_mode():
            z = self.net.normalise_descriptor(torch.from_numpy(desc)).to(torch.bfloat16)
            return self.net.denormalise_vertices(decoder(encoder(z)).float()).numpy()
