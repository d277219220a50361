"""Joint2Coarse's mirrored training clips (``mirror=true``): the mirror map of a proxy, the
mirrored motion, that a mirrored clip is what the mirrored motion gives, and our model's
symmetric prediction (numpy, torch, saved, streamed), and the project stage's fallback for a
garment that is not symmetric."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from core.body.shape import BodyShape
from core.errors import InputError
from core.mesh import Mesh, save_mesh
from pipeline.demo import _mirror_markdown
from pipeline.stages.joint2coarse import mirror_setting
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
from training.joint2coarse.augment import (
    MIRROR_JOINTS,
    mirror_descriptors,
    mirror_map,
    mirror_motion,
)
from training.joint2coarse.body_model import body_rig
from training.joint2coarse.descriptor import JOINT2COARSE_JOINTS
from training.joint2coarse.synthetic import (
    rest_skirt,
    skirt_faces,
    skirt_from_joints,
    synthetic_clip,
)
from training.joint2coarse.train import mirrored_clips


@pytest.fixture(scope="module")
def skirt_map():
    return mirror_map(rest_skirt(), skirt_faces())


def test_joints_swap_left_and_right():
    names = JOINT2COARSE_JOINTS
    for i, j in enumerate(MIRROR_JOINTS):
        assert MIRROR_JOINTS[j] == i
        assert names[j] == names[i].replace("Left", "#").replace("Right", "Left").replace(
            "#", "Right"
        )
    assert names[MIRROR_JOINTS[names.index("LeftUpLeg")]] == "RightUpLeg"
    assert MIRROR_JOINTS[names.index("Spine")] == names.index("Spine")


def test_a_symmetric_proxy_maps_each_vertex_onto_its_partner(skirt_map):
    rest = rest_skirt().astype(np.float64)
    assert skirt_map.asymmetry < 1e-5
    # the skirt's vertex k of a ring sits at angle 2 pi k / 20: its mirror is vertex -k
    assert_close(skirt_map.reflect(rest), rest, atol=1e-5)
    ring, k = np.divmod(np.arange(len(rest)), 20)
    partner = ring * 20 + (-k) % 20
    picked = skirt_map.corners[np.arange(len(rest)), np.argmax(skirt_map.barycentric, 1)]
    assert (picked == partner).all()
    assert_close(skirt_map.barycentric.max(1), np.ones(len(rest)), atol=1e-5)


def test_the_mirrored_clip_is_the_mirrored_motion_and_twice_is_the_clip(skirt_map):
    """The synthetic skirt is a left-right symmetric function of the motion (like the physics):
    the mirror of its clip must be the skirt of the mirrored motion."""
    clip = Joint2CoarseClip(*synthetic_clip(90, 3), name="walk")
    original, mirrored = mirrored_clips([clip], skirt_map)
    assert original is clip and mirrored.name == "walk (mirrored)"
    expected = skirt_from_joints(mirrored.joints, mirrored.root_rotations)
    assert_close(mirrored.proxy, expected, atol=2e-4)
    # the mirrored body is a body: bone lengths kept, the hips' line reversed
    lengths = np.linalg.norm(clip.joints[:, 1:] - clip.joints[:, :1], axis=-1)
    m_lengths = np.linalg.norm(mirrored.joints[:, 1:] - mirrored.joints[:, :1], axis=-1)
    assert_close(m_lengths[:, [j - 1 for j in MIRROR_JOINTS[1:]]], lengths, atol=1e-5)
    assert_close(np.linalg.det(mirrored.root_rotations), np.ones(90), atol=1e-5)
    joints, rotations = mirror_motion(mirrored.joints, mirrored.root_rotations)
    assert_close(joints, clip.joints, atol=1e-5)
    assert_close(rotations, clip.root_rotations, atol=1e-6)
    assert_close(skirt_map.reflect(mirrored.proxy), clip.proxy, atol=2e-4)


def test_an_asymmetric_garment_is_refused_and_the_stage_trains_without_mirrors(tmp_path):
    """Training on the mirror of a lopsided garment is refused, naming the file; the project's
    stage instead leaves the mirrors out, says so in its log, and its report says why."""
    rest = rest_skirt().astype(np.float64)
    lopsided = rest.copy()
    lopsided[rest[:, 0] > 0.05, 0] += 0.2  # one side let out by 20 cm
    bad = mirror_map(lopsided, skirt_faces(), "skirt.obj")
    assert not bad.symmetric and bad.asymmetry > 0.05 * bad.size
    with pytest.raises(InputError, match="not left-right symmetric") as info:
        bad.check("skirt.obj")
    assert "skirt.obj" in str(info.value) and "mirror=false" in str(info.value)
    clip = Joint2CoarseClip(*synthetic_clip(40, 0), name="walk")
    with pytest.raises(InputError, match="not left-right symmetric"):
        mirrored_clips([clip], bad)
    with pytest.raises(InputError, match="vertices and"):
        mirror_map(rest[:, :2], skirt_faces())

    config = Joint2CoarseConfig(model="ours", mirror=True)
    for vertices, symmetric in ((rest, True), (lopsided, False)):
        path = tmp_path / f"proxy-{symmetric}.obj"
        save_mesh(path, Mesh(vertices.astype(np.float32), skirt_faces()))
        said: list[str] = []
        run, mirror, report = mirror_setting(config, path, said.append)
        assert run.mirror is symmetric and (mirror is not None) is symmetric
        assert report["used"] is symmetric and report["size_mm"] > 500
        assert ("not left-right symmetric" in " ".join(said)) is not symmetric
        sentence = _mirror_markdown(report)
        assert ("No mirrored clips" in sentence) is not symmetric
    assert mirror_setting(replace(config, mirror=False), path) == (
        replace(config, mirror=False), None, None,
    )  # fmt: skip
    assert _mirror_markdown(None) == ""


def test_training_with_mirrors_needs_the_map_and_fits_the_mirrored_motion(skirt_map, tmp_path):
    # the linear residual (closed form: fast)
    config = Joint2CoarseConfig(model="ours", mirror=True, residual_widths=(), ridge=1e-4)
    clip = Joint2CoarseClip(*synthetic_clip(240, 0), name="walk")
    rig = body_rig(BodyShape(), rest_skirt(), fade=1.0)
    with pytest.raises(InputError, match="mirror map"):
        train_joint2coarse([clip], tmp_path / "none", config, rig=rig)
    small = mirror_map(rest_skirt()[:40], skirt_faces(2, 20))
    with pytest.raises(InputError, match="mirror map has 40 vertices") as info:
        train_joint2coarse([clip], tmp_path / "wrong", config, rig=rig, mirror=small)
    assert "walk" in str(info.value)
    with_mirror = train_joint2coarse([clip], tmp_path / "on", config, rig=rig, mirror=skirt_map)
    without = train_joint2coarse([clip], tmp_path / "off", replace(config, mirror=False), rig=rig)
    # on the mirror of the training walk (seen by one model, not by the other)
    seen = mirrored_clips([clip], skirt_map)[1]
    errors = {
        name: vertex_errors(predict_proxy(r.net, seen.joints, seen.root_rotations), seen.proxy)
        for name, r in (("mirror", with_mirror), ("plain", without))
    }
    assert errors["mirror"].mean_mm < 0.25 * errors["plain"].mean_mm, errors
    with pytest.raises(InputError, match="must be true or false"):
        replace(config, mirror="yes")


def test_mirrored_descriptors_are_the_mirrored_motions():
    clip = Joint2CoarseClip(*synthetic_clip(60, 5), name="walk")
    config = Joint2CoarseConfig()
    desc = motion_descriptors(clip.joints, clip.root_rotations, config.window, config.stride)[0]
    joints, rotations = mirror_motion(clip.joints, clip.root_rotations)
    expected = motion_descriptors(joints, rotations, config.window, config.stride)[0]
    assert_close(mirror_descriptors(desc, config.num_samples), expected, atol=1e-5)
    as_torch = mirror_descriptors(torch.from_numpy(desc), config.num_samples).numpy()
    assert_close(as_torch, expected, atol=1e-5, what="torch")


@pytest.fixture(scope="module")
def symmetric(skirt_map, tmp_path_factory):
    """Ours trained with mirrors on the synthetic walk (the network: its torch path too)."""
    config = Joint2CoarseConfig(model="ours", mirror=True, residual_steps=300)
    clip = Joint2CoarseClip(*synthetic_clip(120, 0), name="walk")
    rig = body_rig(BodyShape(), rest_skirt(), fade=1.0)
    out = tmp_path_factory.mktemp("symmetric")
    return train_joint2coarse([clip], out, config, rig=rig, mirror=skirt_map), config


def test_ours_with_mirrors_predicts_symmetrically_everywhere(symmetric, skirt_map, tmp_path):
    """On a symmetric proxy the prediction for the mirrored motion is the reflected prediction;
    numpy, torch, the saved file and the stream agree; a file whose mirror map does not fit
    its proxy is refused, naming it."""
    result, config = symmetric
    clip = Joint2CoarseClip(*synthetic_clip(60, 7), name="unseen")
    pred = predict_proxy(result.net, clip.joints, clip.root_rotations)
    other = predict_proxy(result.net, *mirror_motion(clip.joints, clip.root_rotations))
    assert_close(skirt_map.reflect(other), pred, atol=1e-4, what="symmetry")
    desc = motion_descriptors(clip.joints, clip.root_rotations, config.window, config.stride)[0]
    with torch.no_grad():
        out = result.net.to_torch()(torch.from_numpy(desc)).numpy()
    assert_close(out, result.net.predict(desc), atol=1e-5, what="torch vs numpy")
    loaded = load_model(result.model_path)
    assert loaded.config.mirror and "mirror_corners" in loaded.params()
    assert_close(predict_proxy(loaded, clip.joints, clip.root_rotations), pred, what="reload")
    stream = Joint2CoarseStream(loaded)
    for t in range(20):
        frame = stream.push(clip.joints[t], clip.root_rotations[t])
        assert_close(frame, pred[t], atol=1e-4, what=f"stream frame {t}")
    payload = torch.load(result.model_path, weights_only=False)
    payload["state_dict"]["mirror_corners"] = payload["state_dict"]["mirror_corners"] + 1e6
    bad = tmp_path / "bad.pt"
    torch.save(payload, bad)
    with pytest.raises(InputError, match="mirror map") as err:
        load_model(bad)
    assert str(bad) in str(err.value)
