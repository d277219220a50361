"""Procedural clips on the mannequin: dance, twirl, walk, circle-walk, idle, jump, broad-jump,
run, squat, kick, kneel.

Every clip is a function of time in seconds, evaluated at the frame times, so the same seed
describes the same motion at any frame rate and any clip length (a longer clip extends a shorter
one). Random choices come from separate seeded streams (path, steps, arms, ...), drawn in time
order. The pieces:

- The **root** follows a planned path (position on the floor, heading), with sway and bounce.
  Its height is the planned height, lowered smoothly (a soft minimum) wherever a leg could not
  reach its foot otherwise, so walking gets its natural bob and legs never lock.
- **Feet** follow a step schedule: a foot is planted (fixed position, sole flat on the floor;
  it may pivot about the ankle when the body turns) between swings; during a swing it moves on
  a C2 curve to the next foothold, placed where the body will be at the middle of the next
  stance, with a lift and a toe-down / toe-up pitch.
- **Legs** are solved by two-bone IK with the knee towards the foot's heading: knees bend only
  forwards, by construction.
- **Spine, neck, arms** are joint angles driven by smooth signals (sums of sines with seeded
  frequencies and phases) squashed into joint ranges with ``tanh``: bounded and C-infinity.
- ``squat``, ``kick`` and ``kneel`` are scripted instead: seeded key poses (:class:`_Script`),
  each eased into the next (quintic: C2, at rest at every key), with the body standing still
  at least a second between movements.

All signals are at least C1 (the root's vertical path in a jump is a C1 Hermite spline joined to
a ballistic flight), so joint velocities never jump.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from core.body.shape import BodyShape, mannequin_skeleton
from core.constants import GRAVITY
from core.errors import InputError
from core.motion.motion import Motion
from core.motion.retarget import (
    DEFAULT_SHAPE,
    rotation_about_axes,
    swing_rotation,
    twist_towards,
)
from core.skeleton import Skeleton

#: The kinds :func:`make_motion` knows.
PROCEDURAL_KINDS: tuple[str, ...] = (
    "dance", "twirl", "walk", "circle-walk", "idle", "jump", "broad-jump", "run", "squat", "kick",
    "kneel",
)  # fmt: skip

_X, _Y, _Z = np.eye(3)
_DEG = np.pi / 180.0
#: Legs are never asked to stretch beyond this fraction of thigh + shin.
_REACH = 0.975
#: Softness of the root-height soft minimum, metres.
_SOFT = 0.012
#: Time margin (s) before the clip and after it over which step schedules are generated.
_MARGIN = 4.0


# --------------------------------------------------------------------------------------------
# Smooth signals.


class _Signal:
    """Sum of ``n`` sines with seeded frequencies in [fmin, fmax] Hz, unit RMS."""

    def __init__(self, rng: np.random.Generator, fmin: float, fmax: float, n: int = 4):
        self.f = rng.uniform(fmin, fmax, n)
        self.ph = rng.uniform(0.0, 2 * np.pi, n)
        a = rng.uniform(0.5, 1.0, n)
        self.a = a * np.sqrt(2.0) / np.sqrt(np.sum(a * a))

    def __call__(self, t: np.ndarray) -> np.ndarray:
        arg = 2 * np.pi * self.f * np.asarray(t)[..., None] + self.ph
        return np.sum(self.a * np.sin(arg), -1)

    def integral(self, t: np.ndarray) -> np.ndarray:
        """Antiderivative (seconds * value), zero mean."""
        arg = 2 * np.pi * self.f * np.asarray(t)[..., None] + self.ph
        return np.sum(-self.a * np.cos(arg) / (2 * np.pi * self.f), -1)


def _bound(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Squash ``x`` (about unit scale) smoothly into (lo, hi)."""
    return 0.5 * (lo + hi) + 0.5 * (hi - lo) * np.tanh(x)


def _quintic(u: np.ndarray) -> np.ndarray:
    """0 -> 1 with zero first and second derivatives at both ends."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * u * (10.0 + u * (-15.0 + 6.0 * u))


def _quintic_slope(u: np.ndarray) -> np.ndarray:
    """The derivative of :func:`_quintic` in ``u`` (0 outside [0, 1])."""
    u = np.clip(u, 0.0, 1.0)
    return 30.0 * u * u * (1.0 - u) ** 2


def _bump(u: np.ndarray) -> np.ndarray:
    """0 at u = 0 and 1 with zero slope there, 1 at u = 1/2."""
    u = np.clip(u, 0.0, 1.0)
    return 16.0 * u * u * (1.0 - u) ** 2


def _hermite(t: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """C1 piecewise-cubic through keys (K, 3) rows (time, value, slope); constant outside."""
    times, values, slopes = keys.T
    out = np.full(np.shape(t), values[0], np.float64)
    out = np.where(t >= times[-1], values[-1], out)
    for i in range(len(keys) - 1):
        t0, t1 = times[i], times[i + 1]
        m = (t >= t0) & (t < t1)
        if not m.any():
            continue
        d = t1 - t0
        s = (t[m] - t0) / d
        h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
        h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
        out[m] = (
            h00 * values[i] + h10 * d * slopes[i] + h01 * values[i + 1] + h11 * d * slopes[i + 1]
        )
    return out


def _c1_ramp(x: np.ndarray, k: float) -> np.ndarray:
    """0 for x <= 0, x^2/(2k) up to k, then x - k/2: a C1 rectifier never above x."""
    x = np.asarray(x, np.float64)
    return np.where(x <= 0, 0.0, np.where(x < k, x * x / (2 * k), x - k / 2))


def _softmin(values: list[np.ndarray], k: float) -> np.ndarray:
    """Smooth minimum, never above the true minimum."""
    v = np.stack(values)
    m = v.min(0)
    return m - k * np.log(np.sum(np.exp(-(v - m) / k), 0))


def _yaw(psi: np.ndarray) -> np.ndarray:
    """Rotations about +Y by ``psi`` (T,): (T, 3, 3)."""
    return rotation_about_axes(_Y, psi)


def _heading(psi: np.ndarray) -> np.ndarray:
    """Forward direction (+Z turned by ``psi``) as (T, 3)."""
    return np.stack([np.sin(psi), np.zeros_like(psi), np.cos(psi)], -1)


# --------------------------------------------------------------------------------------------
# What a planner hands to the assembler.


@dataclass(frozen=True)
class _Plan:
    """One clip's plan, all arrays over frames (T); angles in radians.

    root_xz : (T, 2) floor position of the root; root_y : (T,) wanted root height
    yaw, pitch, roll : (T,) pelvis orientation (pitch > 0 tips forward)
    ankles : (T, 2, 3) ankle targets (left, right); foot_yaw, foot_pitch : (T, 2)
    spine : (T, 3) forward bend, side bend, twist over the three spine joints together
    neck : (T, 3) the same for neck + head
    arms : (T, 2, 5) per side: clavicle raise, abduction, forward flexion, twist, elbow flexion
    knees : (T, 2, 3) or None: the direction each knee points to (its leg bends towards it);
        None: the foot's heading plus the pelvis's forward direction
    """

    root_xz: np.ndarray
    root_y: np.ndarray
    yaw: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray
    ankles: np.ndarray
    foot_yaw: np.ndarray
    foot_pitch: np.ndarray
    spine: np.ndarray
    neck: np.ndarray
    arms: np.ndarray
    knees: np.ndarray | None = None


@dataclass(frozen=True)
class _Body:
    """Numbers of the mannequin the planners need."""

    skel: Skeleton
    height: float
    root_y: float  # rest root height
    ankle_y: float  # rest ankle height (feet flat on the floor)
    hip_half: float  # half the distance between the hip joints
    leg: float  # thigh + shin

    @staticmethod
    def of(shape: BodyShape) -> _Body:
        skel = mannequin_skeleton(shape)
        rest = skel.rest_positions().astype(np.float64)
        i = skel.index
        leg = float(
            np.linalg.norm(skel.offsets[i("LeftLeg")]) + np.linalg.norm(skel.offsets[i("LeftFoot")])
        )
        return _Body(
            skel=skel,
            height=shape.height,
            root_y=float(rest[0, 1]),
            ankle_y=float(rest[i("LeftFoot"), 1]),
            hip_half=float(abs(rest[i("LeftUpLeg"), 0])),
            leg=leg,
        )


# --------------------------------------------------------------------------------------------
# Steps.


Path = Callable[[np.ndarray], np.ndarray]


def _feet(
    t: np.ndarray,
    swings: list[np.ndarray],
    offsets: list[np.ndarray],
    lifts: list[np.ndarray],
    center: Path,
    psi: Path,
    body: _Body,
    pitch_amp: float,
    toe_off: float = 0.0,
    plant_at: float = 0.5,
    pivot: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ankle targets and foot pitch from a step schedule.

    swings : per foot, (K, 2) [lift-off, touch-down] times, sorted, not overlapping, starting
        before t[0] - 1 s and ending after t[-1].
    offsets : per foot, (K + 1, 2) body-frame (x, z) offset of each foothold from the path.
        Foothold k (before swing k) sits at ``center(m) + yaw(psi(m)) @ offset`` with m the
        middle of its stance.
    lifts : per foot, (K,) peak ankle lift of each swing (m).
    pitch_amp : toe-down / toe-up pitch during a swing (radians).
    toe_off : heel rise at the end of each stance (radians): the foot pivots about its toe.
    plant_at : where in its stance (0..1) the body passes over a foothold.
    pivot : planted feet turn about the ankle with the body (spins) instead of keeping the
        heading they landed with.
    Returns ankles (T, 2, 3), foot pitch (T, 2) (> 0: toes down) and foot yaw (T, 2).
    """
    toe = body.skel.end_sites[body.skel.index("LeftFoot")].astype(np.float64)
    heel = np.array([0.0, toe[1], -0.25 * toe[2]])  # as in retarget.foot_points

    def heel_rise(angle: np.ndarray, about: np.ndarray = toe) -> np.ndarray:
        """Ankle displacement (foot frame, (T, 3)) when the foot pivots about a sole point."""
        r = rotation_about_axes(_X, angle)
        return about - np.einsum("tab,b->ta", r, about)

    ankles = np.empty((len(t), 2, 3))
    pitch = np.zeros((len(t), 2))
    yaw = np.tile(psi(t)[:, None], (1, 2))
    for f in range(2):
        sw, off, lift = swings[f], offsets[f], lifts[f]
        k = len(sw)
        starts = np.concatenate([[sw[0, 0] - 1.0], sw[:, 1]])
        ends = np.concatenate([sw[:, 0], [sw[-1, 1] + 1.0]])
        mid = starts + plant_at * (ends - starts)
        o3 = np.stack([off[:, 0], np.zeros(k + 1), off[:, 1]], -1)
        hold = _to3(center(mid)) + np.einsum("kab,kb->ka", _yaw(psi(mid)), o3)
        i = np.searchsorted(sw[:, 0], t, side="right") - 1
        in_swing = (i >= 0) & (t < sw[np.maximum(i, 0), 1])
        stance_idx = np.where(i < 0, 0, np.where(in_swing, i, i + 1))
        pos = hold[stance_idx].copy()
        st = ~in_swing
        held_yaw = psi(mid)
        if not pivot:
            yaw[st, f] = held_yaw[stance_idx[st]]
        if toe_off and st.any():
            j = stance_idx[st]
            rise_len = np.minimum(0.3, 0.4 * (ends[j] - starts[j]))
            a = toe_off * _quintic((t[st] - (ends[j] - rise_len)) / rise_len)
            a = np.where(j < k, a, 0.0)
            pos[st] += np.einsum("tab,tb->ta", _yaw(yaw[st, f]), heel_rise(a))
            pitch[st, f] = a
        if in_swing.any():
            j = i[in_swing]
            ts = t[in_swing]
            t0, t1 = sw[j, 0], sw[j, 1]
            u = (ts - t0) / (t1 - t0)
            s, b = _quintic(u)[:, None], _bump(u)
            p0, p1 = hold[j], hold[j + 1]
            if toe_off:
                y_off = psi(t0) if pivot else held_yaw[j]
                p0 = p0 + np.einsum("tab,tb->ta", _yaw(y_off), heel_rise(np.full(len(j), toe_off)))
            loc0 = np.einsum("tba,tb->ta", _yaw(psi(t0)), p0 - _to3(center(t0)))
            loc1 = np.einsum("tba,tb->ta", _yaw(psi(t1)), p1 - _to3(center(t1)))
            q = _to3(center(ts)) + np.einsum("tab,tb->ta", _yaw(psi(ts)), loc0 + s * (loc1 - loc0))
            lin = p0 + s * (p1 - p0)
            theta = toe_off * (1 - s[:, 0]) + pitch_amp * b * np.cos(np.pi * u)
            # Ankle height that keeps the lower of toe and heel on the floor at this pitch
            # (a smooth maximum, exact at both ends of the swing), plus the lift.
            a, c = heel_rise(theta)[:, 1], heel_rise(theta, heel)[:, 1]
            eps = 0.04 * b
            clear = 0.5 * (a + c + np.sqrt((a - c) ** 2 + eps**2))
            pos[in_swing] = lin + b[:, None] * (q - lin)
            pos[in_swing, 1] = clear + lift[j] * b
            pitch[in_swing, f] = theta
            if not pivot:
                y0, y1 = held_yaw[j], held_yaw[j + 1]
                lin_yaw = y0 + s[:, 0] * (y1 - y0)
                yaw[in_swing, f] = lin_yaw + b * (psi(ts) - lin_yaw)
        pos[:, 1] += body.ankle_y
        ankles[:, f] = pos
    return ankles, pitch, yaw


def _to3(xz: np.ndarray) -> np.ndarray:
    return np.stack([xz[..., 0], np.zeros(xz.shape[:-1]), xz[..., 1]], -1)


def _alternating(beats: np.ndarray, duty: float, first: int = 0) -> list[np.ndarray]:
    """Swings for alternating feet, one per beat interval (beats (B,) sorted times)."""
    out: list[list[tuple[float, float]]] = [[], []]
    for n in range(len(beats) - 1):
        f = (n + first) % 2
        out[f].append((beats[n], beats[n] + duty * (beats[n + 1] - beats[n])))
    return [np.array(o) for o in out]


def _upper_signals(
    rng: np.random.Generator, t: np.ndarray, fmin: float, fmax: float, ranges: dict
) -> dict[str, np.ndarray]:
    """Bounded smooth signals by name: ``ranges`` maps name -> (lo, hi) in degrees (or m)."""
    out = {}
    for name in sorted(ranges):
        lo, hi = ranges[name]
        sig = _Signal(rng, fmin, fmax)
        out[name] = _bound(0.9 * sig(t), lo, hi)
    return out


def _arms_from(sig: dict[str, np.ndarray], prefix: str = "") -> np.ndarray:
    """(T, 2, 5) arm angles (radians) from signals named ``{side}_{part}`` in degrees."""
    parts = ("clav", "abd", "flex", "twist", "elbow")
    return (
        np.stack([np.stack([sig[f"{prefix}{s}_{p}"] for p in parts], -1) for s in ("l", "r")], 1)
        * _DEG
    )


# --------------------------------------------------------------------------------------------
# Planners. Each takes frame times t (T,) float64, the seed's random streams and the body.


Streams = Callable[[int], np.random.Generator]


def _plan_idle(t: np.ndarray, rng: Streams, body: _Body) -> _Plan:
    r0 = rng(0)
    psi0 = r0.uniform(-np.pi, np.pi)
    c0 = r0.uniform(-0.3, 0.3, 2)
    stance = body.hip_half + r0.uniform(0.0, 0.05)
    sway = _Signal(rng(1), 0.08, 0.3)
    yaw_sig = _Signal(rng(2), 0.05, 0.2)

    def psi(tt):
        return psi0 + 0.12 * yaw_sig(tt)

    def center(tt):
        return np.broadcast_to(c0, np.shape(tt) + (2,))

    far = np.array([[-1e9 - 1.0, -1e9], [1e9, 1e9 + 1.0]])  # one stance, centred on t = 0
    swings = [far, far]
    offs = [np.array([[stance, 0.0]] * 3), np.array([[-stance, 0.0]] * 3)]
    ankles, fpitch, fyaw = _feet(t, swings, offs, [np.zeros(2)] * 2, center, psi, body, 0.0)
    side = 0.45 * stance * np.tanh(sway(t))
    p = psi(t)
    xz = center(t) + side[:, None] * np.stack([np.cos(p), -np.sin(p)], -1)
    s = _upper_signals(
        rng(3), t, 0.08, 0.4,
        {"l_clav": (-3, 6), "r_clav": (-3, 6), "l_abd": (-35, -10), "r_abd": (-35, -10),
         "l_flex": (-10, 25), "r_flex": (-10, 25), "l_twist": (-20, 20), "r_twist": (-20, 20),
         "l_elbow": (5, 35), "r_elbow": (5, 35), "bend": (-4, 8), "side": (-5, 5),
         "twist": (-10, 10), "nbend": (-10, 15), "nside": (-8, 8), "ntwist": (-25, 25),
         "pitch": (-3, 4), "dip": (0.005, 0.03)},
    )  # fmt: skip
    return _Plan(
        root_xz=xz, root_y=body.root_y - s["dip"], yaw=p, pitch=s["pitch"] * _DEG,
        roll=-0.6 * np.tanh(sway(t)) * 4 * _DEG, ankles=ankles, foot_yaw=fyaw,
        foot_pitch=fpitch, spine=np.stack([s["bend"], s["side"], s["twist"]], -1) * _DEG,
        neck=np.stack([s["nbend"], s["nside"], s["ntwist"]], -1) * _DEG, arms=_arms_from(s),
    )  # fmt: skip


@dataclass(frozen=True)
class _Gait:
    """How a walk or a run moves (ranges are drawn per clip; lengths for a 1.70 m body).

    step, period : step length (m) and stride period (s, two steps); speed = 2 step / period
    duty : how long each foot swings, in half strides: under 1 the feet share the floor (a
        walk), over 1 both are in the air between steps (a run's flight)
    lift : peak ankle lift in a swing (m); pitch_amp, toe_off : the swing's toe-down / toe-up
        and the heel rise at the end of a stance (degrees); plant_at : where in its stance the
        body passes over a foothold
    sink : how far the root rides below its standing height (m); with flights (duty over 1)
        the root bounces twice a stride, highest mid-flight, planned to fall at g there (then
        trimmed where a leg could not reach its foot, as every root height is), else it keeps
        one height
    sway : side-to-side shift of the hips over the stance foot (m); hip_yaw : the pelvis's turn
        with the stride (degrees); lean : forward pitch (degrees); arm_amp : the arms' forward
        swing (degrees, drawn); upper : ranges of the upper body's other signals (degrees)
    """

    step: tuple[float, float]
    period: tuple[float, float]
    duty: float
    lift: tuple[float, float]
    pitch_amp: float
    toe_off: float
    plant_at: float
    sink: float
    sway: float
    hip_yaw: float
    lean: float
    arm_amp: tuple[float, float]
    upper: dict


_WALK = _Gait(
    step=(0.5, 0.62), period=(1.0, 1.2), duty=0.8, lift=(0.07, 0.11), pitch_amp=15.0,
    toe_off=25.0, plant_at=0.42, sink=0.03, sway=0.022, hip_yaw=5.0, lean=3.0,
    arm_amp=(15, 30),
    upper={"l_clav": (-2, 4), "r_clav": (-2, 4), "l_abd": (-32, -20), "r_abd": (-32, -20),
           "l_twist": (-10, 10), "r_twist": (-10, 10), "l_elbow": (10, 30), "r_elbow": (10, 30),
           "nbend": (-5, 8), "nside": (-4, 4), "ntwist": (-15, 15), "bend": (0, 6)},
)  # fmt: skip
#: A jog to a run: 2.5 to 3.4 m/s, each foot on the floor about a third of the stride and landing
#: a little ahead of the body, elbows bent and pumping, the body leaning into it.
_RUN = _Gait(
    step=(0.9, 1.1), period=(0.64, 0.72), duty=1.3, lift=(0.22, 0.32), pitch_amp=25.0,
    toe_off=30.0, plant_at=0.3, sink=0.05, sway=0.012, hip_yaw=8.0, lean=9.0,
    arm_amp=(30, 45),
    upper={"l_clav": (0, 6), "r_clav": (0, 6), "l_abd": (-25, -12), "r_abd": (-25, -12),
           "l_twist": (-10, 10), "r_twist": (-10, 10), "l_elbow": (70, 100),
           "r_elbow": (70, 100), "nbend": (-8, 4), "nside": (-4, 4), "ntwist": (-10, 10),
           "bend": (2, 8)},
)  # fmt: skip


def _plan_walk(
    t: np.ndarray, rng: Streams, body: _Body, circle: bool, gait: _Gait = _WALK
) -> _Plan:
    r0 = rng(0)
    scale = body.height / 1.70
    step = r0.uniform(*gait.step) * scale
    period = r0.uniform(*gait.period)  # one stride: two steps
    speed = 2 * step / period
    psi0 = r0.uniform(-np.pi, np.pi)
    start = r0.uniform(-1.0, 1.0, 2)
    width = body.hip_half + r0.uniform(-0.01, 0.02)
    phase0 = r0.uniform(0.0, period)
    if circle:
        radius = r0.uniform(1.5, 3.0) * scale
        turn = 1.0 if r0.uniform() < 0.5 else -1.0

    def psi(tt):
        tt = np.asarray(tt, np.float64)
        return psi0 + (turn * speed * tt / radius if circle else 0.0 * tt)

    def center(tt):
        tt = np.asarray(tt, np.float64)
        if not circle:
            return start + speed * tt[..., None] * np.array([np.sin(psi0), np.cos(psi0)])
        # centre of the circle to the left (turn > 0) or right of the start heading
        left = np.array([np.cos(psi0), -np.sin(psi0)])
        o = start + turn * radius * left
        ang = psi(tt)
        rel = -turn * radius * np.stack([np.cos(ang), -np.sin(ang)], -1)
        return o + rel

    beats = phase0 + 0.5 * period * np.arange(
        np.floor((t[0] - _MARGIN - phase0) / (0.5 * period)),
        np.ceil((t[-1] + _MARGIN - phase0) / (0.5 * period)) + 1,
    )
    first = int(np.round((beats[0] - phase0) / (0.5 * period))) % 2
    swings = _alternating(beats, gait.duty, first)  # a walk's swing: 40 % of the stride
    n = [len(s) for s in swings]
    lifts = [np.full(k, r0.uniform(*gait.lift) * scale) for k in n]
    offs = [np.tile([width, 0.0], (n[0] + 1, 1)), np.tile([-width, 0.0], (n[1] + 1, 1))]
    ankles, fpitch, fyaw = _feet(
        t, swings, offs, lifts, center, psi, body, gait.pitch_amp * _DEG, gait.toe_off * _DEG,
        gait.plant_at,
    )  # fmt: skip
    # Stride phase w: the left foot swings for w in [0, duty pi] (mod 2 pi), the right one for
    # [pi, (1 + duty) pi]. The hips sway over the stance foot (left mid-stance at w = (1 + duty
    # / 2) pi); an arm is furthest forward when the opposite foot lands (the right foot at w =
    # (1 + duty) pi). A run's flights are centred on w = (duty - 1) pi / 2 and pi later.
    w = 2 * np.pi * (t - phase0) / period
    sway = gait.sway * scale * np.cos(w - (1 + 0.5 * gait.duty) * np.pi)
    p = psi(t)
    left = np.stack([np.cos(p), -np.sin(p)], -1)
    xz = center(t) + sway[:, None] * left
    arm_swing = np.cos(w - (1 + gait.duty) * np.pi)
    s = _upper_signals(rng(2), t, 0.1, 0.5, gait.upper)
    amp = rng(3).uniform(*gait.arm_amp)
    s["l_flex"] = amp * arm_swing + 5
    s["r_flex"] = -amp * arm_swing + 5
    lean = 0.0 if not circle else -turn * np.arctan(speed**2 / (radius * GRAVITY)) / _DEG
    zeros = np.zeros_like(t)
    spine = np.stack([s["bend"], zeros + 0.6 * lean, -6 * arm_swing], -1) * _DEG
    root_y = np.full_like(t, body.root_y - gait.sink * scale)
    if gait.duty > 1:  # flights: two bounces a stride, highest mid-flight, falling at g there
        omega = 2 * (2 * np.pi / period)
        root_y += GRAVITY / omega**2 * np.cos(2 * (w - 0.5 * (gait.duty - 1) * np.pi))
    return _Plan(
        root_xz=xz, root_y=root_y, yaw=p - gait.hip_yaw * _DEG * arm_swing,
        pitch=np.full_like(t, gait.lean * _DEG), roll=(lean + 3 * np.cos(w)) * _DEG,
        ankles=ankles, foot_yaw=fyaw, foot_pitch=fpitch, spine=spine,
        neck=np.stack([s["nbend"], s["nside"], s["ntwist"]], -1) * _DEG, arms=_arms_from(s),
    )  # fmt: skip


def _spins(r: np.random.Generator, t_end: float, gap: tuple, dur: tuple) -> np.ndarray:
    """Spin events (N, 3): start time, duration, signed turns; drawn in time order from -MARGIN."""
    out, tt = [], -_MARGIN
    while tt < t_end + _MARGIN:
        tt += r.uniform(*gap)
        d = r.uniform(*dur)
        out.append((tt, d, 1.0 if r.uniform() < 0.5 else -1.0))
        tt += d
    return np.array(out)


def _plan_dance(t: np.ndarray, rng: Streams, body: _Body) -> _Plan:
    r0 = rng(0)
    scale = body.height / 1.70
    psi0 = r0.uniform(-np.pi, np.pi)
    c0 = r0.uniform(-0.5, 0.5, 2)
    beat = r0.uniform(0.42, 0.55)
    wander = (_Signal(rng(1), 0.04, 0.15), _Signal(rng(2), 0.04, 0.15))
    yaw_sig = _Signal(rng(3), 0.08, 0.35)
    spins = _spins(rng(4), t[-1], (1.5, 4.0), (1.5, 2.0))

    def spin_angle(tt):
        tt = np.asarray(tt, np.float64)
        ang = np.zeros_like(tt)
        for t0, d, n in spins:
            ang = ang + 2 * np.pi * n * _quintic((tt - t0) / d)
        return ang

    def spinning(tt):
        tt = np.asarray(tt, np.float64)
        w = np.zeros_like(tt)
        for t0, d, _ in spins:
            w = np.maximum(w, _bump(np.clip((tt - t0 + 0.3) / (d + 0.6), 0, 1)))
        return w

    def psi(tt):
        return psi0 + 0.6 * yaw_sig(tt) + spin_angle(tt)

    def center(tt):
        tt = np.asarray(tt, np.float64)
        return c0 + 0.35 * scale * np.stack([wander[0](tt), wander[1](tt)], -1)

    # Beats from -MARGIN; a beat is sometimes held (no step). While spinning, a step comes
    # every quarter turn (chaine-like), so the feet keep up with the body.
    rb = rng(5)
    beats, tt = [], -_MARGIN
    while tt < t[-1] + _MARGIN:
        beats.append(tt)
        held = rb.uniform() < 0.15
        rate = abs(spin_angle(np.array([tt + 1e-3]))[0] - spin_angle(np.array([tt - 1e-3]))[0])
        rate /= 2e-3  # rad/s
        if spinning(np.array([tt]))[0] > 0.05:
            tt += float(np.clip(0.5 * np.pi / max(rate, 1e-6), 0.2, 0.5 * beat))
        else:
            tt += beat * (2.0 if held else 1.0)
    swings = _alternating(beats, 0.6)
    # One row of random numbers per beat (drawn in time order): the foothold after the step.
    vals = rng(6).uniform(size=(len(beats), 3))
    offs, lifts = [], []
    for f, sx in enumerate((1.0, -1.0)):
        steps = vals[f : len(beats) - 1 : 2]
        wide = body.hip_half + np.r_[0.05, 0.14 * steps[:, 0]] * scale
        fwd = np.r_[0.0, 0.24 * steps[:, 1] - 0.12] * scale
        offs.append(np.stack([sx * wide, fwd], -1))
        swing_time = swings[f][:, 1] - swings[f][:, 0]
        quick = np.minimum(1.0, (swing_time / 0.25) ** 2)  # quick steps stay low
        lifts.append((0.05 + 0.08 * steps[:, 2]) * scale * quick)
    ankles, fpitch, fyaw = _feet(
        t, swings, offs, lifts, center, psi, body, 15 * _DEG, 20 * _DEG, pivot=True
    )
    p = psi(t)
    groove = 2 * np.pi * t / (2 * beat)  # one side to the other per two beats
    sway_amp = r0.uniform(0.04, 0.07) * scale
    left = np.stack([np.cos(p), -np.sin(p)], -1)
    xz = center(t) + (sway_amp * np.sin(groove))[:, None] * left
    bounce = r0.uniform(0.02, 0.05) * scale
    root_y = body.root_y - 0.02 - bounce * 0.5 * (1 - np.cos(2 * np.pi * t / beat))
    spin_w = spinning(t)
    s = _upper_signals(
        rng(7), t, 0.25, 1.2,
        {"l_clav": (-5, 15), "r_clav": (-5, 15), "l_abd": (-35, 110), "r_abd": (-35, 110),
         "l_flex": (-40, 95), "r_flex": (-40, 95), "l_twist": (-45, 45), "r_twist": (-45, 45),
         "l_elbow": (5, 115), "r_elbow": (5, 115), "bend": (-12, 20), "side": (-15, 15),
         "twist": (-30, 30), "nbend": (-15, 20), "nside": (-12, 12), "ntwist": (-35, 35),
         "pitch": (-6, 12)},
    )  # fmt: skip
    for side in ("l", "r"):  # arms out while spinning, so skirts flare
        s[f"{side}_abd"] = (1 - spin_w) * s[f"{side}_abd"] + spin_w * 40.0
        s[f"{side}_flex"] = (1 - spin_w) * s[f"{side}_flex"] + spin_w * 10.0
        s[f"{side}_elbow"] = (1 - spin_w) * s[f"{side}_elbow"] + spin_w * 20.0
    roll = 9 * np.sin(groove) * _DEG
    spine = np.stack([s["bend"], s["side"] - 8 * np.sin(groove), s["twist"]], -1) * _DEG
    return _Plan(
        root_xz=xz, root_y=root_y, yaw=p, pitch=s["pitch"] * _DEG, roll=roll, ankles=ankles,
        foot_yaw=fyaw, foot_pitch=fpitch, spine=spine,
        neck=np.stack([s["nbend"], s["nside"], s["ntwist"]], -1) * _DEG, arms=_arms_from(s),
    )  # fmt: skip


def _plan_twirl(t: np.ndarray, rng: Streams, body: _Body) -> _Plan:
    r0 = rng(0)
    scale = body.height / 1.70
    psi0 = r0.uniform(-np.pi, np.pi)
    c0 = r0.uniform(-0.3, 0.3, 2)
    turn = 1.0 if r0.uniform() < 0.5 else -1.0
    rate0 = r0.uniform(0.8, 1.2)  # revolutions per second
    rate_sig = _Signal(rng(1), 0.05, 0.2)
    drift = (_Signal(rng(2), 0.03, 0.1), _Signal(rng(3), 0.03, 0.1))

    def psi(tt):
        return psi0 + turn * 2 * np.pi * (rate0 * np.asarray(tt) + 0.25 * rate_sig.integral(tt))

    def center(tt):
        tt = np.asarray(tt, np.float64)
        return c0 + 0.15 * scale * np.stack([drift[0](tt), drift[1](tt)], -1)

    # A step (alternating feet) every quarter turn: invert the turned angle on a fine grid.
    grid = np.arange(-_MARGIN, t[-1] + _MARGIN, 1e-3)
    quarter = turn * (psi(grid) - psi0) / (np.pi / 2)
    levels = np.arange(np.ceil(quarter[0]), np.floor(quarter[-1]) + 1)
    beats = np.interp(levels, quarter, grid)
    swings = _alternating(beats, 0.6, int(levels[0]) % 2)
    width = body.hip_half * 0.8
    n = [len(s) for s in swings]
    offs = [np.tile([width, 0.0], (n[0] + 1, 1)), np.tile([-width, 0.0], (n[1] + 1, 1))]
    lifts = [np.full(k, 0.05 * scale) for k in n]
    ankles, fpitch, fyaw = _feet(
        t, swings, offs, lifts, center, psi, body, 10 * _DEG, 15 * _DEG, pivot=True
    )
    p = psi(t)
    s = _upper_signals(
        rng(4), t, 0.1, 0.6,
        {"l_clav": (0, 12), "r_clav": (0, 12), "l_abd": (30, 60), "r_abd": (30, 60),
         "l_flex": (-15, 25), "r_flex": (-15, 25), "l_twist": (-25, 25), "r_twist": (-25, 25),
         "l_elbow": (5, 40), "r_elbow": (5, 40), "bend": (-8, 8), "side": (-8, 8),
         "twist": (-15, 15), "nbend": (-10, 10), "nside": (-8, 8), "ntwist": (-30, 30),
         "dip": (0.01, 0.05)},
    )  # fmt: skip
    zeros = np.zeros_like(t)
    return _Plan(
        root_xz=center(t), root_y=body.root_y - s["dip"] * scale, yaw=p, pitch=zeros,
        roll=zeros, ankles=ankles, foot_yaw=fyaw, foot_pitch=fpitch,
        spine=np.stack([s["bend"], s["side"], s["twist"]], -1) * _DEG,
        neck=np.stack([s["nbend"], s["nside"], s["ntwist"]], -1) * _DEG, arms=_arms_from(s),
    )  # fmt: skip


#: Forward distance of one jump, as a fraction of a 1.70 m body: (low, high) of ``jump`` (mostly
#: upwards) and ``broad-jump`` (a standing long jump, leaning into it).
_JUMP_REACH = {"jump": (0.0, 0.5), "broad-jump": (0.5, 1.0)}
#: Forward lean (degrees) of the torso per m/s of forward speed, and the largest crouch depth
#: (fraction of a 1.70 m body), of each jumping kind.
_JUMP_LEAN = {"jump": 0.0, "broad-jump": 14.0}
_JUMP_DEPTH = {"jump": 0.24, "broad-jump": 0.3}


def _plan_jump(t: np.ndarray, rng: Streams, body: _Body, kind: str = "jump") -> _Plan:
    """Jumps in place or a little forward (``jump``), or standing long jumps (``broad-jump``:
    a deeper crouch, 0.5 to 1 m forward, the torso leaning with the forward speed); each may
    turn in the air."""
    r0 = rng(0)
    scale = body.height / 1.70
    psi0 = r0.uniform(-np.pi, np.pi)
    c0 = r0.uniform(-0.3, 0.3, 2)
    # Standing, taking off and touching down with the knees slightly bent; above this the
    # feet leave the floor.
    stand = top = body.root_y - 0.065 * scale
    rj = rng(1)
    keys = [(-_MARGIN, stand, 0.0)]
    moves = []  # (start, end, forward distance, turn)
    tt = -_MARGIN + 0.3
    while tt < t[-1] + _MARGIN:
        tt += rj.uniform(0.4, 1.0)
        keys.append((tt, stand, 0.0))
        depth = rj.uniform(0.14, _JUMP_DEPTH[kind]) * scale
        tt += rj.uniform(0.35, 0.5)
        keys.append((tt, stand - depth, 0.0))
        v0 = np.sqrt(2 * GRAVITY * rj.uniform(0.15, 0.35) * scale)
        tt += 2.5 * (top - (stand - depth)) / v0
        t_off = tt
        keys.append((tt, top, v0))
        flight = 2 * v0 / GRAVITY
        tt += flight
        keys.append((tt, top, -v0))
        absorb = rj.uniform(0.2, 0.3)
        tt += absorb
        keys.append((tt, stand - v0 * absorb / 2.8, 0.0))
        tt += rj.uniform(0.35, 0.5)
        keys.append((tt, stand, 0.0))
        dist = rj.uniform(*_JUMP_REACH[kind]) * scale
        twist = rj.uniform(-np.pi / 2, np.pi / 2) if rj.uniform() < 0.4 else 0.0
        moves.append((t_off, t_off + flight, dist, twist))
    keys = np.array(keys)
    moves = np.array(moves)

    def root_height(tt):
        tt = np.asarray(tt, np.float64)
        y = _hermite(tt, keys)
        for t0, t1, *_ in moves:  # ballistic flight between the keys
            m = (tt > t0) & (tt < t1)
            tau = tt[m] - t0
            v0 = GRAVITY * (t1 - t0) / 2
            y[m] = top + v0 * tau - 0.5 * GRAVITY * tau**2
        return y

    def psi(tt):
        tt = np.asarray(tt, np.float64)
        out = np.full_like(tt, psi0)
        for t0, t1, _, tw in moves:
            out = out + tw * _quintic((tt - t0 + 0.1) / (t1 - t0 + 0.2))
        return out

    def center(tt):
        tt = np.asarray(tt, np.float64)
        pos = np.broadcast_to(c0, tt.shape + (2,)).copy()
        for t0, t1, dist, _ in moves:
            u = _quintic((tt - t0 + 0.1) / (t1 - t0 + 0.2))
            h = psi(np.array([t1]))[0]
            pos += (dist * u)[:, None] * np.array([np.sin(h), np.cos(h)])
        return pos

    def forward_speed(tt):
        """Speed (m/s) along the heading of each move: the derivative of ``center``'s ramps."""
        out = np.zeros_like(tt)
        for t0, t1, dist, _ in moves:
            d = t1 - t0 + 0.2
            out += dist * _quintic_slope((tt - t0 + 0.1) / d) / d
        return out

    swings = [moves[:, :2].copy(), moves[:, :2].copy()]
    k = len(moves) + 1
    width = body.hip_half + r0.uniform(0.0, 0.06) * scale
    offs = [np.tile([width, 0.0], (k, 1)), np.tile([-width, 0.0], (k, 1))]
    tuck = r0.uniform(0.05, 0.15) * scale
    lifts = [np.full(k - 1, tuck)] * 2
    ankles, fpitch, fyaw = _feet(t, swings, offs, lifts, center, psi, body, 25 * _DEG)
    y = root_height(t)
    # Above ``top`` the legs are nearly straight: the feet follow the root up, first rolling
    # onto the toes (the pitch stays below what would push the toes through the floor).
    rise = _c1_ramp(y - top, 0.05)
    ankles[..., 1] += rise[:, None]
    fpitch = fpitch + (35 * _DEG * np.tanh(rise / (0.2 * scale)))[:, None]
    up = y - stand  # < 0 crouching, > 0 in the air
    s = _upper_signals(
        rng(2), t, 0.1, 0.5,
        {"l_clav": (-3, 8), "r_clav": (-3, 8), "l_abd": (-30, 10), "r_abd": (-30, 10),
         "l_twist": (-20, 20), "r_twist": (-20, 20), "l_elbow": (10, 45), "r_elbow": (10, 45),
         "nbend": (-10, 10), "nside": (-6, 6), "ntwist": (-15, 15), "side": (-5, 5),
         "twist": (-10, 10)},
    )  # fmt: skip
    swing = _bound(4.0 * up / scale, -45, 125)  # arms back in the crouch, up in the air
    s["l_flex"], s["r_flex"] = swing, swing
    bend = _bound(-6.0 * up / scale - 0.6, 0, 40)
    pitch = 0.7 * bend + _JUMP_LEAN[kind] * forward_speed(t)
    p = psi(t)
    return _Plan(
        root_xz=center(t), root_y=y, yaw=p, pitch=pitch * _DEG, roll=np.zeros_like(t),
        ankles=ankles, foot_yaw=fyaw, foot_pitch=fpitch,
        spine=np.stack([0.5 * bend, s["side"], s["twist"]], -1) * _DEG,
        neck=np.stack([s["nbend"] - 0.5 * bend, s["nside"], s["ntwist"]], -1) * _DEG,
        arms=_arms_from(s),
    )  # fmt: skip


# --------------------------------------------------------------------------------------------
# Scripted clips (squat, kick, kneel): key poses, each eased into the next.


class _Script:
    """Key poses in time order, each eased into the next with :func:`_quintic` (C2, the body at
    rest at every key); before the first key and after the last the pose holds.

    A pose maps names to arrays in the clip's body frame (x to the body's left, z forward;
    lengths in metres, angles in degrees), per foot in the order left, right:

    root : (2,) floor position (x, z) of the root; drop : () root below its rest height
    pitch, roll : () pelvis (pitch > 0 tips forward, roll > 0 to the right)
    hold : (2, 2) floor position (x, z) of each ankle with its foot laid flat
    toe : (2,) each foot's pitch about its toe tip (> 0: heel up; the toe tip stays put)
    foot_yaw : (2,) each foot's turn from the heading (> 0: to the left); knee_out : (2,) each
        knee's turn beyond its foot's (the same sense)
    lift : (2,) each ankle's lift; swing : (2,) a kick's leg angle (the knee points up by as
        much), bend : (2,) its knee's bend (:func:`_plan_kick`)
    spine, neck : (3,) bend forward, bend to the left, twist; arms : (2, 5) as in :class:`_Plan`

    ``bump`` values are added on one segment as :func:`_bump` (0 and at rest at both of its
    keys, the whole value half-way): a foot's lift, a weight shift during a step, a knee bent
    as the leg swings.
    """

    def __init__(self, t0: float, pose: dict[str, np.ndarray]):
        self.times = [float(t0)]
        self.poses = [{k: np.array(v, np.float64) for k, v in pose.items()}]
        self.bumps: list[dict[str, np.ndarray]] = []

    @property
    def end(self) -> float:
        """Time of the last key (s)."""
        return self.times[-1]

    @property
    def pose(self) -> dict[str, np.ndarray]:
        """A copy of the last key pose."""
        return {k: v.copy() for k, v in self.poses[-1].items()}

    def to(self, dt: float, bump: dict | None = None, **changes) -> None:
        """A key ``dt`` seconds (> 0) after the last: the last pose with ``changes``."""
        pose = self.pose
        pose.update({k: np.array(v, np.float64) for k, v in changes.items()})  # copies
        self.times.append(self.times[-1] + dt)
        self.poses.append(pose)
        self.bumps.append({k: np.array(v, np.float64) for k, v in (bump or {}).items()})

    def wait(self, dt: float) -> None:
        """Stand still for ``dt`` seconds."""
        self.to(dt)

    def sample(self, t: np.ndarray) -> dict[str, np.ndarray]:
        """The pose at times ``t`` (T,): each name's array with a leading axis T."""
        times = np.array(self.times)
        i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
        u = np.clip((t - times[i]) / (times[i + 1] - times[i]), 0.0, 1.0)
        ease, bump = _quintic(u), _bump(u)
        out = {}
        for name in self.poses[0]:
            v = np.stack([p[name] for p in self.poses])
            b = np.stack([q.get(name, np.zeros_like(v[0])) for q in self.bumps])
            shape = (-1,) + (1,) * (v.ndim - 1)
            out[name] = v[i] + ease.reshape(shape) * (v[i + 1] - v[i]) + bump.reshape(shape) * b[i]
        return out


def _toe_pivot(body: _Body, angle: np.ndarray) -> np.ndarray:
    """Ankle displacement (foot frame, (..., 3)) when a flat foot pivots about its toe tip by
    ``angle`` (radians (...,), > 0: heel up): the toe tip stays where it was."""
    toe = body.skel.end_sites[body.skel.index("LeftFoot")].astype(np.float64)
    return toe - rotation_about_axes(_X, angle) @ toe


def _standing(r: np.random.Generator, body: _Body) -> dict[str, np.ndarray]:
    """A relaxed standing key pose of :class:`_Script` (feet under the hips, arms hanging)."""
    scale = body.height / 1.70
    w = body.hip_half + r.uniform(0.0, 0.03) * scale
    arm = [r.uniform(0, 3), r.uniform(-28, -18), r.uniform(0, 10), 0.0, r.uniform(10, 25)]
    zeros = np.zeros(2)
    return {
        "root": zeros, "drop": r.uniform(0.01, 0.02) * scale, "pitch": 0.0, "roll": 0.0,
        "hold": np.array([[w, 0.0], [-w, 0.0]]), "toe": zeros, "foot_yaw": zeros,
        "knee_out": zeros, "lift": zeros, "swing": zeros, "bend": zeros, "spine": np.zeros(3),
        "neck": np.zeros(3), "arms": np.array([arm, arm]),
    }  # fmt: skip


def _scripted(
    pose: dict[str, np.ndarray], psi0: float, c0: np.ndarray, body: _Body
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World root (T, 3), pelvis orientation (T, 3, 3) and ankle targets (T, 2, 3) of sampled key
    poses (:meth:`_Script.sample`) of a body facing ``psi0`` about the floor point ``c0`` (2,)."""
    turn = _yaw(np.array([psi0]))[0]
    n = len(pose["drop"])
    root = _to3(c0) + _to3(pose["root"]) @ turn.T
    root[:, 1] = body.root_y - pose["drop"]
    g_root = _euler_yxz(np.full(n, psi0), pose["pitch"] * _DEG, pose["roll"] * _DEG)
    ankles = _to3(c0) + _to3(pose["hold"]) @ turn.T
    ankles[..., 1] = body.ankle_y + pose["lift"]
    foot = _yaw(psi0 + pose["foot_yaw"] * _DEG)
    ankles += np.einsum("tfab,tfb->tfa", foot, _toe_pivot(body, pose["toe"] * _DEG))
    return root, g_root, ankles


def _scripted_plan(
    pose: dict[str, np.ndarray],
    psi0: float,
    c0: np.ndarray,
    body: _Body,
    ankles: np.ndarray | None = None,
) -> _Plan:
    """The :class:`_Plan` of sampled key poses (``ankles`` (T, 2, 3) replaces their ankles).
    A knee points where :func:`_assemble` points it by default (its foot's heading plus the
    pelvis's forward), the heading turned by ``knee_out`` and raised by ``swing``."""
    root, g_root, own = _scripted(pose, psi0, c0, body)
    raise_ = pose["swing"][..., None] * _DEG
    ahead = _heading(psi0 + (pose["foot_yaw"] + pose["knee_out"]) * _DEG)
    knees = np.cos(raise_) * ahead + np.sin(raise_) * _Y + (g_root @ _Z)[:, None]
    return _Plan(
        root_xz=root[:, [0, 2]], root_y=root[:, 1], yaw=np.full(len(root), psi0),
        pitch=pose["pitch"] * _DEG, roll=pose["roll"] * _DEG,
        ankles=own if ankles is None else ankles, foot_yaw=psi0 + pose["foot_yaw"] * _DEG,
        foot_pitch=pose["toe"] * _DEG, spine=pose["spine"] * _DEG, neck=pose["neck"] * _DEG,
        arms=pose["arms"] * _DEG, knees=knees,
    )  # fmt: skip


#: Scripted kinds: seconds standing still at the start, and before each movement after the
#: first (at least 1 s, so that a skirt has time to fall back).
_LEAD = (0.3, 0.8)
_STILL = (1.0, 1.8)


def _script_start(rng: Streams, body: _Body) -> tuple[_Script, dict, float, float, np.ndarray]:
    """A scripted clip's start, from stream 0: (the script, standing still for ``_LEAD``
    seconds; the standing pose; lengths' scale for the body, 1 at 1.70 m; heading (rad); floor
    position (2,) of the root)."""
    r0 = rng(0)
    scale = body.height / 1.70
    psi0 = r0.uniform(-np.pi, np.pi)
    c0 = r0.uniform(-0.3, 0.3, 2)
    rest = _standing(r0, body)
    s = _Script(0.0, rest)
    s.wait(r0.uniform(*_LEAD))
    return s, rest, scale, psi0, c0


def _plan_squat(t: np.ndarray, rng: Streams, body: _Body) -> _Plan:
    """Deep wide-legged squats: step out to the ankles 0.6 to 0.8 m apart, toes turned out 30
    to 40 degrees; one to three squats (the root 0.40 to 0.45 m below its height with the feet
    together, the thighs about level, sitting back, the torso leaning, arms forward, the knees
    out towards the toes; held), each followed by standing up and standing still; step back in.
    Lengths for a 1.70 m body."""
    s, rest, scale, psi0, c0 = _script_start(rng, body)
    rs = rng(1)

    def step(f: int, x: float, yaw: float) -> None:
        """Foot ``f`` steps sideways to ``x``, turned out by ``yaw``; the hips lean over the
        other."""
        sx = 1.0 - 2.0 * f
        hold, foot_yaw, lift = s.pose["hold"], s.pose["foot_yaw"], np.zeros(2)
        hold[f, 0], foot_yaw[f], lift[f] = x, yaw, rs.uniform(0.04, 0.07) * scale
        shift = np.array([-sx * rs.uniform(0.02, 0.04) * scale, 0.0])
        s.to(rs.uniform(0.45, 0.6), {"lift": lift, "root": shift}, hold=hold, foot_yaw=foot_yaw)

    while s.end < t[-1] + _MARGIN:
        half = rs.uniform(0.3, 0.4) * scale  # half the distance between the ankles
        out = rs.uniform(30, 40)
        lead = int(rs.integers(2))
        for f in (lead, 1 - lead):
            step(f, (1.0 - 2.0 * f) * half, (1.0 - 2.0 * f) * out)
        s.wait(rs.uniform(0.2, 0.4))
        wide = s.pose
        for _ in range(int(rs.integers(1, 4))):
            lean = rs.uniform(0, 5)
            arm = [rs.uniform(3, 8), rs.uniform(-35, -25), rs.uniform(70, 90), 0.0,
                   rs.uniform(10, 35)]  # fmt: skip
            knee_out = rs.uniform(45, 55)
            s.to(
                rs.uniform(0.9, 1.4), drop=wide["drop"] + rs.uniform(0.40, 0.45) * scale,
                root=[0.0, -rs.uniform(0.08, 0.14) * scale], pitch=lean,
                knee_out=[knee_out, -knee_out], spine=[rs.uniform(10, 25), 0.0, 0.0],
                neck=[-rs.uniform(5, 20), 0.0, 0.0], arms=[arm, arm],
            )  # fmt: skip
            s.wait(rs.uniform(0.3, 0.8))
            s.to(rs.uniform(0.9, 1.4), **wide)
            s.wait(rs.uniform(*_STILL))
        for f in (1 - lead, lead):
            step(f, rest["hold"][f, 0], 0.0)
        s.wait(rs.uniform(*_STILL))
    return _scripted_plan(s.sample(t), psi0, c0, body)


def _plan_kick(t: np.ndarray, rng: Streams, body: _Body) -> _Plan:
    """High front kicks, legs taking turns: the hips shift over the standing foot, the other leg
    swings up in front, the knee bent on the way and nearly straight at the top (the line hip
    to ankle 86 to 98 degrees from straight down, the pelvis leaning back 15 to 22 degrees, the
    foot pointed), comes back down to where it stood; arms out for balance, the arm opposite
    the kicking leg forward. The body then stands still."""
    s, rest, scale, psi0, c0 = _script_start(rng, body)
    rk = rng(1)
    f = int(rk.integers(2))  # the first kicking leg
    # (lift-off, touch-down, leg, swing at the top (deg), hip to ankle at the top (m), how far
    # the ankle comes in under the hip (fraction))
    moves = []
    while s.end < t[-1] + _MARGIN:
        sx = 1.0 - 2.0 * f  # the kicking leg's side
        shifted = s.pose
        shifted["root"] = [rk.uniform(0.75, 0.95) * rest["hold"][1 - f, 0], 0.0]  # over it
        shifted["drop"] = rest["drop"] + rk.uniform(0.01, 0.02) * scale
        front = [rk.uniform(3, 8), rk.uniform(5, 30), rk.uniform(30, 60), 0.0, rk.uniform(30, 60)]
        back = [rk.uniform(3, 8), rk.uniform(15, 40), rk.uniform(-25, 0), 0.0, rk.uniform(15, 40)]
        shifted["arms"] = np.array([back, front] if f == 0 else [front, back])
        s.to(rk.uniform(0.35, 0.5), **shifted)
        t_off = s.end
        top = s.pose
        swing = rk.uniform(86, 98)
        lean = rk.uniform(15, 22)
        top["swing"][f] = swing
        top["toe"][f] = rk.uniform(20, 40) - swing  # pointed, on a leg up in front
        top["pitch"] = -lean
        top["drop"] += rk.uniform(0.01, 0.03) * scale
        top["spine"] = [lean * rk.uniform(0.6, 1.0), 0.0, -sx * rk.uniform(0, 10)]
        top["neck"] = [rk.uniform(0, 10), 0.0, 0.0]
        top["arms"][:, 1] += rk.uniform(5, 15)
        bend = np.zeros(2)
        bend[f] = -rk.uniform(0.06, 0.12) * scale
        s.to(rk.uniform(0.3, 0.45), {"bend": bend}, **top)
        s.wait(rk.uniform(0.05, 0.2))
        bend[f] = -rk.uniform(0.04, 0.1) * scale
        s.to(rk.uniform(0.4, 0.6), {"bend": bend}, **shifted)
        moves.append((t_off, s.end, f, swing, rk.uniform(0.93, 0.96) * body.leg,
                      rk.uniform(0.5, 1.0)))  # fmt: skip
        s.to(rk.uniform(0.35, 0.5), **rest)
        s.wait(rk.uniform(*_STILL))
        f = 1 - f
    pose = s.sample(t)
    root, g_root, ankles = _scripted(pose, psi0, c0, body)
    i = body.skel.index
    hip_offsets = body.skel.offsets[[i("LeftUpLeg"), i("RightUpLeg")]].astype(np.float64)
    hips = root[:, None] + np.einsum("tab,kb->tka", g_root, hip_offsets)
    turn = _yaw(np.array([psi0]))[0]
    swing = pose["swing"] * _DEG
    for t0, t1, f, top, reach, inward in moves:
        during = (t >= t0) & (t <= t1)
        if not during.any():
            continue
        # The ankle in polar coordinates about the moving hip, in the leg's sagittal plane,
        # starting (and ending) where it stood: the leg's angle grows by ``swing``, its length
        # goes to ``reach`` less the knee's bend, the ankle comes in front of the hip.
        root0, g0, ankles0 = _scripted(s.sample(np.array([t0])), psi0, c0, body)
        x, y, z = turn.T @ (ankles0[0, f] - root0[0] - g0[0] @ hip_offsets[f])
        r0, angle0 = np.hypot(y, z), np.arctan2(z, -y)
        k = swing[during, f] / (top * _DEG)
        r = r0 + (reach - r0) * k + pose["bend"][during, f]
        angle = angle0 + swing[during, f]
        local = np.stack([x * (1.0 - inward * k), -r * np.cos(angle), r * np.sin(angle)], -1)
        ankles[during, f] = hips[during, f] + local @ turn.T
    return _scripted_plan(pose, psi0, c0, body, ankles)


def _plan_kneel(t: np.ndarray, rng: Streams, body: _Body) -> _Plan:
    """Going down on one knee and back up, sides taking turns: one foot steps back onto its
    toes (a lunge), the body goes down until that knee rests on the floor (the knee joint
    0.025 to 0.028 body heights up; the knee's radius is 0.03) with the thigh nearly upright, the
    front thigh about level and the back foot's heel up (toes tucked under); held; back up
    to the lunge, and the foot steps back beside the other. The body then stands still."""
    s, rest, scale, psi0, c0 = _script_start(rng, body)
    rk = rng(1)
    skel, i = body.skel, body.skel.index
    thigh = float(np.linalg.norm(skel.offsets[i("LeftLeg")]))
    shin = float(np.linalg.norm(skel.offsets[i("LeftFoot")]))
    side = ("Left", "Right")
    k = int(rk.integers(2))  # the first kneeling leg
    while s.end < t[-1] + _MARGIN:
        # The kneeling pose, from the front foot (it stays) and the floor up: the root behind
        # the front ankle, the back knee on the floor below the back hip (the thigh leaning
        # back), the back shin rising from the knee to the ankle of the foot on its toes.
        pitch = rk.uniform(0, 6)
        g = _euler_yxz(np.zeros(1), np.array([pitch * _DEG]), np.zeros(1))[0]
        off_back = g @ skel.offsets[i(f"{side[k]}UpLeg")].astype(np.float64)
        off_front = g @ skel.offsets[i(f"{side[1 - k]}UpLeg")].astype(np.float64)
        root_z = rest["hold"][1 - k, 1] - rk.uniform(0.25, 0.33) * scale - off_front[2]
        knee_y = rk.uniform(0.025, 0.028) * body.height
        thigh_angle = rk.uniform(3, 12) * _DEG
        knee_z = root_z + off_back[2] - thigh * np.sin(thigh_angle)
        root_y = knee_y + thigh * np.cos(thigh_angle) - off_back[1]
        toes_down = rk.uniform(75, 88)
        ankle = np.array([0.0, body.ankle_y, 0.0]) + _toe_pivot(body, toes_down * _DEG)
        ankle_z = knee_z - np.sqrt(shin**2 - (ankle[1] - knee_y) ** 2)
        hold = s.pose["hold"]
        hold[k] = [off_back[0], ankle_z - ankle[2]]
        # The lunge: the back foot just down on its toes, the root lowered as far as the back
        # leg needs (its ankle 0.92 of a leg from its hip).
        toes_land = rk.uniform(55, 70)
        lunge_z = rk.uniform(0.9, 1.0) * root_z
        land = np.array([0.0, body.ankle_y, hold[k, 1]]) + _toe_pivot(body, toes_land * _DEG)
        dz = lunge_z + off_back[2] - land[2]
        high = land[1] + np.sqrt(max((0.92 * body.leg) ** 2 - dz**2, 0.0)) - off_back[1]
        lunge_drop = max(rest["drop"], body.root_y - high)
        toe = np.zeros(2)
        toe[k] = toes_land
        arm = [rk.uniform(2, 6), rk.uniform(-15, 0), rk.uniform(10, 30), 0.0, rk.uniform(20, 40)]
        lunge = dict(
            root=[0.0, lunge_z], drop=lunge_drop, pitch=0.5 * pitch, hold=hold, toe=toe,
            spine=[rk.uniform(5, 10), 0.0, 0.0], arms=[arm, arm],
        )  # fmt: skip
        lift = np.zeros(2)
        lift[k] = rk.uniform(0.05, 0.08) * scale
        s.to(rk.uniform(0.7, 0.9), {"lift": lift}, **lunge)
        toe = toe.copy()
        toe[k] = toes_down
        arm = [rk.uniform(2, 6), rk.uniform(-30, -20), rk.uniform(20, 45), 0.0, rk.uniform(30, 70)]
        s.to(
            rk.uniform(1.0, 1.5), root=[0.0, root_z], drop=body.root_y - root_y, pitch=pitch,
            toe=toe, spine=[rk.uniform(0, 10), 0.0, 0.0], neck=[rk.uniform(-5, 5), 0.0, 0.0],
            arms=[arm, arm],
        )  # fmt: skip
        s.wait(rk.uniform(0.8, 1.6))
        s.to(rk.uniform(0.9, 1.4), **lunge)
        lift[k] = rk.uniform(0.05, 0.08) * scale
        s.to(rk.uniform(0.7, 0.9), {"lift": lift}, **rest)
        s.wait(rk.uniform(*_STILL))
        k = 1 - k
    return _scripted_plan(s.sample(t), psi0, c0, body)


_PLANNERS = {
    "dance": _plan_dance,
    "twirl": _plan_twirl,
    "walk": lambda t, rng, body: _plan_walk(t, rng, body, circle=False),
    "circle-walk": lambda t, rng, body: _plan_walk(t, rng, body, circle=True),
    "idle": _plan_idle,
    "jump": _plan_jump,
    "broad-jump": lambda t, rng, body: _plan_jump(t, rng, body, "broad-jump"),
    "run": lambda t, rng, body: _plan_walk(t, rng, body, circle=False, gait=_RUN),
    "squat": _plan_squat,
    "kick": _plan_kick,
    "kneel": _plan_kneel,
}
assert tuple(_PLANNERS) == PROCEDURAL_KINDS


# --------------------------------------------------------------------------------------------
# From a plan to joint rotations.


def _euler_yxz(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """``R_y(yaw) @ R_x(pitch) @ R_z(roll)`` for (T,) angles: (T, 3, 3)."""
    return (
        rotation_about_axes(_Y, yaw)
        @ rotation_about_axes(_X, pitch)
        @ rotation_about_axes(_Z, roll)
    )


def _assemble(plan: _Plan, body: _Body, fps: float, name: str, meta: dict) -> Motion:
    skel = body.skel
    i = skel.index
    n = len(plan.yaw)
    local = np.tile(np.eye(3), (n, skel.num_joints, 1, 1))
    g_root = _euler_yxz(plan.yaw, plan.pitch, plan.roll)
    local[:, 0] = g_root
    # Spine and neck: angles shared along the chain. Side bend > 0 leans to the left (+X).
    for joint, share in (("Spine", 0.3), ("Spine1", 0.35), ("Spine2", 0.35)):
        sp = plan.spine * share
        local[:, i(joint)] = _euler_yxz(sp[:, 2], sp[:, 0], -sp[:, 1])
    for joint, share in (("Neck", 0.5), ("Head", 0.5)):
        nk = plan.neck * share
        local[:, i(joint)] = _euler_yxz(nk[:, 2], nk[:, 0], -nk[:, 1])
    # Arms.
    for k, (side, sx) in enumerate((("Left", 1.0), ("Right", -1.0))):
        clav, abd, flex, twist, elbow = np.moveaxis(plan.arms[:, k], -1, 0)
        local[:, i(f"{side}Shoulder")] = rotation_about_axes(sx * _Z, clav)
        d_arm = skel.offsets[i(f"{side}ForeArm")].astype(np.float64)
        d_arm /= np.linalg.norm(d_arm)
        local[:, i(f"{side}Arm")] = (
            rotation_about_axes(-_X, flex)
            @ rotation_about_axes(sx * _Z, abd)
            @ rotation_about_axes(d_arm, sx * twist)
        )
        d_fore = skel.offsets[i(f"{side}Hand")].astype(np.float64)
        d_fore /= np.linalg.norm(d_fore)
        hinge = np.cross(d_fore, _Z)
        local[:, i(f"{side}ForeArm")] = rotation_about_axes(hinge / np.linalg.norm(hinge), elbow)
    # Root height: the plan's, lowered softly where a leg could not reach its ankle target.
    reach = _REACH * body.leg
    limits = [plan.root_y]
    hip_off = {}
    for k, side in enumerate(("Left", "Right")):
        off = g_root @ skel.offsets[i(f"{side}UpLeg")].astype(np.float64)
        hip_off[side] = off
        d = plan.root_xz + off[:, [0, 2]] - plan.ankles[:, k, [0, 2]]
        horiz = np.minimum(np.linalg.norm(d, axis=-1), 0.95 * reach)
        limits.append(plan.ankles[:, k, 1] + np.sqrt(reach**2 - horiz**2) - off[:, 1])
    root_y = _softmin(limits, _SOFT)
    root = np.stack([plan.root_xz[:, 0], root_y, plan.root_xz[:, 1]], -1)
    # Legs: two-bone IK, knee towards the foot's heading (and the pelvis').
    for k, side in enumerate(("Left", "Right")):
        j_up, j_knee, j_foot = i(f"{side}UpLeg"), i(f"{side}Leg"), i(f"{side}Foot")
        l1 = float(np.linalg.norm(skel.offsets[j_knee]))
        l2 = float(np.linalg.norm(skel.offsets[j_foot]))
        hip = root + hip_off[side]
        to_ankle = plan.ankles[:, k] - hip
        dist = np.linalg.norm(to_ankle, axis=-1)
        e = to_ankle / np.maximum(dist, 1e-9)[:, None]
        dist = np.clip(dist, abs(l1 - l2) + 1e-6, (l1 + l2) * (1 - 1e-6))
        if plan.knees is None:
            pole = _heading(plan.foot_yaw[:, k]) + g_root @ _Z
        else:
            pole = plan.knees[:, k]
        pole = pole - np.sum(pole * e, -1, keepdims=True) * e
        pole /= np.maximum(np.linalg.norm(pole, axis=-1), 1e-9)[:, None]
        cos_a = np.clip((l1 * l1 + dist * dist - l2 * l2) / (2 * l1 * dist), -1.0, 1.0)
        sin_a = np.sqrt(1.0 - cos_a * cos_a)
        knee = hip + l1 * (cos_a[:, None] * e + sin_a[:, None] * pole)
        ankle = hip + dist[:, None] * e
        d1 = (knee - hip) / l1
        d1_rest = skel.offsets[j_knee] / l1
        bend_rest = -_Z - np.dot(-_Z, d1_rest) * d1_rest
        bend_rest /= np.linalg.norm(bend_rest)
        sw = swing_rotation(g_root @ d1_rest, d1, g_root @ np.cross(d1_rest, bend_rest)) @ g_root
        g_up = twist_towards(sw, d1, bend_rest, -pole, limb=False)
        d2 = (ankle - knee) / l2
        d2_rest = skel.offsets[j_foot] / l2
        g_knee = swing_rotation(g_up @ d2_rest, d2, g_up @ np.cross(d1_rest, bend_rest)) @ g_up
        g_foot = _euler_yxz(plan.foot_yaw[:, k], plan.foot_pitch[:, k], np.zeros(n))
        local[:, j_up] = np.einsum("tji,tjk->tik", g_root, g_up)
        local[:, j_knee] = np.einsum("tji,tjk->tik", g_up, g_knee)
        local[:, j_foot] = np.einsum("tji,tjk->tik", g_knee, g_foot)
    return Motion(
        skeleton=skel,
        rotations=local.astype(np.float32),
        root_positions=root.astype(np.float32),
        fps=float(fps),
        name=name,
        meta=meta,
    )


def make_motion(
    kind: str, frames: int, fps: float, seed: int, shape: BodyShape = DEFAULT_SHAPE
) -> Motion:
    """A procedural clip on the mannequin of ``shape``.

    Parameters
    ----------
    kind : one of :data:`PROCEDURAL_KINDS`
        ``dance`` (steps, hip sway, spins, big arm swings: the default training motion),
        ``twirl`` (continuous spins in place, arms out), ``walk`` (straight), ``circle-walk``,
        ``idle`` (gentle sway, weight shifts), ``jump`` (crouch, take-off, flight, landing),
        ``broad-jump`` (standing long jumps), ``run`` (a straight jog to run, 2.5 to 3.4 m/s,
        with a flight between steps), ``squat`` (deep wide-legged squats), ``kick`` (high front
        kicks), ``kneel`` (down on one knee and up, sides taking turns); the last three start
        standing still and stand still at least 1 s between movements.
    frames : number of frames (>= 1)
    fps : frames per second (> 0); frame i is at time i / fps seconds
    seed : non-negative integer; the same seed gives the same motion at any fps and length
    shape : the body

    Returns
    -------
    Motion
        On ``mannequin_skeleton(shape)`` (joint order ``MANNEQUIN_JOINTS``): rotations
        (frames, 20, 3, 3) float32, root positions (frames, 3) float32. ``name`` is the kind;
        ``meta`` holds ``kind`` and ``seed``.

    Raises
    ------
    InputError
        Unknown kind (the message lists the kinds), frames < 1, fps <= 0, bad seed.
    """
    if kind not in PROCEDURAL_KINDS:
        raise InputError(
            f"unknown procedural motion {kind!r}: choose one of {', '.join(PROCEDURAL_KINDS)}"
        )
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
        raise InputError(f"frames must be an integer >= 1, got {frames!r}")
    if (
        isinstance(fps, bool)
        or not isinstance(fps, (int, float, np.number))
        or not (np.isfinite(fps) and fps > 0)
    ):
        raise InputError(f"fps must be a positive number, got {fps!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    kind_id = PROCEDURAL_KINDS.index(kind)

    def streams(stream: int) -> np.random.Generator:
        return np.random.default_rng([int(seed), kind_id, stream])

    body = _Body.of(shape)
    t = np.arange(int(frames), dtype=np.float64) / float(fps)
    plan = _PLANNERS[kind](t, streams, body)
    meta = {"kind": kind, "seed": int(seed), "source": "procedural"}
    return _assemble(plan, body, fps, kind, meta)
