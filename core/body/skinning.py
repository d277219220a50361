"""Skinning weights (bone heat) and linear blend skinning of the mannequin.

Weights follow Baran and Popovic's bone heat ("Automatic rigging and animation of 3D
characters", SIGGRAPH 2007, the method behind Blender's automatic weights): each joint's
weight is the steady state of heat diffusion over the surface, where every vertex is heated
by the nearest bone it can see (the sight line to the bone stays inside the body), with a
strength falling off as 1/d^2: ``(M H - L) w_j = M H p_j``, with the intrinsic-Delaunay
cotangent Laplacian ``L`` (non-negative edge weights, so no over- or undershoot on uneven
triangles) and the Voronoi mass matrix ``M``.

Three additions keep limbs apart and the skin smooth:

* a limb's joints are solved with zero weight on the other limbs' vertices (the trunk is
  shared), after islands of a limb's vertices inside another (where limbs nearly touch) are
  given to the surrounding limb; so the left thigh never follows the right leg;
* a short implicit diffusion (``SMOOTHING_FRACTION`` of the height) softens the steep
  transitions near thin bones;
* the at-most-4-influences cut is continuous (:func:`limit_influences`), so neighbours whose
  4th and 5th joints swap order do not tear apart when posed.
"""

from __future__ import annotations

import numpy as np

from core.errors import InputError
from core.motion.motion import Motion
from core.skeleton import Skeleton, forward_kinematics, skinning_transforms

#: Most joints that influence a vertex.
MAX_INFLUENCES = 4
#: Weights below this are dropped (then the row is renormalised).
MIN_WEIGHT = 1e-3


#: Segments to an end site (head top, finger tips, toes) stop this far along: the end sites
#: lie on the skin, and the bone must stay inside it.
END_SITE_FRACTION = 0.75


def bone_segments(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """The segments that carry each joint's weight: joint to each child (or towards its end
    site, ``END_SITE_FRACTION`` of the way).

    Returns
    -------
    owner : (S,) int64
        The joint whose transform moves the segment.
    segments : (S, 2, 3) float64
        Rest-pose endpoints.
    """
    pos = skeleton.rest_positions().astype(np.float64)
    owner, segs = [], []
    for j in range(skeleton.num_joints):
        kids = skeleton.children(j)
        ends = [pos[c] for c in kids]
        if not kids and np.linalg.norm(skeleton.end_sites[j]) > 0:
            ends = [pos[j] + END_SITE_FRACTION * skeleton.end_sites[j]]
        for e in ends:
            if np.linalg.norm(e - pos[j]) > 1e-6:
                owner.append(j)
                segs.append((pos[j], e))
    return np.asarray(owner, np.int64), np.asarray(segs, np.float64)


#: Joints of each limb. A limb's joints get no weight on another limb's vertices (the heat
#: is solved with zero there), so the left thigh never follows the right leg.
#: The clavicles (``*Shoulder``) belong to the trunk: the chest around them is trunk skin.
LIMB_GROUPS: tuple[tuple[str, ...], ...] = (
    ("LeftArm", "LeftForeArm", "LeftHand"),
    ("RightArm", "RightForeArm", "RightHand"),
    ("LeftUpLeg", "LeftLeg", "LeftFoot"),
    ("RightUpLeg", "RightLeg", "RightFoot"),
)
#: Length of the final weight diffusion, as a fraction of the skeleton's height.
SMOOTHING_FRACTION = 0.03
#: Nearest bones tested for visibility per vertex.
_CANDIDATES = 3


def skinning_weights(
    vertices: np.ndarray,
    faces: np.ndarray,
    skeleton: Skeleton,
    smoothing: float | None = None,
) -> np.ndarray:
    """Bone-heat skinning weights of a closed mesh around ``skeleton`` in its rest pose.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
        Closed, outward-oriented.
    skeleton : Skeleton with J joints, posed at rest inside the mesh
    smoothing : float, optional
        Length (metres) of a final diffusion of the weights; default
        ``SMOOTHING_FRACTION`` of the skeleton's height.

    Returns
    -------
    (V, J) float32
        Non-negative, rows sum to 1, at most ``MAX_INFLUENCES`` non-zeros per row.
    """
    import igl
    from scipy.sparse import diags
    from scipy.sparse.linalg import splu

    v = np.ascontiguousarray(vertices, np.float64)
    f = np.ascontiguousarray(faces, np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise InputError(f"need a triangle mesh, got vertices {v.shape} and faces {f.shape}")
    owner, segs = bone_segments(skeleton)
    nv, nj = len(v), skeleton.num_joints
    if smoothing is None:
        rest = skeleton.rest_positions()
        smoothing = SMOOTHING_FRACTION * float(np.ptp(rest[:, 1]) + 1e-9)
    nearest_seg, dist = _nearest_visible_bone(v, f, segs)
    # Which limb each joint, segment and vertex belongs to (-1: the trunk and head).
    limb_of_joint = np.full(nj, -1)
    for g, names in enumerate(LIMB_GROUPS):
        for name in names:
            if name in skeleton.names:
                limb_of_joint[skeleton.index(name)] = g
    nearest_seg = _coherent_limbs(f, nearest_seg, limb_of_joint[owner], dist)
    d_min = dist[np.arange(nv), nearest_seg]
    near_joint = owner[nearest_seg]
    limb_of_vertex = limb_of_joint[near_joint]
    p = np.zeros((nv, nj))
    p[np.arange(nv), near_joint] = 1.0
    heat = 1.0 / np.maximum(d_min, 1e-3) ** 2
    lap = igl.intrinsic_delaunay_cotmatrix(v, f)[0]  # NSD, non-negative off-diagonal
    mass = igl.massmatrix(v, f, igl.MASSMATRIX_TYPE_VORONOI)
    mh = (mass @ diags(heat)).tocsr()
    system = (mh - lap).tocsr()
    rhs = np.asarray(mh @ p)
    w = np.zeros((nv, nj))
    for g in range(-1, len(LIMB_GROUPS)):
        joints = np.nonzero(limb_of_joint == g)[0]
        if len(joints) == 0:
            continue
        # Trunk joints diffuse everywhere; a limb's joints only off the other limbs.
        free = np.ones(nv, bool) if g < 0 else (limb_of_vertex < 0) | (limb_of_vertex == g)
        idx = np.nonzero(free)[0]
        sub = system[idx][:, idx].tocsc()
        x = splu(sub).solve(np.ascontiguousarray(rhs[np.ix_(idx, joints)]))
        if smoothing > 0:
            # Implicit diffusion over a length ``smoothing`` (same domain): softens the steep
            # transitions bone heat gives where the skin is close to the bones (hip crease).
            m_sub = mass[idx][:, idx]
            x = splu((m_sub - smoothing**2 * lap[idx][:, idx]).tocsc()).solve(np.asarray(m_sub @ x))
        w[np.ix_(idx, joints)] = x
    return limit_influences(w, MAX_INFLUENCES, MIN_WEIGHT)


def _coherent_limbs(
    faces: np.ndarray, seg: np.ndarray, limb_of_seg: np.ndarray, dist: np.ndarray
) -> np.ndarray:
    """Make each limb's vertices one connected patch.

    Where two limbs nearly touch (feet, an arm at the side), a few vertices of one can see a
    bone of the other first. Such islands (components of a limb's vertices other than its
    largest) take the limb most common among their neighbours, and the nearest bone of that
    limb (or of the trunk).

    Parameters
    ----------
    faces : (F, 3) int
    seg : (V,) int, nearest visible segment per vertex
    limb_of_seg : (S,) int, limb of each segment (-1 trunk)
    dist : (V, S) float, vertex-to-segment distances

    Returns
    -------
    (V,) int64
        The corrected nearest segment per vertex.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    nv = len(seg)
    e = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    label = limb_of_seg[seg].copy()
    island = np.zeros(nv, bool)
    for g in np.unique(label[label >= 0]):
        mine = label == g
        same = mine[e[:, 0]] & mine[e[:, 1]]
        adj = coo_matrix((np.ones(same.sum()), (e[same, 0], e[same, 1])), shape=(nv, nv))
        _, comp = connected_components(adj, directed=False)
        counts = np.bincount(comp[mine])
        island |= mine & (comp != np.argmax(counts))
    if not island.any():
        return seg
    seg = seg.copy()
    for _ in range(50):  # grow the surrounding labels into the islands
        if not island.any():
            break
        src, dst = e[:, 0], e[:, 1]
        ok = island[dst] & ~island[src]
        if not ok.any():
            break
        votes = {}
        for d, lab in zip(dst[ok].tolist(), label[src[ok]].tolist()):
            votes.setdefault(d, []).append(lab)
        for d, labs in votes.items():
            vals, cnt = np.unique(labs, return_counts=True)
            label[d] = vals[np.argmax(cnt)]
            island[d] = False
            allowed = limb_of_seg == label[d]
            seg[d] = int(np.argmin(np.where(allowed, dist[d], np.inf)))
    return seg


def _nearest_visible_bone(v: np.ndarray, f: np.ndarray, segs: np.ndarray):
    """Per vertex, the nearest bone segment whose closest point it can see from inside.

    A bone is visible when the sight line from the vertex to the bone's closest point does not
    cross the surface (Baran and Popovic); a vertex that sees none of its nearest
    ``_CANDIDATES`` bones takes the nearest one.

    Returns
    -------
    segment : (V,) int64
    distance : (V, S) float64
        From every vertex to every segment.
    """
    import igl

    a, b = segs[:, 0], segs[:, 1]
    ab = b - a
    t = np.einsum("nsk,sk->ns", v[:, None, :] - a[None], ab) / np.einsum("sk,sk->s", ab, ab)
    closest = a[None] + np.clip(t, 0, 1)[..., None] * ab[None]  # (V, S, 3)
    dist = np.linalg.norm(closest - v[:, None, :], axis=2)
    k = min(_CANDIDATES, len(segs))
    cand = np.argsort(dist, axis=1)[:, :k]  # (V, k)
    rows = np.arange(len(v))[:, None]
    target = closest[rows, cand].reshape(-1, 3)  # (V*k, 3)
    origin = np.repeat(v, k, axis=0)
    sight = target - origin
    length = np.maximum(np.linalg.norm(sight, axis=1), 1e-12)
    eps = 1e-5
    origin = origin + sight * (eps / length)[:, None]  # step off the vertex's own faces
    tree = igl.AABB()
    tree.init(v, f)
    face, t_hit, _ = tree.intersect_ray_first(v, f, origin, sight - sight * (eps / length)[:, None])
    # t is in units of the direction vector: a hit before 1 is a wall between. The sight line
    # must also start into the body (against the vertex normal), not through the air.
    normals = igl.per_vertex_normals(v, f)
    inward = np.einsum("nk,nk->n", sight, np.repeat(normals, k, axis=0)) < 0
    visible = (((face < 0) | ~(t_hit < 1.0)) & inward).reshape(len(v), k)
    first = np.where(visible.any(axis=1), np.argmax(visible, axis=1), 0)
    seg = cand[np.arange(len(v)), first]
    return seg, dist


def limit_influences(weights: np.ndarray, k: int = MAX_INFLUENCES, floor: float = MIN_WEIGHT):
    """At most ``k`` influences per row, without the seams that plain truncation makes.

    Each row is lowered by its (k+1)-th largest weight (or ``floor`` when larger) and clipped
    at zero, then renormalised: ``w' = max(w - tau, 0) / sum``. Unlike keeping the top k,
    this is continuous in the weights, so neighbouring vertices whose 4th and 5th joints swap
    order do not jump apart when posed.

    Parameters
    ----------
    weights : (V, J) float
        Non-negative (negatives are clipped).

    Returns
    -------
    (V, J) float32
        Rows sum to 1, at most ``k`` non-zeros.
    """
    w = np.clip(np.asarray(weights, np.float64), 0, None)
    tau = np.full((len(w), 1), float(floor))
    if w.shape[1] > k:
        tau = np.maximum(tau, -np.partition(-w, k, axis=1)[:, k : k + 1])
    w = np.maximum(w - tau, 0.0)
    # Exact ties at the (k+1)-th value could leave more than k: keep the first k.
    w[np.cumsum(w > 0, axis=1) > k] = 0.0
    total = w.sum(axis=1, keepdims=True)
    bad = total[:, 0] <= 0
    if bad.any():
        raise InputError(f"{int(bad.sum())} vertices have no skinning weight")
    return (w / total).astype(np.float32)


def linear_blend_skinning(
    vertices: np.ndarray, weights: np.ndarray, transforms: np.ndarray, chunk: int = 64
) -> np.ndarray:
    """Pose rest vertices with per-joint transforms.

    Parameters
    ----------
    vertices : (V, 3) float
        Rest positions.
    weights : (V, J) float
    transforms : (T, J, 4, 4) float
        From :func:`core.skeleton.skinning_transforms`.
    chunk : int
        Frames per block (bounds memory at ``chunk * V * 12`` floats).

    Returns
    -------
    (T, V, 3) float32
    """
    v = np.asarray(vertices, np.float32)
    w = np.asarray(weights, np.float32)
    m = np.asarray(transforms, np.float32)
    if m.ndim != 4 or m.shape[1:] != (w.shape[1], 4, 4) or w.shape[0] != len(v):
        raise InputError(
            f"shapes disagree: vertices {v.shape}, weights {w.shape}, transforms {m.shape}"
        )
    out = np.empty((len(m), len(v), 3), np.float32)
    for t0 in range(0, len(m), chunk):
        blk = m[t0 : t0 + chunk, :, :3, :]  # (t, J, 3, 4)
        t = len(blk)
        blended = (w @ blk.transpose(1, 0, 2, 3).reshape(w.shape[1], t * 12)).reshape(
            len(v), t, 3, 4
        )
        out[t0 : t0 + t] = np.einsum("vtab,vb->tva", blended[..., :3], v) + blended[
            ..., 3
        ].transpose(1, 0, 2)
    return out


def pose_body(body, motion) -> np.ndarray:
    """The body's vertices posed by a motion on the mannequin skeleton.

    Parameters
    ----------
    body : core.body.mannequin.Body
    motion : core.motion.motion.Motion, or a pair ``(rotations, root_positions)``
        ``rotations`` (T, J, 3, 3) float local joint rotations, ``root_positions`` (T, 3)
        float. A Motion must be on the mannequin's joints (same names and order, e.g. from
        ``core.motion.retarget``); the body's own bone lengths are used, so a motion
        retargeted to another shape still fits this body's mesh.

    Returns
    -------
    (T, V, 3) float32
        Identity rotations with the rest root position give the rest vertices exactly.
    """
    rotations, root = motion_arrays(body.skeleton, motion)
    pos, rot = forward_kinematics(body.skeleton, rotations, root)
    transforms = skinning_transforms(body.skeleton, pos, rot)
    return linear_blend_skinning(body.vertices, body.weights, transforms)


def motion_arrays(skeleton: Skeleton, motion, path=None) -> tuple[np.ndarray, np.ndarray]:
    """A motion's local rotations and root positions, checked against ``skeleton``.

    Parameters
    ----------
    skeleton : Skeleton
        The body's skeleton (the mannequin's joints).
    motion : core.motion.motion.Motion, or a pair ``(rotations, root_positions)``
        A Motion must be on ``skeleton``'s joints (same names and order).
    path : the motion's file, named in errors

    Returns
    -------
    rotations : (T, J, 3, 3) float64
    root_positions : (T, 3) float64

    Raises
    ------
    InputError
        Other joints, wrong shapes, NaN or infinite values.
    """
    if isinstance(motion, Motion):
        if tuple(motion.skeleton.names) != tuple(skeleton.names):
            raise InputError(
                "motion is not on the mannequin's joints "
                f"({motion.skeleton.num_joints} joints from {motion.skeleton.names[0]!r}); "
                "retarget it first (core.motion.retarget / dng motion retarget)",
                path,
            )
        rotations, root = motion.rotations, motion.root_positions
    else:
        try:
            rotations, root = motion
        except (TypeError, ValueError):
            raise InputError(
                "a motion must be a Motion or a pair (rotations, root_positions)", path
            ) from None
    rotations = np.asarray(rotations, np.float64)
    root = np.asarray(root, np.float64)
    j = skeleton.num_joints
    if rotations.ndim != 4 or rotations.shape[1:] != (j, 3, 3):
        raise InputError(f"rotations must be (T, {j}, 3, 3), got {rotations.shape}", path)
    if root.shape != (len(rotations), 3):
        raise InputError(f"root_positions must be ({len(rotations)}, 3), got {root.shape}", path)
    if not (np.isfinite(rotations).all() and np.isfinite(root).all()):
        raise InputError("motion has NaN or infinite values", path)
    return rotations, root
