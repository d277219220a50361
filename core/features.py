"""Screen-space inputs of the neural renderer: the UV map and the motion-feature map.

Both are per-vertex (or per-corner) quantities interpolated at each pixel with the
rasterizer's barycentrics; background pixels are 0.

Motion features (the paper's Sec. 4.2). For proxy vertex ``v`` at frame ``t``, joint ``j`` and
frame offset ``k`` in ``(0, 2, 4, 6, 8)``::

    feature[v, c] = exp(-|v_t - joint_j(t - k)|^2 / sigma),   c = k_index * J + j

i.e. channels are grouped by frame (the 19 joints of frame t, then the 19 of t-2, ...).
**Decision:** ``v`` is the vertex at the *current* frame t for all five joint frames. The
features describe where the recent joint trajectory lies relative to the surface being rendered
now, which is what the renderer needs to place motion-dependent wrinkles on the current image;
it needs only the current proxy (Joint2Coarse's output for frame t) and the joint history, so
rendering a frame never needs earlier proxy frames. Frames before the start of the motion
repeat frame 0 (:func:`joint_window`).

Features are computed per vertex and interpolated. That is an approximation: the Gaussian is
not linear in the position, so inside each triangle the interpolated value differs from the
exact one at the pixel's own surface point. On the quick demo's ~1k-vertex skirt proxy the
difference over garment pixels is 1.1e-3 mean, 1.1e-2 p99 and 2.6e-2 at most (features lie in
[0, 1]; ``python benchmarks/feature_interpolation.py out/demo --motion twirl --size 512``). In
exchange a 2k-vertex proxy needs 10 to 50 times fewer exponentials than the 20k to 110k pixels
it covers at 512 px.
Computation is in float32 (float64 where float32 could overflow: coordinates beyond 1e15 m or
sigma outside [1e-30, 1e30]) and cast at the end, so float16 outputs are safe: every value is in
[0, 1], far joints and tiny sigma give exact zeros, never NaN or inf. float16 maps halve the
memory but are not faster to make (numpy's float32 -> float16 conversion is slow).

Torch versions (:func:`vertex_motion_features_torch`, :func:`interpolate_torch`) run inside
training (on the GPU when there is one); the tests check they match the numpy ones.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from core.errors import InputError
from core.raster import Fragments

#: The paper's frame offsets: t, t-2, t-4, t-6, t-8.
DEFAULT_FRAME_OFFSETS: tuple[int, ...] = (0, 2, 4, 6, 8)
_DTYPES = ("float32", "float16")
#: Pixels interpolated per block in :func:`interpolate` (when it has many channels).
_BLOCK = 2048
#: Up to this many channels :func:`interpolate` works on all pixels at once, without blocks.
_FEW_CHANNELS = 8


@dataclass(frozen=True)
class FeatureConfig:
    """How the motion-feature map is made."""

    sigma: float = 0.1
    """Width of the Gaussian falloff, square metres (the paper: 0.1)."""
    frame_offsets: tuple[int, ...] = DEFAULT_FRAME_OFFSETS
    """Past frames used: joints at ``t - k`` for each k (0 is the current frame)."""
    dtype: str = "float32"
    """Output dtype of the maps: ``float32`` or ``float16`` (half the memory)."""

    def __post_init__(self) -> None:
        _check_sigma(self.sigma)
        if not self.frame_offsets or any(int(k) != k or k < 0 for k in self.frame_offsets):
            raise InputError(
                f"frame_offsets must be non-negative integers, got {self.frame_offsets}"
            )
        if self.dtype not in _DTYPES:
            raise InputError(f"dtype must be one of {_DTYPES}, got {self.dtype!r}")


def _check_sigma(sigma) -> None:
    if isinstance(sigma, bool) or not isinstance(sigma, numbers.Real):
        raise InputError(f"sigma must be a number (m^2), got {sigma!r}")
    if not (math.isfinite(sigma) and sigma > 0):
        raise InputError(f"sigma must be a positive finite number (m^2), got {sigma!r}")


def joint_window(
    joints: np.ndarray, t: int, offsets: Sequence[int] = DEFAULT_FRAME_OFFSETS
) -> np.ndarray:
    """Joints at frames ``t - k`` for each offset: (K, J, 3) float32.

    Parameters
    ----------
    joints : (T, J, 3) float
        Joint positions of the whole motion (world, metres).
    t : int
        Current frame, ``0 <= t < T``. Frames before 0 are clamped to frame 0 (the body is
        taken to have stood still before the motion began).
    """
    joints = np.asarray(joints)
    if joints.ndim != 3 or joints.shape[2] != 3 or len(joints) == 0:
        raise InputError(f"joints must be (T, J, 3) with T > 0, got shape {joints.shape}")
    if not 0 <= t < len(joints):
        raise InputError(f"frame {t} out of range [0, {len(joints)})")
    idx = np.clip(t - np.asarray(offsets, np.int64), 0, None)
    return joints[idx].astype(np.float32)


def _check_motion_inputs(vertices, window, sigma) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices)
    w = np.asarray(window)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"vertices must be (V, 3), got shape {v.shape}")
    if w.ndim != 3 or w.shape[2] != 3:
        raise InputError(f"joint window must be (K, J, 3), got shape {w.shape}")
    _check_sigma(sigma)
    v = v.astype(np.float32)
    w = w.astype(np.float32)
    if not (np.isfinite(v).all() and np.isfinite(w).all()):
        raise InputError("vertices or joints hold NaN or inf")
    return v, w


def vertex_motion_features(
    vertices: np.ndarray, window: np.ndarray, sigma: float = 0.1, dtype: str = "float32"
) -> np.ndarray:
    """Motion features of each vertex: (V, K * J) in ``dtype``, values in [0, 1].

    Parameters
    ----------
    vertices : (V, 3) float
        Proxy vertices at the current frame.
    window : (K, J, 3) float
        Joints at the K frame offsets (:func:`joint_window`).
    sigma : float
        Square metres.
    """
    v, w = _check_motion_inputs(vertices, window, sigma)
    j = w.reshape(-1, 3)
    # Direct differences, not |v|^2 + |j|^2 - 2 v.j: no cancellation, so never below zero.
    # float32 when nothing can overflow into inf / inf (coordinates below 1e15 m, sigma in
    # [1e-30, 1e30]: the squared distance stays finite, and d2 / sigma is finite or +inf, whose
    # exp(-inf) is 0). Otherwise float64, where any float32 input squares without overflow and
    # sigma anywhere from the smallest subnormal to 1e300 divides without NaN.
    coord = max(float(np.abs(v).max(initial=0.0)), float(np.abs(j).max(initial=0.0)))
    work = np.float32 if coord < 1e15 and 1e-30 <= sigma <= 1e30 else np.float64
    vw, jw = v.astype(work, copy=False), j.astype(work, copy=False)
    d2 = np.zeros((len(v), len(j)), work)
    for c in range(3):
        diff = vw[:, c, None] - jw[None, :, c]
        diff *= diff
        d2 += diff
    with np.errstate(over="ignore"):
        d2 /= work(sigma)  # inf for tiny sigma, and exp(-inf) = 0
    np.negative(d2, out=d2)
    np.exp(d2, out=d2)
    return d2.astype(dtype, copy=False)


def vertex_motion_features_reference(
    vertices: np.ndarray, window: np.ndarray, sigma: float = 0.1
) -> np.ndarray:
    """Slow reference of :func:`vertex_motion_features` (float64 loops): (V, K * J) float64."""
    v, w = _check_motion_inputs(vertices, window, sigma)
    k, nj, _ = w.shape
    out = np.zeros((len(v), k * nj))
    for vi in range(len(v)):
        for ki in range(k):
            for ji in range(nj):
                d = v[vi].astype(np.float64) - w[ki, ji].astype(np.float64)
                out[vi, ki * nj + ji] = math.exp(-float(d @ d) / sigma)
    return out


def _face_attributes(faces: np.ndarray, attributes: np.ndarray) -> tuple[np.ndarray, bool]:
    """Check attributes: per vertex (V, C) or per corner (F, 3, C). Returns (attrs, per_corner)."""
    a = np.asarray(attributes)
    if a.ndim == 3:
        if a.shape[:2] != (len(faces), 3):
            raise InputError(f"per-corner attributes must be (F={len(faces)}, 3, C), got {a.shape}")
        return a, True
    if a.ndim != 2:
        raise InputError(f"attributes must be (V, C) or (F, 3, C), got shape {a.shape}")
    if len(faces) and faces.max() >= len(a):
        raise InputError(f"faces index vertex {faces.max()} but attributes has {len(a)} rows")
    return a, False


def interpolate(
    fragments: Fragments, faces: np.ndarray, attributes: np.ndarray, dtype: str | None = None
) -> np.ndarray:
    """Interpolate vertex or corner attributes at each pixel: (H, W, C), background 0.

    Parameters
    ----------
    fragments : Fragments
        From :func:`core.raster.rasterize` of a mesh with these ``faces``.
    faces : (F, 3) int
    attributes : (V, C) per vertex, or (F, 3, C) per corner (UV seams without split vertices)
    dtype : output dtype; default the attributes' float dtype (float32 for integers).
        The sum is taken in float32 whatever the output dtype.
    """
    faces = np.asarray(faces, np.int64)
    a, per_corner = _face_attributes(faces, attributes)
    if dtype is not None:
        out_dtype = np.dtype(dtype)
    else:
        out_dtype = a.dtype if np.issubdtype(a.dtype, np.floating) else np.dtype(np.float32)
    h, w = fragments.face_id.shape
    c = a.shape[-1]
    out = np.zeros((h * w, c), out_dtype)
    fid = fragments.face_id.reshape(-1)
    pix = np.flatnonzero(fid >= 0)
    if len(pix) == 0:
        return out.reshape(h, w, c)
    # np.take: several times faster than fancy row indexing for these gathers.
    f = np.take(fid, pix)
    b = np.take(fragments.barycentrics.reshape(-1, 3), pix, axis=0)
    a32 = a.astype(np.float32, copy=False)
    if per_corner:
        a32 = a32.reshape(-1, c)  # corner (face, k) is row 3 * face + k
        corners = 3 * f[:, None] + np.arange(3)
    else:
        corners = np.take(faces, f, axis=0)
    if c <= _FEW_CHANNELS:
        # Few channels (UVs): three gathers and multiply-adds over all pixels at once.
        acc = np.take(a32, corners[:, 0], axis=0) * b[:, 0:1]
        for k in (1, 2):
            acc += np.take(a32, corners[:, k], axis=0) * b[:, k : k + 1]
        out[pix] = acc
    else:
        # Many channels (motion features): in blocks, so the gathered (block, 3, C) corners stay
        # in cache; about twice as fast as one gather of all pixels for 95 channels at 512 px.
        for s in range(0, len(pix), _BLOCK):
            g = np.take(a32, corners[s : s + _BLOCK], axis=0)  # (B, 3, C)
            out[pix[s : s + _BLOCK]] = np.matmul(b[s : s + _BLOCK, None, :], g)[:, 0]
    return out.reshape(h, w, c)


def interpolate_reference(
    fragments: Fragments, faces: np.ndarray, attributes: np.ndarray
) -> np.ndarray:
    """Slow reference of :func:`interpolate` (a loop over pixels, float64): (H, W, C)."""
    faces = np.asarray(faces, np.int64)
    a, per_corner = _face_attributes(faces, attributes)
    h, w = fragments.face_id.shape
    out = np.zeros((h, w, a.shape[-1]))
    for i in range(h):
        for j in range(w):
            f = fragments.face_id[i, j]
            if f < 0:
                continue
            for k in range(3):
                corner = a[f, k] if per_corner else a[faces[f, k]]
                out[i, j] += float(fragments.barycentrics[i, j, k]) * corner.astype(np.float64)
    return out


def uv_map(fragments: Fragments, faces: np.ndarray, uvs: np.ndarray) -> np.ndarray:
    """UV at each pixel: (H, W, 2) float32, background 0.

    ``uvs`` is per vertex (V, 2) or per corner (F, 3, 2).
    """
    uvs = np.asarray(uvs)
    if uvs.shape[-1] != 2:
        raise InputError(f"uvs must end in 2 coordinates, got shape {uvs.shape}")
    return interpolate(fragments, faces, uvs, np.float32)


def motion_feature_map(
    fragments: Fragments,
    faces: np.ndarray,
    vertices: np.ndarray,
    window: np.ndarray,
    config: FeatureConfig = FeatureConfig(),
) -> np.ndarray:
    """The motion-feature map: (H, W, K * J) in ``config.dtype``, background 0.

    Convenience for one view. For the several cameras of one frame, compute
    :func:`vertex_motion_features` once and call :func:`interpolate` per view.

    Parameters
    ----------
    fragments : Fragments of the proxy at frame t.
    faces : (F, 3) int, the proxy's faces.
    vertices : (V, 3) float, the proxy at frame t.
    window : (K, J, 3) float, joints at ``t - k`` (:func:`joint_window` with
        ``config.frame_offsets``).
    """
    if len(window) != len(config.frame_offsets):
        raise InputError(
            f"joint window has {len(window)} frames, config expects {len(config.frame_offsets)}"
        )
    feats = vertex_motion_features(vertices, window, config.sigma, "float32")
    return interpolate(fragments, faces, feats, config.dtype)


# --------------------------------------------------------------------------------------------
# torch versions (imported lazily)


def vertex_motion_features_torch(vertices, window, sigma: float = 0.1):
    """Torch version of :func:`vertex_motion_features`.

    Parameters
    ----------
    vertices : (..., V, 3) tensor
    window : (..., K, J, 3) tensor (same leading batch shape)

    Returns
    -------
    (..., V, K * J) tensor in the vertices' dtype, computed in float64.
    """
    import torch

    _check_sigma(sigma)
    out_dtype = vertices.dtype
    # float64 as in the numpy version (per vertex: small); float32 where a device lacks it.
    work = torch.float32 if vertices.device.type == "mps" else torch.float64
    v = vertices.to(work)
    j = window.to(work).flatten(-3, -2)  # (..., K*J, 3)
    diff = v.unsqueeze(-2) - j.unsqueeze(-3)
    # sigma is clamped into the work dtype's range: 0 / sigma stays 0, inf / sigma not NaN.
    fi = torch.finfo(work)
    d2 = (diff * diff).sum(-1) / min(max(sigma, fi.tiny), fi.max)
    return torch.exp(-d2).to(out_dtype)


def interpolate_torch(face_id, barycentrics, faces, attributes):
    """Torch version of :func:`interpolate` for per-vertex attributes.

    Parameters
    ----------
    face_id : (..., H, W) int64 tensor, -1 background
    barycentrics : (..., H, W, 3) float tensor
    faces : (F, 3) int64 tensor
    attributes : (V, C) tensor, or (B, V, C) with face_id (B, H, W)

    Returns
    -------
    (..., H, W, C) tensor in the attributes' dtype, background 0.
    """
    import torch

    valid = face_id >= 0
    corners = faces[face_id.clamp(min=0)]  # (..., H, W, 3)
    b = (barycentrics * valid.unsqueeze(-1)).to(
        torch.float32 if attributes.dtype != torch.float64 else torch.float64
    )
    a = attributes.to(b.dtype)
    if a.dim() == 2:
        gathered = a[corners]  # (..., H, W, 3, C)
    else:
        bidx = torch.arange(a.shape[0], device=a.device).view(-1, *([1] * (corners.dim() - 1)))
        gathered = a[bidx, corners]
    out = (gathered * b.unsqueeze(-1)).sum(-2)
    return out.to(attributes.dtype)
