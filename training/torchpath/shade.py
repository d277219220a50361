"""The body-only background in torch: :func:`core.shading.render_background` on the device.

The same image as the ray-traced one (supersampled k x k, box-filtered, hemispherical ambient,
wrapped diffuse camera lights, sheen), rasterized with :func:`training.torchpath.raster.rasterize`
instead of Embree: pixels differ only where a supersample sits on a triangle edge within
rounding (then one sample of k * k sees the neighbour triangle).
"""

from __future__ import annotations

import numpy as np
import torch

from core.errors import InputError
from core.lighting import environment_matrix, sh_basis
from core.shading import Material, ShadingConfig, srgb_to_linear
from training.torchpath.raster import TorchCamera, rasterize


def vertex_normals(
    vertices: torch.Tensor, faces: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Area-weighted unit vertex normals (B, V, 3) and unit face normals (B, F, 3) of
    vertices (B, V, 3) (:func:`core.shading.vertex_normals`)."""
    v = vertices
    c = v[:, faces]  # (B, F, 3, 3)
    fn = torch.linalg.cross(c[:, :, 1] - c[:, :, 0], c[:, :, 2] - c[:, :, 0])
    n = torch.zeros_like(v)
    for k in range(3):
        n.index_add_(1, faces[:, k], fn)
    n = n / n.norm(dim=-1, keepdim=True).clamp(min=1e-30)
    return n, fn / fn.norm(dim=-1, keepdim=True).clamp(min=1e-30)


def _constant(x, like: torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x, np.float32)).to(like.device)


def linear_to_srgb(c: torch.Tensor) -> torch.Tensor:
    """:func:`core.shading.linear_to_srgb` in torch."""
    c = c.clamp(0.0, 1.0)
    return torch.where(c <= 0.0031308, 12.92 * c, 1.055 * c.pow(1 / 2.4) - 0.055)


def shade(
    face_id: torch.Tensor,
    barycentrics: torch.Tensor,
    vertices: torch.Tensor,
    faces: torch.Tensor,
    camera: TorchCamera,
    material: Material,
    config: ShadingConfig,
) -> torch.Tensor:
    """Linear RGB (B, H, W, 3) float32 of a rasterized mesh, the background colour elsewhere
    (:func:`core.shading._shade_samples` for one solid material).

    Parameters
    ----------
    face_id : (B, H, W) int64, barycentrics (B, H, W, 3): fragments of ``vertices`` in ``camera``
    vertices : (B, V, 3) float32 world positions; faces : (F, 3) int64
    camera : TorchCamera, one or a batch of B
    """
    if material.pattern != "solid":
        raise InputError(f"the torch path shades solid materials only, got {material.pattern!r}")
    nb, h, w = face_id.shape
    dev = vertices.device
    vn, fnorm = vertex_normals(vertices.float(), faces)
    R = camera.R.float().expand(nb, 3, 3)
    k = camera.intrinsics.float().expand(nb, 4)
    hit = face_id >= 0
    fid = face_id.clamp(min=0).view(nb, -1)  # (B, P)
    corners = faces[fid]  # (B, P, 3)
    bidx = torch.arange(nb, device=dev)[:, None, None]
    b = barycentrics.float().view(nb, -1, 3)
    normal = (vn[bidx, corners] * b[..., None]).sum(-2) @ R.transpose(-1, -2)  # camera space
    face_normal = fnorm[torch.arange(nb, device=dev)[:, None], fid] @ R.transpose(-1, -2)
    # Unit vector from the hit back to the camera, in camera space.
    jj = torch.arange(w, device=dev, dtype=torch.float32).expand(h, w).reshape(-1)
    ii = torch.arange(h, device=dev, dtype=torch.float32)[:, None].expand(h, w).reshape(-1)
    fx, fy, cx, cy = (c[:, None] for c in k.unbind(-1))
    view = torch.stack(
        [-(jj + 0.5 - cx) / fx, -(ii + 0.5 - cy) / fy, torch.full_like(jj - cx, -1.0)], -1
    )
    view = view / view.norm(dim=-1, keepdim=True)
    flip = 1.0 - 2.0 * ((face_normal * view).sum(-1, keepdim=True) < 0).float()
    normal = normal * flip
    face_normal = face_normal * flip
    length = normal.norm(dim=-1, keepdim=True)
    normal = normal / length.clamp(min=1e-12)
    normal = torch.where(length <= 1e-6, face_normal, normal)
    albedo = _constant(srgb_to_linear(np.asarray(material.color)), normal)
    lit = config.lighting
    sky, ground = _constant(lit.sky, normal), _constant(lit.ground, normal)
    up = 0.5 * (1.0 - normal[..., 1:2])
    light = ground + up * (sky - ground)
    for li in lit.lights:
        d = np.asarray(li.direction, np.float32) / np.float32(np.linalg.norm(li.direction))
        col = np.asarray(li.color, np.float32) * np.float32(li.intensity)
        wrapped = (normal @ _constant(d, normal) + np.float32(config.wrap)) / np.float32(
            1 + config.wrap
        )
        light = light + wrapped.clamp(min=0)[..., None] * _constant(col, normal)
    if lit.environment:
        env = _constant(environment_matrix(lit.environment), normal)
        light = light + (sh_basis(normal, torch) @ env).clamp(min=0)
    color = albedo * light
    if material.sheen > 0:
        rim = 1.0 - (normal * view).sum(-1).clamp(0.0, 1.0)
        rim = rim * rim * rim
        color = color + np.float32(material.sheen) * rim[..., None] * (0.5 * albedo + 0.2 * light)
    backdrop = _constant(srgb_to_linear(np.asarray(config.background)), color)
    color = torch.where(hit.view(nb, -1, 1), color, backdrop)
    return color.view(nb, h, w, 3)


def render_background(
    vertices: torch.Tensor,
    faces: torch.Tensor,
    camera: TorchCamera,
    config: ShadingConfig | None = None,
    *,
    capacity: int | None = None,
    overflow: list | None = None,
) -> torch.Tensor:
    """The body alone: ([B,] H, W, 3) uint8 sRGB on the vertices' device.

    Parameters
    ----------
    vertices : (V, 3) or (B, V, 3) float32, the posed body
    faces : (F, 3) int64
    camera : TorchCamera at the output size (one or a batch of B)
    config : ShadingConfig (default: the data set's)
    capacity : rasterizer pair capacity at the supersampled size (None: exact, one sync)
    overflow : a list the rasterizer's overflow flag (a 0-d bool tensor) is appended to
        when a capacity is given
    """
    config = config or ShadingConfig()
    batched = vertices.dim() == 3
    v = vertices if batched else vertices[None]
    if len(faces) == 0:  # no body: the plain background colour
        colour = torch.as_tensor(np.asarray(config.background, np.float32), device=v.device)
        out = (
            torch.round(colour * 255).to(torch.uint8).expand(len(v), camera.height, camera.width, 3)
        )
        return out.clone() if batched else out[0].clone()
    k = config.supersample
    cam = camera.scaled(k)
    frags = rasterize(v, faces, cam, capacity=capacity)
    if overflow is not None and frags.overflow is not None:
        overflow.append(frags.overflow)
    lin = shade(frags.face_id, frags.barycentrics, v, faces, cam, config.body, config)
    nb, hh, ww, _ = lin.shape
    if k > 1:  # box filter: mean over k x k blocks
        lin = lin.view(nb, hh // k, k, ww // k, k, 3).mean((2, 4))
    out = torch.round(linear_to_srgb(lin) * 255.0).clamp(0, 255).to(torch.uint8)
    return out if batched else out[0]
