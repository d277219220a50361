"""The render path on one torch device: motion descriptor -> Joint2Coarse -> rasterize the proxy
-> neural texture + motion features -> renderer network -> composite over the body background.

:class:`TorchPlayer` plays the clips of a bundle (:mod:`training.torchpath.bundle`)::

    player = TorchPlayer("demo.torch.pt", device="cuda")
    player.set_clip("dance")
    cam = player.camera(0, 512, 512, azimuth_deg=30)
    image = player.render(0, cam)        # (512, 512, 3) uint8 tensor on the device

Everything after the clip's upload (its descriptors, root frames, joints and skinning
transforms, sent once by :meth:`TorchPlayer.set_clip`) stays on the device: Joint2Coarse's
output is posed, rasterized, sampled and rendered there, and only the image's owner copies it
back. Two windows:

- ``window="crop"`` (default) runs the network on the proxy's screen box + margin, as
  :meth:`training.renderer.inference.NeuralRenderer.render`, and gives its pixels; the box's
  four numbers and the rasterizer's pair counts are read from the device (scalars, no images);
- ``window="full"`` runs it on the whole image (:meth:`NeuralRenderer.render_pair` with
  ``crop=False``) with fixed rasterizer capacities: nothing is read back, shapes are static.

Joint2Coarse is the bundle's model: the paper's network, or ours
(:class:`~training.joint2coarse.body_model.BodyResidualNet`, the numpy model's own prediction
functions run on torch tensors; on CUDA its ``torch.linalg.svd`` makes the host wait for the
device once per call, reading nothing back). Streaming keeps frame t-1's latent, like the numpy
path. Pixels match :class:`pipeline.playback.Playback` up to the rasterizers' ties (see the
tests and ``benchmarks/torchpath_match.py``).
"""

from __future__ import annotations

import os

import numpy as np
import torch

from core.camera import Camera, follow_camera
from core.errors import InputError
from core.features import interpolate_torch, vertex_motion_features_torch
from core.shading import ShadingConfig
from training.joint2coarse.body_model import BodyResidualModel
from training.joint2coarse.descriptor import motion_descriptors, tilt_rotvecs
from training.joint2coarse.model import net_from_payload
from training.renderer.config import RendererConfig
from training.renderer.model import RenderNet
from training.torchpath.bundle import load_bundle
from training.torchpath.raster import TorchCamera, pair_count, rasterize
from training.torchpath.shade import render_background

WINDOWS = ("crop", "full")
#: Slack on a first frame's pair count when capacities are fixed (``window="full"``).
CAPACITY_SLACK = 2.0


def rotate_partially(points: torch.Tensor, rotvecs: torch.Tensor, fractions: torch.Tensor):
    """:func:`training.joint2coarse.descriptor.rotate_partially` in torch: points (T, N, 3),
    rotvecs (T, 3), fractions (N,) -> (T, N, 3) (Rodrigues, each point its share of the turn)."""
    angle = rotvecs.norm(dim=-1)
    k = rotvecs / torch.where(angle > 0, angle, torch.ones_like(angle))[:, None]
    a = fractions[None, :, None] * angle[:, None, None]
    kk = k[:, None, :].expand_as(points)
    along = (points * kk).sum(-1, keepdim=True) * kk
    return (points - along) * torch.cos(a) + torch.linalg.cross(kk, points) * torch.sin(a) + along


def linear_blend_skinning(rest, weights, transforms):
    """:func:`core.body.skinning.linear_blend_skinning` in torch: rest (V, 3), weights (V, J),
    transforms (T, J, 4, 4) -> (T, V, 3)."""
    t, j = transforms.shape[:2]
    blended = (weights @ transforms[:, :, :3, :].permute(1, 0, 2, 3).reshape(j, t * 12)).view(
        len(rest), t, 3, 4
    )
    posed = torch.einsum("vtab,vb->tva", blended[..., :3], rest) + blended[..., 3].transpose(0, 1)
    return posed


def limit_stretch_torch(x, edges, lengths, limit: float, sweeps: int):
    """:func:`core.strain.limit_stretch` in torch: x (B, V, 3) float64, edges (E, 2) int64,
    lengths (E,) float64 rest lengths -> (B, V, 3), every edge longer than ``1 + limit`` times
    its rest length shortened back, both ends alike, each vertex by the mean of its edges'
    corrections, ``sweeps`` times (a sweep with no edge over it changes nothing, so the numpy
    version's early stop gives the same result). No value is read back to the host."""
    e0, e1 = edges[:, 0], edges[:, 1]
    most = (1.0 + limit) * lengths
    for _ in range(sweeps):
        vec = x[:, e1] - x[:, e0]
        length = torch.linalg.vector_norm(vec, dim=-1)
        over = length > most
        step = torch.where(over, 0.5 * (1.0 - most / length.clamp_min(1e-300)), 0.0)
        step = step[..., None] * vec
        shift = torch.zeros_like(x).index_add_(1, e0, step).index_add_(1, e1, -step)
        count = torch.zeros_like(x[..., 0]).index_add_(1, e0, over.double())
        count = count.index_add_(1, e1, over.double())
        x = x + shift / count.clamp_min(1.0)[..., None]
    return x


class TorchPlayer:
    """A bundle's project on one device (see the module docstring).

    Parameters
    ----------
    bundle : a bundle file, or the dict :func:`load_bundle` returns
    device : torch device
    window : ``crop`` or ``full``
    channels_last, bf16 : run the renderer network in channels-last memory format / under
        bfloat16 autocast (CUDA options; bf16 changes pixels by its rounding)
    """

    def __init__(
        self,
        bundle: str | os.PathLike | dict,
        device: str | torch.device = "cpu",
        *,
        window: str = "crop",
        channels_last: bool = False,
        bf16: bool = False,
    ):
        if window not in WINDOWS:
            raise InputError(f"window must be one of {WINDOWS}, got {window!r}")
        data = bundle if isinstance(bundle, dict) else load_bundle(bundle)
        self.device = torch.device(device)
        self.window = window
        self.bf16 = bf16
        self.channels_last = channels_last
        dev = self.device
        j2c = net_from_payload(data["joint2coarse"])
        if isinstance(j2c, BodyResidualModel):  # ours: the same prediction as a torch module
            j2c = j2c.to_torch()
        follow = j2c.follow_weights()  # a host copy: read before the move to the device
        self.joint2coarse = j2c.to(dev).eval().requires_grad_(False)
        config = RendererConfig.from_stored(data["renderer"]["config"])
        self.net = RenderNet(config)
        self.net.load_state_dict(data["renderer"]["generator"])
        self.net = self.net.to(dev).eval().requires_grad_(False)
        if channels_last:
            self.net = self.net.to(memory_format=torch.channels_last)
        self.config = config
        proxy, body = data["proxy"], data["body"]
        self.faces = proxy["faces"].to(dev)
        self.uvs = proxy["uvs"].to(dev)
        self.seam_map = proxy["seam_map"].to(dev)
        self.stretch = proxy.get("stretch")  # None in bundles from before the strain limit
        if self.stretch is not None:
            self.stretch = {
                **self.stretch,
                "edges": self.stretch["edges"].to(dev),
                "lengths": self.stretch["lengths"].to(dev).double(),
            }
        self.body_rest = body["vertices"].to(dev)
        self.body_weights = body["weights"].to(dev)
        self.body_faces = body["faces"].to(dev)
        self.rig = dict(data["rig"])
        self.sigma = float(data["features"]["sigma"])
        self.offsets = torch.as_tensor(list(data["features"]["frame_offsets"]), device=dev)
        self.clips = data["clips"]
        self.follow = None if follow is None else torch.from_numpy(follow).to(dev)
        self.clip: str | None = None
        self._capacity: dict = {}
        self.overflow: list[torch.Tensor] = []  # flags of fixed-capacity rasterizations
        self._last = None  # (t, key, latent) of the last streamed frame
        self.encodes = 0

    # -- the clip ----------------------------------------------------------------------------

    def set_clip(self, name: str) -> None:
        """Play clip ``name``: its descriptors and root frames (numpy, once) go to the device."""
        if name not in self.clips:
            raise InputError(f"no clip {name!r} in the bundle ({', '.join(self.clips)})")
        clip = self.clips[name]
        cfg = self.joint2coarse.config
        joints = clip["joints"].numpy()
        root_rot = clip["root_rotations"].numpy()
        desc, origin, heading = motion_descriptors(joints, root_rot, cfg.window, cfg.stride)
        dev = self.device
        self._desc = torch.from_numpy(desc).to(dev)
        self._origin = torch.from_numpy(origin).to(dev)
        self._heading = torch.from_numpy(heading).to(dev)
        self._tilt = torch.from_numpy(tilt_rotvecs(root_rot, heading)).to(dev)
        self._joints = clip["joints"][:, 1:].to(dev)  # the 19 canonical joints of the features
        self._transforms = clip["transforms"].to(dev)
        self._root = clip["root_positions"].numpy()
        self.num_frames = len(joints)
        self.clip = name
        self._last = None

    def _frames(self, frames) -> torch.Tensor:
        if self.clip is None:
            raise InputError("no clip: call set_clip first")
        return torch.as_tensor(frames, device=self.device).long().reshape(-1)

    def proxy(self, frames) -> torch.Tensor:
        """Joint2Coarse's UV-split proxy at frames (B,) int: (B, Vp, 3) float32 on the device."""
        f = self._frames(frames)
        local = self.joint2coarse(self._desc[f]).double()  # (B, Vc, 3) output frame
        if self.follow is not None:
            local = rotate_partially(local, self._tilt[f], self.follow.double())
        world = local @ self._heading[f].transpose(-1, -2) + self._origin[f][:, None]
        if self.stretch is not None:  # as Playback's prediction (pipeline.playback)
            s = self.stretch  # from float32, as predict_proxy limits its float32 output
            world = world.float().double()
            world = limit_stretch_torch(world, s["edges"], s["lengths"], s["limit"], s["sweeps"])
        return world.float()[:, self.seam_map]

    def body(self, frames) -> torch.Tensor:
        """The posed body at frames (B,) int: (B, Vb, 3) float32 on the device."""
        f = self._frames(frames)
        return linear_blend_skinning(self.body_rest, self.body_weights, self._transforms[f])

    def joint_window(self, frames) -> torch.Tensor:
        """Joints at ``t - k`` for the feature offsets: (B, K, 19, 3) on the device."""
        f = self._frames(frames)
        return self._joints[(f[:, None] - self.offsets[None]).clamp(min=0)]

    def camera(
        self,
        t: int,
        width: int,
        height: int,
        azimuth_deg: float = 0.0,
        elevation_deg: float = 10.0,
        distance_scale: float = 1.075,
    ) -> Camera:
        """The camera :meth:`pipeline.playback.Playback.default_camera` makes
        (:func:`core.camera.follow_camera` at frame t's root; host numbers)."""
        rig = self.rig
        return follow_camera(
            self._root[int(t)], rig["target_y"], rig["radius"], rig["fov_y_deg"], width, height,
            azimuth_deg, elevation_deg, distance_scale,
        )  # fmt: skip

    # -- rendering ---------------------------------------------------------------------------

    def _rasterize(self, vertices, faces, camera: TorchCamera, kind: str):
        if self.window == "crop":
            return rasterize(vertices, faces, camera)
        key = (kind, camera.width, camera.height, len(vertices))
        if key not in self._capacity:  # read once per size; later frames read nothing
            n = pair_count(vertices, faces, camera)
            self._capacity[key] = int(CAPACITY_SLACK * n) + 4096
        frags = rasterize(vertices, faces, camera, capacity=self._capacity[key])
        self.overflow.append(frags.overflow)
        if len(self.overflow) > 256:  # folded on the device: a long stream keeps one flag
            self.overflow = [torch.stack(self.overflow).any()]
        return frags

    def check_overflow(self) -> None:
        """Raise if a fixed-capacity rasterization (``window="full"``) dropped pairs since the
        last check (reads the flags once: call it now and then, e.g. at the end of a clip)."""
        if self.overflow and bool(torch.stack(self.overflow).any()):
            raise RuntimeError("rasterizer capacity exceeded: use window='crop'")
        self.overflow = []

    def background(self, frames, camera: TorchCamera) -> torch.Tensor:
        """The body alone at frames: (B, H, W, 3) uint8 on the device."""
        body = self.body(frames)
        if self.window == "crop":
            return render_background(body, self.body_faces, camera)
        key = ("body", camera.width, camera.height, len(body))
        if key not in self._capacity:
            n = pair_count(body, self.body_faces, camera.scaled(ShadingConfig().supersample))
            self._capacity[key] = int(CAPACITY_SLACK * n) + 4096
        return render_background(
            body, self.body_faces, camera, capacity=self._capacity[key], overflow=self.overflow
        )

    def _box(self, vertices: torch.Tensor, camera: TorchCamera):
        """The network window of (B, Vp, 3) proxies: their joint screen box + margin, snapped
        to the stride (:meth:`NeuralRenderer.crop_box`), as host ints; None when off screen."""
        s, m = self.config.stride, self.config.crop_margin
        w, h = camera.width, camera.height
        if self.window == "full":
            return 0, 0, -(-w // s) * s, -(-h // s) * s
        pc = vertices.double() @ camera.R.double().transpose(-1, -2) + camera.t.double()
        z = pc[..., 2]
        fx, fy, cx, cy = camera.intrinsics.double().unbind(-1)
        ok = z > 0
        zs = torch.where(ok, z, torch.ones_like(z))
        uv = torch.stack([fx * pc[..., 0] / zs + cx, fy * pc[..., 1] / zs + cy], -1)
        inf = torch.tensor(float("inf"), dtype=uv.dtype, device=uv.device)
        lo = torch.where(ok[..., None], uv, inf).flatten(0, 1).amin(0)
        hi = torch.where(ok[..., None], uv, -inf).flatten(0, 1).amax(0)
        lo_x, lo_y, hi_x, hi_y = torch.cat([lo, hi]).tolist()  # the one read: four numbers
        if not np.isfinite(lo_x) or hi_x < 0 or hi_y < 0 or lo_x > w or lo_y > h:
            return None
        lo_x, lo_y = max(lo_x, 0.0), max(lo_y, 0.0)
        hi_x, hi_y = min(hi_x, w), min(hi_y, h)
        x0, y0 = (int(np.floor((c - m) / s)) * s for c in (lo_x, lo_y))
        x1, y1 = (int(np.ceil((c + m) / s)) * s for c in (hi_x, hi_y))
        return x0, y0, max(x1 - x0, s), max(y1 - y0, s)

    def _inputs(self, frames: torch.Tensor, vertices: torch.Tensor, crop: TorchCamera):
        """Network input (B, in_channels, h, w) of proxies (B, Vp, 3) in the crop camera."""
        frags = self._rasterize(vertices, self.faces, crop, "proxy")
        fid, bary = frags.face_id, frags.barycentrics.float()
        mask = frags.mask.float()[:, None]
        uv = interpolate_torch(fid, bary, self.faces, self.uvs).permute(0, 3, 1, 2)
        motion = None
        if self.config.use_motion:
            feats = vertex_motion_features_torch(vertices, self.joint_window(frames), self.sigma)
            motion = interpolate_torch(fid, bary, self.faces, feats).permute(0, 3, 1, 2)
        x = self.net.input_features(uv, motion, mask)
        return x.contiguous(memory_format=torch.channels_last) if self.channels_last else x

    def _encode(self, x):
        self.encodes += len(x)
        with torch.autocast(self.device.type, torch.bfloat16, enabled=self.bf16):
            return self.net.encode_with_skips(x)

    def _compose(self, background, box, z, z_prev, skips) -> torch.Tensor:
        """Decode and paste the window over the (B, H, W, 3) uint8 background."""
        x0, y0, bw, bh = box
        nb, h, w, _ = background.shape
        ys = torch.arange(y0, y0 + bh, device=self.device).clamp(0, h - 1)
        xs = torch.arange(x0, x0 + bw, device=self.device).clamp(0, w - 1)
        bg = background[:, ys[:, None], xs[None, :]].permute(0, 3, 1, 2).float() / 255
        if self.channels_last:
            bg = bg.contiguous(memory_format=torch.channels_last)
        with torch.autocast(self.device.type, torch.bfloat16, enabled=self.bf16):
            rgb, _ = self.net.decode(z, z_prev, bg, skips)
        img = (rgb.float().clamp(0, 1).permute(0, 2, 3, 1) * 255 + 0.5).to(torch.uint8)
        out = background.clone()
        ya, yb, xa, xb = max(y0, 0), min(y0 + bh, h), max(x0, 0), min(x0 + bw, w)
        if ya < yb and xa < xb:
            out[:, ya:yb, xa:xb] = img[:, ya - y0 : yb - y0, xa - x0 : xb - x0]
        return out

    @torch.no_grad()
    def render(self, t: int, camera: Camera) -> torch.Tensor:
        """Streaming render of frame t: (H, W, 3) uint8 on the device.

        Frame t-1's latent is reused when the previous call rendered t-1 with the same camera
        and window; otherwise t-1 is encoded again (frame 0 uses itself), as the numpy path.
        """
        f = self._frames([t])
        cam = TorchCamera.from_camera(camera, self.device)
        background = self.background(f, cam)
        vertices = self.proxy(f)
        box = self._box(vertices, cam)
        if box is None:
            self._last = None
            return background[0]
        crop = cam.crop(box[0], box[1], box[2], box[3])
        key = (camera.width, camera.height, camera.K.tobytes(), camera.extrinsic.tobytes(), box)
        z, skips = self._encode(self._inputs(f, vertices, crop))
        if t == 0:
            z_prev = z
        elif self._last is not None and self._last[:2] == (t - 1, key):
            z_prev = self._last[2]
        else:
            fp = self._frames([t - 1])
            z_prev = self._encode(self._inputs(fp, self.proxy(fp), crop))[0]
        self._last = (t, key, z)
        return self._compose(background, box, z, z_prev, skips)[0]

    @torch.no_grad()
    def render_batch(self, start: int, count: int, camera: Camera) -> torch.Tensor:
        """Frames ``start .. start + count - 1`` in one batch: (B, H, W, 3) uint8 on the device.

        One camera and one window for the batch (the union of the frames' boxes with
        ``window="crop"``); frames t-1 are encoded in the same batch (frame ``start - 1``
        once more, or frame 0 itself).
        """
        if count < 1 or start < 0 or start + count > self.num_frames:
            raise InputError(f"frames {start}..{start + count - 1} not in [0, {self.num_frames})")
        f = self._frames(range(start, start + count))
        cam = TorchCamera.from_camera(camera, self.device)
        background = self.background(f, cam)
        fe = self._frames(range(max(start - 1, 0), start + count))  # t-1 of the first, then all
        vertices = self.proxy(fe)
        box = self._box(vertices[-count:], cam)
        if box is None:
            return background
        crop = cam.crop(box[0], box[1], box[2], box[3])
        z, skips = self._encode(self._inputs(fe, vertices, crop))
        first = len(fe) - count
        z_prev = torch.cat([z[:1], z[:-1]]) if first == 0 else z[:-1]
        skips = [s[first:] for s in skips]
        return self._compose(background, box, z[first:], z_prev, skips)
