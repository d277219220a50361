"""The parametric mannequin: closed mesh, girths, skinning weights, posing, colliders, CLI."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.body.colliders import (
    body_capsules,
    capsule_distance,
    closest_on_segments,
    pose_capsules,
    posed_capsules_for,
)
from core.body.mannequin import (
    HIP_LEVEL,
    Body,
    body_mesh,
    girth_at,
    is_closed_manifold,
    make_body,
    torso_range,
)
from core.body.shape import BodyShape, mannequin_skeleton
from core.body.skinning import limit_influences, linear_blend_skinning, pose_body
from core.errors import InputError
from core.skeleton import forward_kinematics, rotation_about, skinning_transforms
from tests.conftest import assert_close

HEAVY = BodyShape(height=1.85, hip=1.25, waist=1.05, chest=1.15, build=1.0)
SLIM = BodyShape(height=1.55, shoulder_width=0.33, hip=0.86, waist=0.60, chest=0.78, build=-1.0)


@pytest.fixture(scope="module")
def body() -> Body:
    return make_body()


def _edges(faces: np.ndarray) -> np.ndarray:
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(e, axis=0)


def _rest(body: Body, t: int = 1) -> tuple[np.ndarray, np.ndarray]:
    j = body.skeleton.num_joints
    rot = np.tile(np.eye(3), (t, j, 1, 1))
    root = np.tile(body.skeleton.rest_positions()[0], (t, 1))
    return rot, root


def _assert_valid_closed(v: np.ndarray, f: np.ndarray) -> None:
    import trimesh

    from core.mesh import count_components

    assert v.dtype == np.float32 and f.dtype == np.int64
    assert np.isfinite(v).all()
    assert is_closed_manifold(f), "not a closed, consistently oriented 2-manifold"
    tm = trimesh.Trimesh(v, f, process=False)
    assert tm.is_watertight and tm.is_winding_consistent
    assert tm.volume > 0, "normals point inwards"
    assert count_components(len(v), f) == 1


# --- the mesh --------------------------------------------------------------------------------


def test_default_body_is_closed_and_sized(body):
    v, f = body.vertices, body.faces
    _assert_valid_closed(v, f)
    assert 5000 <= len(v) <= 15000
    # Genus 0 (arms and legs do not touch the torso in the A-pose).
    assert len(v) - len(_edges(f)) + len(f) == 2
    h = body.shape.height
    assert abs(v[:, 1].min()) < 0.01 * h, "feet on the floor"
    assert abs(v[:, 1].max() - h) < 0.02 * h, "top of the head at the height"
    # Left side towards +X, facing +Z: symmetric about x = 0 within a voxel or two.
    assert abs(v[:, 0].max() + v[:, 0].min()) < 0.01
    assert not v.flags.writeable and not body.weights.flags.writeable


def test_faces_point_out_of_the_implicit_body(body):
    """Every triangle faces the way the implicit surface does (none folded over)."""
    from core.body.mannequin import body_field

    v, f = body.vertices.astype(np.float64), body.faces
    centre = v[f].mean(axis=1)
    eps = 1e-4
    grad = np.stack(
        [
            body_field(body.shape, centre + eps * e) - body_field(body.shape, centre - eps * e)
            for e in np.eye(3)
        ],
        axis=1,
    )
    normal = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    cos = np.einsum("ij,ij->i", normal, grad) / (
        np.linalg.norm(normal, axis=1) * np.linalg.norm(grad, axis=1)
    )
    assert (cos > 0).all(), f"{int((cos <= 0).sum())} faces turned inwards"
    assert np.percentile(cos, 1) > 0.9
    # The vertices lie on the implicit surface (within a millimetre).
    assert np.abs(body_field(body.shape, v)).max() < 1e-3


def test_resolution_sets_vertex_count():
    v, f = body_mesh(BodyShape(), 4000)
    assert abs(len(v) - 4000) <= 0.05 * 4000
    assert is_closed_manifold(f)


@pytest.mark.parametrize("shape", [BodyShape(), HEAVY, SLIM], ids=["default", "heavy", "slim"])
def test_girths_match_the_shape(shape):
    b = make_body(shape)
    for level in ("hip", "waist", "chest"):
        want = getattr(shape, level)
        got = b.girth(level)
        assert abs(got - want) <= 0.03 * want, f"{level}: measured {got:.3f} m, asked {want} m"


def test_skirt_region_is_smooth(body):
    """Hips to waist, and the thighs: no dents or bumps (normals turn slowly between faces)."""
    import trimesh

    tm = trimesh.Trimesh(body.vertices, body.faces, process=False)
    h, hip = body.shape.height, body.shape.hip
    y0, _ = torso_range(body.shape)
    adj = tm.face_adjacency
    mid = tm.triangles_center[adj].mean(axis=1)
    angles = np.degrees(tm.face_adjacency_angles)
    torso = (mid[:, 1] > y0 + 0.03 * h) & (mid[:, 1] < 0.66 * h) & (np.abs(mid[:, 0]) < hip / 3)
    thighs = (mid[:, 1] > 0.30 * h) & (mid[:, 1] < y0 - 0.02 * h)
    for name, sel, p99, worst in (("torso", torso, 15, 30), ("thighs", thighs, 20, 40)):
        assert sel.sum() > 1000
        a = angles[sel]
        assert np.percentile(a, 99) < p99 and a.max() < worst, f"{name}: {a.max():.1f} deg"


def test_girth_at_measures_a_cylinder():
    import trimesh

    cyl = trimesh.creation.cylinder(radius=0.2, height=1.0, sections=256)
    cyl.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    g = girth_at(np.asarray(cyl.vertices), np.asarray(cyl.faces), 0.1)
    assert g == pytest.approx(2 * np.pi * 0.2, rel=1e-3)
    with pytest.raises(InputError):
        girth_at(np.asarray(cyl.vertices), np.asarray(cyl.faces), 5.0)


def test_is_closed_manifold_catches_holes_and_flips():
    import trimesh

    box = trimesh.creation.box()
    f = np.asarray(box.faces)
    assert is_closed_manifold(f)
    assert not is_closed_manifold(f[1:])
    flipped = f.copy()
    flipped[0] = flipped[0, ::-1]
    assert not is_closed_manifold(flipped)


_EXTREMES = [
    (name, value)
    for name, (lo, hi) in {
        "height": (0.5, 2.6),
        "shoulder_width": (0.15, 0.8),
        "chest": (0.4, 2.0),
        "waist": (0.35, 2.0),
        "hip": (0.4, 2.2),
        "build": (-1.0, 1.0),
    }.items()
    for value in (lo, hi)
]


@pytest.mark.parametrize("name,value", _EXTREMES, ids=[f"{n}={v}" for n, v in _EXTREMES])
def test_extreme_shapes_build_valid_meshes(name, value):
    shape = dataclasses.replace(BodyShape(), **{name: value})
    v, f = body_mesh(shape, 3000)
    _assert_valid_closed(v, f)
    assert abs(len(v) - 3000) <= 0.05 * 3000


@pytest.mark.slow
@pytest.mark.parametrize(
    "shape",
    [
        BodyShape(height=0.5, shoulder_width=0.8, chest=2.0, waist=2.0, hip=2.2, build=1.0),
        BodyShape(height=2.6, shoulder_width=0.15, chest=0.4, waist=0.35, hip=0.4, build=-1.0),
        BodyShape(height=2.6, shoulder_width=0.8, chest=2.0, waist=0.35, hip=2.2, build=1.0),
    ],
)
def test_extreme_combinations_make_full_bodies(shape):
    b = make_body(shape)
    _assert_valid_closed(b.vertices, b.faces)
    assert np.allclose(b.weights.sum(1), 1, atol=1e-5)
    assert b.capsules.count > 20
    crotch, _ = torso_range(shape)
    legs = b.vertices[:, 1] < crotch - 0.01 * shape.height
    right_leg = [b.skeleton.index(n) for n in ("RightUpLeg", "RightLeg", "RightFoot")]
    assert b.weights[legs & (b.vertices[:, 0] > 0)][:, right_leg].max() == 0


def test_make_body_validates_and_caches():
    with pytest.raises(InputError):
        make_body(BodyShape(), resolution=10)
    with pytest.raises(InputError):
        make_body(BodyShape(), resolution=9000.5)
    with pytest.raises(InputError):
        make_body({"height": 1.7})
    assert make_body(BodyShape()) is make_body(BodyShape())


# --- skinning --------------------------------------------------------------------------------


def test_weights_are_a_sparse_partition_of_unity(body):
    w = body.weights
    assert w.shape == (body.num_vertices, 20) and w.dtype == np.float32
    assert (w >= 0).all()
    assert_close(w.sum(axis=1), np.ones(len(w)), atol=1e-5, what="weight row sums")
    assert ((w > 0).sum(axis=1) <= 4).all()
    # Every joint moves some skin, and weights change smoothly along edges.
    assert (w.max(axis=0) > 0.3).all()
    e = _edges(body.faces)
    jump = np.abs(w[e[:, 0]] - w[e[:, 1]]).max(axis=1)
    assert np.percentile(jump, 99) < 0.35


@pytest.mark.parametrize(
    "shape", [BodyShape(), BodyShape(hip=0.4, shoulder_width=0.2)], ids=["default", "narrow"]
)
def test_no_weight_bleeds_across_limbs(shape):
    """Not even where the limbs nearly touch (narrow hips: feet and knees close together)."""
    body = make_body(shape)
    sk, v, w = body.skeleton, body.vertices, body.weights
    h = body.shape.height
    crotch, _ = torso_range(body.shape)
    right_leg = [sk.index(n) for n in ("RightUpLeg", "RightLeg", "RightFoot")]
    left_leg = [sk.index(n) for n in ("LeftUpLeg", "LeftLeg", "LeftFoot")]
    legs = v[:, 1] < crotch - 0.01 * h
    assert (legs & (v[:, 0] > 0)).sum() > 500
    assert w[legs & (v[:, 0] > 0)][:, right_leg].max() == 0
    assert w[legs & (v[:, 0] < 0)][:, left_leg].max() == 0
    arm_x = body.shape.shoulder_width / 2 + 0.05
    right_arm = [sk.index(n) for n in ("RightArm", "RightForeArm", "RightHand")]
    assert w[v[:, 0] > arm_x][:, right_arm].max() == 0
    # The thigh follows its own bones.
    thigh = legs & (v[:, 0] > 0) & (v[:, 1] > 0.35 * h)
    assert w[thigh][:, left_leg].sum(axis=1).mean() > 0.9


def test_limit_influences_is_continuous():
    """Swapping the order of the 4th and 5th weights moves the result only a little."""
    a = np.array([[0.4, 0.3, 0.15, 0.0801, 0.0799, 0.0]])
    b = np.array([[0.4, 0.3, 0.15, 0.0799, 0.0801, 0.0]])
    wa, wb = limit_influences(a), limit_influences(b)
    assert ((wa > 0).sum() <= 4) and ((wb > 0).sum() <= 4)
    assert np.abs(wa - wb).max() < 1e-3
    assert_close(wa.sum(), 1.0, atol=1e-6)


# --- posing ----------------------------------------------------------------------------------


def test_rest_pose_reproduces_the_rest_mesh(body):
    posed = pose_body(body, _rest(body, 3))
    assert posed.shape == (3, body.num_vertices, 3) and posed.dtype == np.float32
    assert_close(posed[1], body.vertices, atol=1e-5, what="rest-posed vertices")


def test_rest_pose_from_a_motion_record(body):
    from core.motion.motion import Motion

    rot, root = _rest(body, 2)
    motion = Motion(body.skeleton, rot.astype(np.float32), root.astype(np.float32), fps=30.0)
    assert_close(pose_body(body, motion)[0], body.vertices, atol=1e-5)
    other = Motion(mannequin_skeleton(HEAVY), rot.astype(np.float32), root, fps=30.0)
    assert pose_body(body, other).shape == (2, body.num_vertices, 3)  # same joints: fine


def test_rigid_root_motion_moves_the_body_rigidly(body):
    rot, root = _rest(body)
    r = rotation_about(np.array([0.3, 1.0, 0.2]), np.array(1.1))
    rot[0, 0] = r
    root = root + np.array([0.5, 0.1, -2.0])
    posed = pose_body(body, (rot, root))[0]
    rest_root = body.skeleton.rest_positions()[0]
    want = (body.vertices - rest_root) @ r.T + root[0]
    assert_close(posed, want, atol=2e-5, what="rigidly moved vertices")


def test_lbs_matches_a_per_vertex_reference(body, rng):
    sk = body.skeleton
    t = 2
    rot = np.stack(
        [rotation_about(rng.normal(size=3), rng.uniform(-0.6, 0.6, size=t)) for _ in range(20)],
        axis=1,
    )
    root = rng.normal(size=(t, 3))
    pos, g = forward_kinematics(sk, rot, root)
    m = skinning_transforms(sk, pos, g).astype(np.float64)
    idx = rng.choice(body.num_vertices, 50, replace=False)
    fast = linear_blend_skinning(body.vertices, body.weights, m, chunk=1)
    for i in idx:
        x = np.append(body.vertices[i].astype(np.float64), 1.0)
        for k in range(t):
            ref = sum(body.weights[i, j] * (m[k, j] @ x)[:3] for j in range(20))
            assert_close(fast[k, i], ref, atol=1e-4, what=f"vertex {i} frame {k}")


def _bent(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Right knee bent 90 degrees, right hip flexed, left arm raised to horizontal."""
    sk = body.skeleton
    rot, root = _rest(body)
    x = np.array([1.0, 0.0, 0.0])
    rot[0, sk.index("RightLeg")] = rotation_about(x, np.array(np.pi / 2))
    rot[0, sk.index("RightUpLeg")] = rotation_about(x, np.array(-0.6))
    rot[0, sk.index("LeftArm")] = rotation_about(np.array([0.0, 0.0, 1.0]), np.array(np.pi / 4))
    return rot, root


def test_posed_body_keeps_its_edges_and_other_leg(body):
    rot, root = _bent(body)
    posed = pose_body(body, (rot, root))[0]
    assert np.isfinite(posed).all()
    e = _edges(body.faces)
    rest_len = np.linalg.norm(body.vertices[e[:, 0]] - body.vertices[e[:, 1]], axis=1)
    posed_len = np.linalg.norm(posed[e[:, 0]] - posed[e[:, 1]], axis=1)
    ratio = posed_len / rest_len
    # LBS folds the back of a 90-degree knee and stretches the crotch under hip flexion;
    # nothing collapses to a point or tears, and the bulk keeps its edge lengths.
    assert ratio.min() > 0.08 and ratio.max() < 6.0
    assert np.percentile(ratio, 1) > 0.7 and np.percentile(ratio, 99) < 1.3
    v = body.vertices
    crotch, _ = torso_range(body.shape)
    left_leg = (v[:, 0] > 0) & (v[:, 1] < crotch - 0.01 * body.shape.height)
    assert_close(posed[left_leg], v[left_leg], atol=1e-6, what="left leg under a right-leg pose")
    # The right foot went backwards and up with the shin.
    right_foot = (v[:, 0] < 0) & (v[:, 1] < 0.04 * body.shape.height)
    assert posed[right_foot, 1].mean() > v[right_foot, 1].mean() + 0.2
    # The raised left hand is up at shoulder height.
    hand = v[:, 0] > v[:, 0].max() - 0.05
    shoulder_y = body.skeleton.rest_positions()[body.skeleton.index("LeftArm"), 1]
    assert abs(posed[hand, 1].mean() - shoulder_y) < 0.05


def test_pose_body_rejects_bad_input(body):
    rot, root = _rest(body)
    with pytest.raises(InputError):
        pose_body(body, (rot[:, :19], root))
    with pytest.raises(InputError):
        pose_body(body, (rot, root[:, :2]))
    with pytest.raises(InputError):
        pose_body(body, rot)
    bad = rot.copy()
    bad[0, 3, 0, 0] = np.nan
    with pytest.raises(InputError):
        pose_body(body, (bad, root))
    from core.motion.motion import Motion
    from core.skeleton import Skeleton

    sk = Skeleton(
        ("a",), np.array([-1]), np.zeros((1, 3), np.float32), np.zeros((1, 3), np.float32)
    )
    m = Motion(
        sk, np.tile(np.eye(3, dtype=np.float32), (1, 1, 1, 1)), np.zeros((1, 3), np.float32), 30.0
    )
    with pytest.raises(InputError, match="retarget"):
        pose_body(body, m)


# --- colliders -------------------------------------------------------------------------------


def _axis_samples(endpoints: np.ndarray, n: int = 9) -> np.ndarray:
    t = np.linspace(0, 1, n)[None, :, None]
    return endpoints[:, :1] + t * (endpoints[:, 1:] - endpoints[:, :1])  # (K, n, 3)


@pytest.mark.parametrize("shape", [BodyShape(), HEAVY], ids=["default", "heavy"])
def test_body_carries_the_simulation_collider_with_its_axes_inside_the_skin(shape):
    import igl

    b = make_body(shape)
    c = b.capsules
    want = body_capsules(b.skeleton, shape)  # what the simulation collides with
    assert c.names == want.names
    for got, ref in ((c.joints, want.joints), (c.endpoints, want.endpoints), (c.radii, want.radii)):
        assert np.array_equal(got, ref)
    assert c.count >= 30 and (c.radii > 0).all()
    pts = _axis_samples(c.endpoints.astype(np.float64))
    sd = igl.signed_distance(
        pts.reshape(-1, 3),
        b.vertices.astype(np.float64),
        b.faces,
        igl.SIGNED_DISTANCE_TYPE_WINDING_NUMBER,
    )[0].reshape(pts.shape[:2])
    # Every capsule's axis runs inside the rendered skin (the capsules may bulge out of it).
    assert (sd < 0).all()
    # Skirt region (crotch to waist and the thighs): the skin is close to a capsule.
    h = shape.height
    v = b.vertices
    region = (v[:, 1] > 0.30 * h) & (v[:, 1] < 0.63 * h) & (np.abs(v[:, 0]) < shape.hip / 3)
    d = capsule_distance(v[region], c.endpoints, c.radii)
    assert region.sum() > 1000
    assert np.abs(np.median(d)) < 0.02 and np.percentile(d, 95) < 0.01


def test_capsule_distance_is_the_minimum_over_every_capsule_to_the_bit(body, rng):
    """The pruned search (a bound from each segment's middle) gives exactly the brute-force
    minimum over every point and capsule, near the body, inside it and far from it."""
    c = body.capsules
    pts = np.concatenate(
        [
            body.vertices + 0.02 * rng.standard_normal(body.vertices.shape),
            rng.uniform(-1.5, 2.5, (500, 3)),
            c.endpoints.mean(1),  # on the axes: deep inside
        ]
    )
    e = c.endpoints.astype(np.float64)
    d = closest_on_segments(pts[:, None], e[None, :, 0], e[None, :, 1])[0] - c.radii[None]
    want = d.min(1).astype(np.float32)
    got = capsule_distance(pts, c.endpoints, c.radii)
    assert np.array_equal(got, want)
    assert (got < 0).any() and (got > 0.5).any()
    assert capsule_distance(np.zeros((0, 3)), c.endpoints, c.radii).shape == (0,)


def test_capsules_follow_the_skeleton(body):
    c = body.capsules
    rot, root = _bent(body)
    pos, g = forward_kinematics(body.skeleton, rot, root)
    transforms = skinning_transforms(body.skeleton, pos, g)
    posed = pose_capsules(c, transforms)
    assert posed.shape == (1, c.count, 2, 3)
    # At rest they are where they were built.
    rpos, rg = forward_kinematics(body.skeleton, *_rest(body))
    rest = pose_capsules(c, skinning_transforms(body.skeleton, rpos, rg))[0]
    assert_close(rest, c.endpoints, atol=1e-6)
    # Posed like points skinned fully to their joint.
    m = transforms[0].astype(np.float64)
    for k in range(c.count):
        j = c.joints[k]
        want = c.endpoints[k] @ m[j, :3, :3].T + m[j, :3, 3]
        assert_close(posed[0, k], want, atol=1e-5, what=c.names[k])
    # The shin capsule follows the posed shin's skin.
    shin = [k for k, n in enumerate(c.names) if n == "RightLeg"]
    skin = pose_body(body, (rot, root))[0]
    on_shin = body.weights[:, body.skeleton.index("RightLeg")] > 0.9
    assert on_shin.sum() > 100
    d = capsule_distance(skin[on_shin], posed[0, shin], c.radii[shin])
    assert np.median(np.abs(d)) < 0.02
    assert_close(posed_capsules_for(body, (rot, root)), posed, atol=1e-6)
    with pytest.raises(InputError):
        pose_capsules(c, transforms[:, :5])


# --- CLI -------------------------------------------------------------------------------------


def _write_bvh(path, frames: int = 4) -> None:
    """A short clip on the mannequin: the right knee bends over the frames."""
    from core.motion.bvh import write_bvh
    from core.motion.motion import Motion

    sk = mannequin_skeleton()
    rot = np.tile(np.eye(3), (frames, sk.num_joints, 1, 1))
    rot[:, sk.index("RightLeg")] = rotation_about(
        np.array([1.0, 0.0, 0.0]), np.linspace(0, 1.2, frames)
    )
    root = np.tile(sk.rest_positions()[0], (frames, 1))
    write_bvh(path, Motion(sk, rot.astype(np.float32), root.astype(np.float32), 30.0, "knee"))


def test_cli_writes_a_closed_obj(tmp_path, capsys):
    from app.cli import main
    from core.mesh import load_mesh

    out = tmp_path / "body.obj"
    shape = [f"{k}={v}" for k, v in SLIM.as_dict().items()]  # built above: cached
    assert main(["body", "make", "--shape", *shape, "--out", str(out)]) == 0
    mesh, report = load_mesh(out)
    assert report.boundary_edges == 0 and report.non_manifold_edges == 0
    assert_close(mesh.vertices, make_body(SLIM).vertices, atol=1e-6, what="written vertices")
    assert "wrote" in capsys.readouterr().out


def test_cli_poses_a_frame_of_a_motion(tmp_path):
    from app.cli import main
    from core.mesh import load_mesh

    bvh = tmp_path / "knee.bvh"
    _write_bvh(bvh)
    rest, posed = tmp_path / "rest.obj", tmp_path / "posed.obj"
    assert main(["body", "make", "--motion", str(bvh), "--frame", "0", "--out", str(rest)]) == 0
    assert main(["body", "make", "--motion", str(bvh), "--frame", "3", "--out", str(posed)]) == 0
    a, b = load_mesh(rest)[0].vertices, load_mesh(posed)[0].vertices
    assert a.shape == b.shape
    moved = np.linalg.norm(a - b, axis=1)
    assert moved.max() > 0.1  # the right shin swung
    h = BodyShape().height
    assert np.median(moved[a[:, 1] > HIP_LEVEL * h]) < 0.02  # the upper body stayed


@pytest.mark.parametrize(
    "extra",
    [
        ["--shape", "height=9"],
        ["--shape", "nonsense=1"],
        ["--frame", "99"],
        ["--resolution", "5"],
        ["--frame", "2", "--no-motion"],
    ],
    ids=[
        "shape-out-of-range",
        "unknown-shape-key",
        "frame-out-of-range",
        "resolution",
        "frame-no-motion",
    ],
)
def test_cli_rejects_bad_input(tmp_path, capsys, extra):
    from app.cli import main

    bvh = tmp_path / "knee.bvh"
    _write_bvh(bvh)
    out = tmp_path / "body.obj"
    if "--no-motion" in extra:
        args = ["body", "make", "--frame", "2", "--out", str(out)]
    else:
        args = ["body", "make", "--motion", str(bvh), "--out", str(out), *extra]
    assert main(args) == 2
    assert not out.exists()
    assert "error" in capsys.readouterr().err


def test_cli_rejects_unknown_mesh_type(tmp_path):
    from app.cli import main

    out = tmp_path / "body.xyz"
    assert main(["body", "make", "--out", str(out)]) == 2
    assert not out.exists()
