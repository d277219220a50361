"""Skeleton animation from a skinned glTF 2.0 file (``.gltf`` or ``.glb``) as a :class:`Motion`.

Mixamo and Blender export characters this way. glTF is metres, Y up, right-handed, so the
result needs no unit or axis detection; :func:`core.motion.load.load_motion` maps its joints
onto the canonical skeleton exactly as it does a BVH file's.

What is read
------------
- The skin with the most joints; its joints are the motion's joints. A joint's parent is its
  nearest ancestor node among the joints; when the joints have several roots, their lowest
  common ancestor node (the armature) becomes the root joint.
- The animation that drives the most of those joints (``animation`` picks another by index or
  name). ``translation``/``rotation``/``scale`` channels with ``LINEAR``, ``STEP`` or
  ``CUBICSPLINE`` samplers; ``weights`` (morph targets) are ignored.
- Every node's rest TRS (or ``matrix``), including the non-joint ancestors of the skeleton
  (an armature node's scale or rotation applies to the whole motion).

How it becomes a :class:`Motion`
--------------------------------
The animation is sampled at ``fps`` (default: its keyframe rate, or 30 when it has none
usable) from its first key to its last, and every joint's world transform is evaluated.
The rest pose is the nodes' rest TRS: offsets are the rest world joint positions relative to
the parent joint, in world axes (a Motion's rest rotations are identities). A joint's world
rotation per frame is ``polar(A(t)) @ polar(A_rest).T`` (``A`` the linear part of its world
transform, ``polar`` its nearest rotation), so forward kinematics reproduces every world joint
position exactly when joints other than the root keep their rest translation and scale over
the clip. Where they do not (animated bone lengths, varying scale), the positions are as close
as a rigid skeleton allows and ``meta["varying_translations"]`` names the joints and the largest
error in metres, as the BVH reader does for varying position channels.
"""

from __future__ import annotations

import base64
import binascii
import json
import math
import os
import struct
import urllib.parse
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

from core.errors import InputError
from core.fileio import read_input_bytes
from core.motion.motion import Motion
from core.skeleton import Skeleton, forward_kinematics

if TYPE_CHECKING:
    from pygltflib import GLTF2

#: File name suffixes read as glTF.
GLTF_SUFFIXES: tuple[str, ...] = (".gltf", ".glb")
#: Frame rate when the animation has no usable keyframe rate (a single key, sparse keys).
DEFAULT_FPS = 30.0
#: Keyframe rates (fps) believed as the animation's frame rate; others give :data:`DEFAULT_FPS`.
KEYFRAME_FPS_RANGE = (10.0, 240.0)
#: Keyframe rates within this relative distance of a whole number are snapped to it
#: (float32 key times make 1/30 s steps come out as 29.99998 fps).
_FPS_SNAP_REL = 1e-3
#: Longest clip read, in frames (memory: a 4x4 transform per node and frame).
MAX_FRAMES = 100_000
#: A sample time this close (relative) below a key counts as on it (STEP samplers).
_KEY_TIME_REL = 1e-6
#: A joint whose FK position misses its glTF world position by more than this fraction of the
#: skeleton's size is reported in ``meta["varying_translations"]``.
_VARYING_REL = 1e-5

_GLB_MAGIC = b"glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942
_COMPONENT_DTYPES = {
    5120: np.dtype("<i1"), 5121: np.dtype("<u1"), 5122: np.dtype("<i2"),
    5123: np.dtype("<u2"), 5125: np.dtype("<u4"), 5126: np.dtype("<f4"),
}  # fmt: skip
_NORMALIZED_DIVISOR = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0}
_TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_PATH_SIZES = {"translation": 3, "rotation": 4, "scale": 3}
_INTERPOLATIONS = ("LINEAR", "STEP", "CUBICSPLINE")


@dataclass(frozen=True)
class GltfFile:
    """A parsed glTF document and its buffers' bytes.

    Attributes
    ----------
    doc : pygltflib.GLTF2
        The JSON structure.
    buffers : tuple of bytes
        The data of every buffer, in ``doc.buffers`` order (checked to hold ``byteLength``).
    path : str
        The file, for error messages.
    """

    doc: GLTF2
    buffers: tuple[bytes, ...]
    path: str


# ----------------------------------------------------------------------------------- reading


def read_gltf(path: str | os.PathLike) -> GltfFile:
    """Parse a ``.gltf`` (JSON, with data-URI or external buffers) or ``.glb`` file.

    Raises
    ------
    InputError
        Missing or unreadable file, not glTF (no GLB signature, invalid JSON, no ``asset``),
        a glTF version other than 2, a truncated GLB, a buffer that is missing or shorter than
        its ``byteLength``.
    """
    path = os.fspath(path)
    raw = read_input_bytes(path, "a glTF file")
    blob = None
    if raw[:4] == _GLB_MAGIC:
        text, blob = _split_glb(raw, path)
    elif Path(path).suffix.lower() == ".glb":
        raise InputError("not a GLB file: no 'glTF' signature", path)
    else:
        try:
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError:
            raise InputError("not a glTF file: neither GLB nor UTF-8 JSON", path) from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(
            f"not a glTF file: invalid JSON ({exc.msg}, line {exc.lineno})", path
        ) from None
    if not isinstance(data, dict) or not isinstance(data.get("asset"), dict):
        raise InputError("not a glTF file: no 'asset' object", path)
    version = str(data["asset"].get("version", ""))
    if not version.startswith("2."):
        raise InputError(f"glTF version {version or '?'} is not supported (2.x only)", path)
    from pygltflib import GLTF2  # ~70 ms: only glTF files pay for it

    try:
        doc = GLTF2.from_json(json.dumps(data), infer_missing=True)
    except Exception as exc:  # the dataclass decoder raises assorted errors on odd values
        raise InputError(f"malformed glTF ({type(exc).__name__}: {exc})", path) from None
    buffers = []
    for i, buf in enumerate(doc.buffers or []):
        buffers.append(_buffer_bytes(i, buf, blob, path))
    return GltfFile(doc=doc, buffers=tuple(buffers), path=path)


def _split_glb(raw: bytes, path: str) -> tuple[str, bytes | None]:
    """The JSON text and the BIN chunk of a GLB, checking every length against the file."""
    if len(raw) < 12:
        raise InputError(f"truncated GLB: {len(raw)} bytes, shorter than its 12-byte header", path)
    _magic, version, length = struct.unpack_from("<4sII", raw)
    if version != 2:
        raise InputError(f"GLB version {version} is not supported (2 only)", path)
    if length > len(raw):
        raise InputError(f"truncated GLB: header says {length} bytes, file has {len(raw)}", path)
    text, blob, at = None, None, 12
    while at < length:
        if at + 8 > length:
            raise InputError(f"truncated GLB: chunk header at byte {at} runs past the end", path)
        size, kind = struct.unpack_from("<II", raw, at)
        if at + 8 + size > length:
            raise InputError(
                f"truncated GLB: chunk at byte {at} says {size} bytes, "
                f"only {length - at - 8} remain",
                path,
            )
        body = raw[at + 8 : at + 8 + size]
        if kind == _CHUNK_JSON and text is None:
            try:
                text = body.decode("utf-8")
            except UnicodeDecodeError:
                raise InputError("GLB JSON chunk is not UTF-8", path) from None
        elif kind == _CHUNK_BIN and blob is None:
            blob = body
        at += 8 + size
    if text is None:
        raise InputError("GLB has no JSON chunk", path)
    return text, blob


def _buffer_bytes(i: int, buf, blob: bytes | None, path: str) -> bytes:
    uri = buf.uri
    if uri is None:
        if i != 0 or blob is None:
            raise InputError(f"buffer {i} has no uri and no GLB binary chunk", path)
        data = blob
    elif uri.startswith("data:"):
        head, sep, payload = uri.partition(",")
        if not sep or not head.endswith(";base64"):
            raise InputError(f"buffer {i}: only base64 data URIs are supported", path)
        try:
            data = base64.b64decode(payload, validate=True)
        except (binascii.Error, ValueError):
            raise InputError(f"buffer {i}: data URI is not valid base64", path) from None
    else:
        file = Path(path).parent / urllib.parse.unquote(uri)
        try:
            data = file.read_bytes()
        except OSError:
            raise InputError(f"buffer {i}: cannot read its file {uri!r}", path) from None
    length = buf.byteLength
    if not isinstance(length, int) or length < 0:
        raise InputError(f"buffer {i} has no valid byteLength", path)
    if len(data) < length:
        raise InputError(
            f"buffer {i} is truncated: {len(data)} bytes, byteLength says {length}", path
        )
    return data[:length]


def read_accessor(gltf: GltfFile, index) -> np.ndarray:
    """An accessor's elements as (count, n) float64 (n = 1, 2, 3, 4 or 16; normalised integers
    divided as the spec says).

    Raises
    ------
    InputError
        A missing accessor, buffer view or buffer, an unknown component type or element type,
        a sparse accessor, or elements that lie outside their buffer view or buffer.
    """
    doc, path = gltf.doc, gltf.path
    acc = _item(doc.accessors, index, "accessor", path)
    what = f"accessor {index}"
    if acc.sparse is not None:
        raise InputError(f"{what} is sparse: sparse accessors are not supported", path)
    if acc.componentType not in _COMPONENT_DTYPES:
        raise InputError(f"{what} has unknown componentType {acc.componentType}", path)
    if acc.type not in _TYPE_SIZES:
        raise InputError(f"{what} has unsupported type {acc.type!r}", path)
    count = acc.count
    if not isinstance(count, int) or count < 1:
        raise InputError(f"{what} has count {count!r}", path)
    n = _TYPE_SIZES[acc.type]
    dtype = _COMPONENT_DTYPES[acc.componentType]
    if acc.bufferView is None:
        return np.zeros((count, n))
    view = _item(doc.bufferViews, acc.bufferView, "buffer view", path)
    data = _item(gltf.buffers, view.buffer, "buffer", path)
    elem = dtype.itemsize * n
    stride = view.byteStride or elem
    v_off, v_len, a_off = view.byteOffset or 0, view.byteLength, acc.byteOffset or 0
    if not isinstance(v_len, int) or v_off < 0 or v_len < 0 or v_off + v_len > len(data):
        raise InputError(
            f"buffer view {acc.bufferView} (bytes {v_off}+{v_len}) lies outside buffer "
            f"{view.buffer} ({len(data)} bytes)",
            path,
        )
    need = a_off + stride * (count - 1) + elem
    if a_off < 0 or stride < elem or need > v_len:
        raise InputError(
            f"{what} out of range: {count} x {acc.type} needs {need} bytes of buffer view "
            f"{acc.bufferView}, which has {v_len}",
            path,
        )
    arr = np.ndarray(
        (count, n), dtype=dtype, buffer=data, offset=v_off + a_off, strides=(stride, dtype.itemsize)
    ).astype(np.float64)
    if acc.normalized and acc.componentType in _NORMALIZED_DIVISOR:
        arr = np.maximum(arr / _NORMALIZED_DIVISOR[acc.componentType], -1.0)
    if not np.isfinite(arr).all():
        raise InputError(f"{what} holds NaN or inf values", path)
    return arr


def _item(seq, index, what: str, path: str):
    seq = seq or []
    if not isinstance(index, int) or not 0 <= index < len(seq):
        raise InputError(f"{what} {index} does not exist (the file has {len(seq)})", path)
    return seq[index]


# -------------------------------------------------------------------------------- sampling


def sample_channel(
    inputs: np.ndarray, outputs: np.ndarray, interpolation: str, times: np.ndarray, rotation: bool
) -> np.ndarray:
    """Evaluate one animation sampler at ``times`` (clamped to its first and last keys).

    Parameters
    ----------
    inputs : (K,) float, strictly increasing key times in seconds
    outputs : (K, n) float for LINEAR/STEP, (3K, n) for CUBICSPLINE (in-tangent, value,
        out-tangent per key)
    interpolation : ``"LINEAR"``, ``"STEP"`` or ``"CUBICSPLINE"``
    times : (T,) float seconds
    rotation : the values are quaternions (x, y, z, w): LINEAR slerps (shortest arc), every
        result is normalised

    Returns
    -------
    (T, n) float64
    """
    inputs = np.asarray(inputs, np.float64)
    times = np.clip(np.asarray(times, np.float64), inputs[0], inputs[-1])
    k_count = len(inputs)
    if interpolation == "CUBICSPLINE":
        triples = np.asarray(outputs, np.float64).reshape(k_count, 3, -1)
        values = triples[:, 1]
    else:
        values = np.asarray(outputs, np.float64)
    if k_count == 1:
        out = np.repeat(values[:1], len(times), axis=0)
        return _unit(out) if rotation else out
    if interpolation == "STEP":
        # A frame on a key takes that key, though key times are float32 (1/30 s is not exact).
        snapped = times + _KEY_TIME_REL * np.maximum(np.abs(times), 1.0)
        k = np.clip(np.searchsorted(inputs, snapped, side="right") - 1, 0, k_count - 1)
        out = values[k]
        return _unit(out) if rotation else out
    k = np.clip(np.searchsorted(inputs, times, side="right") - 1, 0, k_count - 2)
    dt = inputs[k + 1] - inputs[k]
    u = np.clip((times - inputs[k]) / dt, 0.0, 1.0)[:, None]
    v0, v1 = values[k], values[k + 1]
    if interpolation == "CUBICSPLINE":
        b0, a1 = triples[k, 2], triples[k + 1, 0]
        u2, u3 = u * u, u * u * u
        out = (
            (2 * u3 - 3 * u2 + 1) * v0
            + (u3 - 2 * u2 + u) * dt[:, None] * b0
            + (-2 * u3 + 3 * u2) * v1
            + (u3 - u2) * dt[:, None] * a1
        )
        return _unit(out) if rotation else out
    if not rotation:
        return (1 - u) * v0 + u * v1
    q0, q1 = _unit(v0), _unit(v1)
    dot = np.sum(q0 * q1, axis=1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin = np.sin(theta)
    near = sin < 1e-8
    safe = np.where(near, 1.0, sin)
    w0 = np.where(near, 1 - u, np.sin((1 - u) * theta) / safe)
    w1 = np.where(near, u, np.sin(u * theta) / safe)
    return _unit(w0 * q0 + w1 * q1)


def _unit(q: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    return q / np.where(n > 0, n, 1.0)


def keyframe_fps(inputs: list[np.ndarray]) -> float | None:
    """The animation's keyframe rate: 1 / the median key step over all samplers, snapped to a
    whole number when within 0.1%; None when no sampler has two keys or the rate lies outside
    :data:`KEYFRAME_FPS_RANGE`."""
    steps = np.concatenate([np.diff(np.asarray(x, np.float64)) for x in inputs] or [np.empty(0)])
    steps = steps[steps > 0]
    if not len(steps):
        return None
    rate = 1.0 / float(np.median(steps))
    nearest = round(rate)
    if abs(rate - nearest) <= _FPS_SNAP_REL * rate:
        rate = float(nearest)
    lo, hi = KEYFRAME_FPS_RANGE
    return rate if lo <= rate <= hi else None


# ------------------------------------------------------------------------------- transforms


def _trs_matrices(t: np.ndarray, q: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(T, 4, 4) float64 ``T @ R @ S`` from (T, 3) translations, (T, 4) xyzw quaternions and
    (T, 3) scales."""
    m = np.zeros((len(t), 4, 4))
    m[:, :3, :3] = Rotation.from_quat(q).as_matrix() * s[:, None, :]
    m[:, :3, 3] = t
    m[:, 3, 3] = 1.0
    return m


def _polar(a: np.ndarray) -> np.ndarray:
    """Nearest rotation to each (…, 3, 3) matrix (a reflection is flipped along its smallest
    singular direction)."""
    u, _s, vt = np.linalg.svd(a)
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= d[..., None]
    return u @ vt


def _parents_of_nodes(doc: GLTF2, path: str) -> np.ndarray:
    n = len(doc.nodes or [])
    parent = np.full(n, -1, np.int64)
    for i, node in enumerate(doc.nodes or []):
        for c in node.children or []:
            if not isinstance(c, int) or not 0 <= c < n:
                raise InputError(f"node {i} has child {c}, which does not exist", path)
            if parent[c] >= 0 or c == i:
                raise InputError(f"node {c} has more than one parent", path)
            parent[c] = i
    for i in range(n):  # a cycle never reaches a root
        k, seen = i, 0
        while k >= 0:
            k, seen = parent[k], seen + 1
            if seen > n:
                raise InputError(f"node hierarchy has a cycle through node {i}", path)
    return parent


def _ancestors(node: int, parent: np.ndarray) -> list[int]:
    """``node`` and its ancestors, root last."""
    out = []
    while node >= 0:
        out.append(int(node))
        node = parent[node]
    return out


def _rest_trs(node, i: int, path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | np.ndarray:
    """A node's rest transform: (translation, quaternion, scale), or its 4x4 ``matrix``."""
    if node.matrix is not None:
        m = np.asarray(node.matrix, np.float64)
        if m.shape != (16,) or not np.isfinite(m).all():
            raise InputError(f"node {i} has a malformed matrix", path)
        return m.reshape(4, 4).T  # column-major
    vals = []
    for key, default in (
        ("translation", (0, 0, 0)),
        ("rotation", (0, 0, 0, 1)),
        ("scale", (1, 1, 1)),
    ):
        v = np.asarray(
            getattr(node, key) if getattr(node, key) is not None else default, np.float64
        )
        if v.shape != (len(default),) or not np.isfinite(v).all():
            raise InputError(f"node {i} has a malformed {key}", path)
        vals.append(v)
    if not np.linalg.norm(vals[1]) > 0:
        raise InputError(f"node {i} has a zero rotation quaternion", path)
    return tuple(vals)


# ---------------------------------------------------------------------------- to a Motion


def _pick_skin(doc: GLTF2, path: str) -> int:
    skins = doc.skins or []
    if not skins:
        raise InputError(
            "no skin: not a skinned character (export the armature with its mesh)", path
        )
    sizes = [len(s.joints or []) for s in skins]
    best = int(np.argmax(sizes))
    if sizes[best] == 0:
        raise InputError("the skin has no joints", path)
    return best


def _pick_animation(doc: GLTF2, nodes: set[int], animation, path: str) -> int:
    anims = doc.animations or []
    if not anims:
        raise InputError("no animation: the file holds a character but no motion", path)
    if animation is not None:
        for i, a in enumerate(anims):
            if animation == i or (isinstance(animation, str) and animation == a.name):
                return i
        names = [a.name or str(i) for i, a in enumerate(anims)]
        raise InputError(f"no animation {animation!r}; the file has {names}", path)
    driven = [
        sum(c.target is not None and c.target.node in nodes for c in a.channels or [])
        for a in anims
    ]
    best = int(np.argmax(driven))
    if driven[best] == 0:
        raise InputError("no animation drives the skin's joints", path)
    return best


def gltf_to_motion(
    path: str | os.PathLike, *, fps: float | None = None, animation: int | str | None = None
) -> Motion:
    """Read a skinned glTF/GLB's skeleton animation as a Motion (metres, Y up, source names).

    Parameters
    ----------
    path : the ``.gltf`` or ``.glb`` file
    fps : sample at this rate; default the keyframe rate (:func:`keyframe_fps`) or 30
    animation : index or name of the animation; default the one driving most joints

    Returns
    -------
    Motion on the skin's joints (parents first), ``name`` the file stem, ``meta``:
    ``source_joints``, ``path``, ``format`` (``gltf``), ``animation`` (its name or index),
    ``animations`` (all names), ``keyframe_fps`` (None when not usable), ``wrapper_joints``
    (the nodes above the root joint, whose transforms are composed into it) and, when rigid
    bones cannot reproduce the file, ``varying_translations`` ({joint: metres}).

    Raises
    ------
    InputError
        Everything :func:`read_gltf` and :func:`read_accessor` refuse, no skin, no animation,
        a bad node hierarchy, a sampler whose key times are not increasing or whose output
        count disagrees, an unknown interpolation, ``fps`` not positive.
    """
    path = os.fspath(path)
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be positive, got {fps}", path)
    gltf = read_gltf(path)
    doc = gltf.doc
    node_parent = _parents_of_nodes(doc, path)
    skin = doc.skins[_pick_skin(doc, path)]
    joints = list(dict.fromkeys(skin.joints))
    for j in joints:
        _item(doc.nodes, j, "node", path)
    joint_set = set(joints)

    # The joint tree: nearest joint ancestor; several roots meet at their common ancestor.
    def joint_parent(node: int) -> int:
        for a in _ancestors(node, node_parent)[1:]:
            if a in joint_set:
                return a
        return -1

    roots = [j for j in joints if joint_parent(j) < 0]
    if len(roots) > 1:
        common = set(_ancestors(roots[0], node_parent))
        for r in roots[1:]:
            common &= set(_ancestors(r, node_parent))
        if not common:
            raise InputError(
                f"the skin's joints form {len(roots)} separate trees with no common parent node",
                path,
            )
        root = next(a for a in _ancestors(roots[0], node_parent) if a in common)
        joints.append(root)
        joint_set.add(root)
    order: list[int] = []
    children: dict[int, list[int]] = {j: [] for j in joints}
    for j in joints:
        p = joint_parent(j)
        if p >= 0:
            children[p].append(j)
    stack = [j for j in joints if joint_parent(j) < 0]
    while stack:
        j = stack.pop(0)
        order.append(j)
        stack[:0] = children[j]
    needed = sorted({a for j in order for a in _ancestors(j, node_parent)})

    anim_index = _pick_animation(doc, set(needed), animation, path)
    anim = doc.animations[anim_index]
    channels: dict[tuple[int, str], tuple[np.ndarray, np.ndarray, str]] = {}
    for c_index, ch in enumerate(anim.channels or []):
        target = ch.target
        if target is None or target.path not in _PATH_SIZES or target.node not in needed:
            continue
        sampler = _item(anim.samplers, ch.sampler, f"animation {anim_index} sampler", path)
        interp = sampler.interpolation or "LINEAR"
        if interp not in _INTERPOLATIONS:
            raise InputError(
                f"animation {anim_index} sampler {ch.sampler}: unknown interpolation {interp!r}",
                path,
            )
        inputs = read_accessor(gltf, sampler.input)
        if inputs.shape[1] != 1:
            raise InputError(
                f"animation {anim_index} sampler {ch.sampler}: key times are not scalars", path
            )
        inputs = inputs[:, 0]
        outputs = read_accessor(gltf, sampler.output)
        if len(inputs) > 1 and not (np.diff(inputs) > 0).all():
            raise InputError(
                f"animation {anim_index} sampler {ch.sampler}: key times are not increasing", path
            )
        want = _PATH_SIZES[target.path]
        keys = len(inputs) * (3 if interp == "CUBICSPLINE" else 1)
        if outputs.shape != (keys, want):
            raise InputError(
                f"animation {anim_index} channel {c_index} ({target.path}): sampler output "
                f"has {outputs.shape[0]} x {outputs.shape[1]} values, {keys} x {want} expected",
                path,
            )
        channels[(target.node, target.path)] = (inputs, outputs, interp)
    if not channels:
        raise InputError(f"animation {anim_index} drives none of the skeleton's nodes", path)

    all_inputs = [v[0] for v in channels.values()]
    t0 = min(float(x[0]) for x in all_inputs)
    t1 = max(float(x[-1]) for x in all_inputs)
    key_fps = keyframe_fps(all_inputs)
    rate = float(fps) if fps is not None else (key_fps or DEFAULT_FPS)
    num_frames = int(round((t1 - t0) * rate)) + 1
    if num_frames > MAX_FRAMES:
        raise InputError(
            f"animation {anim_index} lasts {t1 - t0:g} s: {num_frames} frames at {rate:g} fps, "
            f"more than {MAX_FRAMES}",
            path,
        )
    times = np.minimum(t0 + np.arange(num_frames) / rate, t1)

    # World transforms of the needed nodes, animated (T, 4, 4) and at rest (4, 4).
    world: dict[int, np.ndarray] = {}
    world_rest: dict[int, np.ndarray] = {}
    for i in needed:  # ancestors are filled first, recursively
        _world(i, doc, node_parent, channels, times, world, world_rest, path)

    p = np.stack([world[j][:, :3, 3] for j in order], axis=1)  # (T, J, 3)
    p_rest = np.stack([world_rest[j][:3, 3] for j in order])  # (J, 3)
    g = np.stack([_polar(world[j][:, :3, :3]) for j in order], axis=1)  # (T, J, 3, 3)
    g_rest = np.stack([_polar(world_rest[j][:3, :3]) for j in order])  # (J, 3, 3)
    g = g @ np.swapaxes(g_rest, -1, -2)[None]
    index = {n: k for k, n in enumerate(order)}
    parents = np.array([index.get(joint_parent(j), -1) for j in order], np.int64)
    offsets = p_rest.copy()
    offsets[1:] -= p_rest[parents[1:]]
    local = g.copy()
    local[:, 1:] = np.swapaxes(g[:, parents[1:]], -1, -2) @ g[:, 1:]

    names = _joint_names(doc, order, path)
    skeleton = Skeleton(
        names=names,
        parents=parents,
        offsets=offsets.astype(np.float32),
        end_sites=np.zeros((len(order), 3), np.float32),
    )
    meta: dict = {
        "source_joints": list(names),
        "path": path,
        "format": "gltf",
        "animation": anim.name or anim_index,
        "animations": [a.name or str(i) for i, a in enumerate(doc.animations)],
        "keyframe_fps": key_fps,
        "wrapper_joints": [
            doc.nodes[a].name or f"node_{a}" for a in _ancestors(order[0], node_parent)[1:]
        ],
    }
    fk = forward_kinematics(skeleton, local, p[:, 0])[0].astype(np.float64)
    miss = np.linalg.norm(fk - p, axis=2).max(axis=0)
    size = max(float(np.ptp(p_rest, axis=0).max()) if len(order) > 1 else 0.0, 1e-9)
    varying = {names[k]: float(miss[k]) for k in np.flatnonzero(miss > _VARYING_REL * size)}
    if varying:
        meta["varying_translations"] = varying
    return Motion(
        skeleton=skeleton,
        rotations=local.astype(np.float32),
        root_positions=p[:, 0].astype(np.float32),
        fps=rate,
        name=Path(path).stem,
        meta=meta,
    )


def _world(i, doc, node_parent, channels, times, world, world_rest, path) -> None:
    """Fill ``world[i]`` (T, 4, 4) and ``world_rest[i]`` (4, 4) for node ``i`` and its ancestors."""
    if i in world:
        return
    rest = _rest_trs(doc.nodes[i], i, path)
    n = len(times)
    if isinstance(rest, np.ndarray):
        if any((i, key) in channels for key in _PATH_SIZES):
            raise InputError(f"node {i} is animated but has a matrix instead of TRS", path)
        local_rest = rest
        local = np.broadcast_to(rest, (n, 4, 4))
    else:
        local_rest = _trs_matrices(*(v[None] for v in rest))[0]
        trs = []
        for key, v in zip(("translation", "rotation", "scale"), rest):
            if (i, key) in channels:
                inputs, outputs, interp = channels[(i, key)]
                trs.append(sample_channel(inputs, outputs, interp, times, key == "rotation"))
            else:
                trs.append(np.broadcast_to(v, (n, len(v))))
        if not (np.linalg.norm(trs[1], axis=1) > 0).all():
            raise InputError(f"node {i}: the animation gives a zero rotation quaternion", path)
        local = _trs_matrices(*trs)
    p = node_parent[i]
    if p < 0:
        world[i], world_rest[i] = np.array(local), local_rest
        return
    _world(p, doc, node_parent, channels, times, world, world_rest, path)
    world[i] = world[p] @ local
    world_rest[i] = world_rest[p] @ local_rest


def _joint_names(doc: GLTF2, order: list[int], path: str) -> tuple[str, ...]:
    """Node names of the joints (``node_N`` where unnamed; duplicates refused)."""
    names = tuple(doc.nodes[j].name or f"node_{j}" for j in order)
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise InputError(f"joint names appear twice: {dup}", path)
    return names
