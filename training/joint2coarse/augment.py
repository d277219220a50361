"""Joint2Coarse training data for free: each simulated clip's left-right mirror.

Physics does not change under a mirror. With a left-right symmetric body (the mannequin's
skeleton is: its left joints are its right ones at -x) and a garment whose rest shape maps onto
itself under ``x -> -x``, the mirror of a simulated clip is the simulation of the mirrored
motion: the joints reflected through the body's plane of symmetry with their left and right
names swapped, the root's rotation ``M R M`` (``M = diag(-1, 1, 1)``, so the heading turns the
other way), and the proxy reflected. A proxy's vertices are not themselves symmetric (it is a
remesh), so the mirrored clip's vertex ``v`` takes the reflected surface point that, in the rest
pose, lies where ``v``'s mirror image does (:func:`mirror_map`: a closest point on the rest
proxy and its barycentric coordinates). That linear interpolation smooths the target a little
(mirroring a simulated clip twice, ``MirrorMap.reflect`` of ``MirrorMap.reflect``, does not give
it back exactly).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from core.errors import InputError
from core.proxy.metrics import correspond
from training.joint2coarse.descriptor import JOINT2COARSE_JOINTS

#: Reflection through the body's plane of symmetry (world x = 0; y up, z forward).
MIRROR = np.diag([-1.0, 1.0, 1.0])
#: A garment further from symmetric than this (the largest distance from a rest vertex's mirror
#: image to the rest proxy, over the proxy's bounding-box diagonal) is refused: its mirror would
#: be another garment. The quick project's multilayer skirt is at 1.8%.
MAX_ASYMMETRY = 0.05
#: Each joint's mirror partner in ``JOINT2COARSE_JOINTS`` order (left and right swapped).
_SWAP = {"Left": "Right", "Right": "Left"}
MIRROR_JOINTS = tuple(
    JOINT2COARSE_JOINTS.index(
        next((n.replace(a, b, 1) for a, b in _SWAP.items() if n.startswith(a)), n)
    )
    for n in JOINT2COARSE_JOINTS
)

#: The same over the descriptor's 19 joints (the root is its origin).
_MIRROR_DESCRIPTOR_JOINTS = tuple(j - 1 for j in MIRROR_JOINTS[1:])


@dataclass(frozen=True)
class MirrorMap:
    """Where each proxy vertex's mirror image lies on the rest proxy.

    Attributes
    ----------
    corners : (V, 3) int64
        The proxy vertices of the face holding vertex v's mirror image.
    barycentric : (V, 3) float64
        Its barycentric coordinates in that face (rows sum to 1).
    asymmetry : float
        The largest distance (m) from a rest vertex's mirror image to the rest proxy.
    size : float
        The rest proxy's bounding-box diagonal (m).
    """

    corners: np.ndarray
    barycentric: np.ndarray
    asymmetry: float
    size: float

    @property
    def symmetric(self) -> bool:
        """Whether the garment is close enough to symmetric to train on its mirror
        (:data:`MAX_ASYMMETRY`)."""
        return self.asymmetry <= MAX_ASYMMETRY * self.size

    def check(self, source: str = "") -> None:
        """Raise :class:`InputError` unless :attr:`symmetric`: training on the mirror of a
        garment that is not would teach another garment."""
        if not self.symmetric:
            raise InputError(
                f"the garment is not left-right symmetric (a vertex's mirror image lies "
                f"{1000 * self.asymmetry:.0f} mm from it, over {100 * MAX_ASYMMETRY:.0f}% of "
                f"its {1000 * self.size:.0f} mm size): train Joint2Coarse with --set mirror=false",
                source or None,
            )

    def reflect(self, positions: np.ndarray) -> np.ndarray:
        """Proxy positions (..., V, 3) -> their mirror (..., V, 3) float64, vertex for vertex."""
        x = np.asarray(positions, np.float64)
        return reflect_positions(x, self.corners, self.barycentric)


def _negate_x(x):
    """(..., 3) -> the same with x negated (numpy or torch)."""
    lib = torch if isinstance(x, torch.Tensor) else np
    return lib.concatenate([-x[..., :1], x[..., 1:]], -1)


def reflect_positions(positions, corners, barycentric):
    """:meth:`MirrorMap.reflect` for numpy arrays or torch tensors (of one kind, on one device):
    positions (..., V, 3), corners (V, 3) int, barycentric (V, 3) of positions' dtype ->
    (..., V, 3)."""
    lib = torch if isinstance(positions, torch.Tensor) else np
    return _negate_x(lib.einsum("vk,...vkj->...vj", barycentric, positions[..., corners, :]))


def mirror_descriptors(desc, num_samples: int):
    """Motion descriptors (B, K * 57) of a motion -> those of its mirror (numpy or torch).

    A descriptor holds root-relative joints in the heading frame; the mirrored motion's heading
    is the mirror of the original's, so its descriptor is the original's with x negated and left
    and right swapped (:func:`mirror_motion`, in the heading frame)."""
    x = desc.reshape(len(desc), num_samples, 19, 3)[:, :, list(_MIRROR_DESCRIPTOR_JOINTS)]
    return _negate_x(x).reshape(len(desc), -1)


def mirror_map(rest_vertices: np.ndarray, faces: np.ndarray, source: str = "") -> MirrorMap:
    """The proxy's map onto itself under ``x -> -x`` (:class:`MirrorMap`).

    Parameters
    ----------
    rest_vertices : (V, 3) float, the rest proxy in the body's frame (``proxy/positions.obj``)
    faces : (F, 3) int
    source : str, named in the error

    Any garment gets its map; :attr:`MirrorMap.symmetric` says whether it may be used.
    """
    v = np.asarray(rest_vertices, np.float64)
    f = np.asarray(faces, np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0 or f.ndim != 2 or f.shape[1:] != (3,):
        raise InputError(
            f"mirror map needs (V, 3) vertices and (F, 3) faces, got {v.shape}, {f.shape}",
            source or None,
        )
    c = correspond(v @ MIRROR, v, f)
    size = float(np.linalg.norm(v.max(0) - v.min(0)))
    return MirrorMap(f[c.face], c.barycentric.astype(np.float64), float(c.distance.max()), size)


def mirror_motion(joints: np.ndarray, root_rotations: np.ndarray) -> tuple[np.ndarray, ...]:
    """The mirrored motion: joints (T, 20, 3) reflected with left and right swapped, root
    rotations (T, 3, 3) as ``M R M``; both float32."""
    j = np.asarray(joints, np.float64)[:, list(MIRROR_JOINTS)] @ MIRROR
    r = MIRROR @ np.asarray(root_rotations, np.float64) @ MIRROR
    return j.astype(np.float32), r.astype(np.float32)
