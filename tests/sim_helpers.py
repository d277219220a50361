"""Small garments and motions for the simulation tests (made here, no templates needed).

Helpers only (no tests); named test_sim_* to live beside the tests that use them."""

from __future__ import annotations

import numpy as np

from core.body.shape import BodyShape, mannequin_skeleton
from core.mesh import Mesh
from core.motion.motion import Motion
from core.proxy.testing import ring_grid, skirt_tube
from core.skeleton import rotation_about


def frustum_skirt(
    around: int = 24,
    rings: int = 12,
    height: float = 1.70,
    *,
    hem_height: float = 0.36,
    hem_radius: float = 0.30,
    folds: int = 0,
    fold_depth: float = 0.0,
) -> Mesh:
    """An open cone frustum from just above the hips (waist loop on top) to above the knees
    (``hem_height`` x ``height``). With ``folds`` > 0 the hem is gathered into that many radial
    folds of ``fold_depth`` metres, fading to none at the waist: more cloth at the hem than its
    hanging circle, as a skirt that can flare has. :func:`core.proxy.testing.skirt_tube` with a
    straight flare."""
    vertices, faces = skirt_tube(
        waist_y=0.57 * height,
        length=(0.57 - hem_height) * height,
        waist_r=0.19,
        hem_r=hem_radius,
        n_around=around,
        n_along=rings,
        folds=folds,
        fold_depth=fold_depth,
        flare_power=1.0,
        fold_power=1.5,
    )
    return Mesh(vertices.astype(np.float32), faces)


def spin_motion(frames: int = 6, fps: float = 30.0, turns_per_s: float = 0.5) -> Motion:
    """The mannequin turning about Y at the hips, a leg swinging forward."""
    sk = mannequin_skeleton(BodyShape())
    t = np.arange(frames) / fps
    rot = np.broadcast_to(np.eye(3), (frames, sk.num_joints, 3, 3)).copy()
    rot[:, 0] = rotation_about([0, 1, 0], 2 * np.pi * turns_per_s * t)
    rot[:, sk.index("LeftUpLeg")] = rotation_about([1, 0, 0], -0.4 * np.sin(2 * np.pi * t))
    root = np.broadcast_to(sk.rest_positions()[0], (frames, 3)).copy()
    return Motion(sk, rot.astype(np.float32), root.astype(np.float32), fps, name="test-spin")


def two_layer_skirt(around: int = 24, rings: int = 10) -> Mesh:
    """Two nested frustum skirts (separate pieces) sharing a waist height, 1.5 cm apart."""
    inner = frustum_skirt(around, rings)
    outer = frustum_skirt(around, rings)
    v = outer.vertices.copy()
    r = np.linalg.norm(v[:, [0, 2]], axis=1, keepdims=True)
    v[:, [0, 2]] *= (r + 0.015) / r
    faces = np.concatenate([inner.faces, outer.faces + inner.num_vertices])
    return Mesh(np.concatenate([inner.vertices, v]).astype(np.float32), faces)


def frilled_skirt(around: int = 24, rings: int = 10, gap: float = 0.002) -> tuple[Mesh, np.ndarray]:
    """Two stacked frustum skirts pinned at one waist ``gap`` apart (closer than the cloth-cloth
    contact thickness: their pinned waistbands touch), and a loose frill ring (its own piece,
    pinned nowhere) over the outer layer's hem, its top 1.5 cm above the hem, 4 mm outside the
    hem's radius (wider than the hem: unsewn, it slides off).

    Returns the mesh and each vertex's piece: 0 inner, 1 outer, 2 frill.
    """
    h = 1.70
    y_bot, r_bot = 0.36 * h, 0.30  # frustum_skirt's hem
    inner = frustum_skirt(around, rings)
    v = inner.vertices.copy()
    r = np.linalg.norm(v[:, [0, 2]], axis=1, keepdims=True)
    v[:, [0, 2]] *= (r + gap) / r
    frill_rings, frill_around = 4, 2 * around
    t = np.arange(frill_rings) / (frill_rings - 1)
    rad = r_bot + gap + 0.004 + 0.01 * t  # wider than the hem: slides off
    fv, ff = ring_grid(y_bot + 0.015 - 0.065 * t, np.repeat(rad[:, None], frill_around, 1))
    n = inner.num_vertices
    verts = np.concatenate([inner.vertices, v, fv]).astype(np.float32)
    faces = np.concatenate([inner.faces, inner.faces + n, ff + 2 * n])
    piece = np.repeat([0, 1, 2], [n, n, frill_rings * frill_around])
    return Mesh(verts, faces), piece
