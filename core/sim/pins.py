"""Which garment vertices hold on to the body, and to which bone.

A skirt hangs from its waistband, a dress from its neckline and shoulder straps: the vertices
within ``pin_distance`` of the garment's top boundary loop(s) are pinned. Each connected
pinned band follows one torso bone rigidly (the bone nearest to most of its vertices in the
rest pose), so the band moves exactly with the body every substep: kinematic particles (zero
inverse mass), which is stable at any step size, unlike stiff springs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import InputError
from core.skeleton import Skeleton

#: Bones a pinned vertex may follow: segments whose parent joint is one of these (the frame
#: of the parent moves the segment).
TORSO_JOINTS = ("Hips", "Spine", "Spine1", "Spine2", "Neck", "LeftShoulder", "RightShoulder")
#: Boundary loops whose mean height is within this fraction of the body height below the
#: highest loop are pinned too (a dress's armholes and neckline together).
LOOP_BAND = 0.06


@dataclass(frozen=True)
class Pins:
    """Pinned vertices.

    Attributes
    ----------
    indices : (P,) int64
        Vertex indices, ascending.
    joints : (P,) int64
        Skeleton joint whose frame carries each pinned vertex.
    rest : (P, 3) float32
        Rest positions of the pinned vertices.
    """

    indices: np.ndarray
    joints: np.ndarray
    rest: np.ndarray

    def targets(self, transforms: np.ndarray) -> np.ndarray:
        """Posed positions for skinning transforms (..., J, 4, 4) -> (..., P, 3) float32."""
        m = np.asarray(transforms, np.float64)[..., self.joints, :, :]
        x = self.rest.astype(np.float64)
        out = np.einsum("...pab,pb->...pa", m[..., :3, :3], x) + m[..., :3, 3]
        return out.astype(np.float32)


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Boundary loops of a triangle mesh: a list of (L,) int64 vertex index arrays.

    Boundary edges are those used by one face; each loop is followed vertex to vertex (a
    vertex with several boundary edges, a non-manifold pinch, ends a walk).
    """
    e = np.asarray(faces, np.int64)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    key = np.sort(e, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    b = e[counts[inv.reshape(-1)] == 1]
    nxt: dict[int, int] = {}
    for a, c in b:
        nxt.setdefault(int(a), int(c))
    loops, seen = [], set()
    for start in sorted(nxt):
        if start in seen:
            continue
        loop, v = [], start
        while v in nxt and v not in seen:
            seen.add(v)
            loop.append(v)
            v = nxt[v]
        if len(loop) >= 3:
            loops.append(np.array(loop, np.int64))
    return loops


def _segment_distance(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, 3) points to (K,) segments a->b (K, 3): (N, K) distances."""
    d = b - a
    dd = np.maximum((d * d).sum(-1), 1e-20)
    s = np.clip(((x[:, None] - a[None]) * d[None]).sum(-1) / dd[None], 0.0, 1.0)
    return np.linalg.norm(x[:, None] - (a[None] + s[..., None] * d[None]), axis=-1)


def find_pins(
    vertices: np.ndarray,
    faces: np.ndarray,
    skeleton: Skeleton,
    pin_distance: float,
    height: float,
    path=None,
) -> Pins:
    """Pin the vertices near the garment's top boundary loop(s) to the nearest torso bones.

    Parameters
    ----------
    vertices : (V, 3) float, rest positions (on the rest mannequin)
    faces : (F, 3) int
    skeleton : the mannequin's rest skeleton
    pin_distance : metres from a top loop within which vertices are pinned
    height : body height in metres (scales :data:`LOOP_BAND`)
    path : garment file, for messages

    Raises
    ------
    InputError
        The garment has no boundary loop (nothing to hang it from).
    """
    v = np.asarray(vertices, np.float64)
    loops = boundary_loops(faces)
    if not loops:
        raise InputError("garment has no open boundary (waistband or neckline) to pin", path)
    mean_y = np.array([v[lp, 1].mean() for lp in loops])
    top = [lp for lp, y in zip(loops, mean_y) if y >= mean_y.max() - LOOP_BAND * height]
    loop_v = np.unique(np.concatenate(top))
    # Distance of every vertex to the top loops' vertices (chunked to bound memory).
    near = np.zeros(len(v), bool)
    lv = v[loop_v]
    for i in range(0, len(v), 4096):
        chunk = v[i : i + 4096]
        d2 = ((chunk[:, None] - lv[None]) ** 2).sum(-1).min(axis=1)
        near[i : i + 4096] = d2 <= pin_distance**2
    near[loop_v] = True
    idx = np.flatnonzero(near)
    rest = skeleton.rest_positions().astype(np.float64)
    seg_parent, seg_child = [], []
    for j, p in enumerate(skeleton.parents):
        if p >= 0 and skeleton.names[p] in TORSO_JOINTS:
            seg_parent.append(p)
            seg_child.append(j)
    dist = _segment_distance(v[idx], rest[seg_parent], rest[seg_child])
    joints = np.array(seg_parent, np.int64)[dist.argmin(axis=1)]
    # One bone per connected pinned band (its majority): a band split between two rigid
    # bones would be torn along the split as the spine bends.
    label = _pinned_components(len(v), faces, idx)
    for c in np.unique(label):
        members = label == c
        joints[members] = np.bincount(joints[members]).argmax()
    return Pins(idx.astype(np.int64), joints, v[idx].astype(np.float32))


def _pinned_components(num_vertices: int, faces: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Connected-component label of each pinned vertex (edges between pinned vertices only)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pinned = np.zeros(num_vertices, bool)
    pinned[idx] = True
    e = np.asarray(faces, np.int64)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    e = e[pinned[e[:, 0]] & pinned[e[:, 1]]]
    local = np.full(num_vertices, -1)
    local[idx] = np.arange(len(idx))
    n = len(idx)
    adj = coo_matrix((np.ones(len(e)), (local[e[:, 0]], local[e[:, 1]])), shape=(n, n))
    return connected_components(adj, directed=False)[1]
