"""Live neural rendering for the GUI and the CLI: ``NeuralRenderer.render(camera, frame)``.

One call: rasterize the proxy (:mod:`core.raster`, one :class:`MeshScene` per frame, reused for
every camera) -> UV and motion-feature maps (:mod:`core.features`) -> neural texture sample ->
network -> paste onto the background. The network runs only on a crop around the proxy's
screen-space box (padded by ``config.crop_margin`` and snapped outwards to the network's stride
in image coordinates, so crops of the same view share the latent grid); outside the crop the
output *is* the background.

Streaming: the encoder latent of the previous call is kept, so playing a motion encodes each
frame once. It is reused for frame t-1 when the camera and the crop are unchanged and the
previous call rendered the frame given as ``previous``; otherwise t-1 is encoded again (so a
streamed frame has exactly the pixels of the stateless :meth:`NeuralRenderer.render_pair`).
The first frame of a stream uses itself as t-1.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import torch

from core.camera import Camera, crop_camera, project
from core.errors import InputError
from core.features import FeatureConfig, interpolate, uv_map, vertex_motion_features
from core.raster import MeshScene, RasterConfig, check_mesh_arrays
from training.renderer.model import RenderNet


@dataclass(frozen=True)
class FrameState:
    """What the renderer needs of one frame.

    Attributes
    ----------
    vertices : (Vp, 3) float32
        Proxy vertices at frame t (Joint2Coarse's output), world metres.
    window : (K, J, 3) float32
        Joints at ``t - k`` for the feature offsets (:func:`core.features.joint_window`).
    background : (H, W, 3) uint8
        The body-only image of this frame from the camera being rendered.
    """

    vertices: np.ndarray
    window: np.ndarray
    background: np.ndarray


@dataclass(frozen=True)
class CropBox:
    """Window ``[x0, x0 + width) x [y0, y0 + height)`` of the image (may pass its edges)."""

    x0: int
    y0: int
    width: int
    height: int


class _FrameData:
    """A frame's scene and per-vertex motion features (computed once, reused per camera)."""

    def __init__(self, frame: FrameState, faces: np.ndarray, fc: FeatureConfig, motion: bool):
        self.frame = frame
        self.scene = MeshScene(frame.vertices, faces)
        self.features = (
            vertex_motion_features(frame.vertices, frame.window, fc.sigma) if motion else None
        )


class NeuralRenderer:
    """A trained renderer for one garment's proxy (fixed faces and UVs).

    Parameters
    ----------
    net : RenderNet (its config gives stride, margin, motion switch)
    faces : (F, 3) int, the proxy's triangles
    uvs : (V, 2) float per vertex, or (F, 3, 2) per corner
    feature_config : how motion features are made (must match training)
    device : torch device of the network
    """

    def __init__(
        self,
        net: RenderNet,
        faces: np.ndarray,
        uvs: np.ndarray,
        feature_config: FeatureConfig | None = None,
        device: str | torch.device = "cpu",
        raster: RasterConfig | None = None,
    ):
        self.net = net.eval().to(device)
        self.config = net.config
        self.device = torch.device(device)
        self.faces = np.asarray(faces, np.int64)
        self.uvs = np.asarray(uvs, np.float32)
        self.feature_config = feature_config or FeatureConfig()
        self.raster = raster or RasterConfig()
        self._frames: list[_FrameData] = []  # the last two frames seen
        self._last: tuple | None = None  # (key, frame, latent) of the previous call
        self.encodes = 0  # encoder runs (for tests and benchmarks)

    @classmethod
    def from_file(
        cls, path: str | os.PathLike, faces: np.ndarray, uvs: np.ndarray, **kwargs
    ) -> NeuralRenderer:
        """Load a model file written by training."""
        from training.renderer.train import load_model

        return cls(load_model(path)[1], faces, uvs, **kwargs)

    def reset(self) -> None:
        """Forget the stream (the next frame is treated as the first)."""
        self._frames = []
        self._last = None

    # -- parts ---------------------------------------------------------------------------------

    def _frame_data(self, frame: FrameState) -> _FrameData:
        for fd in self._frames:
            if fd.frame is frame:
                return fd
        v, _ = check_mesh_arrays(frame.vertices, self.faces)
        w = np.asarray(frame.window)
        if w.ndim != 3 or w.shape[0] != len(self.feature_config.frame_offsets) or w.shape[2] != 3:
            raise InputError(f"joint window must be (K, J, 3) with K matching, got {w.shape}")
        fd = _FrameData(frame, self.faces, self.feature_config, self.config.use_motion)
        self._frames = [*self._frames[-1:], fd]
        return fd

    def crop_box(self, camera: Camera, frame: FrameState) -> CropBox | None:
        """The network's window for this view: the proxy's box + margin, snapped to the stride;
        None when no vertex projects into the image."""
        uv, depth = project(np.asarray(frame.vertices, np.float64), camera)
        ok = np.isfinite(uv).all(1) & (depth > 0)
        if not ok.any():
            return None
        lo, hi = uv[ok].min(0), uv[ok].max(0)
        if hi[0] < 0 or hi[1] < 0 or lo[0] > camera.width or lo[1] > camera.height:
            return None
        # Vertices far behind the image edge would give huge crops: clip the box to the image.
        lo = np.maximum(lo, 0.0)
        hi = np.minimum(hi, [camera.width, camera.height])
        s, m = self.config.stride, self.config.crop_margin
        x0, y0 = (int(np.floor((c - m) / s)) * s for c in lo)
        x1, y1 = (int(np.ceil((c + m) / s)) * s for c in hi)
        return CropBox(x0, y0, max(x1 - x0, s), max(y1 - y0, s))

    def full_box(self, camera: Camera) -> CropBox:
        """The whole image, rounded up to the stride."""
        s = self.config.stride
        return CropBox(0, 0, -(-camera.width // s) * s, -(-camera.height // s) * s)

    def features(self, fd: _FrameData, camera: Camera) -> torch.Tensor:
        """Rasterize and sample: network input (1, in_channels, h, w) for a (cropped) camera."""
        frag = fd.scene.rasterize(camera, self.raster)
        chw = lambda a: torch.from_numpy(np.ascontiguousarray(np.moveaxis(a, -1, 0)))[None]  # noqa: E731
        uv = chw(uv_map(frag, self.faces, self.uvs)).to(self.device)
        mask = torch.from_numpy(frag.mask.astype(np.float32))[None, None].to(self.device)
        motion = None
        if self.config.use_motion:
            motion = chw(interpolate(frag, self.faces, fd.features, "float32")).to(self.device)
        return self.net.input_features(uv, motion, mask)

    def _encode(self, fd: _FrameData, camera: Camera) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """(latent, encoder skips) of a frame; only the latent is kept for the next frame."""
        self.encodes += 1
        return self.net.encode_with_skips(self.features(fd, camera))

    def _background(self, background: np.ndarray, camera: Camera, box: CropBox) -> torch.Tensor:
        bg = np.asarray(background)
        if bg.shape != (camera.height, camera.width, 3) or bg.dtype != np.uint8:
            raise InputError(
                f"background must be ({camera.height}, {camera.width}, 3) uint8, "
                f"got {bg.shape} {bg.dtype}"
            )
        # Edge-padded where the crop passes the image's edges.
        ys = np.clip(np.arange(box.y0, box.y0 + box.height), 0, camera.height - 1)
        xs = np.clip(np.arange(box.x0, box.x0 + box.width), 0, camera.width - 1)
        crop = bg[ys[:, None], xs[None, :]].astype(np.float32) / 255
        return torch.from_numpy(np.ascontiguousarray(crop.transpose(2, 0, 1)))[None].to(self.device)

    def _compose(
        self, camera: Camera, frame: FrameState, box: CropBox, z: torch.Tensor, z_prev, skips
    ) -> np.ndarray:
        background = self._background(frame.background, camera, box)
        rgb, _ = self.net.decode(z, z_prev, background, skips)
        img = (rgb[0].clamp(0, 1).permute(1, 2, 0).float().cpu().numpy() * 255 + 0.5).astype(
            np.uint8
        )
        out = np.array(frame.background, np.uint8, copy=True)
        ya, yb = max(box.y0, 0), min(box.y0 + box.height, camera.height)
        xa, xb = max(box.x0, 0), min(box.x0 + box.width, camera.width)
        if ya < yb and xa < xb:
            out[ya:yb, xa:xb] = img[ya - box.y0 : yb - box.y0, xa - box.x0 : xb - box.x0]
        return out

    @staticmethod
    def _key(camera: Camera, box: CropBox) -> tuple:
        return (camera.width, camera.height, camera.K.tobytes(), camera.extrinsic.tobytes(), box)

    # -- the two entry points --------------------------------------------------------------------

    @torch.no_grad()
    def render_pair(
        self,
        camera: Camera,
        frame: FrameState,
        previous: FrameState | None = None,
        *,
        crop: bool = True,
    ) -> np.ndarray:
        """Stateless render of ``frame`` with ``previous`` as t-1 (itself when None):
        (H, W, 3) uint8. ``crop=False`` runs the network on the whole image."""
        box = self.crop_box(camera, frame) if crop else self.full_box(camera)
        if box is None:
            return np.array(frame.background, np.uint8, copy=True)
        cam = crop_camera(camera, box.x0, box.y0, box.width, box.height)
        z, skips = self._encode(self._frame_data(frame), cam)
        z_prev = z if previous is None else self._encode(self._frame_data(previous), cam)[0]
        return self._compose(camera, frame, box, z, z_prev, skips)

    @torch.no_grad()
    def render(
        self, camera: Camera, frame: FrameState, previous: FrameState | None = None
    ) -> np.ndarray:
        """Streaming render: (H, W, 3) uint8 of ``frame`` over its background.

        ``previous`` is frame t-1 (None: the frame this renderer rendered last, or, on a
        fresh stream, ``frame`` itself). Reuses the last call's latent when it can.
        """
        if previous is None and self._last is not None:
            previous = self._last[1]
        box = self.crop_box(camera, frame)
        if box is None:
            self._last = None
            return np.array(frame.background, np.uint8, copy=True)
        cam = crop_camera(camera, box.x0, box.y0, box.width, box.height)
        key = self._key(camera, box)
        z, skips = self._encode(self._frame_data(frame), cam)
        if previous is None or previous is frame:
            z_prev = z
        elif self._last is not None and self._last[0] == key and self._last[1] is previous:
            z_prev = self._last[2]
        else:
            z_prev = self._encode(self._frame_data(previous), cam)[0]
        self._last = (key, frame, z)
        return self._compose(camera, frame, box, z, z_prev, skips)
