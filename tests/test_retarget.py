"""Retargeting joint positions of other rigs onto the mannequin: round trips, bone directions
and lengths, floor contact, facing, scale, degenerate frames, smoothness, real motion capture."""

from __future__ import annotations

import numpy as np
import pytest

from core.body.shape import _PARENT, MANNEQUIN_JOINTS, BodyShape, mannequin_skeleton
from core.errors import InputError
from core.motion.load import load_motion
from core.motion.mapping import canonical_positions
from core.motion.procedural import make_motion
from core.motion.retarget import (
    DEFAULT_SHAPE,
    SOURCE_JOINTS,
    foot_points,
    retarget,
    rotation_about_axes,
)
from core.skeleton import Skeleton, forward_kinematics
from tests.conftest import assert_close

TO_SOURCE = [MANNEQUIN_JOINTS.index(n) for n in SOURCE_JOINTS]
#: Bones whose parent has a single child: retargeting makes them point exactly like the source.
SINGLE_CHILD_BONES = [
    (p, c) for c, p in _PARENT.items() if p not in ("Hips", "Spine2")
]  # fmt: skip


def smooth_signal(rng, t, scale, fmin=0.2, fmax=1.0):
    f, ph = rng.uniform(fmin, fmax, 3), rng.uniform(0, 2 * np.pi, 3)
    return scale * np.mean(np.sin(2 * np.pi * f * t[:, None] + ph), axis=1)


def plausible_rotations(rng, skel: Skeleton, t: np.ndarray, hyperextend: float = 0.0):
    """Smooth random local rotations (T, J, 3, 3) within human-like ranges: hinge knees and
    elbows (bent 0..~100 deg, or down to -``hyperextend`` rad), a turning pelvis."""
    n = len(t)
    rot = np.tile(np.eye(3), (n, skel.num_joints, 1, 1))
    for j, name in enumerate(skel.names):
        if name == "Hips":
            yaw = smooth_signal(rng, t, 3.0)
            tilt = rotation_about_axes(rng.normal(size=3), smooth_signal(rng, t, 0.3))
            rot[:, j] = rotation_about_axes(np.array([0.0, 1.0, 0.0]), yaw) @ tilt
        elif name in ("LeftLeg", "RightLeg"):
            bend = 0.7 + smooth_signal(rng, t, 1.4)
            bend = np.maximum(bend, -hyperextend)
            rot[:, j] = rotation_about_axes(np.array([1.0, 0.0, 0.0]), bend)
        elif name in ("LeftForeArm", "RightForeArm"):
            d = skel.offsets[skel.index(name.replace("ForeArm", "Hand"))]
            hinge = np.cross(d / np.linalg.norm(d), [0.0, 0.0, 1.0])
            bend = np.maximum(0.8 + smooth_signal(rng, t, 1.6), -hyperextend)
            rot[:, j] = rotation_about_axes(hinge, bend)
        else:
            big = name.endswith("Arm") or name.endswith("UpLeg")
            axis = rng.normal(size=3)
            rot[:, j] = rotation_about_axes(axis, smooth_signal(rng, t, 1.2 if big else 0.5))
    return rot


def source_clip(rng, shape=DEFAULT_SHAPE, frames=90, fps=30.0, bone_jitter=0.0, hyperextend=0.0):
    """Positions (T, 20, 3) in source order from FK of a mannequin, feet on its floor: the
    lowest ankle over the clip sits at the rest ankle height (flat feet touch y = 0)."""
    skel = mannequin_skeleton(shape)
    if bone_jitter:
        scale = rng.uniform(1 - bone_jitter, 1 + bone_jitter, (skel.num_joints, 1))
        skel = Skeleton(
            skel.names, skel.parents, (skel.offsets * scale).astype(np.float32), skel.end_sites
        )
    t = np.arange(frames) / fps
    rot = plausible_rotations(rng, skel, t, hyperextend)
    root = np.stack([smooth_signal(rng, t, 1.0), np.zeros_like(t), smooth_signal(rng, t, 1.0)], 1)
    pos = forward_kinematics(skel, rot, root)[0].astype(np.float64)[:, TO_SOURCE]
    ankles = pos[:, [SOURCE_JOINTS.index("LeftFoot"), SOURCE_JOINTS.index("RightFoot")], 1]
    pos[..., 1] += skel.rest_positions()[skel.index("LeftFoot"), 1] - ankles.min()
    return pos


def fk(motion):
    pos, rot = forward_kinematics(motion.skeleton, motion.rotations, motion.root_positions)
    return pos.astype(np.float64), rot.astype(np.float64)


def bone_angles(src: np.ndarray, out: np.ndarray, bones) -> np.ndarray:
    """Angle (deg) between source and result bone directions, (T, bones)."""
    ang = []
    for p, c in bones:
        a = src[:, SOURCE_JOINTS.index(c)] - src[:, SOURCE_JOINTS.index(p)]
        b = out[:, SOURCE_JOINTS.index(c)] - out[:, SOURCE_JOINTS.index(p)]
        cos = np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
        ang.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.stack(ang, 1)


def per_frame_rotation_change(rotations: np.ndarray) -> np.ndarray:
    """Angle (deg) each local rotation turns between consecutive frames: (T-1, J)."""
    r = rotations.astype(np.float64)
    rel = np.einsum("tjba,tjbc->tjac", r[:-1], r[1:])
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1) / 2
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def check_invariants(motion, shape=DEFAULT_SHAPE):
    """Mannequin bone lengths, NaN-free, proper rotations, feet on and never below the floor."""
    skel = mannequin_skeleton(shape)
    pos, rot = fk(motion)
    assert motion.skeleton.names == MANNEQUIN_JOINTS
    assert np.isfinite(pos).all() and np.isfinite(motion.rotations).all()
    r = motion.rotations.astype(np.float64)
    assert_close(np.einsum("tjab,tjac->tjbc", r, r), np.broadcast_to(np.eye(3), r.shape), 1e-5)
    lengths = np.linalg.norm(pos[:, 1:] - pos[:, skel.parents[1:]], axis=-1)
    assert_close(
        lengths, np.broadcast_to(skel.bone_lengths()[1:], lengths.shape), 1e-5, what="bones"
    )
    f = foot_points(skel, pos, rot)[..., 1]
    assert f.min() > -1e-4, "a foot below the floor"
    assert f.min() < 0.02, "feet never touch the floor"
    return pos, rot


# --------------------------------------------------------------------------------------------


def test_bad_input():
    good = source_clip(np.random.default_rng(0), frames=5)
    with pytest.raises(InputError, match=r"\(T, 20, 3\)"):
        retarget(good[:, :19], 30.0)
    with pytest.raises(InputError, match=r"\(T, 20, 3\)"):
        retarget(good[:0], 30.0)
    bad = good.copy()
    bad[2, 5, 1] = np.nan
    with pytest.raises(InputError, match="non-finite.*frame 2"):
        retarget(bad, 30.0)
    for fps in (0.0, -1.0, float("nan")):
        with pytest.raises(InputError, match="fps"):
            retarget(good, fps)
    with pytest.raises(InputError, match="legs"):
        retarget(np.zeros((4, 20, 3)), 30.0)


def test_round_trip_of_the_mannequin_itself():
    """FK of the mannequin with plausible random rotations retargets to the same positions."""
    rng = np.random.default_rng(1)
    for shape in (BodyShape(), BodyShape(height=1.55, shoulder_width=0.34, hip=1.1)):
        src = source_clip(rng, shape, frames=120)
        m = retarget(src, 30.0, shape)
        pos, _ = check_invariants(m, shape)
        assert m.meta["scale"] == pytest.approx(1.0, abs=1e-6)
        err = np.linalg.norm(pos[:, TO_SOURCE] - src, axis=-1)
        assert err.max() < 0.01, f"round trip error {err.max():.4f} m"


def test_round_trip_of_procedural_clips():
    for kind in ("dance", "jump"):
        clip = make_motion(kind, 150, 30.0, 3)
        src = fk(clip)[0][:, TO_SOURCE]
        pos, _ = check_invariants(retarget(src, 30.0))
        err = np.linalg.norm(pos[:, TO_SOURCE] - src, axis=-1)
        assert err.max() < 0.01, f"{kind}: round trip error {err.max():.4f} m"


def test_other_proportions_bones_point_like_the_source():
    """A taller rig with jittered bone lengths: single-child bones point exactly where the
    source's do, the pelvis and chest bones nearly, and lengths stay the mannequin's."""
    rng = np.random.default_rng(2)
    shape = BodyShape(height=1.92, shoulder_width=0.46, hip=0.9)
    src = source_clip(rng, shape, frames=120, bone_jitter=0.15)
    m = retarget(src, 30.0)
    pos, _ = check_invariants(m)
    out = pos[:, TO_SOURCE]
    assert bone_angles(src, out, SINGLE_CHILD_BONES).max() < 0.1
    multi = [(p, c) for c, p in _PARENT.items() if p in ("Hips", "Spine2")]
    assert np.median(bone_angles(src, out, multi)) < 15.0
    # the clip is scaled by the leg ratio: the root's path shrinks for a taller source
    ratio = m.meta["scale"]
    assert 0.75 < ratio < 1.0
    path_src = np.linalg.norm(np.diff(src[:, 0, [0, 2]], axis=0), axis=1).sum()
    path_out = np.linalg.norm(np.diff(pos[:, 0, [0, 2]], axis=0), axis=1).sum()
    assert path_out == pytest.approx(ratio * path_src, rel=1e-4)


def test_upright_and_facing_kept():
    """An upright source (a procedural dance on a taller body with jittered bone lengths)."""
    rng = np.random.default_rng(3)
    dance = make_motion("dance", 150, 30.0, 4, BodyShape(height=1.8))
    skel = dance.skeleton
    jitter = rng.uniform(0.9, 1.1, (skel.num_joints, 1))
    skel = Skeleton(
        skel.names, skel.parents, (skel.offsets * jitter).astype(np.float32), skel.end_sites
    )
    src = forward_kinematics(skel, dance.rotations, dance.root_positions)[0][:, TO_SOURCE]
    src = src.astype(np.float64)
    m = retarget(src, 30.0)
    pos, rot = check_invariants(m)
    names = MANNEQUIN_JOINTS
    head, hips = pos[:, names.index("Head"), 1], pos[:, 0, 1]
    feet = pos[:, [names.index("LeftFoot"), names.index("RightFoot")], 1].max(1)
    assert ((head > hips) & (hips > feet)).mean() >= 0.95

    def facing(left_hip, right_hip):
        across = left_hip - right_hip
        fwd = np.cross(across, [0.0, 1.0, 0.0])
        return np.degrees(np.arctan2(fwd[:, 0], fwd[:, 2]))

    s = facing(src[:, SOURCE_JOINTS.index("LeftUpLeg")], src[:, SOURCE_JOINTS.index("RightUpLeg")])
    o = facing(pos[:, names.index("LeftUpLeg")], pos[:, names.index("RightUpLeg")])
    diff = (o - s + 180) % 360 - 180
    assert np.abs(diff).max() < 5.0


def test_floor_is_the_sources_floor():
    """Moving the source up or down changes nothing; a jump's flight is kept, scaled."""
    rng = np.random.default_rng(4)
    src = source_clip(rng, frames=60)
    a = retarget(src, 30.0)
    b = retarget(src + np.array([0.0, 0.37, 0.0]), 30.0)
    assert_close(a.root_positions, b.root_positions, 1e-5)
    jump = fk(make_motion("jump", 120, 30.0, 1, BodyShape(height=1.9)))[0][:, TO_SOURCE]
    m = retarget(jump, 30.0)
    pos, rot = check_invariants(m)
    lowest = foot_points(m.skeleton, pos, rot)[..., 1].min((1, 2))
    src_ankle = jump[:, [SOURCE_JOINTS.index("LeftFoot"), SOURCE_JOINTS.index("RightFoot")], 1]
    src_elev = src_ankle.min(1) - src_ankle.min()
    out_ankle = pos[:, [MANNEQUIN_JOINTS.index("LeftFoot"), MANNEQUIN_JOINTS.index("RightFoot")], 1]
    out_elev = out_ankle.min(1) - out_ankle.min()
    assert_close(out_elev, m.meta["scale"] * src_elev, 0.01, what="ankle elevation")
    assert lowest.max() > 0.1 and lowest.min() < 1e-3


def test_degenerate_frames_stay_finite():
    """Coincident joints (a collapsed skeleton, zero-length limbs, merged hips) give finite,
    proper rotations and the mannequin's bone lengths."""
    rng = np.random.default_rng(5)
    src = source_clip(rng, frames=40)
    src[5] = src[5, 0]  # every joint on the hips
    arm = [SOURCE_JOINTS.index(n) for n in ("LeftArm", "LeftForeArm", "LeftHand")]
    src[10:14, arm] = src[10:14, arm[:1]]  # a zero-length arm
    legs = [SOURCE_JOINTS.index(n) for n in ("LeftUpLeg", "RightUpLeg")]
    src[20, legs] = src[20, 0]  # hips merged
    spine = [SOURCE_JOINTS.index(n) for n in ("Spine", "Spine1", "Spine2", "Neck")]
    src[25, spine] = src[25, 0]  # spine collapsed
    knee = SOURCE_JOINTS.index("RightLeg")
    src[30, knee] = src[30, SOURCE_JOINTS.index("RightUpLeg")]  # zero-length thigh
    check_invariants(retarget(src, 30.0))


def test_smooth_in_time_through_straight_and_hyperextended_limbs():
    """Limbs that straighten and hyperextend slightly (as mocap does) never flip: each local
    rotation turns little more per frame than the source's joints do."""
    rng = np.random.default_rng(6)
    shape = BodyShape()
    skel = mannequin_skeleton(shape)
    t = np.arange(240) / 60.0
    rot = plausible_rotations(rng, skel, t, hyperextend=0.12)
    for name in ("LeftForeArm", "RightForeArm", "LeftLeg", "RightLeg"):  # through straight
        j = skel.index(name)
        angle = np.arccos(np.clip((np.trace(rot[:, j], axis1=-2, axis2=-1) - 1) / 2, -1, 1))
        assert angle.min() < 0.15
    noise = rotation_about_axes(rng.normal(size=(len(t), 3)), rng.normal(0, 0.01, len(t)))
    rot[:, skel.index("LeftForeArm")] = rot[:, skel.index("LeftForeArm")] @ noise
    root = np.stack([smooth_signal(rng, t, 0.5), 0.9 + 0 * t, smooth_signal(rng, t, 0.5)], 1)
    src = forward_kinematics(skel, rot, root)[0].astype(np.float64)[:, TO_SOURCE]
    m = retarget(src, 60.0)
    check_invariants(m)
    change = per_frame_rotation_change(m.rotations)
    source_change = per_frame_rotation_change(rot.astype(np.float32)).max()
    assert change.max() < max(3 * source_change, 10.0), (change.max(), source_change)


def test_real_motion_capture(bvh_dir):
    """CMU 01_01 through the loader and joint mapping."""
    clip = load_motion(bvh_dir / "01_01.bvh", fps=30.0)
    src = canonical_positions(clip).astype(np.float64)
    m = retarget(src, clip.fps, name="01_01")
    pos, rot = check_invariants(m)
    names = MANNEQUIN_JOINTS
    head, hips = pos[:, names.index("Head"), 1], pos[:, 0, 1]
    feet = pos[:, [names.index("LeftFoot"), names.index("RightFoot")], 1].max(1)
    assert ((head > hips) & (hips > feet)).mean() >= 0.95
    assert bone_angles(src, pos[:, TO_SOURCE], SINGLE_CHILD_BONES).max() < 0.5
    # smooth wherever the source is (CMU clips start with a T-pose frame: skip that jump)
    src_speed = np.linalg.norm(np.diff(src, axis=0), axis=-1).max(1) * clip.fps
    change = per_frame_rotation_change(m.rotations)[src_speed < 8.0]
    assert np.percentile(change, 99.9) < 20.0 and change.max() < 60.0
