"""Which garment vertices hold on to the body, and to which bone.

A skirt hangs from its waistband, a dress from its neckline and shoulder straps: the vertices
within ``pin_distance`` of the garment's top boundary loop(s) are pinned. Each connected
pinned band follows one torso bone rigidly (the bone nearest to most of its vertices in the
rest pose), so the band moves exactly with the body every substep: kinematic particles (zero
inverse mass), which is stable at any step size, unlike stiff springs.

Pieces that no pin holds (a frill sewn at a tier's hem, a dress's sash and bow: separate
components whose top loop is not at the waist) are sewn to the part beside them
(:func:`find_seams`): their top loop's closest vertices follow points of that part's cloth,
kinematic too, every step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from core.body.colliders import closest_on_segments
from core.errors import InputError
from core.mesh import boundary_loops, vertex_normals
from core.proxy.metrics import barycentric, point_to_mesh
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


def _segment_distance(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, 3) points to (K,) segments a->b (K, 3): (N, K) distances."""
    return closest_on_segments(x[:, None], a[None], b[None])[0]


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
    pinned = np.zeros(num_vertices, bool)
    pinned[idx] = True
    e = np.asarray(faces, np.int64)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    e = e[pinned[e[:, 0]] & pinned[e[:, 1]]]
    local = np.full(num_vertices, -1)
    local[idx] = np.arange(len(idx))
    n = len(idx)
    adj = coo_matrix((np.ones(len(e)), (local[e[:, 0]], local[e[:, 1]])), shape=(n, n))
    return connected_components(adj, directed=False)[1]


#: A loose piece is sewn to another part only where that part is within this many
#: ``pin_distance`` of its top loop (a frill overlaps its tier's hem by a centimetre or two).
SEW_REACH = 2.0
#: A loose piece's top-loop vertices within this distance (metres) of its closest one to the
#: host are its stitches.
SEAM_BAND = 0.008


@dataclass(frozen=True)
class Seams:
    """Vertices of loose pieces (parts that no pin holds: a frill sewn at a tier's hem, a sash, a
    bow) sewn to the cloth of another part: each follows a point of a host triangle, kept at its
    rest offset along the triangle's normal (exact at rest and under rigid motion).

    Attributes
    ----------
    indices : (A,) int64, the sewn vertices, ascending
    hosts : (A, 3) int64, vertices of each one's host triangle (another part)
    barycentric : (A, 3) float32, of the closest point on the host triangle
    normal_offset : (A,) float32, distance from that point along the host's interpolated
        vertex normal there (metres): smooth across the host's triangles, so neighbouring
        sewn vertices keep their spacing when the host bends
    residual : (A, 3) float32, the rest of the offset in the triangle's frame (edge 0->1,
        normal x edge, normal), metres
    pieces : int, how many loose pieces were sewn
    loose : int, loose pieces with no part within reach (left free)
    """

    indices: np.ndarray
    hosts: np.ndarray
    barycentric: np.ndarray
    normal_offset: np.ndarray
    residual: np.ndarray
    pieces: int = 0
    loose: int = 0

    def targets(self, positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """Positions of the sewn vertices for garment positions (V, 3) and the garment's
        faces: (A, 3) float32."""
        x = np.asarray(positions, np.float64)
        tri = x[self.hosts]
        w = self.barycentric.astype(np.float64)
        n = np.einsum("ai,aij->aj", w, vertex_normals(x, faces)[self.hosts])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        p = np.einsum("ai,aij->aj", w, tri) + self.normal_offset[:, None] * n
        rest = np.einsum("ak,akj->aj", self.residual.astype(np.float64), triangle_frames(tri))
        return (p + rest).astype(np.float32)


def triangle_frames(tri: np.ndarray) -> np.ndarray:
    """Orthonormal frames of triangles (N, 3, 3): rows e1 (edge 0->1), n x e1, n: (N, 3, 3)."""
    e1 = tri[:, 1] - tri[:, 0]
    n = np.cross(e1, tri[:, 2] - tri[:, 0])
    e1 = e1 / np.maximum(np.linalg.norm(e1, axis=-1, keepdims=True), 1e-12)
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    return np.stack([e1, np.cross(n, e1), n], axis=1)


def _components(num_vertices: int, faces: np.ndarray) -> np.ndarray:
    """Connected-component label of every vertex (isolated vertices get their own)."""
    e = np.asarray(faces, np.int64)[:, [0, 1, 1, 2]].reshape(-1, 2)
    adj = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(num_vertices,) * 2)
    return connected_components(adj, directed=False)[1]


def find_seams(
    vertices: np.ndarray, faces: np.ndarray, pinned: np.ndarray, pin_distance: float
) -> Seams:
    """Sew every loose piece (a connected part with no pinned vertex) to the part beside it.

    A piece whose top boundary loop is not among the garment's top loops (a frill at a tier's
    hem, a sash at the waist of a dress) is not pinned by :func:`find_pins`; left free it falls
    off the body. Its top boundary loop (or, for a closed piece, its vertices within
    ``pin_distance`` of its top) is sewn, where it lies closest, to the nearest triangles of an
    anchored part within ``SEW_REACH * pin_distance``. Anchored: pinned, or sewn in an earlier
    round (a bow to the sash that is sewn to the dress); host triangles touch no sewn vertex,
    so every seam hangs on free or pinned cloth, never on another seam (no cycles, no seam
    placed from a stale one). A piece with nothing within reach stays loose.

    Parameters
    ----------
    vertices : (V, 3) float, rest positions
    faces : (F, 3) int
    pinned : (P,) int, indices of pinned vertices (:attr:`Pins.indices`)
    pin_distance : metres (see :class:`core.sim.config.SimConfig`)
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    label = _components(len(v), f)
    face_label = label[f[:, 0]]
    anchored = np.zeros(label.max() + 1, bool)
    anchored[label[np.asarray(pinned, np.int64)]] = True
    loops = boundary_loops(f)
    normals = vertex_normals(v, f)
    sewn = np.zeros(len(v), bool)
    tops = {}
    for c in np.unique(face_label):
        if anchored[c]:
            continue
        own = [lp for lp in loops if label[lp[0]] == c]
        if own:
            tops[c] = own[int(np.argmax([v[lp, 1].mean() for lp in own]))]
        else:
            members = np.flatnonzero(label == c)
            tops[c] = members[v[members, 1] >= v[members, 1].max() - pin_distance]
    idx, hosts, bary, offset, residual = [], [], [], [], []
    while tops:
        usable = anchored[face_label] & ~sewn[f].any(axis=1)
        if not usable.any():
            break
        others = f[usable]
        found = {}
        for c, top in tops.items():
            dist, face, closest = point_to_mesh(v[top], v, others)
            if dist.min() <= SEW_REACH * pin_distance:
                found[c] = (top, dist, face, closest)
        if not found:
            break
        for c, (top, dist, face, closest) in found.items():
            del tops[c]
            anchored[c] = True
            # The stitches: where the loop lies closest to the host (a gathered frill's inner
            # folds); its far points (outer folds, centimetres off) would swing about the
            # host's normals on a coarse mesh and tear the seam.
            near = dist <= dist.min() + SEAM_BAND
            top, tri = top[near], others[face[near]]
            w = barycentric(closest[near], v[tri])
            n = np.einsum("ai,aij->aj", w, normals[tri])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            delta = v[top] - closest[near]
            d = (delta * n).sum(1)
            idx.append(top)
            hosts.append(tri)
            bary.append(w)
            offset.append(d)
            residual.append(
                np.einsum("akj,aj->ak", triangle_frames(v[tri]), delta - d[:, None] * n)
            )
        for top in idx[-len(found) :]:
            sewn[top] = True
    loose = len(tops)
    if not idx:
        z3 = np.zeros((0, 3), np.float32)
        return Seams(np.zeros(0, np.int64), np.zeros((0, 3), np.int64), z3, z3[:, 0], z3, 0, loose)
    pieces = len(idx)
    idx = np.concatenate(idx)
    order = np.argsort(idx)
    return Seams(
        idx[order],
        np.concatenate(hosts)[order],
        np.concatenate(bary)[order].astype(np.float32),
        np.concatenate(offset)[order].astype(np.float32),
        np.concatenate(residual)[order].astype(np.float32),
        pieces,
        loose,
    )
