"""glTF/GLB skeleton animation in: files written here with pygltflib from a known motion.

The known motion is a procedural clip on the mannequin's 20 joints. Written as a Mixamo-like
rig (``mixamorig:`` names, an ``Armature`` node scaled 0.01 above bones in centimetres, a rest
rotation on every bone, the skin's joints listed out of order), every loaded world joint
position must match the clip's to 1e-5 m.
"""

from __future__ import annotations

import base64
import json
import struct
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from scipy.spatial.transform import Rotation

from core.errors import InputError
from core.motion.gltf import gltf_to_motion, keyframe_fps, read_gltf
from core.motion.load import load_motion, resample
from core.motion.motion import Motion
from core.motion.procedural import make_motion
from core.skeleton import Skeleton
from tests.conftest import assert_close

FLOAT = pygltflib.FLOAT
ARMATURE_SCALE = 0.01  # bones in centimetres under a 0.01 armature, as Blender writes Mixamo rigs


class _Builder:
    """Accumulates accessors in one binary buffer (little-endian, 4-byte aligned)."""

    def __init__(self) -> None:
        self.blob = bytearray()
        self.views: list[pygltflib.BufferView] = []
        self.accessors: list[pygltflib.Accessor] = []

    def add(self, array: np.ndarray, kind: str) -> int:
        data = np.ascontiguousarray(array, "<f4")
        offset = len(self.blob)
        self.blob += data.tobytes()
        self.blob += b"\0" * (-len(self.blob) % 4)
        self.views.append(pygltflib.BufferView(buffer=0, byteOffset=offset, byteLength=data.nbytes))
        acc = pygltflib.Accessor(
            bufferView=len(self.views) - 1,
            componentType=FLOAT,
            count=len(data),
            type=kind,
        )
        if kind == "SCALAR":
            acc.min, acc.max = [float(data.min())], [float(data.max())]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def _quat(m: np.ndarray) -> np.ndarray:
    """(…, 3, 3) rotations as (…, 4) xyzw quaternions."""
    return (
        Rotation.from_matrix(np.asarray(m, np.float64).reshape(-1, 3, 3))
        .as_quat()
        .reshape(*m.shape[:-2], 4)
    )


def motion_to_gltf(motion: Motion, seed: int = 0, prefix: str = "mixamorig:") -> pygltflib.GLTF2:
    """The motion as a skinned glTF: every bone gets a random rest frame ``C_j`` (its glTF
    local rotation is ``C_p^T r_j C_j``, translation ``C_p^T offset_j``), so the file's local
    transforms differ from the motion's while the world joint positions are the same."""
    sk = motion.skeleton
    j, t = sk.num_joints, motion.num_frames
    frames = Rotation.random(j, random_state=seed).as_matrix()
    parent_frames = np.stack(
        [np.eye(3) if p < 0 else frames[p] for p in sk.parents]
    )  # (J, 3, 3) C_p
    pt = np.swapaxes(parent_frames, 1, 2)
    rest_rot = _quat(pt @ frames)
    rest_tr = np.einsum("jab,jb->ja", pt, sk.offsets.astype(np.float64)) / ARMATURE_SCALE
    rest_tr[0] = sk.offsets[0] / ARMATURE_SCALE
    anim_rot = _quat(pt[None] @ motion.rotations.astype(np.float64) @ frames[None])  # (T, J, 4)
    b = _Builder()
    times = b.add(np.arange(t) / motion.fps, "SCALAR")
    # Node 0: the armature; joints are nodes 1..J; the skin lists them in reverse order.
    nodes = [pygltflib.Node(name="Armature", scale=[ARMATURE_SCALE] * 3, children=[1])]
    for k in range(j):
        nodes.append(
            pygltflib.Node(
                name=prefix + sk.names[k],
                translation=rest_tr[k].tolist(),
                rotation=rest_rot[k].tolist(),
                children=[c + 1 for c in sk.children(k)],
            )
        )
    samplers, channels = [], []
    root_tr = b.add(motion.root_positions.astype(np.float64) / ARMATURE_SCALE, "VEC3")
    samplers.append(pygltflib.AnimationSampler(input=times, output=root_tr))
    channels.append(
        pygltflib.AnimationChannel(
            sampler=0, target=pygltflib.AnimationChannelTarget(node=1, path="translation")
        )
    )
    for k in range(j):
        out = b.add(anim_rot[:, k], "VEC4")
        samplers.append(pygltflib.AnimationSampler(input=times, output=out))
        channels.append(
            pygltflib.AnimationChannel(
                sampler=len(samplers) - 1,
                target=pygltflib.AnimationChannelTarget(node=k + 1, path="rotation"),
            )
        )
    gltf = pygltflib.GLTF2(
        scene=0,
        scenes=[pygltflib.Scene(nodes=[0])],
        nodes=nodes,
        skins=[pygltflib.Skin(joints=list(range(j, 0, -1)))],
        animations=[pygltflib.Animation(name="mixamo.com", samplers=samplers, channels=channels)],
        accessors=b.accessors,
        bufferViews=b.views,
        buffers=[pygltflib.Buffer(byteLength=len(b.blob))],
    )
    gltf.set_binary_blob(bytes(b.blob))
    return gltf


def save(gltf: pygltflib.GLTF2, path: Path, how: str) -> Path:
    """Write ``gltf`` as ``glb``, a ``.gltf`` with a data URI, or a ``.gltf`` beside a ``.bin``."""
    blob = gltf.binary_blob()
    if how == "glb":
        gltf.save_binary(str(path))
        return path
    doc = pygltflib.GLTF2.from_json(gltf.to_json())
    if how == "data-uri":
        doc.buffers[0].uri = "data:application/octet-stream;base64," + base64.b64encode(
            blob
        ).decode("ascii")
    else:
        (path.parent / (path.stem + " data.bin")).write_bytes(blob)
        doc.buffers[0].uri = path.stem + "%20data.bin"  # a URI: the space is escaped
    path.write_text(doc.gltf_to_json(), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def dance() -> Motion:
    return make_motion("dance", 45, 30.0, 3)


@pytest.fixture(scope="module")
def dance_files(dance, tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("gltf")
    gltf = motion_to_gltf(dance)
    return {
        "glb": save(gltf, out / "dance.glb", "glb"),
        "data-uri": save(gltf, out / "dance_embedded.gltf", "data-uri"),
        "bin": save(gltf, out / "dance_separate.gltf", "bin"),
    }


def _positions_by_name(motion: Motion, names: tuple[str, ...], prefix: str = "") -> np.ndarray:
    pos = motion.joint_positions()
    return pos[:, [motion.skeleton.names.index(prefix + n) for n in names]]


@pytest.mark.parametrize("how", ["glb", "data-uri", "bin"])
def test_world_positions_match_the_known_motion(dance, dance_files, how):
    loaded = load_motion(dance_files[how])
    assert loaded.num_frames == dance.num_frames and loaded.fps == 30.0
    assert loaded.skeleton.names[0] == "mixamorig:Hips"
    assert loaded.meta["rig"] == "mixamo" and loaded.meta["unit"] == "m"
    assert loaded.meta["up_axis"] == "y" and loaded.meta["wrapper_joints"] == ["Armature"]
    assert loaded.meta["animation"] == "mixamo.com"
    assert "varying_translations" not in loaded.meta
    got = _positions_by_name(loaded, dance.skeleton.names, "mixamorig:")
    assert_close(got, dance.joint_positions(), atol=1e-5, what="world joint positions (m)")
    # The mapping onto the canonical joints is the one BVH files get.
    assert loaded.meta["mapping"]["LeftForeArm"] == "mixamorig:LeftForeArm"


def test_resampled_at_another_rate_is_a_slerp_of_the_keys(dance, dance_files):
    """LINEAR rotations are slerped, the root lerped: the same as resampling the known motion
    with scipy's Slerp (slerp commutes with the fixed rest frames of the file)."""
    loaded = load_motion(dance_files["glb"], fps=60.0)
    expected = resample(dance, 60.0)
    assert loaded.num_frames == expected.num_frames == 89 and loaded.fps == 60.0
    assert loaded.meta["source_fps"] == 30.0
    got = _positions_by_name(loaded, dance.skeleton.names, "mixamorig:")
    assert_close(got, expected.joint_positions(), atol=1e-5, what="positions at 60 fps")


def test_motion_info_and_retarget_cli(dng, dance_files, tmp_path):
    code, out, err = dng("motion", "info", dance_files["glb"], "--json")
    assert code == 0 and not err
    info = json.loads(out)
    assert info["frames"] == 45 and info["fps"] == 30.0 and info["rig"] == "mixamo"
    assert info["joints"]["Head"] == "mixamorig:Head" and info["unit"] == "m"
    assert 1.5 < info["standing_height_m"] < 1.9
    out_bvh = tmp_path / "retargeted.bvh"
    code, out, err = dng("motion", "retarget", dance_files["bin"], "--out", out_bvh)
    assert code == 0 and out_bvh.is_file(), err
    assert load_motion(out_bvh).num_frames == 45


def _two_joint_gltf(path: Path, interpolation: str, times, values, path_kind="translation"):
    """A root and one child 0.5 m above it; one sampler on the root."""
    b = _Builder()
    ti = b.add(np.asarray(times, np.float64), "SCALAR")
    vo = b.add(np.asarray(values, np.float64), "VEC4" if path_kind == "rotation" else "VEC3")
    gltf = pygltflib.GLTF2(
        scenes=[pygltflib.Scene(nodes=[0])],
        nodes=[
            pygltflib.Node(name="root", children=[1]),
            pygltflib.Node(name="tip", translation=[0.0, 0.5, 0.0]),
        ],
        skins=[pygltflib.Skin(joints=[0, 1])],
        animations=[
            pygltflib.Animation(
                samplers=[
                    pygltflib.AnimationSampler(input=ti, output=vo, interpolation=interpolation)
                ],
                channels=[
                    pygltflib.AnimationChannel(
                        sampler=0, target=pygltflib.AnimationChannelTarget(node=0, path=path_kind)
                    )
                ],
            )
        ],
        accessors=b.accessors,
        bufferViews=b.views,
        buffers=[pygltflib.Buffer(byteLength=len(b.blob))],
    )
    gltf.set_binary_blob(bytes(b.blob))
    gltf.save_binary(str(path))
    return path


def test_step_holds_each_key(tmp_path):
    keys = np.array([[0, 0, 0], [1, 0, 0], [1, 2, 0]], np.float64)
    f = _two_joint_gltf(tmp_path / "step.glb", "STEP", [0.0, 0.1, 0.2], keys)
    m = gltf_to_motion(f, fps=40.0)  # 9 frames, 4 per key step
    assert m.num_frames == 9
    expected = keys[[0, 0, 0, 0, 1, 1, 1, 1, 2]]
    assert_close(m.root_positions, expected, atol=1e-6, what="STEP root")
    assert_close(m.joint_positions()[:, 1], expected + [0, 0.5, 0], atol=1e-6, what="STEP tip")


def test_cubicspline_is_the_hermite_of_the_spec(tmp_path):
    """Keys at 0 and 1 s with in/out tangents; values at quarter seconds from the spec's formula
    p = (2s^3-3s^2+1) v0 + (s^3-2s^2+s) dt b0 + (-2s^3+3s^2) v1 + (s^3-s^2) dt a1."""
    v0, v1 = np.array([0.0, 1.0, 0.0]), np.array([2.0, 1.0, -1.0])
    b0, a1 = np.array([1.0, 0.0, 3.0]), np.array([0.0, -2.0, 1.0])
    outputs = [[9, 9, 9], v0, b0, a1, v1, [9, 9, 9]]  # in, value, out per key (ends unused)
    f = _two_joint_gltf(tmp_path / "cubic.glb", "CUBICSPLINE", [0.0, 1.0], outputs)
    m = gltf_to_motion(f, fps=4.0)
    s = np.arange(5)[:, None] / 4.0
    expected = (
        (2 * s**3 - 3 * s**2 + 1) * v0
        + (s**3 - 2 * s**2 + s) * b0
        + (-2 * s**3 + 3 * s**2) * v1
        + (s**3 - s**2) * a1
    )
    assert_close(m.root_positions, expected, atol=1e-6, what="CUBICSPLINE root")


def test_linear_rotation_of_the_root_turns_the_child(tmp_path):
    """A 90 degree turn about Z over 1 s: at 0.5 s the tip (0.5 m up) is 45 degrees over."""
    q = Rotation.from_euler("z", [[0], [90]], degrees=True).as_quat()
    f = _two_joint_gltf(tmp_path / "turn.glb", "LINEAR", [0.0, 1.0], q, "rotation")
    m = gltf_to_motion(f, fps=2.0)
    tip = m.joint_positions()[:, 1]
    h = 0.5 / np.sqrt(2)
    assert_close(tip, [[0, 0.5, 0], [-h, h, 0], [-0.5, 0, 0]], atol=1e-6, what="turned tip")


def test_keyframe_rate_detection():
    assert keyframe_fps([np.arange(10, dtype=np.float32) / np.float32(30)]) == 30.0
    assert keyframe_fps([np.arange(5) / 24.0, np.array([0.0, 2.0])]) == 24.0
    assert keyframe_fps([np.array([0.0, 1.0, 2.0])]) is None  # 1 fps: sparse keys, not a rate
    assert keyframe_fps([np.array([0.0])]) is None


# ------------------------------------------------------------------------------- bad files


def _error(dng, path: Path) -> str:
    code, out, err = dng("motion", "info", path)
    assert code == 2 and not out, (code, out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0], err
    return lines[0]


def test_bad_files_exit_2_with_one_line(dng, dance_files, tmp_path):
    text = tmp_path / "notes.glb"
    text.write_text("HIERARCHY\nthis is not a GLB\n")
    assert "no 'glTF' signature" in _error(dng, text)

    garbage = tmp_path / "garbage.gltf"
    garbage.write_text("{ not json")
    assert "invalid JSON" in _error(dng, garbage)

    other_json = tmp_path / "other.gltf"
    other_json.write_text('{"hello": 1}')
    assert "no 'asset'" in _error(dng, other_json)

    raw = dance_files["glb"].read_bytes()
    truncated = tmp_path / "truncated.glb"
    truncated.write_bytes(raw[: len(raw) // 2])
    assert "truncated GLB" in _error(dng, truncated)

    still = tmp_path / "still.gltf"
    still.write_text(json.dumps({"asset": {"version": "2.0"}, "nodes": [{"name": "cube"}]}))
    assert "no skin" in _error(dng, still)

    doc = json.loads(
        save(
            motion_to_gltf(make_motion("idle", 3, 30.0, 0)), tmp_path / "x.gltf", "data-uri"
        ).read_text()
    )
    no_anim = dict(doc)
    del no_anim["animations"]
    (tmp_path / "no_anim.gltf").write_text(json.dumps(no_anim))
    assert "no animation" in _error(dng, tmp_path / "no_anim.gltf")

    far = json.loads(json.dumps(doc))
    far["accessors"][3]["count"] = 1000
    (tmp_path / "far.gltf").write_text(json.dumps(far))
    assert "accessor 3 out of range" in _error(dng, tmp_path / "far.gltf")

    missing = json.loads(json.dumps(doc))
    missing["animations"][0]["samplers"][0]["output"] = 99
    (tmp_path / "missing.gltf").write_text(json.dumps(missing))
    assert "accessor 99 does not exist" in _error(dng, tmp_path / "missing.gltf")

    assert "no such file" in _error(dng, tmp_path / "absent.glb")


def test_truncated_glb_chunk_and_missing_bin(dance_files, tmp_path):
    """The header's length agrees with the file but the BIN chunk claims a megabyte; a .gltf
    whose .bin is not beside it."""
    bad = bytearray(dance_files["glb"].read_bytes())
    json_len = struct.unpack_from("<I", bad, 12)[0]
    struct.pack_into("<I", bad, 12 + 8 + json_len, 10**6)
    cut = tmp_path / "cut.glb"
    cut.write_bytes(bytes(bad))
    with pytest.raises(InputError, match="truncated GLB: chunk"):
        read_gltf(cut)
    lone = tmp_path / "lone.gltf"
    lone.write_text(dance_files["bin"].read_text())
    with pytest.raises(InputError, match="cannot read its file"):
        gltf_to_motion(lone)


def test_skeleton_with_two_roots_gets_their_common_parent(tmp_path):
    """Two joint trees under one armature node: the armature becomes the root joint."""
    b = _Builder()
    ti = b.add(np.array([0.0, 1.0]), "SCALAR")
    vo = b.add(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), "VEC3")
    gltf = pygltflib.GLTF2(
        scenes=[pygltflib.Scene(nodes=[0])],
        nodes=[
            pygltflib.Node(name="Armature", children=[1, 2]),
            pygltflib.Node(name="a", translation=[1.0, 0.0, 0.0]),
            pygltflib.Node(name="b", translation=[-1.0, 0.0, 0.0]),
        ],
        skins=[pygltflib.Skin(joints=[1, 2])],
        animations=[
            pygltflib.Animation(
                samplers=[pygltflib.AnimationSampler(input=ti, output=vo)],
                channels=[
                    pygltflib.AnimationChannel(
                        sampler=0,
                        target=pygltflib.AnimationChannelTarget(node=0, path="translation"),
                    )
                ],
            )
        ],
        accessors=b.accessors,
        bufferViews=b.views,
        buffers=[pygltflib.Buffer(byteLength=len(b.blob))],
    )
    gltf.set_binary_blob(bytes(b.blob))
    gltf.save_binary(str(tmp_path / "two.glb"))
    m = gltf_to_motion(tmp_path / "two.glb")
    assert m.skeleton.names == ("Armature", "a", "b") and m.fps == 30.0 and m.num_frames == 31
    assert_close(m.joint_positions()[-1], [[0, 0, 1], [1, 0, 1], [-1, 0, 1]], atol=1e-6)
    assert isinstance(m.skeleton, Skeleton)
