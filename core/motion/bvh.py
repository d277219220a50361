"""BVH reading and writing, in the file's own units and axes.

Reading gives a :class:`BvhClip` (the hierarchy and the raw channel values, exactly as written)
and :func:`clip_to_motion` turns it into a :class:`~core.motion.motion.Motion` in file units.
Normalising units and up axis and mapping onto the canonical skeleton happen in
:mod:`core.motion.load`.

Conventions handled here:

- Euler channels compose in the listed order, intrinsically: ``CHANNELS 3 Zrotation Xrotation
  Yrotation`` means ``R = Rz @ Rx @ Ry``. Angles are in degrees.
- Position channels, on the root or on any other joint, give the joint's local translation and
  replace the ``OFFSET`` on the axes they cover (Blender's and 3ds Max's reading). On the root they
  are the world position. On other joints a :class:`Motion` has no per-frame translation, so a
  constant channel becomes the offset and a varying one is replaced by its mean over the clip; the
  affected joints and the largest deviation from the mean (file units) are recorded in
  ``meta["varying_translations"]`` so nobody mistakes the result for exact.
- A wrapper above the skeleton (glTF's ``GLTF_created_0_rootJoint``, Blender's ``Armature``, FBX's
  ``RootNode``, Biped's ``Bip001``): when the root and the joints below it have one child each and
  one of them carries varying position channels (the hips, typically), the joints above it are
  folded into it, their static or animated transform composed with its own, so that it becomes the
  root and keeps its exact path. Only joints that no convention names as a body joint are folded
  (:func:`core.motion.mapping.is_body_joint`); their names go to ``meta["wrapper_joints"]``.
- Keywords are case-insensitive; CRLF line ends, tabs, blank lines and a UTF-8 BOM are fine; joint
  names may contain spaces (``Bip001 L Thigh``).
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass

import numpy as np

from core.errors import InputError
from core.fileio import atomic_open, read_input_bytes
from core.motion.mapping import is_body_joint
from core.motion.motion import Motion
from core.skeleton import Skeleton

#: Channel names a BVH file may use, in their canonical spelling.
CHANNEL_NAMES: tuple[str, ...] = (
    "Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation",
)  # fmt: skip
_CHANNEL_LOOKUP = {c.lower(): c for c in CHANNEL_NAMES}
#: Rotation orders the writer accepts (the common exporters' two).
WRITE_ORDERS: tuple[str, ...] = ("ZXY", "XYZ")
#: A non-root position channel whose values stay within this fraction of the skeleton's size
#: of each other is treated as constant.
_CONSTANT_TRANSLATION_REL = 1e-5
#: Frame rates within this relative distance of a whole number are snapped to it
#: (``Frame Time: .0083333`` is 120 fps).
_FPS_SNAP_REL = 2e-4


@dataclass(frozen=True)
class BvhClip:
    """A BVH file as written: hierarchy and raw channel values, file units and axes.

    Attributes
    ----------
    names : tuple of J str
        Joint names in file order (parents first); joint 0 is the root.
    parents : (J,) int64
        Parent index per joint, -1 for the root.
    offsets : (J, 3) float64
        ``OFFSET`` of each joint in its parent's frame, file units.
    end_sites : (J, 3) float64
        ``End Site`` offset per joint, zeros where it has none.
    has_end_site : (J,) bool
    channels : tuple of J tuples of str
        Each joint's channels in file order, canonical spelling (``"Zrotation"``).
    frame_time : float
        Seconds per frame.
    values : (T, C) float64
        Channel values per frame, C the total channel count; degrees for rotations.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    end_sites: np.ndarray
    has_end_site: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    frame_time: float
    values: np.ndarray

    @property
    def num_frames(self) -> int:
        return len(self.values)

    @property
    def fps(self) -> float:
        fps = 1.0 / self.frame_time
        nearest = round(fps)
        return float(nearest) if abs(fps - nearest) <= _FPS_SNAP_REL * fps else fps

    def channel_slices(self) -> list[slice]:
        """Columns of :attr:`values` belonging to each joint."""
        out, start = [], 0
        for ch in self.channels:
            out.append(slice(start, start + len(ch)))
            start += len(ch)
        return out


# ----------------------------------------------------------------------------------- reading


def read_bvh(path: str | os.PathLike) -> BvhClip:
    """Parse a BVH file.

    Raises
    ------
    InputError
        Missing, empty, malformed or truncated file, naming the file and, where it helps, the
        line: unbalanced braces, unknown channel names, a ``CHANNELS`` count that disagrees with
        the names, zero frames, fewer frame lines than ``Frames:`` says, a frame line with the
        wrong number of values, values that are not finite numbers. Lines after the declared
        number of frames are ignored.
    """
    path = os.fspath(path)
    raw = read_input_bytes(path, "a BVH file")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    lines = text.splitlines()
    return _parse(lines, path)


def _parse(lines: list[str], path: str) -> BvhClip:
    n = len(lines)
    i = 0

    def err(problem: str, line: int | None = None) -> InputError:
        return InputError(problem if line is None else f"line {line + 1}: {problem}", path)

    def next_content(k: int) -> int:
        while k < n and not lines[k].strip():
            k += 1
        return k

    i = next_content(0)
    if lines[i].strip().upper() != "HIERARCHY":
        raise err("not a BVH file: expected 'HIERARCHY' first", i)
    i += 1

    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    end_sites: list[list[float]] = []
    has_end: list[bool] = []
    # Stack entries: joint index, or -2 for an End Site block.
    stack: list[int] = []
    pending: int | None = None  # a ROOT/JOINT/End Site line waiting for its "{"
    current = -1  # the block whose OFFSET/CHANNELS come next
    seen_root = False

    def parse_floats(tokens: list[str], count: int, what: str, line: int) -> list[float]:
        if len(tokens) != count:
            raise err(f"{what} needs {count} numbers, got {len(tokens)}", line)
        try:
            vals = [float(t) for t in tokens]
        except ValueError:
            raise err(
                f"{what} has a value that is not a number: {' '.join(tokens)}", line
            ) from None
        if not all(math.isfinite(v) for v in vals):
            raise err(f"{what} has a value that is not finite: {' '.join(tokens)}", line)
        return vals

    while True:
        i = next_content(i)
        if i >= n:
            if stack or pending is not None or not seen_root:
                raise err("unbalanced braces: the hierarchy is not closed before the end of file")
            raise err("no MOTION section")
        ln = i
        i += 1
        stripped = lines[ln].strip()
        tokens = stripped.split()
        key = tokens[0].upper()
        if key in ("ROOT", "JOINT"):
            if pending is not None:
                raise err("expected '{' after the joint name", ln)
            if key == "ROOT":
                if seen_root:
                    raise err("more than one ROOT: only single-skeleton files are supported", ln)
                if stack:
                    raise err("ROOT inside another joint", ln)
            elif not stack or stack[-1] < 0:
                raise err("JOINT outside a joint block (unbalanced braces?)", ln)
            name = stripped[len(tokens[0]) :].strip()
            opens = name.endswith("{")
            name = name.rstrip("{").strip()
            if not name:
                raise err(f"{tokens[0]} without a name", ln)
            if name in names:
                raise err(f"joint name {name!r} appears twice", ln)
            seen_root = True
            names.append(name)
            parents.append(stack[-1] if stack else -1)
            offsets.append([0.0, 0.0, 0.0])
            channels.append(())
            end_sites.append([0.0, 0.0, 0.0])
            has_end.append(False)
            pending = len(names) - 1
            if opens:
                stack.append(pending)
                current, pending = stack[-1], None
        elif key == "END":
            if pending is not None:
                raise err("expected '{' after the joint name", ln)
            if not stack or stack[-1] < 0:
                raise err("End Site outside a joint block", ln)
            has_end[stack[-1]] = True
            pending = -2
            if stripped.endswith("{"):
                stack.append(-2)
                current, pending = -2, None
        elif stripped == "{":
            if pending is None:
                raise err("unbalanced braces: '{' without a joint", ln)
            stack.append(pending)
            current, pending = pending, None
        elif stripped == "}":
            if pending is not None:
                raise err("expected '{' after the joint name", ln)
            if not stack:
                raise err("unbalanced braces: '}' without a matching '{'", ln)
            stack.pop()
            current = stack[-1] if stack else -1
            if not stack:
                break
        elif key == "OFFSET":
            vals = parse_floats(tokens[1:], 3, "OFFSET", ln)
            if current == -2:
                end_sites[stack[-2]] = vals
            elif current >= 0:
                offsets[current] = vals
            else:
                raise err("OFFSET outside a joint block", ln)
        elif key == "CHANNELS":
            if current < 0:
                raise err("CHANNELS outside a joint block", ln)
            try:
                count = int(tokens[1])
            except (IndexError, ValueError):
                raise err("CHANNELS needs a count", ln) from None
            chans = tokens[2:]
            if len(chans) != count:
                raise err(f"CHANNELS says {count} but names {len(chans)}", ln)
            spelled = []
            for c in chans:
                if c.lower() not in _CHANNEL_LOOKUP:
                    raise err(f"unknown channel name {c!r}", ln)
                spelled.append(_CHANNEL_LOOKUP[c.lower()])
            if len(set(spelled)) != len(spelled):
                raise err(f"repeated channel in {' '.join(chans)}", ln)
            channels[current] = tuple(spelled)
        elif key == "MOTION":
            raise err("unbalanced braces: MOTION before the hierarchy is closed", ln)
        else:
            raise err(f"unexpected {tokens[0]!r} in the hierarchy", ln)

    # ---- MOTION section
    i = next_content(i)
    if i >= n or lines[i].strip().upper() != "MOTION":
        if i < n and lines[i].strip() == "}":
            raise err("unbalanced braces: '}' without a matching '{'", i)
        raise err("expected 'MOTION' after the hierarchy", min(i, n - 1))
    i = next_content(i + 1)
    frames = _header_value(lines, i, "frames", path)
    try:
        num_frames = int(frames)
    except ValueError:
        raise err(f"'Frames:' is not a whole number: {frames!r}", i) from None
    if num_frames <= 0:
        raise err(f"no frames ('Frames: {num_frames}')", i)
    i = next_content(i + 1)
    ft = _header_value(lines, i, "frame time", path)
    try:
        frame_time = float(ft)
    except ValueError:
        raise err(f"'Frame Time:' is not a number: {ft!r}", i) from None
    if not (math.isfinite(frame_time) and frame_time > 0):
        raise err(f"'Frame Time:' must be positive, got {ft}", i)
    i += 1

    num_channels = sum(len(c) for c in channels)
    rows: list[str] = []
    row_lines: list[int] = []
    while i < n and len(rows) < num_frames:
        if lines[i].strip():
            rows.append(lines[i])
            row_lines.append(i)
        i += 1
    if len(rows) < num_frames:
        raise err(f"truncated: 'Frames: {num_frames}' but only {len(rows)} frame lines")
    if num_channels == 0:
        raise err("no joint has channels")
    values = np.empty((num_frames, num_channels), np.float64)
    for r, (row, ln) in enumerate(zip(rows, row_lines)):
        toks = row.split()
        if len(toks) != num_channels:
            raise err(
                f"frame {r + 1} has {len(toks)} values, the hierarchy has {num_channels} channels",
                ln,
            )
        try:
            values[r] = [float(t) for t in toks]
        except ValueError:
            raise err(f"frame {r + 1} has a value that is not a number", ln) from None
    bad = ~np.isfinite(values)
    if bad.any():
        r = int(np.argmax(bad.any(axis=1)))
        raise err(f"frame {r + 1} has a value that is not finite (NaN or inf)", row_lines[r])
    return BvhClip(
        names=tuple(names),
        parents=np.asarray(parents, np.int64),
        offsets=np.asarray(offsets, np.float64).reshape(-1, 3),
        end_sites=np.asarray(end_sites, np.float64).reshape(-1, 3),
        has_end_site=np.asarray(has_end, bool),
        channels=tuple(channels),
        frame_time=frame_time,
        values=values,
    )


def _header_value(lines: list[str], i: int, key: str, path: str) -> str:
    if i >= len(lines):
        raise InputError(f"truncated: missing '{key.title()}:' line", path)
    line = lines[i].strip()
    head, sep, value = line.partition(":")
    if not sep or " ".join(head.lower().split()) != key:
        raise InputError(f"line {i + 1}: expected '{key.title()}:', got {line[:40]!r}", path)
    return value.strip()


# ------------------------------------------------------------------------------ to a Motion


def euler_to_matrix(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """Intrinsic Euler angles to matrices: ``R = R_order[0] @ R_order[1] @ ...``.

    Parameters
    ----------
    angles_deg : (T, K) float
        One column per axis in ``order`` (K = len(order), 0 to 3), degrees.
    order : str
        Axis letters, e.g. ``"ZXY"``.

    Returns
    -------
    (T, 3, 3) float64
    """
    angles = np.radians(np.asarray(angles_deg, np.float64))
    t = len(angles)
    out = np.broadcast_to(np.eye(3), (t, 3, 3)).copy()
    for k, axis in enumerate(order.upper()):
        c, s = np.cos(angles[:, k]), np.sin(angles[:, k])
        m = np.zeros((t, 3, 3))
        a = "XYZ".index(axis)
        b, d = (a + 1) % 3, (a + 2) % 3
        m[:, a, a] = 1.0
        m[:, b, b] = c
        m[:, d, d] = c
        m[:, b, d] = -s
        m[:, d, b] = s
        out = out @ m
    return out


def matrix_to_euler(rotations: np.ndarray, order: str) -> np.ndarray:
    """Inverse of :func:`euler_to_matrix` for three axes: (T, 3, 3) -> (T, 3) float64 degrees."""
    from scipy.spatial.transform import Rotation

    with warnings.catch_warnings():  # gimbal lock: the angles still reproduce the matrix
        warnings.simplefilter("ignore", UserWarning)
        return Rotation.from_matrix(np.asarray(rotations, np.float64)).as_euler(
            order.upper(), degrees=True
        )


def clip_to_motion(clip: BvhClip, name: str = "", path: str | None = None) -> Motion:
    """The clip as a :class:`Motion` in file units and axes (no normalisation, no mapping).

    A wrapper above the skeleton is folded into the joint below it that moves (see the module
    docstring); every other joint keeps its place. ``meta`` gets ``source_joints`` (the joints
    kept), ``channels`` (per joint, as written), ``wrapper_joints`` (folded, possibly empty) and,
    where non-root position channels vary, ``varying_translations`` ({joint: largest deviation
    in file units}).
    """
    j = len(clip.names)
    t = clip.num_frames
    rotations = np.empty((t, j, 3, 3), np.float64)
    translations = np.broadcast_to(clip.offsets, (t, j, 3)).copy()  # local, per frame
    has_position = np.zeros((j, 3), bool)
    for k, (chans, cols) in enumerate(zip(clip.channels, clip.channel_slices())):
        vals = clip.values[:, cols]
        rot_cols = [c for c, ch in enumerate(chans) if ch.endswith("rotation")]
        order = "".join(chans[c][0] for c in rot_cols)
        rotations[:, k] = euler_to_matrix(vals[:, rot_cols], order)
        for c, ch in enumerate(chans):
            if ch.endswith("position"):
                axis = "XYZ".index(ch[0])
                translations[:, k, axis] = vals[:, c]
                has_position[k, axis] = True
    size = max(float(np.abs(clip.offsets).sum()), 1e-9)
    mean = translations.mean(axis=0)
    deviation = np.abs(translations - mean).max(axis=(0, 2))
    varying = deviation > _CONSTANT_TRANSLATION_REL * size
    offsets = clip.offsets.copy()
    offsets[has_position] = mean[has_position]  # a constant channel is the offset, else its mean
    end_sites = clip.end_sites.copy()
    root_index = len(_wrapper_chain(clip, varying))
    if root_index:
        # The wrappers' world transform (w_pos, w_rot) moves the new root; the skeleton below is
        # expressed in the wrappers' first-frame axes c, so the rest pose is the file's world
        # (a Y-up to Z-up wrapper gives a Z-up rest pose): offsets c @ o, rotations c R c^T, and
        # the root's rotation w_rot R c^T. Forward kinematics then gives the file's world exactly.
        w_pos, w_rot = translations[:, 0], rotations[:, 0]
        for k in range(1, root_index):
            w_pos = w_pos + np.einsum("tab,tb->ta", w_rot, translations[:, k])
            w_rot = w_rot @ rotations[:, k]
        c = w_rot[0]
        translations[:, root_index] = w_pos + np.einsum(
            "tab,tb->ta", w_rot, translations[:, root_index]
        )
        rotations[:, root_index] = w_rot @ rotations[:, root_index] @ c.T
        rotations[:, root_index + 1 :] = c @ rotations[:, root_index + 1 :] @ c.T
        offsets, end_sites = offsets @ c.T, end_sites @ c.T
    keep = np.arange(root_index, j)
    root = translations[:, root_index].copy()
    offsets[root_index] = root[0]
    names = clip.names[root_index:]
    skeleton = Skeleton(
        names=names,
        parents=np.where(clip.parents[keep] >= root_index, clip.parents[keep] - root_index, -1),
        offsets=offsets[keep].astype(np.float32),
        end_sites=end_sites[keep].astype(np.float32),
    )
    meta: dict = {
        "source_joints": list(names),
        "channels": {n: list(c) for n, c in zip(names, clip.channels[root_index:])},
        "wrapper_joints": list(clip.names[:root_index]),
    }
    moved = {clip.names[k]: float(deviation[k]) for k in keep[1:] if varying[k]}
    if moved:
        meta["varying_translations"] = moved
    if path is not None:
        meta["path"] = str(path)
    return Motion(
        skeleton=skeleton,
        rotations=rotations[:, keep].astype(np.float32),
        root_positions=root.astype(np.float32),
        fps=clip.fps,
        name=name,
        meta=meta,
    )


def _wrapper_chain(clip: BvhClip, varying: np.ndarray) -> tuple[str, ...]:
    """The wrapper joints to fold (see the module docstring): the root and the joints below it,
    each with one child, down to the deepest joint on that chain with a varying translation
    (``varying`` (J,) bool), when none of them is a body joint; else ``()``. In file order, so
    the joints kept are ``clip.names[len(result):]``."""
    children = np.bincount(clip.parents[1:], minlength=len(clip.names))
    chain = [0]
    while children[chain[-1]] == 1:
        # File order lists a joint's subtree right after it: the one child is the next joint.
        chain.append(chain[-1] + 1)
    moving = [k for k in chain[1:] if varying[k]]
    if not moving:
        return ()
    above = clip.names[: moving[-1]]
    return () if any(is_body_joint(n) for n in above) else above


# ----------------------------------------------------------------------------------- writing


def format_bvh(motion: Motion, order: str = "ZXY") -> str:
    """The BVH text for ``motion``: 6 channels on the root, 3 rotation channels elsewhere.

    The root's ``OFFSET`` is its rest position and its position channels its world position per
    frame. Every leaf joint gets an ``End Site`` (its end-site offset, zeros if it has none); BVH
    allows ``End Site`` only on leaves, so a non-leaf joint's end site is not written. Units and
    axes are the motion's own (metres, Y up for every normalised motion).
    """
    order = order.upper()
    if order not in WRITE_ORDERS:
        raise ValueError(f"rotation order must be one of {WRITE_ORDERS}, got {order!r}")
    sk = motion.skeleton
    rot_channels = " ".join(f"{a}rotation" for a in order)
    children = [sk.children(k) for k in range(sk.num_joints)]
    out: list[str] = ["HIERARCHY"]

    def vec(v: np.ndarray) -> str:
        return " ".join(f"{float(x):.6f}" for x in v)

    def emit(k: int, depth: int) -> None:
        pad = "\t" * depth
        kw = "ROOT" if k == 0 else "JOINT"
        out.append(f"{pad}{kw} {sk.names[k]}")
        out.append(f"{pad}{{")
        out.append(f"{pad}\tOFFSET {vec(sk.offsets[k])}")
        if k == 0:
            out.append(f"{pad}\tCHANNELS 6 Xposition Yposition Zposition {rot_channels}")
        else:
            out.append(f"{pad}\tCHANNELS 3 {rot_channels}")
        for c in children[k]:
            emit(c, depth + 1)
        if not children[k]:
            out.append(f"{pad}\tEnd Site")
            out.append(f"{pad}\t{{")
            out.append(f"{pad}\t\tOFFSET {vec(sk.end_sites[k])}")
            out.append(f"{pad}\t}}")
        out.append(f"{pad}}}")

    emit(0, 0)
    t, j = motion.num_frames, sk.num_joints
    angles = matrix_to_euler(motion.rotations.reshape(t * j, 3, 3), order).reshape(t, j * 3)
    frames = np.concatenate([motion.root_positions.astype(np.float64), angles], axis=1)
    out.append("MOTION")
    out.append(f"Frames: {t}")
    out.append(f"Frame Time: {1.0 / motion.fps:.8f}")
    out.extend(" ".join(f"{x:.6f}" for x in row) for row in frames)
    return "\n".join(out) + "\n"


def write_bvh(path: str | os.PathLike, motion: Motion, order: str = "ZXY") -> None:
    """Write ``motion`` as BVH (see :func:`format_bvh`), atomically."""
    text = format_bvh(motion, order)
    with atomic_open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write(text)
