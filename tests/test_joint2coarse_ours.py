"""Our Joint2Coarse (model=ours): the body-driven base, the residual (network, or linear by
ridge), save and load, the torch module, bad model files."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from core.body.shape import BodyShape, mannequin_skeleton
from core.errors import InputError
from tests.conftest import assert_close
from training.joint2coarse import (
    Joint2CoarseClip,
    Joint2CoarseConfig,
    Joint2CoarseStream,
    load_model,
    motion_descriptors,
    predict_proxy,
    train_joint2coarse,
    vertex_errors,
)
from training.joint2coarse.body_model import (
    BodyResidualModel,
    body_rig,
    bone_transforms,
    hidden_names,
    motion_features,
    residual_hidden,
)
from training.joint2coarse.descriptor import canonical_joint_order
from training.joint2coarse.synthetic import rest_skirt, synthetic_clip

OURS = Joint2CoarseConfig(model="ours", ridge=1e-4)
LINEAR = replace(OURS, residual_widths=())


@pytest.fixture(scope="module")
def rig():
    return body_rig(BodyShape(), rest_skirt(), fade=1.0)


@pytest.fixture(scope="module")
def clips():
    return [Joint2CoarseClip(*synthetic_clip(240, s), name=f"skirt-{s}") for s in (0, 1)]


@pytest.fixture(scope="module")
def trained(clips, rig, tmp_path_factory):
    return train_joint2coarse(clips, tmp_path_factory.mktemp("ours"), OURS, rig=rig)


def test_rig_weights_fade_from_the_body_to_the_hips(rig):
    weights, rest_joints, rest_vertices = rig
    v = len(rest_skirt())
    assert weights.shape == (v, 20) and rest_joints.shape == (20, 3)
    assert rest_vertices.shape == (v, 3)
    assert (weights >= 0).all() and np.allclose(weights.sum(1), 1.0, atol=1e-5)
    assert np.allclose(rest_joints[0], 0.0)  # relative to the rest root
    height = rest_vertices[:, 1]
    hem = height <= height.min() + 1e-6
    assert_close(weights[hem, 0], np.ones(hem.sum()), atol=1e-6, what="hem follows the hips")
    # Fully skinned (fade 0): the hem takes the legs' weights too, never the arms'.
    full = body_rig(BodyShape(), rest_skirt(), fade=0.0)[0]
    skel = mannequin_skeleton()
    names = canonical_joint_order(skel.rest_positions()[None], skel.names)  # order check only
    assert names.shape == (1, 20, 3)
    assert full[hem][:, 1:].sum() > 0.1 * hem.sum()
    with pytest.raises(InputError):
        body_rig(BodyShape(), np.zeros((0, 3)), 1.0)


def test_base_is_the_rest_proxy_at_rest_and_moves_rigidly_with_the_body(rig):
    weights, rest_joints, rest_vertices = rig
    pose = rest_joints[None, 1:].astype(np.float64)
    m = bone_transforms(pose, rest_joints)
    assert_close(m[..., :3], np.broadcast_to(np.eye(3), m[..., :3].shape), atol=1e-9)
    # The whole body pitched forward 20 degrees about the hips: every bone turns with it.
    a = np.radians(20.0)
    r = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    m = bone_transforms(pose @ r.T, rest_joints)
    assert_close(m[0, :, :, :3], np.broadcast_to(r, (20, 3, 3)), atol=1e-6, what="rotations")
    k = motion_features(np.zeros((1, 17 * 57)), 17).shape[1]
    arrays = {
        "weights": weights, "rest_joints": rest_joints, "rest_vertices": rest_vertices,
        "feat_mean": np.zeros(k), "feat_std": np.ones(k), "coef": np.zeros((k + 1, weights.size // 20 * 3)),
    }  # fmt: skip
    model = BodyResidualModel(OURS, 17 * 57, arrays)
    desc = np.tile(pose.reshape(1, 1, -1), (1, 17, 1)).reshape(1, -1)
    assert_close(model.base(model.transforms(desc))[0], rest_vertices, atol=1e-5, what="rest")
    desc = np.tile((pose @ r.T).reshape(1, 1, -1), (1, 17, 1)).reshape(1, -1)
    pitched = model.base(model.transforms(desc))[0]
    assert_close(pitched, rest_vertices @ r.T, atol=1e-5, what="pitched base")


@pytest.mark.parametrize("residual", ["network", "linear"])
def test_ours_fits_the_synthetic_skirt_and_holds_on_an_unseen_walk(
    residual, trained, clips, rig, tmp_path
):
    if residual == "network":
        res, stage = trained, "residual"
    else:
        res, stage = train_joint2coarse(clips, tmp_path, LINEAR, rig=rig), "ridge"
    assert isinstance(res.net, BodyResidualModel) and res.model_path.is_file()
    base = res.baseline.mean_mm
    assert res.stage_errors[stage].mean_mm < 0.2 * base
    joints, root_rot, skirt = synthetic_clip(200, 7)  # a walk never trained on
    pred = predict_proxy(res.net, joints, root_rot)
    assert pred.shape == skirt.shape and pred.dtype == np.float32 and np.isfinite(pred).all()
    assert vertex_errors(pred, skirt).mean_mm < 0.2 * base


def test_the_network_is_plain_matrices_and_runs_in_torch_as_in_numpy(trained, clips, tmp_path):
    """The residual network folds into ``hidden0``, ``hidden1`` and ``coef`` (bias rows last);
    the torch module gives numpy's prediction; a file whose layer shapes do not chain is
    refused, naming it."""
    net = trained.net
    arrays = net.arrays
    assert hidden_names(arrays) == ["hidden0", "hidden1"]
    n_features = len(arrays["feat_mean"])
    assert arrays["hidden0"].shape == (n_features + 1, 256)
    assert arrays["hidden1"].shape == (257, 256)
    k = arrays["basis"].shape[0]  # the principal components and the mean residual
    assert arrays["coef"].shape == (257, k) and arrays["basis"].shape == (k, net.n_vertices * 3)
    desc = motion_descriptors(clips[1].joints, clips[1].root_rotations, OURS.window, OURS.stride)
    desc = desc[0][:50]
    with torch.no_grad():
        out = net.to_torch()(torch.from_numpy(desc)).numpy()
    assert_close(out, net.predict(desc), atol=1e-5, what="torch vs numpy")
    payload = torch.load(trained.model_path, weights_only=False)
    payload["state_dict"]["hidden1"] = payload["state_dict"]["hidden1"][:-3]
    bad = tmp_path / "bad.pt"
    torch.save(payload, bad)
    with pytest.raises(InputError, match="hidden1") as err:
        load_model(bad)
    assert str(bad) in str(err.value)
    payload = torch.load(trained.model_path, weights_only=False)
    payload["state_dict"]["basis"] = payload["state_dict"]["basis"][:, :-3]
    torch.save(payload, bad)
    with pytest.raises(InputError, match="vertices need") as err:
        load_model(bad)
    assert str(bad) in str(err.value)


def test_members_fold_into_one_network_that_predicts_their_mean():
    """``residual_members``: networks trained from successive seeds, stacked (first layers side
    by side, later ones block diagonal, last layers averaged) give the mean of their outputs."""
    from training.joint2coarse.body_model import fit_residual_network, stack_members

    rng = np.random.default_rng(1)
    x = np.concatenate([rng.standard_normal((80, 5)), np.ones((80, 1))], 1)
    y = np.tanh(x[:, :2]) @ rng.standard_normal((2, 9)) * 0.01
    cfg = replace(OURS, residual_widths=(6, 4), residual_steps=20, residual_basis=3)
    members = [fit_residual_network(replace(cfg, seed=s), x, y) for s in (0, 1, 2)]
    assert all(np.array_equal(m[2], members[0][2]) for m in members)  # one shared basis
    outputs = [residual_hidden(x, h) @ c @ b for h, c, b in members]
    hidden, coef = stack_members([(h, c) for h, c, _ in members])
    assert [w.shape for w in hidden] == [(6, 18), (19, 12)] and coef.shape == (13, 4)
    stacked = residual_hidden(x, hidden) @ coef @ members[0][2]
    assert_close(stacked, np.mean(outputs, 0), atol=1e-9, what="stacked vs mean of members")
    one = [members[0][:2]]
    assert stack_members(one) is one[0]  # a single member as it is
    with pytest.raises(InputError, match="residual_members"):
        replace(cfg, residual_members=0)


def test_ours_saves_loads_and_streams_like_the_batch(trained, clips, tmp_path):
    net = load_model(trained.model_path)
    assert isinstance(net, BodyResidualModel) and net.config == OURS
    clip = clips[1]
    pred = predict_proxy(net, clip.joints, clip.root_rotations)
    assert_close(pred, predict_proxy(trained.net, clip.joints, clip.root_rotations), what="reload")
    stream = Joint2CoarseStream(net)
    for t in range(40):
        frame = stream.push(clip.joints[t], clip.root_rotations[t])
        assert_close(frame, pred[t], atol=1e-4, what=f"stream frame {t}")


def test_ours_stays_finite_on_extreme_motion_and_needs_a_rig(trained, clips, tmp_path):
    clip = clips[0]
    rng = np.random.default_rng(0)
    wild = clip.joints + rng.normal(0, 0.5, clip.joints.shape).astype(np.float32)
    pred = predict_proxy(trained.net, wild, clip.root_rotations)
    assert np.isfinite(pred).all()
    desc = motion_descriptors(wild, clip.root_rotations, OURS.window, OURS.stride)[0]
    assert np.isfinite(motion_features(desc, OURS.num_samples)).all()
    with pytest.raises(InputError, match="rig"):
        train_joint2coarse(clips, tmp_path, OURS)
    with pytest.raises(InputError):
        Joint2CoarseConfig(model="graph")


def test_residual_input_noise_and_weight_decay_change_only_what_they_say():
    from training.joint2coarse.body_model import fit_residual_network

    rng = np.random.default_rng(0)
    x = np.concatenate([rng.standard_normal((64, 6)), np.ones((64, 1))], 1)
    y = np.tanh(x[:, :3]) @ rng.standard_normal((3, 12)) * 0.01
    cfg = replace(OURS, residual_widths=(8,), residual_steps=30, residual_basis=4)

    def fit(**changes):
        hidden, coef, _ = fit_residual_network(replace(cfg, **changes), x, y)
        return np.concatenate([hidden[0].ravel(), coef.ravel()])

    plain = fit()
    assert np.array_equal(plain, fit())  # seeded: the same network twice
    assert np.array_equal(plain, fit(residual_input_noise=0.0))
    assert not np.array_equal(plain, fit(residual_input_noise=0.3))
    assert not np.array_equal(plain, fit(residual_weight_decay=0.5))
    for bad in ({"residual_input_noise": -0.1}, {"residual_weight_decay": float("nan")}):
        with pytest.raises(InputError, match=next(iter(bad))):
            replace(cfg, **bad)


def test_distance_loss_learns_the_median_where_squared_error_learns_the_mean(monkeypatch):
    """``residual_loss="distance"`` minimises the reported error (each vertex's distance):
    where one input has two outcomes (a vertex at rest in two frames of three, 30 mm away in
    the third) it predicts the geometric median (rest), squared error the mean (10 mm)."""
    from training.joint2coarse import body_model

    monkeypatch.setattr(body_model, "DISTANCE_VERTICES", 2)  # a random half of the 4 each step
    rng = np.random.default_rng(0)
    n = 300
    x = np.concatenate([rng.standard_normal((n, 3)) * 1e-3, np.ones((n, 1))], 1)
    y = np.zeros((n, 4, 3))
    y[::3, :, 0] = 0.03  # every vertex, one frame in three
    y = y.reshape(n, -1)
    cfg = replace(OURS, residual_widths=(8,), residual_steps=400, residual_basis=2)

    def offset(loss: str) -> float:
        hidden, coef, basis = body_model.fit_residual_network(
            replace(cfg, residual_loss=loss), x, y
        )
        return float(np.mean(residual_hidden(x, hidden) @ coef @ basis))  # mean x-offset, m

    squared, distance = offset("squared") * 3, offset("distance") * 3  # mean over x of 4 verts
    assert abs(squared - 0.01) < 0.002, squared
    assert abs(distance) < 0.003, distance
    with pytest.raises(InputError, match="residual_loss"):
        replace(cfg, residual_loss="huber")


def _rot(axis: int, degrees: float) -> np.ndarray:
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    i, j = [k for k in range(3) if k != axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def test_hips_frame_features_see_a_tilted_body_as_the_same_motion(clips):
    """feature_frame=hips: the whole motion turned about the root (a pelvis tilted, say) gives
    the same features but gravity's direction; ``hips+heading`` adds the heading-frame pose;
    the count matches :func:`feature_count`."""
    from training.joint2coarse.body_model import feature_count

    rest = body_rig(BodyShape(), rest_skirt(), fade=1.0)[1]
    desc = motion_descriptors(clips[0].joints, clips[0].root_rotations, OURS.window, OURS.stride)
    desc = desc[0][100:110].astype(np.float64)
    k = OURS.num_samples
    tilt = _rot(0, 25.0) @ _rot(2, -10.0)
    tilted = (desc.reshape(len(desc), k, 19, 3) @ tilt.T).reshape(len(desc), -1)
    hips = bone_transforms(desc[:, :57].reshape(-1, 19, 3), rest)[:, 0, :, :3]
    hips_t = bone_transforms(tilted[:, :57].reshape(-1, 19, 3), rest)[:, 0, :, :3]
    assert_close(hips_t, tilt @ hips, atol=1e-9, what="the hips turn with the body")
    a = motion_features(desc, k, "hips", hips)
    b = motion_features(tilted, k, "hips", hips_t)
    up = slice(57, 60)
    assert_close(np.delete(a, up, 1), np.delete(b, up, 1), atol=1e-9, what="tilt-free features")
    assert_close(a[:, up], hips[:, 1, :], what="gravity's direction in the hips' frame")
    assert not np.allclose(a[:, up], b[:, up])
    head = motion_features(desc, k)
    assert not np.allclose(head, motion_features(tilted, k))  # the heading frame sees the tilt
    both = motion_features(desc, k, "hips+heading", hips)
    assert_close(both[:, 60:117], desc[:, :57], what="heading-frame pose")
    for frame, f in (("heading", head), ("hips", a), ("hips+heading", both)):
        assert feature_count(replace(OURS, feature_frame=frame), desc.shape[1]) == f.shape[1]
    with pytest.raises(InputError, match="feature_frame"):
        replace(OURS, feature_frame="pelvis")
    with pytest.raises(InputError, match="residual_frame"):
        replace(OURS, residual_frame="world")


def test_vertex_frames_are_rotations_that_follow_their_bones(rig):
    from training.joint2coarse.body_model import skin_matrix, skin_weights, vertex_frames

    weights, rest_joints, rest_vertices = rig
    used, skin = skin_matrix(weights, rest_vertices)
    assert_close(skin_weights(skin), weights[:, used], what="weights inside the skin matrix")
    pose = rest_joints[None, 1:].astype(np.float64)
    f = vertex_frames(bone_transforms(pose, rest_joints), used, skin_weights(skin))
    assert_close(f, np.broadcast_to(np.eye(3), f.shape), atol=1e-6, what="rest: identity")
    tilt = _rot(0, 30.0)
    f = vertex_frames(bone_transforms(pose @ tilt.T, rest_joints), used, skin_weights(skin))
    assert_close(f, np.broadcast_to(tilt, f.shape), atol=1e-5, what="rigid: the body's turn")
    # a leg lifted: the frames stay rotations (orthonormal, det 1)
    from training.joint2coarse.descriptor import JOINT2COARSE_JOINTS

    ix = {n: i - 1 for i, n in enumerate(JOINT2COARSE_JOINTS)}  # pose has no root row
    hip, leg = ix["LeftUpLeg"], [ix["LeftLeg"], ix["LeftFoot"]]
    lifted = pose.copy()
    lifted[0, leg] = (pose[0, leg] - pose[0, hip]) @ _rot(0, -60.0).T + pose[0, hip]
    f = vertex_frames(bone_transforms(lifted, rest_joints), used, skin_weights(skin))[0]
    assert_close(f @ np.swapaxes(f, 1, 2), np.broadcast_to(np.eye(3), f.shape), atol=1e-9)
    assert np.allclose(np.linalg.det(f), 1.0)


@pytest.mark.parametrize(
    "changes", [{"feature_frame": "hips+heading"}, {"residual_frame": "skinned"}]
)
def test_other_frames_train_save_load_and_run_in_torch_as_in_numpy(changes, clips, rig, tmp_path):
    cfg = replace(OURS, residual_steps=800, **changes)
    res = train_joint2coarse(clips, tmp_path, cfg, rig=rig)
    assert res.stage_errors["residual"].mean_mm < 0.3 * res.baseline.mean_mm
    net = load_model(res.model_path)
    assert net.config == cfg
    clip = clips[1]
    pred = predict_proxy(net, clip.joints, clip.root_rotations)
    assert_close(pred, predict_proxy(res.net, clip.joints, clip.root_rotations), what="reload")
    desc = motion_descriptors(clip.joints, clip.root_rotations, cfg.window, cfg.stride)[0][:40]
    with torch.no_grad():
        out = net.to_torch()(torch.from_numpy(desc)).numpy()
    assert_close(out, net.predict(desc), atol=1e-5, what="torch vs numpy")
