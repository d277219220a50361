"""Small garments and motions for the simulation tests (made here, no templates needed).

Helpers only (no tests); named test_sim_* to live beside the tests that use them."""

from __future__ import annotations

import numpy as np

from core.body.shape import BodyShape, mannequin_skeleton
from core.mesh import Mesh
from core.motion.motion import Motion
from core.skeleton import rotation_about


def frustum_skirt(around: int = 24, rings: int = 12, height: float = 1.70) -> Mesh:
    """An open cone frustum from just above the hips (waist loop on top) to above the knees."""
    h = height
    y_top, y_bot = 0.57 * h, 0.36 * h
    r_top, r_bot = 0.19, 0.30
    verts = []
    for j in range(rings):
        s = j / (rings - 1)
        y, r = y_top + (y_bot - y_top) * s, r_top + (r_bot - r_top) * s
        a = 2 * np.pi * np.arange(around) / around
        verts.append(np.stack([r * np.sin(a), np.full(around, y), r * np.cos(a)], axis=1))
    faces = []
    for j in range(rings - 1):
        for i in range(around):
            a, b = j * around + i, j * around + (i + 1) % around
            faces += [(a, a + around, b), (b, a + around, b + around)]
    return Mesh(np.concatenate(verts).astype(np.float32), np.array(faces, np.int64))


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
