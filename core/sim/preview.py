"""A preview of a simulation: a PNG grid of frames, garment over the posed body.

(:func:`core.shading.contact_sheet` lays out image tiles; this draws 3-D frames with matplotlib.)
"""

from __future__ import annotations

import os

import numpy as np

from core.body.colliders import body_capsules, capsule_distance, pose_capsules
from core.body.mannequin import make_body
from core.body.shape import BodyShape, mannequin_skeleton
from core.body.skinning import linear_blend_skinning
from core.fileio import atomic_path
from core.sim.cache import SimCache
from core.skeleton import forward_kinematics, skinning_transforms


def pick_frames(num_frames: int, count: int) -> np.ndarray:
    """``count`` frame indices spread evenly over the clip, first and last included."""
    return np.unique(np.linspace(0, num_frames - 1, min(count, num_frames)).round().astype(int))


def preview_sheet(
    path: str | os.PathLike,
    cache: SimCache,
    motion,
    shape: BodyShape | None = None,
    frames: int = 8,
    columns: int = 4,
    title: str = "",
) -> list[int]:
    """Render ``frames`` frames of ``cache`` (front view, flat shading) to a PNG grid.

    The body is the posed mannequin mesh when :mod:`core.body.mannequin` can build it, else the
    collision capsules as grey segments. Garment vertices inside the body colliders are red.

    Parameters
    ----------
    motion : the Motion the cache was simulated with (on the mannequin's joints)

    Returns
    -------
    The frame indices drawn.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    shape = BodyShape() if shape is None else shape
    idx = pick_frames(cache.num_frames, frames)
    skeleton = mannequin_skeleton(shape)
    rot, root = np.asarray(motion.rotations)[idx], np.asarray(motion.root_positions)[idx]
    pos, grot = forward_kinematics(skeleton, rot, root)
    transforms = skinning_transforms(skeleton, pos, grot)
    capsules = body_capsules(skeleton, shape)
    ends = pose_capsules(capsules, transforms)
    body_v = body_f = None
    try:  # the mannequin mesh needs libigl and fast-simplification
        body = make_body(shape, 3000)
        body_v = linear_blend_skinning(body.vertices, body.weights, transforms)
        body_f = body.faces
    except (ImportError, AttributeError):
        pass
    rows = int(np.ceil(len(idx) / columns))
    fig = plt.figure(figsize=(3.0 * columns, 4.2 * rows), dpi=90)
    light = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])
    faces = cache.faces
    for i, t in enumerate(idx):
        ax = fig.add_subplot(rows, columns, i + 1, projection="3d")
        v = cache.positions[t].astype(np.float64)
        centre = v.mean(axis=0)
        inside = capsule_distance(v, ends[i], capsules.radii) < 0
        tris = [v[faces]]
        bases = [np.where(inside[faces].any(axis=1)[:, None], (0.85, 0.15, 0.1), (0.2, 0.4, 0.8))]
        if body_v is not None:  # one collection, so body and garment are depth-sorted together
            tris.append(body_v[i].astype(np.float64)[body_f])
            bases.append(np.broadcast_to((0.75, 0.72, 0.68), (len(body_f), 3)))
        else:
            for a, b in ends[i]:
                ax.plot(*zip(a[[0, 2, 1]], b[[0, 2, 1]]), color="0.5", lw=4)
        ax.add_collection3d(
            _shaded(np.concatenate(tris), light, np.concatenate(bases), Poly3DCollection)
        )
        r = 0.6
        ax.set_xlim(centre[0] - r, centre[0] + r)
        ax.set_ylim(centre[2] - r, centre[2] + r)
        ax.set_zlim(centre[1] - r, centre[1] + r)
        ax.view_init(elev=5, azim=-90)
        ax.set_axis_off()
        ax.set_title(f"frame {t}", fontsize=9)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp)
    plt.close(fig)
    return [int(t) for t in idx]


def _shaded(tri: np.ndarray, light: np.ndarray, base, poly_cls):
    """Flat-shaded triangles (N, 3, 3) in (x, y, z) world -> matplotlib (x, z, y) axes."""
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    shade = 0.35 + 0.65 * np.abs(n @ light)
    colours = np.clip(np.asarray(base, np.float64) * shade[:, None], 0, 1)  # base (N, 3) or (3,)
    coll = poly_cls(tri[:, :, [0, 2, 1]], facecolors=colours, edgecolors="none")
    return coll
