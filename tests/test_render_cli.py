"""``dng render``, ``dng finetune`` and ``dng bench render`` on the smoke project."""

from __future__ import annotations

import json

import imageio_ffmpeg
import numpy as np
import pytest
import torch


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)


RENDER = ("--frames", 3, "--size", 64)


def test_render_gif_png_mp4(smoke_project, tmp_path, dng):
    from PIL import Image

    code, out, err = dng(
        "render", smoke_project, "--motion", "walk", *RENDER, "--out", tmp_path / "a.gif"
    )
    assert code == 0, err
    assert "3 frames, 64x64" in out and "ms" in out
    with Image.open(tmp_path / "a.gif") as g:
        assert g.n_frames == 3 and g.size == (64, 64)

    frames = tmp_path / "frames"
    code, out, err = dng(
        "render", smoke_project, "--motion", "dance", *RENDER,
        "--camera", "front", "--side-by-side", "--out", f"{frames}/",
    )  # fmt: skip
    assert code == 0, err
    names = sorted(p.name for p in frames.iterdir())
    assert names == [f"frame_{i:05d}.png" for i in range(3)]
    first = np.asarray(Image.open(frames / names[0]))
    assert first.shape == (64, 128, 3)  # render | simulation
    assert "simulation" in out

    code, out, err = dng(
        "render", smoke_project, "--motion", "twirl", *RENDER,
        "--fps", 12, "--out", tmp_path / "a.mp4",
    )  # fmt: skip
    assert code == 0, err
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "a.mp4"))
    meta = next(reader)
    assert meta["size"] == (64, 64) and meta["fps"] == pytest.approx(12)
    assert sum(1 for _ in reader) == 3


def test_render_camera_file(smoke_project, tmp_path, dng):
    from PIL import Image

    from core.camera import camera_to_dict, make_camera

    cams = [
        camera_to_dict(make_camera((0.3 * i, 1.0, 2.5), (0.0, 0.8, 0.0), width=40, height=32))
        for i in range(2)
    ]
    path = tmp_path / "path.json"
    path.write_text(json.dumps(cams))
    out_dir = tmp_path / "f"
    code, _, err = dng(
        "render", smoke_project, "--motion", "walk", "--frames", 3,
        "--camera", path, "--out", out_dir,
    )  # fmt: skip
    assert code == 0, err
    frames = sorted(out_dir.iterdir())
    assert len(frames) == 3
    assert np.asarray(Image.open(frames[0])).shape == (32, 40, 3)
    # Frame 2 holds the list's last camera: the same camera as frame 1.
    single = tmp_path / "one.json"
    single.write_text(json.dumps(cams[0]))
    code, _, err = dng(
        "render", smoke_project, "--motion", "walk", "--frames", 2,
        "--camera", single, "--size", 20, "--out", tmp_path / "one.gif",
    )  # fmt: skip
    assert code == 0, err
    with Image.open(tmp_path / "one.gif") as g:
        assert g.size == (20, 16)


def test_render_keyed_camera_path(smoke_project, tmp_path, dng):
    """The studio's saved camera path (keys at frames) drives ``--camera PATH.json``."""
    from PIL import Image

    from core.camera import CameraKey, camera_path_to_dict

    keys = [
        CameraKey(0, (0.0, 1.0, 2.5), (0.0, 0.8, 0.0)),
        CameraKey(2, (2.5, 1.0, 0.0), (0.0, 0.8, 0.0), 35.0),
    ]
    path = tmp_path / "keys.json"
    path.write_text(json.dumps(camera_path_to_dict(keys)))
    out_dir = tmp_path / "k"
    code, _, err = dng(
        "render", smoke_project, "--motion", "walk", "--frames", 3, "--size", 32,
        "--camera", path, "--out", out_dir,
    )  # fmt: skip
    assert code == 0, err
    frames = [np.asarray(Image.open(p), np.float32) for p in sorted(out_dir.iterdir())]
    assert len(frames) == 3 and frames[0].shape == (32, 32, 3)
    assert np.abs(frames[0] - frames[2]).mean() > 1  # front, then the side
    bad = tmp_path / "bad-keys.json"
    bad.write_text(json.dumps({"keys": [keys[0].as_dict(), keys[0].as_dict()]}))
    code, _, err = dng(
        "render", smoke_project, "--motion", "walk", "--camera", bad, "--out", tmp_path / "b.gif"
    )
    assert code == 2 and str(bad) in err and "share a frame" in err
    assert not (tmp_path / "b.gif").exists()


def test_render_bad_inputs(smoke_project, tmp_path, dng):
    missing = tmp_path / "no-project"
    code, _, err = dng("render", missing, "--motion", "walk", "--out", tmp_path / "x.gif")
    assert code == 2 and str(missing) in err
    model = tmp_path / "nothing.pt"
    code, _, err = dng(
        "render", smoke_project, "--motion", "walk", "--renderer", model,
        "--out", tmp_path / "x.gif",
    )  # fmt: skip
    assert code == 2 and str(model) in err and "no trained renderer" in err
    code, _, err = dng(
        "render", smoke_project, "--motion", "walk", *RENDER, "--out", tmp_path / "x.avi"
    )
    assert code == 2 and "x.avi" in err
    bad_cam = tmp_path / "cam.json"
    bad_cam.write_text('{"width": 10}')
    code, _, err = dng(
        "render", smoke_project, "--motion", "walk", "--camera", bad_cam,
        "--out", tmp_path / "x.gif",
    )  # fmt: skip
    assert code == 2 and str(bad_cam) in err
    code, _, err = dng("render", smoke_project, "--motion", "moonwalk", "--out", tmp_path / "x.gif")
    assert code == 2 and "moonwalk" in err
    assert not (tmp_path / "x.gif").exists() and not (tmp_path / "x.avi").exists()


def test_finetune_background_trains_only_allowed_parameters(smoke_project, tmp_path, dng):
    from PIL import Image

    from training.renderer import background_finetune_parameters, load_model

    y, x = np.mgrid[0:40, 0:70]
    image = np.stack([x * 3 % 256, y * 6 % 256, np.full_like(x, 90)], -1).astype(np.uint8)
    Image.fromarray(image).save(tmp_path / "backdrop.png")
    code, out, err = dng(
        "finetune", smoke_project, "--background", tmp_path / "backdrop.png",
        "--steps", 2, "--name", "test-bg",
    )  # fmt: skip
    assert code == 0, err
    folder = smoke_project / "finetune" / "background-test-bg"
    assert str(folder / "renderer.pt") in out
    assert "loss: generator" in out and "->" in out
    assert (folder / "backdrop-0.png").is_file()
    _, parent, parent_d = load_model(smoke_project / "renderer" / "renderer.pt")
    _, tuned, tuned_d = load_model(folder / "renderer.pt")
    allowed = set(background_finetune_parameters(parent))
    before, after = parent.state_dict(), tuned.state_dict()
    changed = {k for k in before if not torch.equal(before[k], after[k])}
    assert changed and changed <= allowed, changed - allowed
    d0, d1 = parent_d.state_dict(), tuned_d.state_dict()
    assert any(not torch.equal(d0[k], d1[k]) for k in d0)  # the discriminator trains too

    # Playing it: the backdrop beside the model is picked up.
    code, out, err = dng(
        "render", smoke_project, "--motion", "walk", "--frames", 2, "--size", 48,
        "--renderer", folder / "renderer.pt", "--out", tmp_path / "bg.gif",
    )  # fmt: skip
    assert code == 0, err
    with Image.open(tmp_path / "bg.gif") as g:
        corner = np.asarray(g.convert("RGB"))[0, 0]
    assert abs(int(corner[2]) - 90) < 30  # the backdrop's blue channel, not the studio grey


def test_backdrop_samples_per_vertex_for_a_gpu(smoke_project):
    """Fine-tuning on a GPU loads the backdrop samples with per-vertex motion features, the
    recomposited images unchanged."""
    import torch

    from pipeline.finetune import BackdropDataset
    from training.dataset import GarmentDataset
    from training.loader import for_device

    image = np.full((20, 30, 3), 200, np.uint8)
    data = BackdropDataset(GarmentDataset(smoke_project), [image])
    dense, compact = data[0], for_device(data, "cuda")[0]
    assert "motion" in dense and "vertex_motion" in compact and "motion" not in compact
    for k in ("target", "background", "target_mask", "uv"):
        assert torch.equal(dense[k], compact[k]), k


def test_finetune_lighting_relights_and_plays(smoke_project, tmp_path, dng):
    """``dng finetune --lighting``: the relit model, its light and examples; ``dng render``
    lights the body and the reference with the light beside the model."""
    from PIL import Image

    from core.lighting import PRESETS, load_lighting
    from training.renderer import load_model, relight_parameters

    code, out, err = dng("finetune", smoke_project, "--lighting", "low-sun", "--steps", 2)
    assert code == 0, err
    folder = smoke_project / "finetune" / "light-low-sun"
    assert str(folder / "renderer.pt") in out and "loss: generator" in out
    assert load_lighting(folder / "lighting.json") == PRESETS["low-sun"]
    assert (folder / "examples.png").is_file() and not (folder / "backdrop-0.png").exists()
    _, parent, parent_d = load_model(smoke_project / "renderer" / "renderer.pt")
    _, tuned, tuned_d = load_model(folder / "renderer.pt")
    before, after = parent.state_dict(), tuned.state_dict()
    changed = {k for k in before if not torch.equal(before[k], after[k])}
    assert changed == set(relight_parameters(parent))
    d0, d1 = parent_d.state_dict(), tuned_d.state_dict()
    assert any(not torch.equal(d0[k], d1[k]) for k in d0)  # the discriminator trains too

    def reference(*extra):
        frames = tmp_path / f"ref{len(extra)}"
        code, _, err = dng(
            "render", smoke_project, "--motion", "walk", "--frames", 1, "--size", 48,
            "--camera", "front", "--side-by-side", "--renderer", folder / "renderer.pt",
            *extra, "--out", f"{frames}/",
        )  # fmt: skip
        assert code == 0, err
        return np.asarray(Image.open(frames / "frame_00000.png").convert("RGB"))[:, 48:]

    warm, studio = reference(), reference("--lighting", "studio")
    lit = np.abs(warm.astype(int) - studio).sum(-1) > 30
    assert lit.mean() > 0.02  # the reference is lit by the model's light unless told otherwise


def test_finetune_lighting_from_an_environment_image(smoke_project, tmp_path, dng):
    import cv2
    from PIL import Image

    sky = np.zeros((16, 32, 3), np.float32)
    sky[:8] = (0.4, 0.6, 1.5)  # a blue sky above a dark ground
    cv2.imwrite(str(tmp_path / "sky.hdr"), sky[..., ::-1])
    code, out, err = dng(
        "finetune", smoke_project, "--lighting", tmp_path / "sky.hdr", "--steps", 1
    )
    assert code == 0, err
    folder = smoke_project / "finetune" / "light-sky"
    backdrop = np.asarray(Image.open(folder / "backdrop-0.png"))
    assert backdrop[0, 0, 2] > backdrop[0, 0, 0] and backdrop[-1, 0].max() == 0  # its own view


def test_finetune_lighting_from_your_own_renders(smoke_project, tmp_path, dng):
    """``--examples SAMPLE=IMG``: a user's renders replace the garment on the body at frame t;
    the body alone is rendered under the light given."""
    from PIL import Image

    from core.lighting import PRESETS
    from pipeline.finetune import LitDataset, read_examples
    from training.dataset import GarmentDataset

    blue = np.zeros((64, 64, 3), np.uint8)
    blue[..., 2] = 200
    Image.fromarray(blue).save(tmp_path / "a.png")
    Image.fromarray(blue[..., ::-1].copy()).save(tmp_path / "b.png")
    items = [f"0={tmp_path / 'a.png'}", f"3={tmp_path / 'b.png'}"]
    code, out, err = dng(
        "finetune", smoke_project, "--lighting", "overcast", "--examples", *items,
        "--steps", 1, "--name", "mine",
    )  # fmt: skip
    assert code == 0, err
    folder = smoke_project / "finetune" / "light-mine"
    record = json.loads((folder / "finetune.json").read_text())
    assert record["examples"] == [0, 3] and len(record["example_images"]) == 2
    base = GarmentDataset(smoke_project, source="joint2coarse")
    given = read_examples(items, len(base), 64)
    data = LitDataset(base, PRESETS["overcast"], indices=[0, 3], targets=given)
    sample = data[0]
    assert np.allclose(sample["target"][1].numpy(), blue.transpose(2, 0, 1) / 255)
    assert not np.allclose(sample["target"][0].numpy(), blue.transpose(2, 0, 1) / 255)


def test_finetune_lighting_bad_inputs_write_nothing(smoke_project, tmp_path, dng):
    root = smoke_project / "finetune"
    before = set(root.iterdir()) if root.is_dir() else set()
    gone = tmp_path / "gone.hdr"
    code, _, err = dng("finetune", smoke_project, "--lighting", gone)
    assert code == 2 and str(gone) in err and len(err.strip().splitlines()) == 1
    broken = tmp_path / "broken.exr"
    broken.write_text("not an image")
    code, _, err = dng("finetune", smoke_project, "--lighting", broken)
    assert code == 2 and str(broken) in err
    code, _, err = dng("finetune", smoke_project, "--lighting", "dusk")
    assert code == 2 and "unknown light preset" in err
    code, _, err = dng("finetune", smoke_project, "--lighting", "overcast", "--examples", 0)
    assert code == 2 and "at least one example" in err
    code, _, err = dng(
        "finetune", smoke_project, "--lighting", "overcast", "--background", tmp_path / "no.png"
    )
    assert code == 2 and "no.png" in err
    from PIL import Image

    small = tmp_path / "small.png"
    Image.new("RGB", (32, 40)).save(small)
    code, _, err = dng(
        "finetune", smoke_project, "--lighting", "low-sun", "--examples", f"0={small}"
    )
    assert code == 2 and str(small) in err and "32 x 40" in err
    code, _, err = dng("finetune", smoke_project, "--lighting", "low-sun", "--examples", small)
    assert code == 2 and "SAMPLE=IMAGE" in err
    code, _, err = dng(
        "finetune", smoke_project, "--lighting", "low-sun", "--examples", "99999=x.png"
    )
    assert code == 2 and "samples 0 to" in err
    code, _, err = dng("finetune", smoke_project)
    assert code == 2 and "--lighting" in err
    code, _, err = dng(
        "finetune", smoke_project, "--body-shape", "height=1.8", "--background", "a.png"
    )
    assert code == 2 and "one at a time" in err
    after = set(root.iterdir()) if root.is_dir() else set()
    assert after == before  # no half-written model


def test_finetune_bad_inputs(smoke_project, tmp_path, dng):
    bad = tmp_path / "broken.png"
    bad.write_text("not an image")
    code, _, err = dng("finetune", smoke_project, "--background", bad, "--steps", 1)
    assert code == 2 and str(bad) in err
    gone = tmp_path / "gone.jpg"
    code, _, err = dng("finetune", smoke_project, "--background", gone)
    assert code == 2 and str(gone) in err
    missing = tmp_path / "no-project"
    code, _, err = dng("finetune", missing, "--body-shape", "height=1.8")
    assert code == 2 and str(missing) in err
    code, _, err = dng("finetune", smoke_project, "--body-shape", "neck=3")
    assert code == 2 and "neck" in err
    model = tmp_path / "none.pt"
    code, _, err = dng("finetune", smoke_project, "--body-shape", "height=1.8", "--renderer", model)
    assert code == 2 and str(model) in err


@pytest.mark.slow
def test_finetune_body_shape(smoke_project, tmp_path, dng):
    from core.project import Project
    from pipeline.config import project_config

    code, out, err = dng(
        "finetune", smoke_project, "--body-shape", "height=1.8", "build=0.4",
        "--steps", 2, "--name", "test-tall",
    )  # fmt: skip
    assert code == 0, err
    sub = smoke_project / "finetune" / "body-test-tall"
    assert (sub / "renderer" / "renderer.pt").is_file() and "loss: generator" in out
    config = project_config(Project(sub))
    assert config.body.height == pytest.approx(1.8) and config.body.build == pytest.approx(0.4)
    for name in ("proxy/proxy.obj", "proxy/seams.npz", "garment/target.obj"):
        assert (sub / name).read_bytes() == (smoke_project / name).read_bytes()
    assert (sub / "dataset" / "samples.json").is_file()
    code, _, err = dng("render", sub, "--motion", "walk", *RENDER, "--out", tmp_path / "tall.gif")
    assert code == 0, err


def test_bench_render(tmp_path, dng):
    code, out, err = dng(
        "bench", "render", "--sizes", 32, "--threads", 1, "--frames", 1,
        "--presets", "tiny", "--out", tmp_path, "--json",
    )  # fmt: skip
    assert code == 0, err
    table = json.loads(out)
    (row,) = table["rows"]
    assert row["size"] == 32 and row["fps"] > 0 and row["frame_ms"] > row["network_ms"] > 0
    assert len(table["load_average_before"]) == 3
    assert (tmp_path / "render.json").is_file() and (tmp_path / "render.png").is_file()


def test_relight_benchmark_prints_its_figures(smoke_project, tmp_path):
    from tests.conftest import run_benchmark

    r = run_benchmark(
        "relight.py", smoke_project, "--lights", "overcast", "--steps", 1,
        "--scratch-steps", 2, "--out", tmp_path, "--json",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout.strip().splitlines()[-1])
    assert "--lights overcast" in data["command"]
    (row,) = data["rows"]
    assert row["light"] == "overcast" and row["held_out"] == "val-walk"
    for model in ("before", "after", "scratch"):
        assert 0 < row[f"{model}_mse"] < 1 and -1 <= row[f"{model}_ssim"] <= 1
        assert 0 <= row[f"{model}_colour"] <= 3**0.5
    assert row["after_seconds"] > 0 and row["scratch_seconds"] > 0
    assert (tmp_path / "relight-overcast.png").is_file()
    r = run_benchmark("relight.py", smoke_project, "--lights", "dusk")
    assert r.returncode == 2 and "unknown light preset" in r.stderr


@pytest.mark.slow
def test_body_finetune_benchmark_prints_its_figures(smoke_project):
    from tests.conftest import run_benchmark

    r = run_benchmark(
        "body_finetune.py", smoke_project, "--shape", "bench-short", "height=1.6",
        "--fractions", 0.2, 0.5, "--json",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout.strip().splitlines()[-1])
    assert (
        data["shape"]["height"] == pytest.approx(1.6) and "--shape bench-short" in data["command"]
    )
    names = [row["name"] for row in data["rows"]]
    assert names == ["before (the project's)", "fine-tuned", "fine-tuned", "from scratch"]
    assert [row["steps"] for row in data["rows"]] == [0, 6, 15, 30]  # the smoke preset's 30
    assert all(0 < row["mse"] < 1 for row in data["rows"])
    reached = data["fraction_reached"]
    assert reached is None or reached in (0.2, 0.5)
    r = run_benchmark("body_finetune.py", smoke_project, "--shape", "x", "neck=3")
    assert r.returncode == 2 and "neck" in r.stderr
