"""The training-sample contract of the neural renderer, and a small synthetic scene.

A sample (one camera view, frames t-1, t, t+1 in that order along the first axis) is a dict of
float32 tensors, channels first:

=============  =================  =====================================================
key            shape              meaning
=============  =================  =====================================================
uv             (3, 2, H, W)       proxy UVs in [0, 1] per pixel, 0 where no proxy
motion         (3, 95, H, W)      motion features (core.features layout), 0 off-proxy
proxy_mask     (3, 1, H, W)       1 where the proxy covers the pixel
target         (3, 3, H, W)       ground truth (garment + body + background) in [0, 1]
background     (3, 3, H, W)       the same view without the garment, in [0, 1]
target_mask    (3, 1, H, W)       garment coverage in the ground truth
=============  =================  =====================================================

A DataLoader batch adds a leading B. :meth:`RenderBatch.from_dict` checks one and names the
generator's inputs: frame t is index 1, t-1 is index 0, t+1 is index 2.

Instead of ``motion``, a sample may carry its motion features per vertex, for the trainer's
device to interpolate (:func:`motion_maps`; what a data set feeding a GPU does: the per-pixel
map is 95 floats a pixel, this 6, so batches are several times smaller to make, pass between
processes, pin and copy):

=================  =================  ================================================
motion_corners     (3, 3, H, W)       int32 vertex ids of the covering face's corners
motion_weights     (3, 3, H, W)       their barycentric weights, 0 off the proxy
vertex_motion      (3, V, 95)         motion features per proxy vertex
=================  =================  ================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from core.camera import Camera, CameraRigConfig, random_cameras
from core.errors import InputError
from core.features import (
    FeatureConfig,
    interpolate,
    joint_window,
    uv_map,
    vertex_motion_features,
)
from core.mesh import Mesh
from core.raster import MeshScene
from core.shading import Material, ShadingConfig, render_views

#: Keys of a sample and their channel counts (motion: the config's ``motion_channels``).
SAMPLE_KEYS = {
    "uv": 2,
    "motion": None,
    "proxy_mask": 1,
    "target": 3,
    "background": 3,
    "target_mask": 1,
}
#: The per-vertex form of ``motion`` (see the module docstring).
VERTEX_MOTION_KEYS = ("motion_corners", "motion_weights", "vertex_motion")
PREV, CUR, NEXT = 0, 1, 2


def motion_maps(corners: torch.Tensor, weights: torch.Tensor, vertex_motion: torch.Tensor):
    """Per-vertex motion features interpolated at each pixel, on their device.

    corners : (B, 3, H, W) int vertex ids of the covering face's corners
    weights : (B, 3, H, W) float barycentric weights, 0 off the proxy
    vertex_motion : (B, V, C) float features per vertex

    Returns (B, C, H, W) in ``vertex_motion``'s dtype: ``sum_k weights_k * features[corner_k]``
    (:func:`core.features.interpolate` of per-vertex attributes, with the rasterization
    already gathered), built one corner at a time so no (B, 3, C, H, W) gather is held.
    """
    b, _, h, w = corners.shape
    features = vertex_motion.transpose(1, 2)  # (B, C, V)
    c = features.shape[1]
    out = None
    for k in range(3):
        idx = corners[:, k].reshape(b, 1, h * w).long().expand(b, c, h * w)
        term = torch.gather(features, 2, idx) * weights[:, k].reshape(b, 1, h * w)
        out = term if out is None else out + term
    return out.reshape(b, c, h, w)


@dataclass(frozen=True)
class RenderBatch:
    """A checked batch. Every image field is (B, 3, C, H, W) float32 (frames t-1, t, t+1).

    ``motion`` is None when the batch carries its motion features per vertex: then
    ``motion_corners`` (B, 3, 3, H, W) int32, ``motion_weights`` (B, 3, 3, H, W) float32 and
    ``vertex_motion`` (B, 3, V, C) float32, interpolated by :meth:`motion_frame` where the
    batch is (after :meth:`to`, on the trainer's device).
    """

    uv: torch.Tensor
    motion: torch.Tensor | None
    proxy_mask: torch.Tensor
    target: torch.Tensor
    background: torch.Tensor
    target_mask: torch.Tensor
    motion_corners: torch.Tensor | None = None
    motion_weights: torch.Tensor | None = None
    vertex_motion: torch.Tensor | None = None

    @classmethod
    def from_dict(
        cls, sample: dict, motion_channels: int = 95, name: str | None = None
    ) -> RenderBatch:
        """Check a sample (no B) or a batch (leading B) and wrap it; ``InputError`` naming
        ``name`` (the data set's file) on a missing key or a wrong shape."""
        if not isinstance(sample, dict):
            raise InputError(f"a renderer sample must be a dict, got {type(sample).__name__}", name)
        per_vertex = "motion" not in sample and all(k in sample for k in VERTEX_MOTION_KEYS)
        keys = {k: c for k, c in SAMPLE_KEYS.items() if not (per_vertex and k == "motion")}
        missing = [k for k in keys if k not in sample]
        if missing:
            raise InputError(f"renderer sample is missing {missing}", name)
        out = {}
        ref = None
        for k, c in keys.items():
            t = torch.as_tensor(sample[k])
            if t.dim() == 4:
                t = t.unsqueeze(0)
            c = motion_channels if c is None else c
            if t.dim() != 5 or t.shape[1] != 3 or t.shape[2] != c:
                raise InputError(
                    f"sample[{k!r}] must be (B, 3, {c}, H, W) or (3, {c}, H, W), "
                    f"got {tuple(sample[k].shape)}",
                    name,
                )
            if ref is None:
                ref = (t.shape[0], *t.shape[3:])
            elif (t.shape[0], *t.shape[3:]) != ref:
                raise InputError(
                    f"sample[{k!r}] has batch/size {(t.shape[0], *t.shape[3:])}, expected {ref}",
                    name,
                )
            out[k] = t.float()
        if per_vertex:
            out.update(_check_vertex_motion(sample, motion_channels, ref, name), motion=None)
        return cls(**out)

    def _map(self, fn) -> RenderBatch:
        return RenderBatch(**{k: None if v is None else fn(v) for k, v in vars(self).items()})

    def to(self, device, non_blocking: bool = False) -> RenderBatch:
        return self._map(lambda t: t.to(device, non_blocking=non_blocking))

    def pin_memory(self) -> RenderBatch:
        """Page-locked copies (what a DataLoader with ``pin_memory=True`` calls)."""
        return self._map(lambda t: t.pin_memory())

    def motion_frame(self, i: int) -> torch.Tensor:
        """Motion features of frame ``i`` (PREV, CUR or NEXT): (B, C, H, W), interpolated here
        from the per-vertex form when the batch carries that."""
        if self.motion is not None:
            return self.motion[:, i]
        return motion_maps(
            self.motion_corners[:, i], self.motion_weights[:, i], self.vertex_motion[:, i]
        )

    @property
    def size(self) -> tuple[int, int]:
        """(H, W)."""
        return tuple(self.uv.shape[-2:])

    def generator_inputs(self, use_motion: bool = True) -> dict[str, torch.Tensor | None]:
        """Keyword arguments of :meth:`RenderNet.forward` for frame t."""
        return {
            "uv": self.uv[:, CUR],
            "motion": self.motion_frame(CUR) if use_motion else None,
            "mask": self.proxy_mask[:, CUR],
            "uv_prev": self.uv[:, PREV],
            "motion_prev": self.motion_frame(PREV) if use_motion else None,
            "mask_prev": self.proxy_mask[:, PREV],
            "background": self.background[:, CUR],
        }


def _check_vertex_motion(
    sample: dict, motion_channels: int, ref: tuple, name: str | None
) -> dict[str, torch.Tensor]:
    """The per-vertex motion keys of a sample or batch, checked against the images' (B, H, W)
    ``ref``: (B, 3, 3, H, W) corners and weights, (B, 3, V, C) features."""
    out = {}
    for k in VERTEX_MOTION_KEYS:
        t = torch.as_tensor(sample[k])
        if t.dim() == (3 if k == "vertex_motion" else 4):
            t = t.unsqueeze(0)
        if k == "vertex_motion":
            ok = t.dim() == 4 and t.shape[:2] == (ref[0], 3) and t.shape[3] == motion_channels
            want = f"(B, 3, V, {motion_channels})"
        else:
            ok = t.dim() == 5 and t.shape[:3] == (ref[0], 3, 3) and tuple(t.shape[3:]) == ref[1:]
            want = f"(B, 3, 3, {ref[1]}, {ref[2]})"
        if not ok:
            raise InputError(f"sample[{k!r}] must be {want}, got {tuple(sample[k].shape)}", name)
        out[k] = t.int() if k == "motion_corners" else t.float()
    v = out["vertex_motion"].shape[2]
    corners = out["motion_corners"]
    if corners.numel() and (int(corners.min()) < 0 or int(corners.max()) >= v):
        raise InputError(f"sample['motion_corners'] holds ids outside the {v} vertices", name)
    return out


# --------------------------------------------------------------------------------------------
# A synthetic scene built with the core modules (tests, benchmarks, the torchrun smoke run)


@dataclass(frozen=True)
class SyntheticScene:
    """A swaying skirt-like proxy (a cone band with UVs) on a cylinder body, and fake joints.

    Attributes
    ----------
    proxy : (T, V, 3) float32 per-frame proxy vertices
    faces : (F, 3) int64
    uvs : (V, 2) float32
    body : (T, Vb, 3) float32 body vertices; body_faces (Fb, 3) int64
    joints : (T, 19, 3) float32
    """

    proxy: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    body: np.ndarray
    body_faces: np.ndarray
    joints: np.ndarray


def _band(n_around: int, n_up: int, r0: float, r1: float, y0: float, y1: float):
    a = np.linspace(0, 2 * math.pi, n_around + 1)  # seam: first and last column split
    h = np.linspace(0, 1, n_up)
    aa, hh = np.meshgrid(a, h)
    r = r0 + (r1 - r0) * (1 - hh)
    v = np.stack([r * np.sin(aa), y0 + (y1 - y0) * hh, r * np.cos(aa)], -1).reshape(-1, 3)
    uv = np.stack([aa / (2 * math.pi), hh], -1).reshape(-1, 2)
    faces = []
    w = n_around + 1
    for i in range(n_up - 1):
        for j in range(n_around):
            p = i * w + j
            faces += [(p, p + 1, p + w + 1), (p, p + w + 1, p + w)]
    return v.astype(np.float32), np.asarray(faces, np.int64), uv.astype(np.float32)


def synthetic_scene(frames: int = 6, resolution: int = 24, seed: int = 0) -> SyntheticScene:
    """A small animated scene: the skirt sways with the hips (deterministic for a seed)."""
    rng = np.random.default_rng(seed)
    v0, faces, uvs = _band(resolution, max(resolution // 2, 3), 0.45, 0.2, 0.45, 1.0)
    b0, bfaces, _ = _band(16, 8, 0.16, 0.16, 0.3, 1.5)
    phase = rng.uniform(0, 2 * math.pi)
    proxy, body, joints = [], [], []
    base_joints = np.stack([np.zeros(19), np.linspace(1.7, 0.1, 19), np.zeros(19)], -1).astype(
        np.float32
    )
    for t in range(frames):
        s = 0.08 * math.sin(phase + 0.7 * t)
        low = (1.0 - (v0[:, 1] - 0.45) / 0.55) ** 2  # hem moves most
        v = v0.copy()
        v[:, 0] += s * low
        v[:, 2] += 0.5 * s * low * np.cos(3 * uvs[:, 0] * 2 * math.pi)
        proxy.append(v)
        b = b0.copy()
        b[:, 0] += 0.3 * s
        body.append(b)
        j = base_joints.copy()
        j[:, 0] += s * np.linspace(0, 1, 19)
        joints.append(j)
    return SyntheticScene(
        np.stack(proxy), faces, uvs, np.stack(body).astype(np.float32), bfaces, np.stack(joints)
    )


class SyntheticDataset(torch.utils.data.Dataset):
    """Samples (the contract above) rendered from a :class:`SyntheticScene`.

    Each item is a camera and a frame t (1 <= t <= T-2); the target garment is the proxy itself
    with a checker pattern, lit by :mod:`core.shading`. Everything is computed in ``__init__``.

    Parameters
    ----------
    scene : SyntheticScene
    size : image size (pixels, square)
    cameras_per_frame : random cameras per frame (seeded by ``(seed, t)``)
    """

    def __init__(
        self,
        scene: SyntheticScene,
        size: int = 32,
        cameras_per_frame: int = 1,
        seed: int = 0,
        material: Material | None = None,
    ):
        self.scene = scene
        rig = CameraRigConfig(
            width=size, height=size, radius_range=(2.4, 2.6), elevation_deg_range=(0.0, 10.0)
        )
        shading = ShadingConfig(
            supersample=1,
            garment=material or Material(pattern="checker", pattern_scale=6.0),
        )
        fc = FeatureConfig()
        self.items: list[dict[str, torch.Tensor]] = []
        self.cameras: list[Camera] = []
        n = len(scene.proxy)
        for t in range(1, n - 1):
            for cam in random_cameras(cameras_per_frame, (seed, t), rig):
                frames = [_view(scene, f, cam, shading, fc) for f in (t - 1, t, t + 1)]
                self.items.append({k: torch.stack([fr[k] for fr in frames]) for k in SAMPLE_KEYS})
                self.cameras.append(cam)

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return self.items[i]


def _view(scene: SyntheticScene, t: int, cam: Camera, shading: ShadingConfig, fc: FeatureConfig):
    garment = Mesh(scene.proxy[t], scene.faces, scene.uvs)
    body = Mesh(scene.body[t], scene.body_faces)
    gt = render_views(garment, body, [cam], shading)[0]
    frag = MeshScene(scene.proxy[t], scene.faces).rasterize(cam)
    win = joint_window(scene.joints, t, fc.frame_offsets)
    feats = vertex_motion_features(scene.proxy[t], win, fc.sigma)
    chw = lambda a: torch.from_numpy(np.ascontiguousarray(np.moveaxis(a, -1, 0)))  # noqa: E731
    return {
        "uv": chw(uv_map(frag, scene.faces, scene.uvs)),
        "motion": chw(interpolate(frag, scene.faces, feats, "float32")),
        "proxy_mask": torch.from_numpy(frag.mask.astype(np.float32))[None],
        "target": chw(gt.image.astype(np.float32) / 255),
        "background": chw(gt.background.astype(np.float32) / 255),
        "target_mask": torch.from_numpy(gt.coverage.astype(np.float32))[None],
    }
