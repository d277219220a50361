"""Rasterization in torch: the same face ids, barycentrics and depth as :mod:`core.raster`, on
any torch device (the CPU, a CUDA GPU), with no other library.

Each triangle's screen bounding box is expanded into (triangle, pixel) pairs; each pair runs the
homogeneous edge-function test of :func:`core.raster.rasterize_reference` (two-sided, pixel
``(i, j)`` sampled at ``(j + 0.5, i + 0.5)``, perspective-correct barycentrics, triangles
crossing behind the camera handled without clipping), and a z-buffer keeps the nearest: one
``scatter_reduce(amin)`` of a key that packs the float32 depth's bits above the face index, so
equal depths go to the lower face index, as in the reference. The winner's barycentrics and
depth are then recomputed per pixel.

Shapes are static when a pair ``capacity`` is given (no host synchronisation: CUDA-graph and
stream friendly); pairs past the capacity are dropped and :attr:`TorchFragments.overflow` says
so. Without a capacity the exact pair count is read from the device (one scalar).

The per-face set-up (camera-space corners, edge planes, boxes) and the winners' barycentrics
and depth are float64; the (triangle, pixel) tests are float32 by default
(``dtype=torch.float64``: the reference's arithmetic, and its face ids exactly, in the tests).
In float32 results differ from the reference only where two triangles tie (a pixel centre on a
shared edge, equal depths in float32) or a pixel centre lies on a silhouette edge within
rounding.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from core.camera import Camera
from core.errors import InputError
from core.raster import Fragments

#: Pairs tested per block (bounds memory at about 100 bytes per pair).
PAIR_BLOCK = 1 << 21
#: Pixels by which a face's screen box is widened on each side. Far below a pixel: a triangle
#: of a pixel or two (a body at 3x supersampling) tests a handful of pixels, not 3 x 3 or more.
BOX_SLACK = 0.01
_NO_HIT = torch.iinfo(torch.int64).max
_FACE_BITS = 32


@dataclass(frozen=True)
class TorchCamera:
    """Pinhole cameras as device tensors (see :class:`core.camera.Camera`), one or a batch.

    Attributes
    ----------
    R : (3, 3) or (B, 3, 3) tensor, world-to-camera rotation
    t : (3,) or (B, 3) tensor, world-to-camera translation
    intrinsics : (4,) or (B, 4) tensor ``(fx, fy, cx, cy)`` in pixels (a tensor, so a crop's
        offset can be computed on the device)
    width, height : int, shared by the batch
    """

    R: torch.Tensor
    t: torch.Tensor
    intrinsics: torch.Tensor
    width: int
    height: int

    @classmethod
    def from_camera(
        cls, camera: Camera, device: str | torch.device = "cpu", dtype=torch.float32
    ) -> TorchCamera:
        k = torch.tensor([camera.fx, camera.fy, camera.cx, camera.cy], dtype=torch.float64)
        return cls(
            torch.as_tensor(camera.R).to(device, dtype),
            torch.as_tensor(camera.t).to(device, dtype),
            k.to(device, dtype),
            int(camera.width),
            int(camera.height),
        )

    @classmethod
    def stack(cls, cameras: list[TorchCamera]) -> TorchCamera:
        """A batch of single cameras of one size."""
        c0 = cameras[0]
        if any((c.width, c.height) != (c0.width, c0.height) for c in cameras):
            raise InputError("a camera batch needs one image size")
        return cls(
            torch.stack([c.R for c in cameras]),
            torch.stack([c.t for c in cameras]),
            torch.stack([c.intrinsics for c in cameras]),
            c0.width,
            c0.height,
        )

    def crop(self, x0, y0, width: int, height: int) -> TorchCamera:
        """The camera of the window ``[x0, x0 + width) x [y0, y0 + height)`` (x0, y0: ints, or
        tensors of the batch shape), as :func:`core.camera.crop_camera`."""
        k = self.intrinsics
        x0 = torch.as_tensor(x0).to(k)
        y0 = torch.as_tensor(y0).to(k)
        zero = torch.zeros_like(x0)
        shift = torch.stack(torch.broadcast_tensors(zero, zero, x0, y0), -1)
        return TorchCamera(self.R, self.t, k - shift, int(width), int(height))

    def scaled(self, k: int) -> TorchCamera:
        """The same view ``k`` times larger on each axis (:func:`core.camera.resize_camera`)."""
        return TorchCamera(self.R, self.t, self.intrinsics * k, k * self.width, k * self.height)


@dataclass(frozen=True)
class TorchFragments:
    """Per-pixel result of :func:`rasterize` (as :class:`core.raster.Fragments`).

    Attributes
    ----------
    face_id : ([B,] H, W) int64 tensor, -1 for background
    barycentrics : ([B,] H, W, 3) float32 tensor, zeros for background
    depth : ([B,] H, W) float32 tensor, camera-space z, inf for background
    overflow : 0-d bool tensor or None: pairs were dropped for lack of capacity
    """

    face_id: torch.Tensor
    barycentrics: torch.Tensor
    depth: torch.Tensor
    overflow: torch.Tensor | None = None

    @property
    def mask(self) -> torch.Tensor:
        """([B,] H, W) bool: pixels that see a triangle."""
        return self.face_id >= 0

    def numpy(self):
        """The :class:`core.raster.Fragments` of this (unbatched) result, copied to the host."""
        return Fragments(
            self.face_id.cpu().numpy(),
            self.barycentrics.float().cpu().numpy(),
            self.depth.float().cpu().numpy(),
        )


def _corners(vertices: torch.Tensor, faces: torch.Tensor, camera: TorchCamera, dtype):
    """Camera-space corners (B * F, 3, 3) of every face of every batch item."""
    R, t = camera.R.to(dtype), camera.t.to(dtype)
    v = vertices.to(dtype)
    pc = v @ R.transpose(-1, -2) + t.unsqueeze(-2)  # (B, V, 3)
    return pc[:, faces].flatten(0, 1)


def _edge_planes(p: torch.Tensor):
    """Cross products (N, 3, 3) (row k: ``P_j x P_k``) and det (N,) of corners (N, 3, 3)."""
    p0, p1, p2 = p.unbind(1)
    planes = torch.stack(
        [torch.linalg.cross(p1, p2), torch.linalg.cross(p2, p0), torch.linalg.cross(p0, p1)], 1
    )
    return planes, (p0 * planes[:, 0]).sum(-1)


def _bounds(p: torch.Tensor, det: torch.Tensor, k: torch.Tensor, width: int, height: int, near):
    """Per-face pixel window (x0, y0, w, h) (N,) int64 each; zero size for skipped faces.

    A face in front of ``near`` gets its projected bounding box (widened by
    :data:`BOX_SLACK`); a face
    crossing ``near`` the whole image; a face behind it, or degenerate, nothing.
    ``k`` (N, 4) are the faces' intrinsics.
    """
    z = p[..., 2]
    front = z > near
    n_front = front.sum(1)
    usable = (n_front > 0) & (det.abs() >= 1e-18)
    fx, fy, cx, cy = (c[:, None] for c in k.to(p.dtype).unbind(-1))
    zs = torch.where(front, z, torch.ones_like(z))
    u = fx * p[..., 0] / zs + cx
    v = fy * p[..., 1] / zs + cy
    big = float(4 * max(width, height) + 16)  # far off-screen corners stay finite as ints
    # Pixel j's centre is j + 0.5: a box [a, b] covers pixels ceil(a - 0.5) .. floor(b - 0.5),
    # here widened by BOX_SLACK pixels (the box is float64, the edge tests may be float32).
    x0 = torch.ceil(u.amin(1) - 0.5 - BOX_SLACK).clamp(-big, big)
    x1 = torch.floor(u.amax(1) - 0.5 + BOX_SLACK).clamp(-big, big) + 1  # exclusive
    y0 = torch.ceil(v.amin(1) - 0.5 - BOX_SLACK).clamp(-big, big)
    y1 = torch.floor(v.amax(1) - 0.5 + BOX_SLACK).clamp(-big, big) + 1
    crossing = n_front < 3
    x0 = torch.where(crossing, torch.zeros_like(x0), x0.clamp(0, width)).long()
    y0 = torch.where(crossing, torch.zeros_like(y0), y0.clamp(0, height)).long()
    x1 = torch.where(crossing, torch.full_like(x1, width), x1.clamp(0, width)).long()
    y1 = torch.where(crossing, torch.full_like(y1, height), y1.clamp(0, height)).long()
    bw = torch.where(usable, (x1 - x0).clamp(min=0), torch.zeros_like(x0))
    bh = torch.where(usable, (y1 - y0).clamp(min=0), torch.zeros_like(y0))
    return x0, y0, bw, bh


def _batch_intrinsics(camera: TorchCamera, batch: int) -> torch.Tensor:
    k = camera.intrinsics
    return k.expand(batch, 4) if k.dim() == 1 else k


def rasterize(
    vertices: torch.Tensor,
    faces: torch.Tensor,
    camera: TorchCamera,
    *,
    near: float = 0.0,
    capacity: int | None = None,
    dtype: torch.dtype = torch.float32,
) -> TorchFragments:
    """Rasterize a triangle mesh (or a batch of poses of it) on its device.

    Parameters
    ----------
    vertices : (V, 3) or (B, V, 3) float tensor, world positions
    faces : (F, 3) int64 tensor on the same device
    camera : TorchCamera on the same device (one, or a batch of B)
    near : surfaces at camera-space depth <= near are not seen
    capacity : (triangle, pixel) pairs to test; None counts them exactly (one scalar read
        from the device). With a capacity nothing is read back.
    dtype : work dtype of the (triangle, pixel) tests (float32, or float64 as the
        reference); the set-up per face and the winners' barycentrics and depth are float64

    Returns
    -------
    TorchFragments of shape ([B,] camera.height, camera.width)
    """
    batched = vertices.dim() == 3
    if vertices.shape[-1] != 3 or vertices.dim() not in (2, 3) or faces.dim() != 2:
        raise InputError(f"vertices (V, 3) and faces (F, 3), got {vertices.shape}, {faces.shape}")
    if not batched:
        vertices = vertices[None]
    dev = vertices.device
    nb = len(vertices)
    h, w = camera.height, camera.width
    hw = h * w
    n_faces = len(faces)
    shape = (nb, h, w) if batched else (h, w)
    if n_faces == 0:
        return TorchFragments(
            torch.full(shape, -1, dtype=torch.long, device=dev),
            torch.zeros((*shape, 3), device=dev),
            torch.full(shape, float("inf"), device=dev),
            None if capacity is None else torch.zeros((), dtype=torch.bool, device=dev),
        )
    faces = faces.long()
    # Per-face set-up in float64 (few faces: cheap anywhere), per-pair work in ``dtype``.
    p = _corners(vertices, faces, camera, torch.float64)  # (B * F, 3, 3)
    planes, det = _edge_planes(p)
    planes64, det64, k64 = planes, det, _batch_intrinsics(camera, nb).double()
    planes, det = planes.to(dtype), det.to(dtype)
    kf = _batch_intrinsics(camera, nb).to(dtype).repeat_interleave(n_faces, 0)  # (B * F, 4)
    x0, y0, bw, bh = _bounds(p, det, kf, w, h, near)
    counts = bw * bh
    ends = torch.cumsum(counts, 0)
    overflow = None
    if capacity is None:
        n = int(ends[-1])
    else:
        n = int(capacity)
        overflow = ends[-1] > n
    zbuf = torch.full((nb * hw,), _NO_HIT, dtype=torch.long, device=dev)
    total_faces = len(p)
    for start in range(0, n, PAIR_BLOCK):
        pair = torch.arange(start, min(n, start + PAIR_BLOCK), device=dev)
        f = torch.searchsorted(ends, pair, right=True)
        live = f < total_faces
        f = f.clamp(max=total_faces - 1)
        local = pair - (ends[f] - counts[f])
        fw = bw[f].clamp(min=1)
        row = y0[f] + torch.div(local, fw, rounding_mode="floor")
        col = x0[f] + local % fw
        e, z = _edge_values(planes[f], det[f], row, col, kf[f])
        s = e.sum(-1)
        inside = live & ((e * s[:, None]) >= 0).all(-1) & torch.isfinite(z) & (z > near)
        key = (z.float().view(torch.int32).long() << _FACE_BITS) | f
        key = torch.where(inside, key, torch.full_like(key, _NO_HIT))
        b = torch.div(f, n_faces, rounding_mode="floor")
        pix = torch.where(inside, b * hw + row * w + col, torch.zeros_like(row))
        zbuf.scatter_reduce_(0, pix, key, "amin")
    hit = zbuf != _NO_HIT
    fg = torch.where(hit, zbuf & ((1 << _FACE_BITS) - 1), torch.zeros_like(zbuf))
    # The winners' barycentrics and depth, recomputed per pixel in float64 (float32 loses
    # 1e-5 of the depth of a surface seen at a grazing angle), in blocks: bounded memory.
    # On the CPU only the covered pixels are visited (finding them costs nothing there); on
    # other devices every pixel, so that nothing is read back.
    bary = torch.zeros((nb * hw, 3), dtype=torch.float32, device=dev)
    depth = torch.full((nb * hw,), float("inf"), dtype=torch.float32, device=dev)
    pixels = hit.nonzero()[:, 0] if dev.type == "cpu" else None
    n_visit = nb * hw if pixels is None else len(pixels)
    for start in range(0, n_visit, PAIR_BLOCK):
        stop = min(n_visit, start + PAIR_BLOCK)
        pixel = torch.arange(start, stop, device=dev) if pixels is None else pixels[start:stop]
        b = torch.div(pixel, hw, rounding_mode="floor")
        rest = pixel - b * hw
        row, col = torch.div(rest, w, rounding_mode="floor"), rest % w
        g = fg[pixel]
        e, z = _edge_values(planes64[g], det64[g], row, col, k64[b])
        lam = (e / e.sum(-1, keepdim=True)).clamp(0, 1)
        lam = lam / lam.sum(-1, keepdim=True).clamp(min=1e-12)
        on = hit[pixel]
        bary[pixel] = torch.where(on[:, None], lam, torch.zeros_like(lam)).float()
        depth[pixel] = torch.where(on, z.float(), depth[pixel])
    face_id = torch.where(hit, fg % n_faces, torch.full_like(fg, -1))
    return TorchFragments(face_id.view(shape), bary.view(*shape, 3), depth.view(shape), overflow)


def _edge_values(planes, det, row, col, k):
    """Edge functions (N, 3) of pixel centres (row, col) (N,) against faces' planes (N, 3, 3)
    seen with intrinsics k (N, 4), and the hit depth (N,) ``det / sum(e)``."""
    fx, fy, cx, cy = k.unbind(-1)
    dx = (col.to(planes.dtype) + 0.5 - cx) / fx
    dy = (row.to(planes.dtype) + 0.5 - cy) / fy
    e = planes[..., 0] * dx[:, None] + planes[..., 1] * dy[:, None] + planes[..., 2]
    return e, det / e.sum(-1)


def pair_count(
    vertices: torch.Tensor, faces: torch.Tensor, camera: TorchCamera, near: float = 0.0
) -> int:
    """The (triangle, pixel) pairs :func:`rasterize` tests for this view (read to the host):
    size a ``capacity`` from it with some slack."""
    v = vertices if vertices.dim() == 3 else vertices[None]
    p = _corners(v, faces.long(), camera, torch.float32)
    planes, det = _edge_planes(p)
    kf = _batch_intrinsics(camera, len(v)).repeat_interleave(len(faces), 0)
    _, _, bw, bh = _bounds(p, det, kf, camera.width, camera.height, near)
    return int((bw * bh).sum())
