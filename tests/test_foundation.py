"""The shared foundation: skeleton and FK, body shape, mesh validation, atomic files, the CLI."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from core.body.shape import MANNEQUIN_JOINTS, BodyShape, mannequin_skeleton
from core.errors import InputError
from core.fileio import atomic_open, atomic_path, write_json
from core.mesh import Mesh, load_mesh, save_mesh, validate_mesh
from core.skeleton import (
    CANONICAL_JOINTS,
    forward_kinematics,
    rotation_about,
    skinning_transforms,
)
from tests.conftest import assert_close


def test_canonical_skeleton_has_19_named_joints():
    assert len(CANONICAL_JOINTS) == 19 and len(set(CANONICAL_JOINTS)) == 19
    assert MANNEQUIN_JOINTS[0] == "Hips" and set(MANNEQUIN_JOINTS[1:]) == set(CANONICAL_JOINTS)


def test_fk_rest_pose_reproduces_rest_positions():
    sk = mannequin_skeleton()
    t = 3
    rot = np.broadcast_to(np.eye(3), (t, sk.num_joints, 3, 3))
    root = np.tile(sk.offsets[0], (t, 1))
    pos, grot = forward_kinematics(sk, rot, root)
    assert pos.shape == (t, sk.num_joints, 3) and grot.shape == (t, sk.num_joints, 3, 3)
    assert_close(pos[1], sk.rest_positions(), atol=1e-6, what="rest positions")
    m = skinning_transforms(sk, pos, grot)
    assert_close(m, np.broadcast_to(np.eye(4), m.shape), atol=1e-5, what="rest skinning transforms")


def test_fk_keeps_bone_lengths_and_rotates_children(rng):
    sk = mannequin_skeleton()
    t, j = 5, sk.num_joints
    axes = rng.normal(size=(t, j, 3))
    rot = np.stack(
        [[rotation_about(axes[i, k], rng.uniform(-1, 1)) for k in range(j)] for i in range(t)]
    )
    pos, _ = forward_kinematics(sk, rot, rng.normal(size=(t, 3)))
    parents = sk.parents
    lengths = np.linalg.norm(pos[:, 1:] - pos[:, parents[1:]], axis=-1)
    assert_close(lengths, np.broadcast_to(sk.bone_lengths()[1:], lengths.shape), atol=1e-5)
    # A quarter turn of the root about +Y moves the left hip (+X) to -Z.
    rot = np.broadcast_to(np.eye(3), (1, j, 3, 3)).copy()
    rot[0, 0] = rotation_about([0, 1, 0], np.pi / 2)
    pos, _ = forward_kinematics(sk, rot, np.zeros((1, 3)))
    left = pos[0, sk.index("LeftUpLeg")] - pos[0, 0]
    assert left[0] == pytest.approx(0, abs=1e-6) and left[2] < -0.05


def test_skinning_transforms_move_attached_points():
    sk = mannequin_skeleton()
    j = sk.num_joints
    rot = np.broadcast_to(np.eye(3), (1, j, 3, 3)).copy()
    knee = sk.index("LeftLeg")
    rot[0, knee] = rotation_about([1, 0, 0], 0.8)
    pos, grot = forward_kinematics(sk, rot, sk.offsets[None, 0])
    m = skinning_transforms(sk, pos, grot)[0, knee]
    rest_ankle = sk.rest_positions()[sk.index("LeftFoot")]
    moved = m[:3, :3] @ rest_ankle + m[:3, 3]
    assert_close(moved, pos[0, sk.index("LeftFoot")], atol=1e-5, what="ankle via LBS transform")


def test_mannequin_proportions_follow_shape():
    for height in (1.5, 1.7, 2.0):
        sk = mannequin_skeleton(BodyShape(height=height))
        rest = sk.rest_positions()
        head = sk.index("Head")
        assert rest[head, 1] + sk.end_sites[head, 1] == pytest.approx(height, rel=1e-5)
        foot = sk.index("LeftFoot")
        assert rest[foot, 1] + sk.end_sites[foot, 1] == pytest.approx(0.0, abs=1e-6)
        # Facing +Z: toes in front of the ankle; left side at +X.
        assert sk.end_sites[foot, 2] > 0
        assert rest[sk.index("LeftArm"), 0] > 0 > rest[sk.index("RightArm"), 0]
    wide = mannequin_skeleton(BodyShape(shoulder_width=0.5)).rest_positions()
    sk = mannequin_skeleton(BodyShape(shoulder_width=0.5))
    assert wide[sk.index("LeftArm"), 0] - wide[sk.index("RightArm"), 0] == pytest.approx(0.5)


def test_body_shape_parse_and_limits():
    s = BodyShape.parse(["height=1.8", "build=0.5", "shoulder-width=0.4"])
    assert (s.height, s.build, s.shoulder_width) == (1.8, 0.5, 0.4)
    with pytest.raises(InputError, match="k=v"):
        BodyShape.parse(["weight=80"])
    with pytest.raises(InputError, match="not a number"):
        BodyShape.parse(["height=tall"])
    with pytest.raises(InputError, match="outside"):
        BodyShape.parse(["height=nan"])
    with pytest.raises(InputError, match="outside"):
        BodyShape(height=4.0)


def _quad():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    return v, f


def test_validate_repairs_duplicates_and_degenerates():
    v, f = _quad()
    v2 = np.concatenate([v, v[:1]])  # vertex 4 duplicates vertex 0
    f2 = np.array([[4, 1, 2], [0, 2, 3], [0, 2, 3], [1, 1, 2], [0, 1, 1]])
    mesh, rep = validate_mesh(v2, f2)
    assert mesh.num_vertices == 4 and mesh.num_faces == 2
    assert rep.merged_vertices == 1 and rep.duplicate_faces == 1 and rep.degenerate_faces == 2
    assert rep.boundary_edges == 4 and rep.components == 1 and rep.non_manifold_edges == 0
    assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.int64


def test_validate_reports_non_manifold_and_components():
    v, f = _quad()
    fan = np.concatenate([v, [[0.5, 0.5, 1.0], [5, 5, 5], [6, 5, 5], [5, 6, 5]]]).astype(np.float32)
    faces = np.concatenate([f, [[0, 2, 4]], [[5, 6, 7]]])
    _, rep = validate_mesh(fan, faces)
    assert rep.non_manifold_edges == 1 and rep.components == 2


@pytest.mark.parametrize(
    "vertices, faces, message",
    [
        (np.zeros((0, 3)), np.zeros((0, 3), int), "empty"),
        (np.array([[0, 0, 0], [1, 0, np.nan], [0, 1, 0]]), np.array([[0, 1, 2]]), "NaN"),
        (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 3]]), "out of range"),
        (np.zeros((3, 2)), np.array([[0, 1, 2]]), "shape"),
        (np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]]), np.array([[0, 1, 2]]), "degenerate"),
    ],
)
def test_validate_rejects_bad_arrays(vertices, faces, message):
    with pytest.raises(InputError, match=message) as info:
        validate_mesh(vertices, faces, path="garment.obj")
    assert str(info.value).startswith("garment.obj: ")


def test_mesh_io_round_trip_with_uvs(tmp_path):
    v, f = _quad()
    uv = v[:, :2] * 0.5 + 0.25
    path = tmp_path / "quad.obj"
    save_mesh(path, Mesh(v, f, uv))
    mesh, rep = load_mesh(path)
    assert_close(mesh.vertices, v, atol=1e-6) and (mesh.faces == f).all()
    assert_close(mesh.uvs, uv, atol=1e-6, what="uvs")
    for suffix in (".ply", ".stl", ".off", ".glb"):
        save_mesh(tmp_path / f"quad{suffix}", Mesh(v, f))
        back, _ = load_mesh(tmp_path / f"quad{suffix}")
        assert back.num_faces == 2, suffix
    assert not list(tmp_path.glob(".*tmp*")), "temporary files left behind"


def test_load_mesh_rejects_bad_files(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        load_mesh(tmp_path / "missing.obj")
    (tmp_path / "x.fbx").write_text("x")
    with pytest.raises(InputError, match="unsupported"):
        load_mesh(tmp_path / "x.fbx")
    (tmp_path / "empty.obj").write_text("")
    with pytest.raises(InputError, match="empty"):
        load_mesh(tmp_path / "empty.obj")
    (tmp_path / "junk.ply").write_bytes(b"ply\nformat nonsense\n\x00\x01")
    with pytest.raises(InputError, match="junk.ply"):
        load_mesh(tmp_path / "junk.ply")
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="nan.obj: .*NaN"):
        load_mesh(tmp_path / "nan.obj")
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\n")
    with pytest.raises(InputError, match="points.obj"):
        load_mesh(tmp_path / "points.obj")


def test_atomic_writes_leave_nothing_on_failure(tmp_path):
    target = tmp_path / "out.json"
    write_json(target, {"a": np.float32(1.5), "b": np.arange(3)})
    assert target.read_text().count("1.5") == 1
    assert target.stat().st_mode & 0o644 == 0o644, "written files are readable by others"
    with pytest.raises(RuntimeError), atomic_open(target, "w") as f:
        f.write("half")
        raise RuntimeError("killed")
    assert "half" not in target.read_text()
    with pytest.raises(RuntimeError), atomic_path(tmp_path / "new.bin"):
        raise RuntimeError("killed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_cli_reports_input_errors_on_one_line_with_exit_2(capsys, monkeypatch):
    import argparse

    from app import cli

    def handler(args):
        raise InputError("truncated: expected 10 frames, found 3", "clip.bvh")

    parser = argparse.ArgumentParser(prog="dng")
    sub = parser.add_subparsers(dest="command")
    sub.add_parser("boom").set_defaults(handler=handler)
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    assert cli.main(["boom"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "clip.bvh: truncated: expected 10 frames" in err


def test_cli_help_lists_commands():
    out = subprocess.run(
        [sys.executable, "-m", "app.cli", "--help"], capture_output=True, text=True
    )
    assert out.returncode == 0 and "COMMAND" in out.stdout


def test_core_import_is_light():
    code = (
        "import sys, core, core.mesh, core.skeleton, core.body.shape, core.motion;"
        "heavy = {'open3d', 'torch', 'newton', 'warp', 'pyvista'} & set(sys.modules);"
        "print(sorted(heavy)); sys.exit(bool(heavy))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, f"importing core pulled in {out.stdout.strip()}"
