"""Procedural clips: input checks, determinism, fps independence, feet, smoothness, joint
limits, and kinds that differ from each other more than seeds do."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from core.body.shape import BodyShape, mannequin_skeleton
from core.errors import InputError
from core.motion.procedural import PROCEDURAL_KINDS, make_motion
from core.motion.retarget import foot_points
from core.skeleton import forward_kinematics
from tests.conftest import assert_close

#: Feet closer to the floor than this are touching it (metres).
CONTACT = 0.005


@functools.cache
def clip(kind: str, seed: int = 0, frames: int = 300, fps: float = 30.0):
    m = make_motion(kind, frames, fps, seed)
    pos, rot = forward_kinematics(m.skeleton, m.rotations, m.root_positions)
    return m, pos.astype(np.float64), rot.astype(np.float64)


def feet(kind: str, seed: int = 0, frames: int = 300):
    m, pos, rot = clip(kind, seed, frames)
    return foot_points(m.skeleton, pos, rot)  # (T, 2, 3, 3): ankle, heel, toe


def rotation_angle(r: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip((np.trace(r, axis1=-2, axis2=-1) - 1) / 2, -1, 1)))


def rotvec(r: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(r.reshape(-1, 3, 3)).as_rotvec().reshape(r.shape[:-2] + (3,))


# --------------------------------------------------------------------------------------------


def test_bad_input_is_refused_with_the_kinds_listed():
    with pytest.raises(InputError) as err:
        make_motion("moonwalk", 10, 30.0, 0)
    for kind in PROCEDURAL_KINDS:
        assert kind in str(err.value)
    for frames in (0, -3, 2.5):
        with pytest.raises(InputError, match="frames"):
            make_motion("walk", frames, 30.0, 0)
    for fps in (0.0, -30.0, float("nan"), float("inf")):
        with pytest.raises(InputError, match="fps"):
            make_motion("walk", 10, fps, 0)
    with pytest.raises(InputError, match="seed"):
        make_motion("walk", 10, 30.0, -1)


@pytest.mark.parametrize("kind", PROCEDURAL_KINDS)
def test_shapes_dtypes_and_name(kind):
    m, pos, _ = clip(kind)
    assert m.rotations.shape == (300, 20, 3, 3) and m.rotations.dtype == np.float32
    assert m.root_positions.shape == (300, 3) and m.root_positions.dtype == np.float32
    assert m.name == kind and m.meta["seed"] == 0 and m.fps == 30.0
    assert np.isfinite(pos).all()
    # local rotations are proper rotations
    r = m.rotations.astype(np.float64)
    assert_close(np.einsum("tjab,tjac->tjbc", r, r), np.broadcast_to(np.eye(3), r.shape), 1e-5)
    one = make_motion(kind, 1, 24.0, 3)
    assert one.num_frames == 1 and np.isfinite(one.rotations).all()


@pytest.mark.parametrize("kind", PROCEDURAL_KINDS)
def test_deterministic_and_seeded(kind):
    a = make_motion(kind, 90, 30.0, 7)
    b = make_motion(kind, 90, 30.0, 7)
    c = make_motion(kind, 90, 30.0, 8)
    assert np.array_equal(a.rotations, b.rotations)
    assert np.array_equal(a.root_positions, b.root_positions)
    diff = np.abs(a.joint_positions() - a.root_positions[:, None]) - np.abs(
        c.joint_positions() - c.root_positions[:, None]
    )
    assert np.abs(diff).max() > 0.05  # a different pose, not only a different place


@pytest.mark.parametrize("kind", PROCEDURAL_KINDS)
def test_timing_is_in_seconds(kind):
    """The same seed at 30 and 60 fps is the same motion; a longer clip extends a shorter one."""
    slow = make_motion(kind, 61, 30.0, 5)
    fast = make_motion(kind, 121, 60.0, 5)
    assert_close(fast.root_positions[::2], slow.root_positions, 1e-4, what="root")
    assert_close(fast.rotations[::2], slow.rotations, 1e-4, what="rotations")
    longer = make_motion(kind, 150, 30.0, 5)
    assert_close(longer.rotations[:61], slow.rotations, 1e-4, what="prefix")


@pytest.mark.parametrize("kind", PROCEDURAL_KINDS)
def test_feet_never_below_the_floor(kind):
    assert feet(kind)[..., 1].min() > -1e-3


@pytest.mark.parametrize("kind", ("dance", "twirl", "walk", "circle-walk", "idle"))
def test_always_standing_on_a_foot(kind):
    low = feet(kind)[..., 1].min(2)  # (T, 2) lowest point per foot
    assert (low.min(1) < CONTACT).all(), "both feet in the air"
    if kind == "idle":
        assert (low < CONTACT).all(), "idle lifts a foot"
    else:  # each foot steps: it spends time both on the floor and in the air
        on = (low < CONTACT).mean(0)
        assert ((on > 0.4) & (on < 0.95)).all(), on


def test_jump_leaves_the_floor_and_lands():
    low = feet("jump")[..., 1].min(2).min(1)  # lowest foot point per frame
    air = low > 0.05
    assert air.any() and (low < CONTACT).mean() > 0.3
    m, pos, _ = clip("jump")
    root_y = pos[:, 0, 1]
    # in flight the root follows gravity: second differences = -g dt^2 where both feet are high
    flying = np.convolve(low > 0.02, np.ones(5), "same") == 5
    acc = np.diff(root_y, 2)[flying[1:-1]] * m.fps**2
    assert flying.sum() > 10
    assert_close(acc, np.full_like(acc, -9.81), atol=1.0, what="flight acceleration")
    assert root_y.max() - np.median(root_y) > 0.1


def test_broad_jump_goes_further_and_leans_into_it():
    """``broad-jump`` is ``jump`` with longer flights forward (0.5 to 1 m a jump against 0 to 0.5)
    and the torso leaning with the forward speed; both land and fly as ``jump`` does."""
    low = feet("broad-jump")[..., 1].min(2).min(1)
    assert (low > 0.05).any() and (low < CONTACT).mean() > 0.3
    travel, lean = {}, {}
    for kind in ("jump", "broad-jump"):
        m, pos, rot = clip(kind)
        root = pos[:, 0]
        speed = np.linalg.norm(np.diff(root[:, [0, 2]], axis=0), axis=1) * m.fps
        travel[kind] = np.percentile(speed, 95)
        up = rot[:, 0] @ np.array([0.0, 1.0, 0.0])
        lean[kind] = np.degrees(np.arccos(np.clip(up[:, 1], -1, 1))).max()
    assert travel["broad-jump"] > 1.5 * travel["jump"] and travel["broad-jump"] > 1.0, travel
    assert lean["broad-jump"] > lean["jump"] + 10.0, lean


def test_run_flies_between_steps():
    """``run``: 2.5 to 3.4 m/s, each foot on the floor about a third of the time, both in the air
    between steps, the root higher in those flights than on the floor (its bounce is planned to
    fall at g mid-flight, then trimmed where a leg could not reach its foot: not ballistic)."""
    m, pos, _ = clip("run")
    low = feet("run")[..., 1].min(2)  # (T, 2)
    on = (low < CONTACT).mean(0)
    assert ((on > 0.3) & (on < 0.5)).all(), on
    flying = (low > CONTACT).all(1)
    assert 0.1 < flying.mean() < 0.35, flying.mean()
    root = pos[:, 0]
    speed = np.linalg.norm(root[-1, [0, 2]] - root[0, [0, 2]]) / m.duration
    assert 2.4 < speed < 3.5, speed
    assert root[flying, 1].mean() > root[~flying, 1].mean() + 0.01


#: Kinds made of key poses, with the body standing still between movements.
SCRIPTED = ("squat", "kick", "kneel")


def longest_run(mask: np.ndarray) -> int:
    """Length of the longest run of True in a 1-D boolean array."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(int), 0]))
    return int(np.max(edges[1::2] - edges[::2], initial=0))


@pytest.mark.parametrize("kind", SCRIPTED)
def test_scripted_kinds_start_standing_and_stand_still_between_movements(kind):
    """A foot is always on the floor; the clip starts standing (feet flat under the hips, the
    root within 5 cm of its rest height, not moving); between two movements (a squat, a kick,
    a knee down) the whole body stands still at least 1 s."""
    m, pos, _ = clip(kind, frames=600)
    i = m.skeleton.index
    f = feet(kind, frames=600)
    low = f[..., 1].min(2)  # (T, 2) lowest point per foot
    assert (low.min(1) < CONTACT).all(), "both feet in the air"
    assert (f[0, :, 1:, 1] < CONTACT).all(), "not standing flat at the start"
    hips = np.linalg.norm(pos[0, i("LeftUpLeg"), [0, 2]] - pos[0, i("RightUpLeg"), [0, 2]])
    apart = np.linalg.norm(f[0, 0, 0, [0, 2]] - f[0, 1, 0, [0, 2]])
    assert hips - 0.01 < apart < hips + 0.08, (apart, hips)
    assert abs(pos[0, 0, 1] - m.skeleton.rest_positions()[0, 1]) < 0.05
    speed = np.linalg.norm(np.diff(pos, axis=0), axis=-1).max(1) * m.fps  # fastest joint, m/s
    assert speed[:5].max() < 1e-3
    if kind == "squat":
        event = pos[:, 0, 1] < pos[0, 0, 1] - 0.3
    elif kind == "kick":
        event = low.max(1) > 0.5
    else:
        event = pos[:, [i("LeftLeg"), i("RightLeg")], 1].min(1) < 0.1
    edges = np.flatnonzero(np.diff(np.r_[0, event.astype(int), 0]))
    assert len(edges) >= 4, "fewer than two movements in 20 s"
    for a, b in zip(edges[1:-1:2], edges[2::2]):  # from the end of one to the next's start
        still = longest_run(speed[a:b] < 1e-3) / m.fps
        assert still >= 0.95, f"stands still only {still:.2f} s between movements"


def test_squat_goes_deep_with_the_feet_wide_and_stands_back_up():
    """The root drops at least 0.35 m below its standing height (0.40 to 0.45 m for a 1.70 m
    body); after each squat it comes back within 2 cm of where it stood before it (with the
    feet wide, a few cm below its height with the feet together), and after the feet step back
    in, within 2 cm of its height at the start. While squatting the ankles are 0.6 to 0.8 m
    apart (more than the hips' width) and the knees are out, about over the feet."""
    m, pos, _ = clip("squat", frames=600)
    i = m.skeleton.index
    y = pos[:, 0, 1]
    assert y[0] - y.min() > 0.35, y[0] - y.min()
    assert y.max() < y[0] + 0.02
    speed = np.linalg.norm(np.diff(pos, axis=0), axis=-1).max(1) * m.fps
    still = np.flatnonzero(np.r_[speed < 1e-3, False])
    deep = y < y[0] - 0.3
    edges = np.flatnonzero(np.diff(np.r_[0, deep.astype(int), 0]))
    assert len(edges) >= 4
    for a, b in zip(edges[::2], edges[1::2]):
        if not (still > b).any():
            continue  # the clip ends before the body stands still again
        before, after = still[still < a][-1], still[still > b][0]
        assert abs(y[after] - y[before]) < 0.02, (y[before], y[after])
    assert y[edges[0] :].max() > y[0] - 0.02  # the feet stepped back in
    ankles = pos[:, [i("LeftFoot"), i("RightFoot")]][..., [0, 2]]
    knees = pos[:, [i("LeftLeg"), i("RightLeg")]][..., [0, 2]]
    hips = pos[:, [i("LeftUpLeg"), i("RightUpLeg")]][..., [0, 2]]
    apart = np.linalg.norm(ankles[:, 0] - ankles[:, 1], axis=-1)[deep]
    assert ((apart > 0.6) & (apart < 0.8)).all(), apart
    assert (apart > np.linalg.norm(hips[deep, 0] - hips[deep, 1], axis=-1)).all()
    knees_apart = np.linalg.norm(knees[:, 0] - knees[:, 1], axis=-1)[deep]
    assert (knees_apart > 0.75 * apart).all()


def test_kick_reaches_hip_height_on_a_standing_foot_that_stays_put():
    """A kicking foot rises to 0.8 m or more (the default body's hips are at 0.85 m) and lands
    where it took off; the standing foot stays flat and does not move; legs take turns."""
    f = feet("kick", frames=600)
    kicked = set()
    for foot in range(2):
        flat = np.flatnonzero((f[:, foot, 1:, 1] < CONTACT).all(1))
        up = f[:, foot, :, 1].min(1) > 0.05
        edges = np.flatnonzero(np.diff(np.r_[0, up.astype(int), 0]))
        for a, b in zip(edges[::2], edges[1::2]):
            if not (flat >= b).any():
                continue  # the clip ends before the foot is down again
            kicked.add(foot)
            assert f[a:b, foot, :, 1].max() >= 0.8, f[a:b, foot, :, 1].max()
            off, on = flat[flat < a][-1], flat[flat >= b][0]  # last and first flat frames
            land = np.linalg.norm(f[on, foot, 0, [0, 2]] - f[off, foot, 0, [0, 2]])
            assert land < 0.01, land
            other = f[off : on + 1, 1 - foot]
            assert (other[:, 1:, 1] < CONTACT).all(), "the standing foot lifts"
            slide = np.linalg.norm(other[:, 0, [0, 2]] - other[0, 0, [0, 2]], axis=-1).max()
            assert slide < 1e-3, slide
    assert kicked == {0, 1}


def test_kneel_puts_a_knee_on_the_floor_and_stands_back_up():
    """A knee joint comes within 5 cm of the floor (the knee's radius is 5.1 cm), the front
    thigh near level; the root comes back to its standing height; sides take turns."""
    m, pos, _ = clip("kneel", frames=600)
    i = m.skeleton.index
    knees = pos[:, [i("LeftLeg"), i("RightLeg")], 1]
    hips = pos[:, [i("LeftUpLeg"), i("RightUpLeg")], 1]
    down = knees.min(0)
    assert (down < 0.05).all(), down  # both knees, one after the other
    t = int(np.argmin(knees[:, 0]))
    assert abs(knees[t, 1] - hips[t, 1]) < 0.12  # the front thigh about level (within 20 deg)
    y = pos[:, 0, 1]
    assert y[0] - y.min() > 0.3
    first_up = t + int(np.argmax(y[t:] > y[0] - 0.02))
    assert first_up > t and abs(y[first_up:].max() - y[0]) < 0.02


@pytest.mark.parametrize("kind", ("walk", "circle-walk", "run", *SCRIPTED))
def test_walk_stance_feet_do_not_slide(kind):
    """A heel or toe touching the floor stays where it touched down (within 2 cm)."""
    f = feet(kind)
    worst = 0.0
    for foot in range(2):
        for point in (1, 2):  # heel, toe
            p = f[:, foot, point]
            touch = p[:, 1] < CONTACT
            edges = np.flatnonzero(np.diff(np.r_[0, touch.astype(int), 0]))
            for a, b in zip(edges[::2], edges[1::2]):
                xz = p[a:b][:, [0, 2]]
                worst = max(worst, float(np.linalg.norm(xz - xz[0], axis=1).max()))
    assert worst < 0.02, f"a planted foot point slides {worst:.3f} m"


@pytest.mark.parametrize("kind", PROCEDURAL_KINDS)
def test_flat_feet_stay_put(kind):
    """A foot flat on the floor (heel and toe down) may pivot about its ankle, not slide."""
    f = feet(kind)
    worst = 0.0
    for foot in range(2):
        flat = (f[:, foot, 1:, 1] < CONTACT).all(1)
        edges = np.flatnonzero(np.diff(np.r_[0, flat.astype(int), 0]))
        for a, b in zip(edges[::2], edges[1::2]):
            xz = f[a:b, foot, 0][:, [0, 2]]
            worst = max(worst, float(np.linalg.norm(xz - xz[0], axis=1).max()))
    assert worst < 0.01, f"a flat foot slides {worst:.3f} m"


def test_walk_bobs_and_moves():
    m, pos, _ = clip("walk")
    root = pos[:, 0]
    speed = np.linalg.norm(root[-1, [0, 2]] - root[0, [0, 2]]) / m.duration
    assert 0.7 < speed < 1.8
    bob = root[:, 1].max() - root[:, 1].min()
    assert 0.01 < bob < 0.08


def test_walk_is_straight_and_circle_walk_turns():
    """walk and circle-walk share their poses; they differ by the path (a split by path)."""
    for kind, turning in (("walk", False), ("circle-walk", True)):
        m, _, rot = clip(kind)
        fwd = rot[:, 0] @ np.array([0.0, 0.0, 1.0])
        yaw = np.unwrap(np.arctan2(fwd[:, 0], fwd[:, 2]))
        rate = abs(yaw[-1] - yaw[0]) / m.duration
        assert (rate > 0.2) if turning else (rate < 0.05), (kind, rate)


@pytest.mark.parametrize("kind", PROCEDURAL_KINDS)
def test_smooth_velocities(kind):
    """C1: joint accelerations stay bounded as the frame rate grows (a velocity jump would
    make the finite-difference acceleration grow with fps)."""
    acc = {}
    for fps in (120.0, 480.0):
        m = make_motion(kind, int(3 * fps) + 1, fps, 2)
        pos = m.joint_positions().astype(np.float64)
        acc[fps] = np.linalg.norm(np.diff(pos, 2, axis=0), axis=-1).max() * fps**2
    # a velocity jump dv would show as dv * fps: 4 times larger at 480 than at 120 fps
    assert acc[480.0] < 1.5 * acc[120.0] + 1.0, acc
    assert acc[480.0] < 250.0, acc


#: Largest plausible rotation (degrees) of each joint relative to its parent.
MAX_ANGLE = {
    "Spine": 25, "Spine1": 25, "Spine2": 25, "Neck": 35, "Head": 35,
    "LeftShoulder": 20, "RightShoulder": 20, "LeftArm": 150, "RightArm": 150,
    "LeftForeArm": 135, "RightForeArm": 135, "LeftHand": 1, "RightHand": 1,
    "LeftUpLeg": 110, "RightUpLeg": 110, "LeftLeg": 150, "RightLeg": 150,
    "LeftFoot": 60, "RightFoot": 60,
}  # fmt: skip


@pytest.mark.parametrize("kind", PROCEDURAL_KINDS)
def test_joint_limits(kind):
    m, _, _ = clip(kind)
    skel = m.skeleton
    r = m.rotations.astype(np.float64)
    for name, limit in MAX_ANGLE.items():
        ang = rotation_angle(r[:, skel.index(name)])
        assert ang.max() <= limit, f"{kind}: {name} turns {ang.max():.1f} deg > {limit}"
    # Knees are hinges about the thigh's +X (the shin swings backwards); elbows are hinges
    # about (forearm x forward) (the forearm swings forwards), never the other way.
    for side in ("Left", "Right"):
        knee = rotvec(r[:, skel.index(f"{side}Leg")])
        ang = np.linalg.norm(knee, axis=-1)
        bent = ang > np.radians(5)
        assert bent.mean() > 0.5, "knees never bend"
        assert (knee[bent] @ np.array([1.0, 0.0, 0.0]) / ang[bent] > 0.97).all()
        d = skel.offsets[skel.index(f"{side}Hand")].astype(np.float64)
        hinge = np.cross(d / np.linalg.norm(d), [0.0, 0.0, 1.0])
        hinge /= np.linalg.norm(hinge)
        elbow = rotvec(r[:, skel.index(f"{side}ForeArm")])
        ang = np.linalg.norm(elbow, axis=-1)
        assert (ang > np.radians(2)).all()
        assert (elbow @ hinge / ang > 0.999).all()


def _pose_descriptors(kind: str, seed: int) -> np.ndarray:
    """Root-relative joint positions in the root's heading frame, (T, 20, 3)."""
    m = make_motion(kind, 240, 8.0, seed)
    pos, rot = forward_kinematics(m.skeleton, m.rotations, m.root_positions)
    rel = pos.astype(np.float64) - pos[:, :1]
    fwd = rot[:, 0].astype(np.float64) @ np.array([0.0, 0.0, 1.0])
    yaw = np.arctan2(fwd[:, 0], fwd[:, 2])
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    x = c * rel[..., 0] - s * rel[..., 2]
    z = s * rel[..., 0] + c * rel[..., 2]
    return np.stack([x, rel[..., 1], z], -1)


def _energy_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Energy distance between two pose samples (frames, J, 3); the distance between two poses
    is their mean per-joint distance (metres), a metric of negative type, so the energy
    distance is >= 0 and 0 only for equal distributions."""

    def mean_dist(p, q):
        return float(np.linalg.norm(p[:, None] - q[None], axis=-1).mean())

    return 2 * mean_dist(a, b) - mean_dist(a, a) - mean_dist(b, b)


def test_kinds_differ_more_than_seeds():
    desc = {(k, s): _pose_descriptors(k, s) for k in PROCEDURAL_KINDS for s in (0, 1)}
    within = {k: _energy_distance(desc[k, 0], desc[k, 1]) for k in PROCEDURAL_KINDS}
    for i, a in enumerate(PROCEDURAL_KINDS):
        for b in PROCEDURAL_KINDS[i + 1 :]:
            if {a, b} in ({"walk", "circle-walk"}, {"jump", "broad-jump"}):
                continue  # the same poses on another path: see test_walk_is_straight...,
                # test_broad_jump_goes_further_and_leans_into_it
            between = _energy_distance(desc[a, 0], desc[b, 0])
            assert between > 2.0 * max(within[a], within[b]) and between > 0.015, (
                a, b, between, within[a], within[b],
            )  # fmt: skip


def test_dance_covers_poses_and_turns():
    """The default training motion: wide arm range, spins, hip sway."""
    m, pos, rot = clip("dance", frames=600)
    skel = m.skeleton
    fwd = rot[:, 0] @ np.array([0.0, 0.0, 1.0])
    yaw = np.unwrap(np.arctan2(fwd[:, 0], fwd[:, 2]))
    assert np.ptp(yaw) > 2 * np.pi  # at least one full spin in 20 s
    hands = pos[:, [skel.index("LeftHand"), skel.index("RightHand")], 1]
    assert np.ptp(hands) > 0.8  # hands from hip height to above the shoulders
    hips_x = (pos[:, 0] - pos[:, skel.index("Neck")])[:, [0, 2]]
    assert np.linalg.norm(hips_x, axis=1).max() > 0.05  # the hips sway under the chest


def test_other_body_shapes():
    for shape in (BodyShape(height=1.5, hip=1.2), BodyShape(height=1.95, shoulder_width=0.45)):
        m = make_motion("walk", 120, 30.0, 0, shape)
        pos, rot = forward_kinematics(m.skeleton, m.rotations, m.root_positions)
        f = foot_points(m.skeleton, pos, rot)
        assert f[..., 1].min() > -1e-3 and (f[..., 1].min((1, 2)) < CONTACT).all()
        assert_close(m.skeleton.offsets, mannequin_skeleton(shape).offsets)
