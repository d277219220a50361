"""Joint2Coarse: descriptor invariants, training on a synthetic skirt, resume, streaming, extremes."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from core.body.shape import MANNEQUIN_JOINTS
from core.errors import InputError
from core.skeleton import CANONICAL_JOINTS, ROOT_JOINT, rotation_about
from tests.conftest import assert_close
from training.joint2coarse import (
    JOINT2COARSE_JOINTS,
    Joint2CoarseClip,
    Joint2CoarseConfig,
    Joint2CoarseStream,
    canonical_joint_order,
    follow_weights,
    from_output_frame,
    heading_rotations,
    joint2coarse_inputs,
    load_model,
    motion_descriptors,
    predict_proxy,
    prepare_data,
    push_out_of_capsules,
    reconstruct_proxy,
    tilt_rotvecs,
    to_output_frame,
    to_root_frame,
    train_joint2coarse,
    vertex_errors,
)
from training.joint2coarse.descriptor import rotate_partially
from training.joint2coarse.model import (
    MODEL_FORMAT,
    Joint2CoarseNet,
    OutputBasis,
    principal_basis,
    save_model,
)
from training.joint2coarse.predict import FrozenForward
from training.joint2coarse.synthetic import synthetic_clip, synthetic_walk

torch.set_num_threads(1)

#: A small network for a 120-vertex skirt (the paper's sizes are for thousands of vertices).
SMALL = Joint2CoarseConfig(
    window=8,
    stride=2,
    encoder_widths=(128, 64),
    latent_dim=16,
    motion_widths=(128, 64),
    output_basis=64,  # 64 x (128 + 360) < 128 x 360: used (the default 256 would not be)
    min_width=16,
    width_reference_vertices=120,
    batch_size=64,
    autoencoder_steps=250,
    motion_steps=350,
    finetune_steps=150,
    checkpoint_every=100,
    log_every=50,
    eval_every=100,
)
#: An even shorter schedule for the determinism and resume runs.
TINY = replace(
    SMALL, autoencoder_steps=40, motion_steps=40, finetune_steps=20, checkpoint_every=15,
    log_every=5, eval_every=10,
)  # fmt: skip

Y = np.array([0.0, 1.0, 0.0])


def _clips(frames=300, seeds=(0, 1)) -> list[Joint2CoarseClip]:
    return [Joint2CoarseClip(*synthetic_clip(frames, s), name=f"skirt-{s}.npz") for s in seeds]


@pytest.fixture(scope="module")
def clips() -> list[Joint2CoarseClip]:
    return _clips()


@pytest.fixture(scope="module")
def trained(clips, tmp_path_factory):
    out = tmp_path_factory.mktemp("j2c")
    return train_joint2coarse(clips, out, SMALL, progress=False)


def _weights(net) -> dict[str, np.ndarray]:
    return {k: v.detach().numpy().copy() for k, v in net.state_dict().items()}


# -- inputs -------------------------------------------------------------------------------------


def test_canonical_order_matches_names():
    motion = synthetic_walk(12, seed=3)
    world = motion.joint_positions()
    joints, root_rot = joint2coarse_inputs(motion)
    assert joints.shape == (12, 20, 3) and joints.dtype == np.float32
    assert root_rot.shape == (12, 3, 3)
    assert JOINT2COARSE_JOINTS == (ROOT_JOINT, *CANONICAL_JOINTS)
    for i, name in enumerate(JOINT2COARSE_JOINTS):
        assert_close(joints[:, i], world[:, MANNEQUIN_JOINTS.index(name)], what=name)
    names = list(MANNEQUIN_JOINTS)
    names[MANNEQUIN_JOINTS.index("Head")] = "Skull"
    with pytest.raises(InputError, match=r"x\.bvh: skeleton lacks joints \['Head'\]"):
        canonical_joint_order(world, names, "x.bvh")


def test_heading_is_the_yaw_even_when_tilted():
    yaw = np.linspace(-3.0, 3.0, 13)
    for tilt_axis in (np.array([1.0, 0, 0]), np.array([0.6, 0, 0.8])):
        for tilt in (0.0, 0.4, 1.5, 2.0):  # past 90 degrees too
            r = rotation_about(Y, yaw) @ rotation_about(tilt_axis, tilt)
            assert_close(heading_rotations(r), rotation_about(Y, yaw), atol=1e-9, what="heading")


def test_descriptor_invariant_to_walk_position_and_facing_not_tilt():
    joints, root_rot = joint2coarse_inputs(synthetic_walk(40, seed=2))
    desc, _, _ = motion_descriptors(joints, root_rot, window=34, stride=2)
    assert desc.shape == (40, 969) and desc.dtype == np.float32
    # Frames before the start repeat frame 0: frame 0's samples are all the same.
    first = desc[0].reshape(17, 19, 3)
    assert_close(first, np.broadcast_to(first[0], first.shape), what="frame 0 history")

    spin = rotation_about(Y, 2.1)
    moved = joints.astype(np.float64) @ spin.T + np.array([1000.0, 0.3, -250.0])
    desc2, _, _ = motion_descriptors(moved, spin @ root_rot, 34, 2)
    assert_close(desc2, desc, atol=2e-4, what="descriptor after moving and turning the walk")

    tilt = rotation_about(np.array([1.0, 0.0, 0.0]), 0.5)
    desc3, _, _ = motion_descriptors(joints @ tilt.T, tilt @ root_rot, 34, 2)
    assert np.abs(desc3 - desc).max() > 0.05, "a tilted body must change the descriptor"


def test_tilt_is_the_swing_past_the_heading_up_to_a_half_turn():
    rng = np.random.default_rng(5)
    yaw = rng.uniform(-3, 3, 9)
    axis = np.array([0.6, 0.0, 0.8])
    for angle in (0.0, 1e-9, 1e-4, 0.7, np.pi / 2, 2.5, np.pi - 1e-6, np.pi):
        r = rotation_about(Y, yaw) @ rotation_about(axis, angle)
        heading = heading_rotations(r)
        tilt = tilt_rotvecs(r, heading)
        assert tilt.shape == (9, 3) and np.isfinite(tilt).all()
        # Turning the basis vectors by the whole tilt gives heading^T root (its columns).
        turned = rotate_partially(np.broadcast_to(np.eye(3), (9, 3, 3)), tilt, np.ones(3))
        swing = np.swapaxes(heading, -1, -2) @ r
        assert_close(np.swapaxes(turned, -1, -2), swing, atol=1e-9, what=f"tilt {angle}")
        if angle < 2.6:  # nearer a half turn the yaw/swing split itself is ill-conditioned
            assert_close(tilt, np.broadcast_to(axis * angle, tilt.shape), atol=1e-6, what="axis")


def test_output_frames_follow_the_tilt_by_height():
    rng = np.random.default_rng(6)
    weights = follow_weights(np.array([0.0, -0.3, -0.6, -0.15]), 0.8)
    assert_close(weights, np.array([0.8, 0.4, 0.0, 0.6]), atol=1e-6, what="linear in height")
    assert_close(follow_weights(np.zeros(3), 0.5), np.full(3, 0.5), what="one height")

    t, v = 6, 4
    yaw, pitch = rng.uniform(-3, 3, t), rng.uniform(-1.2, 1.2, t)
    root = rotation_about(Y, yaw) @ rotation_about(np.array([1.0, 0.0, 0.0]), pitch)
    heading = heading_rotations(root)
    tilt = tilt_rotvecs(root, heading)
    origin = rng.normal(size=(t, 3))
    points = rng.normal(size=(t, v, 3))
    rooted = to_root_frame(points, origin, heading)
    assert_close(to_output_frame(points, origin, heading, tilt, None), rooted, what="no follow")
    full = to_output_frame(points, origin, heading, tilt, np.ones(v))
    pelvis = np.einsum("tji,tvj->tvi", root, points - origin[:, None])  # root^T (p - o)
    assert_close(full, pelvis, atol=1e-9, what="follow 1 is the root's own frame")
    local = to_output_frame(points, origin, heading, tilt, weights)
    assert_close(local[:, 2], rooted[:, 2], atol=1e-12, what="follow 0 is the heading frame")
    back = from_output_frame(local, origin, heading, tilt, weights)
    assert_close(back, points, atol=1e-9, what="from_output_frame inverts to_output_frame")

    # A garment fixed to the pelvis: its waistband is still in the output frame, however the
    # hips tilt; its hem moves (it is predicted in the heading frame).
    walk_joints, walk_rot = joint2coarse_inputs(synthetic_walk(t, seed=3))
    rest = np.array([[0.0, 0.0, 0.15], [0.2, -0.2, 0.0], [0.0, -0.6, 0.3]])
    proxy = walk_joints[:, :1].astype(np.float64) + np.einsum("tij,vj->tvi", root, rest)
    clip = Joint2CoarseClip(walk_joints, root.astype(np.float32), proxy.astype(np.float32))
    cfg = replace(SMALL, window=2, val_fraction=0.0, tilt_follow=1.0)
    verts = prepare_data([clip], cfg).train_verts.reshape(t, 3, 3)
    assert_close(verts[:, 0], np.broadcast_to(rest[0], (t, 3)), atol=1e-5, what="waistband")
    assert np.ptp(verts[:, 2], axis=0).max() > 0.1, "the hem is in the heading frame"
    paper = prepare_data([clip], replace(cfg, tilt_follow=0.0))
    assert not paper.follow.any()
    assert np.ptp(paper.train_verts.reshape(t, 3, 3)[:, 0], axis=0).max() > 0.05


# -- training -----------------------------------------------------------------------------------


def test_training_beats_mean_shape_and_writes_files(trained, clips):
    res = trained
    # The default config predicts coefficients of a basis of the training shapes' principal
    # directions, scaled to unit-size coefficients: orthogonal rows, norms decreasing.
    basis = res.net.shape_decoder[-1].basis.numpy().astype(np.float64)
    assert res.net.n_basis == SMALL.output_basis == 64
    gram = basis @ basis.T
    norms = np.diag(gram)
    assert_close(gram, np.diag(norms), atol=1e-4 * norms[0], what="basis rows orthogonal")
    assert (np.diff(norms) <= 1e-6 * norms[0]).all() and norms[0] > 1.0
    assert res.model_path.is_file() and res.checkpoint_path.is_file()
    base = res.baseline.mean_mm
    for stage in ("autoencoder", "motion", "finetune"):
        err = res.stage_errors[stage]
        assert err.mean_mm < 0.2 * base, f"{stage}: {err.mean_mm:.2f} mm vs baseline {base:.2f}"
    with open(res.log_path, newline="") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["step"]) for r in rows] == list(range(50, SMALL.total_steps + 1, 50))
    assert {r["stage"] for r in rows} == {"autoencoder", "motion", "finetune"}
    assert all(np.isfinite(float(r["train_loss"])) for r in rows)

    # The saved model predicts world-space proxies as well as validation said (validation
    # frames are the last 15 % of each clip).
    net = load_model(res.model_path)
    clip = clips[1]
    pred = predict_proxy(net, clip.joints, clip.root_rotations)
    assert pred.shape == clip.proxy.shape and pred.dtype == np.float32
    val = slice(255, None)
    err = vertex_errors(pred[val], clip.proxy[val])
    assert err.mean_mm < 0.2 * base
    assert_close(pred, predict_proxy(res.net, clip.joints, clip.root_rotations), what="reload")
    # Batch size only splits the work.
    assert_close(
        predict_proxy(net, clip.joints, clip.root_rotations, batch_size=7), pred, atol=1e-5
    )


def test_autoencoder_bound_is_tight_on_known_shapes_and_loose_on_foreign_ones(trained, clips):
    net, clip = trained.net, clips[1]
    known = vertex_errors(
        reconstruct_proxy(net, clip.proxy, clip.joints, clip.root_rotations), clip.proxy
    )
    # Validation frames are seen by no stage: the autoencoder still reproduces them closely.
    assert known.mean_mm < 0.2 * trained.baseline.mean_mm
    # The skirt blown 30 cm sideways in the root frame is a shape no training frame had.
    blown = clip.proxy.copy()
    blown[..., 0] += 0.3 * (blown[..., 1] < np.median(blown[..., 1]))
    foreign = vertex_errors(reconstruct_proxy(net, blown, clip.joints, clip.root_rotations), blown)
    assert foreign.mean_mm > 5 * known.mean_mm
    was = net.training
    net.train()  # dropout on: the call still evaluates in eval mode and puts the mode back
    again = reconstruct_proxy(net, clip.proxy, clip.joints, clip.root_rotations)
    assert net.training
    net.train(was)
    assert vertex_errors(again, clip.proxy).mean_mm == pytest.approx(known.mean_mm, rel=1e-5)
    with pytest.raises(InputError, match="proxy must be"):
        reconstruct_proxy(net, clip.proxy[:, :-1], clip.joints, clip.root_rotations)


def test_same_seed_same_weights_and_resume_equals_uninterrupted(clips, tmp_path):
    a = train_joint2coarse(clips, tmp_path / "a", TINY, progress=False)
    b = train_joint2coarse(clips, tmp_path / "b", TINY, progress=False)
    wa, wb = _weights(a.net), _weights(b.net)
    for k in wa:
        np.testing.assert_array_equal(wa[k], wb[k], err_msg=k)
    other = train_joint2coarse(clips, tmp_path / "s1", replace(TINY, seed=1), progress=False)
    assert any(not np.array_equal(wa[k], v) for k, v in _weights(other.net).items())

    # "Kill" the run at step 52 (mid-stage, 7 steps after the checkpoint at 45), then rerun.
    class Killed(Exception):
        pass

    def kill(step, stage, loss):
        if step == 52:
            raise Killed

    with pytest.raises(Killed):
        train_joint2coarse(clips, tmp_path / "c", TINY, progress=False, callback=kill)
    assert not (tmp_path / "c" / "joint2coarse.pt").exists()
    c = train_joint2coarse(clips, tmp_path / "c", TINY, progress=False)
    assert c.resumed_at_step == 45
    for k, v in _weights(c.net).items():
        np.testing.assert_array_equal(v, wa[k], err_msg=f"resumed run differs in {k}")
    assert (tmp_path / "c" / "joint2coarse_loss.csv").read_text() == a.log_path.read_text()
    assert c.stage_errors == a.stage_errors

    # A finished run is not retrained; another config in the same folder is refused.
    again = train_joint2coarse(clips, tmp_path / "a", TINY, progress=False)
    assert again.resumed_at_step == TINY.total_steps
    with pytest.raises(InputError, match="different config"):
        train_joint2coarse(clips, tmp_path / "a", replace(TINY, dropout=0.1), progress=False)


_KILL_SCRIPT = """
import sys, time, torch
torch.set_num_threads(1)
sys.path.insert(0, {root!r})
from tests.test_joint2coarse import TINY, _clips
from training.joint2coarse import train_joint2coarse
from dataclasses import replace
train_joint2coarse(_clips(120), {out!r}, replace(TINY, **{overrides!r}), progress=False,
                   callback=lambda *a: time.sleep(0.02))
"""


@pytest.mark.slow
def test_sigkill_mid_run_then_resume(tmp_path):
    """A real kill -9 while training: the rerun resumes and ends with the uninterrupted weights."""
    overrides = {"autoencoder_steps": 80, "motion_steps": 80, "finetune_steps": 40}
    config = replace(TINY, **overrides)
    root = str(Path(__file__).resolve().parents[1])
    out = tmp_path / "killed"
    code = _KILL_SCRIPT.format(root=root, out=str(out), overrides=overrides)
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=root)
    ckpt = out / "joint2coarse_train.pt"
    deadline = time.monotonic() + 120
    while not ckpt.is_file() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)  # let it get a few checkpoints further
    assert proc.poll() is None, "training ended before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    resumed = train_joint2coarse(_clips(120), out, config, progress=False)
    assert 0 < resumed.resumed_at_step < config.total_steps
    straight = train_joint2coarse(_clips(120), tmp_path / "straight", config, progress=False)
    ws = _weights(straight.net)
    for k, v in _weights(resumed.net).items():
        np.testing.assert_array_equal(v, ws[k], err_msg=k)
    assert resumed.log_path.read_text() == straight.log_path.read_text()


# -- prediction ---------------------------------------------------------------------------------


def test_streaming_equals_batch(trained):
    net = trained.net
    assert net.follow_weights() is not None  # output frames that follow the tilt
    joints, root_rot, _ = synthetic_clip(40, seed=7)
    pitch = rotation_about(np.array([1.0, 0.0, 0.0]), 1.2 * np.sin(np.arange(40) / 5.0))
    for r_clip in (root_rot, (root_rot @ pitch).astype(np.float32)):  # and hips tilted far
        batch = predict_proxy(net, joints, r_clip)
        stream = Joint2CoarseStream(net)
        for _ in range(2):  # and again after a reset
            frames = np.stack([stream.push(j, r) for j, r in zip(joints, r_clip)])
            assert_close(frames, batch, atol=1e-5, what="stream vs batch")
            stream.reset()


def _random_net(config: Joint2CoarseConfig, n_vertices: int, seed: int = 0) -> Joint2CoarseNet:
    """An untrained network with made-up statistics and (when it has one) output basis."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    d, out = config.num_samples * 57, 3 * n_vertices
    net = Joint2CoarseNet(config, n_vertices, d)
    net.set_statistics(
        rng.normal(0, 0.3, d), rng.uniform(0.05, 0.3, d),
        rng.normal(0, 0.3, out), rng.uniform(0.001, 0.05, out),
    )  # fmt: skip
    net.set_output_basis(rng.normal(size=(50, out)))
    return net.eval()


def test_output_basis_sizes_and_principal_basis():
    cfg = replace(SMALL, output_basis=32)
    assert cfg.basis_size(120) == 32 and cfg.basis_size(10) == 0  # 32 >= 30 coordinates: full
    assert replace(SMALL, output_basis=0).basis_size(120) == 0
    # The default: a basis where it makes the last layer smaller (2000 vertices: 2.0 M weights
    # instead of 12 M), none for small proxies (300 vertices: 307 k against 270 k).
    assert Joint2CoarseConfig().basis_size(2000) == 256
    assert Joint2CoarseConfig().basis_size(300) == 0
    with pytest.raises(InputError, match="output_basis"):
        Joint2CoarseConfig(output_basis=-1)
    net = Joint2CoarseNet(cfg, 120, cfg.num_samples * 57)
    assert net.n_basis == 32 and isinstance(net.shape_decoder[-1], OutputBasis)
    assert net.shape_decoder[-2].out_features == 32
    assert net.shape_decoder(torch.zeros(5, cfg.latent_dim)).shape == (5, 360)
    full = Joint2CoarseNet(replace(cfg, output_basis=0), 120, cfg.num_samples * 57)
    assert full.n_basis == 0 and full.shape_decoder[-1].out_features == 360

    # Rank-6 data: 6 orthogonal rows that reproduce it exactly with coefficients of RMS 1; the
    # rest zero; deterministic; the same from the SVD branch (N <= D) and the eigen one (N > D).
    rng = np.random.default_rng(3)
    data = rng.normal(size=(40, 6)) @ rng.normal(size=(6, 30))
    basis = principal_basis(data, 8)
    assert basis.shape == (8, 30) and basis.dtype == np.float32
    b = basis[:6].astype(np.float64)
    norms = (b**2).sum(1)
    assert_close(b @ b.T, np.diag(norms), atol=1e-5 * norms[0], what="orthogonal rows")
    coefficients = data @ b.T / norms
    assert_close((coefficients**2).mean(0), np.ones(6), atol=1e-4, what="unit-size coefficients")
    assert_close(coefficients @ b, data, atol=1e-4, what="rank-6 reconstruction")
    assert np.abs(basis[6:]).max() < 1e-5  # beyond the rank: the RMS there is rounding noise
    np.testing.assert_array_equal(basis, principal_basis(data, 8))
    peaks = basis[np.arange(6), np.abs(basis[:6]).argmax(1)]
    assert (peaks > 0).all()
    wide = data[:10, :20]  # 10 samples of 20 coordinates: SVD branch
    tall = np.tile(wide, (3, 1))  # 30 samples, the same directions: eigen branch
    assert_close(principal_basis(tall, 5), principal_basis(wide, 5), atol=1e-4, what="eigh")
    assert not principal_basis(data[:3], 8)[3:].any()  # 3 samples: rank 3 at most


def test_principal_basis_does_not_follow_numpy_blas_threads():
    # The quick preset's size (900 training shapes of a 1033-vertex proxy): numpy's SVD gave a
    # float32 basis that differed bit-wise between 1 and 2 OpenBLAS threads, and so trained a
    # different Joint2Coarse from the same seed depending on OMP_NUM_THREADS. The basis is
    # computed in torch (one thread here), which does not read that variable.
    code = (
        "import hashlib, numpy as np, torch; torch.set_num_threads(1);"
        "from training.joint2coarse.model import principal_basis;"
        "x = np.random.default_rng(0).standard_normal((900, 3099)).astype(np.float32);"
        "print(hashlib.sha256(principal_basis(x, 256).tobytes()).hexdigest())"
    )
    digests = set()
    for threads in ("1", "2"):
        env = {**os.environ, "OMP_NUM_THREADS": threads, "OPENBLAS_NUM_THREADS": threads}
        out = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True,
            cwd=Path(__file__).resolve().parents[1],
        )  # fmt: skip
        digests.add(out.stdout.strip())
    assert len(digests) == 1


@pytest.mark.parametrize("output_basis", [0, 32])
def test_frozen_forward_equals_network(output_basis):
    net = _random_net(replace(SMALL, output_basis=output_basis), 120)
    desc = torch.from_numpy(np.random.default_rng(1).normal(0, 1.0, (6, net.descriptor_dim)))
    desc = desc.float()
    with torch.inference_mode():
        ref = net(desc).reshape(6, -1).numpy()
        fast = FrozenForward(net)
        assert_close(fast(desc).numpy(), ref, atol=2e-6, what="frozen batch")
        for i in range(6):  # one frame at a time, through the preallocated buffers
            assert_close(fast(desc[i : i + 1]).numpy(), ref[i : i + 1], atol=2e-6, what="one")
        again = FrozenForward(net)(desc).numpy()
        np.testing.assert_array_equal(again, FrozenForward(net)(desc).numpy())
        # Far outside the training range the output clamp still holds.
        wild = FrozenForward(net)(desc * 1e4).numpy()
        assert_close(wild, net(desc * 1e4).reshape(6, -1).numpy(), atol=1e-5, what="clamped")
        half = FrozenForward(net, torch.bfloat16)(desc).numpy()
        assert np.abs(half - ref).max() < 0.02  # bfloat16 rounding of made-up weights


def test_stream_snapshots_weights_and_full_layer_stream_equals_batch():
    net = _random_net(replace(SMALL, output_basis=0), 120)
    joints, root_rot, _ = synthetic_clip(25, seed=11)
    stream = Joint2CoarseStream(net)
    frames = np.stack([stream.push(j, r) for j, r in zip(joints, root_rot)])
    batch = predict_proxy(net, joints, root_rot)
    assert frames.shape == (25, 120, 3) and frames.dtype == np.float32
    assert_close(frames, batch, atol=1e-5, what="full-layer stream vs batch")
    with torch.no_grad():  # the stream took a copy: later changes to net are not seen
        net.shape_decoder[-1].bias.add_(1.0)
    stream.reset()
    again = np.stack([stream.push(j, r) for j, r in zip(joints, root_rot)])
    np.testing.assert_array_equal(again, frames)


def test_model_files_from_before_the_output_basis(tmp_path, clips):
    """Files written before ``output_basis`` existed load as full-layer models; a file whose
    weights do not fit its config, and an old training checkpoint, are refused clearly."""
    net = _random_net(replace(SMALL, output_basis=0), 120)
    save_model(net, tmp_path / "new.pt")
    payload = torch.load(tmp_path / "new.pt", weights_only=True)
    assert payload["format"] == MODEL_FORMAT
    del payload["config"]["output_basis"]  # what an older version wrote
    del payload["config"]["tilt_follow"]
    del payload["state_dict"]["follow"]
    torch.save(payload, tmp_path / "old.pt")
    old = load_model(tmp_path / "old.pt")
    assert old.config.output_basis == 0 and old.n_basis == 0
    assert old.config.tilt_follow == 0.0 and old.follow_weights() is None  # the root frame
    joints, root_rot, _ = synthetic_clip(12, seed=2)
    assert_close(
        predict_proxy(old, joints, root_rot), predict_proxy(net, joints, root_rot), what="old"
    )
    payload["config"]["output_basis"] = 32  # a config that does not match the weights
    torch.save(payload, tmp_path / "mismatch.pt")
    with pytest.raises(InputError, match=r"mismatch\.pt: Joint2Coarse weights do not fit"):
        load_model(tmp_path / "mismatch.pt")
    payload["config"]["colour"] = "red"
    torch.save(payload, tmp_path / "unknown.pt")
    with pytest.raises(InputError, match=r"unknown\.pt: .*unknown joint2coarse config keys"):
        load_model(tmp_path / "unknown.pt")

    # An older training checkpoint of the default config: resuming it with today's default
    # (an output basis) is refused, not silently mixed.
    run = tmp_path / "run"
    train_joint2coarse(clips, run, replace(TINY, output_basis=0), progress=False)
    ckpt = torch.load(run / "joint2coarse_train.pt", weights_only=True)
    del ckpt["config"]["output_basis"]
    torch.save(ckpt, run / "joint2coarse_train.pt")
    with pytest.raises(InputError, match="different config"):
        train_joint2coarse(clips, run, TINY, progress=False)
    again = train_joint2coarse(clips, run, replace(TINY, output_basis=0), progress=False)
    assert again.resumed_at_step == TINY.total_steps


def test_extreme_motion_is_finite_and_bounded(trained):
    net = trained.net
    mean = net.vert_mean.numpy().reshape(-1, 3)
    std = net.vert_std.numpy().reshape(-1, 3)
    bound = np.abs(mean) + SMALL.clamp_z * std + 1e-3  # output-frame metres, per coordinate

    joints, root_rot = joint2coarse_inputs(synthetic_walk(10_000, seed=4))
    far = joints + np.array([1000.0, 0.0, -1000.0], np.float32)  # 1.4 km away
    rng = np.random.default_rng(0)
    wild = joints[:300] + rng.normal(0.0, 50.0, joints[:300].shape).astype(np.float32)
    cases = [(far, root_rot), (wild, root_rot[:300])]
    flipped = np.einsum("ij,tjk->tik", rotation_about(np.array([1.0, 0, 0]), np.pi), root_rot)
    cases.append((joints[:300], flipped[:300].astype(np.float32)))  # upside down
    for j, r in cases:
        pred = predict_proxy(net, j, r)
        assert np.isfinite(pred).all()
        heading = heading_rotations(r)
        frame = (j[:, 0], heading, tilt_rotvecs(r, heading), net.follow_weights())
        local = to_output_frame(pred, *frame)
        assert (np.abs(local) <= bound).all(), f"max local {np.abs(local).max():.3f} m"
    # Far away, the proxy still follows the body (float32 positions at 1 km: ~0.1 mm steps).
    near = predict_proxy(net, joints[:500], root_rot[:500])
    shifted = predict_proxy(net, far[:500], root_rot[:500]) - np.array([1000.0, 0.0, -1000.0])
    assert_close(shifted, near, atol=2e-3, what="proxy of a walk moved 1.4 km")


def test_bf16_stream_close_to_float32(trained):
    joints, root_rot, _ = synthetic_clip(30, seed=8)
    ref = predict_proxy(trained.net, joints, root_rot)
    stream = Joint2CoarseStream(trained.net, bfloat16=True)
    frames = np.stack([stream.push(j, r) for j, r in zip(joints, root_rot)])
    assert vertex_errors(frames, ref).max_mm < 5.0


# -- collision push-out -------------------------------------------------------------------------


def _push_reference(v, caps, radii, margin):
    """Slow per-vertex version of one pass over the capsules."""
    out = np.array(v, np.float64)
    for k, (a, b) in enumerate(caps):
        for i, p in enumerate(out):
            ab = b - a
            s = np.clip(np.dot(p - a, ab) / np.dot(ab, ab), 0, 1) if ab @ ab > 0 else 0.0
            c = a + s * ab
            d = np.linalg.norm(p - c)
            if d < radii[k] + margin:
                out[i] = c + (radii[k] + margin) * (p - c) / d
    return out


def test_push_out_of_capsules():
    rng = np.random.default_rng(1)
    caps = np.array([[[0, 0, 0], [0, 1, 0]], [[1, 0, 0], [1.5, 0.5, 0]], [[3, 0, 0], [3, 0, 0]]])
    radii = np.array([0.2, 0.15, 0.3])
    v = rng.uniform([-0.5, -0.5, -0.5], [3.5, 1.5, 0.5], (4000, 3))
    out = push_out_of_capsules(v, caps, radii, margin=0.01, iterations=1)
    assert out.shape == v.shape and out.dtype == np.float32
    assert_close(out, _push_reference(v, caps, radii, 0.01), atol=1e-5, what="push-out")
    # Batched over frames with moving capsules, and a vertex exactly on an axis.
    frames = np.stack([v, v + 0.1])
    caps_t = np.stack([caps, caps + 0.1])
    frames[0, 0] = [0.0, 0.5, 0.0]
    out_t = push_out_of_capsules(frames, caps_t, radii, margin=0.01)

    def distances(points, t):  # (V, K) distance of every point to every capsule axis
        d = []
        for a, b in caps_t[t]:
            ab = b - a
            s = np.clip(((points - a) @ ab) / max(ab @ ab, 1e-12), 0, 1)
            d.append(np.linalg.norm(points - (a + s[:, None] * ab), axis=1))
        return np.stack(d, axis=1)

    for t in range(2):
        assert (distances(out_t[t], t) >= radii + 0.01 - 1e-5).all(), t
        # Exactly the vertices that started inside (capsules + margin) moved; no others.
        inside = (distances(frames[t], t) < radii + 0.01).any(axis=1)
        moved = np.linalg.norm(out_t[t] - frames[t], axis=1) > 1e-6
        assert inside.sum() > 50 and (~inside).sum() > 1000
        np.testing.assert_array_equal(moved, inside)


def test_prediction_with_capsules_and_stream(trained):
    joints, root_rot, _ = synthetic_clip(20, seed=9)
    hips, knees = joints[:, 0], joints[:, [14, 17]].mean(1)
    caps = np.stack([hips, knees], axis=1)[:, None]  # one fat capsule along the thighs
    radii = np.array([0.25])
    pred = predict_proxy(trained.net, joints, root_rot, capsules=caps, radii=radii)
    stream = Joint2CoarseStream(trained.net, radii=radii)
    frames = np.stack([stream.push(j, r, c) for j, r, c in zip(joints, root_rot, caps)])
    assert_close(frames, pred, atol=1e-5, what="stream with capsules")
    a, b = caps[:, 0, 0], caps[:, 0, 1]
    ab = b - a
    s = np.clip(np.einsum("tvi,ti->tv", pred - a[:, None], ab) / (ab * ab).sum(-1)[:, None], 0, 1)
    dist = np.linalg.norm(pred - (a[:, None] + s[..., None] * ab[:, None]), axis=-1)
    assert dist.min() >= 0.25 + 0.002 - 1e-5


def test_prediction_strain_limited_and_stream(trained, clips):
    # The network's proxy with its edges shortened toward its strain limit against the rest ring
    # skirt, the same in batch and in the stream.
    from core.sim.embed import strain_stats
    from core.strain import limit_stretch
    from training.joint2coarse import prediction_stretch_limit
    from training.joint2coarse.synthetic import skirt_faces

    joints, root_rot, proxy = synthetic_clip(20, seed=9)
    rest, faces = proxy[0], skirt_faces()
    raw = predict_proxy(trained.net, joints, root_rot)
    limit = prediction_stretch_limit(rest, faces)
    held = limit_stretch(raw, limit)
    before, after = strain_stats(raw, rest, faces), strain_stats(held, rest, faces)
    assert before.stretch_max > 0.2
    # the small network's proxy is stretched everywhere (p99 0.34): 30 sweeps of a Jacobi
    # projection bring it most of the way to the limit
    assert after.stretch_max < before.stretch_max / 5 and after.stretch_p99 < 0.05
    pred = predict_proxy(trained.net, joints, root_rot, stretch=limit)
    np.testing.assert_allclose(pred, held, atol=1e-6)
    stream = Joint2CoarseStream(trained.net, stretch=limit)
    frames = np.stack([stream.push(j, r) for j, r in zip(joints, root_rot)])
    # the stream's 1e-5 of float32 rounding can put an edge on the other side of the limit
    assert_close(frames, pred, atol=1e-3, what="strain-limited stream")
    with pytest.raises(InputError, match="120-vertex proxy"):
        predict_proxy(trained.net, joints, root_rot, stretch=prediction_stretch_limit(
            np.zeros((200, 3)), np.array([[0, 1, 199]])))  # fmt: skip


# -- metrics and bad input ----------------------------------------------------------------------


def test_vertex_errors():
    ref = np.zeros((4, 10, 3), np.float32)
    pred = ref.copy()
    pred[..., 0] = 0.003
    pred[0, 0] = [0.0, 0.04, 0.0]
    e = vertex_errors(pred, ref)
    assert e.max_mm == pytest.approx(40.0, rel=1e-5)
    assert e.mean_mm == pytest.approx((39 * 3.0 + 40.0) / 40, rel=1e-5)
    assert e.p95_mm == pytest.approx(3.0, rel=1e-5)
    with pytest.raises(ValueError):
        vertex_errors(pred, ref[:3])


def test_bad_inputs_are_refused(clips, trained, tmp_path):
    c = clips[0]
    with pytest.raises(InputError, match=r"skirt\.npz: proxy cache has 299 frames but the motion"):
        Joint2CoarseClip(c.joints, c.root_rotations, c.proxy[:-1], name="skirt.npz")
    with pytest.raises(InputError, match=r"root_rotations must be \(300, 3, 3\)"):
        Joint2CoarseClip(c.joints, c.root_rotations[:-1], c.proxy)
    with pytest.raises(InputError, match=r"joints must be \(T, 20, 3\)"):
        Joint2CoarseClip(c.joints[:, 1:], c.root_rotations, c.proxy)
    bad = c.proxy.copy()
    bad[3, 4, 1] = np.nan
    with pytest.raises(InputError, match="cache.npz: proxy cache contains NaN"):
        Joint2CoarseClip(c.joints, c.root_rotations, bad, name="cache.npz")
    nan_joints = c.joints.copy()
    nan_joints[0, 0, 0] = np.inf
    with pytest.raises(InputError, match="joints contain NaN"):
        predict_proxy(trained.net, nan_joints, c.root_rotations)
    other = Joint2CoarseClip(c.joints, c.root_rotations, c.proxy[:, :50], name="small.npz")
    with pytest.raises(InputError, match="small.npz: proxy cache has 50 vertices"):
        train_joint2coarse([c, other], tmp_path, TINY, progress=False)
    with pytest.raises(InputError, match="window"):
        Joint2CoarseConfig(window=0)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="junk.pt: cannot read"):
        load_model(junk)
    with pytest.raises(InputError, match="capsules exactly"):
        Joint2CoarseStream(trained.net).push(c.joints[0], c.root_rotations[0], np.zeros((1, 2, 3)))
