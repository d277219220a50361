"""Light for the ground truth (core.lighting): rigs, environment images, their reader, and the
torch path's copy of the shading."""

from __future__ import annotations

import json

import numpy as np
import pytest

from core.camera import make_camera
from core.color import linear_to_srgb, srgb_to_linear, to_uint8
from core.errors import InputError
from core.lighting import (
    PRESETS,
    Light,
    Lighting,
    environment_coefficients,
    environment_light,
    environment_view,
    load_lighting,
    read_environment,
)
from core.mesh import Mesh
from core.shading import Material, ShadingConfig, render_ground_truth

#: A camera on the +z axis looking at the origin: camera space's -z points at it.
CAM = make_camera((0.0, 0.0, 2.0), (0.0, 0.0, 0.0), width=32, height=32, fov_y_deg=30)
WHITE = Material(color=(1.0, 1.0, 1.0), sheen=0.0)


def _patch() -> Mesh:
    """A 1 m square in the plane z = 0, facing the camera."""
    v = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], np.float32)
    return Mesh(v, np.array([[0, 1, 2], [0, 2, 3]]))


def _centre(lighting: Lighting) -> np.ndarray:
    cfg = ShadingConfig(supersample=1, garment=WHITE, wrap=0.0, lighting=lighting)
    gt = render_ground_truth(_patch(), None, CAM, cfg)
    assert gt.mask[12:20, 12:20].all()
    return gt.image[16, 16].astype(int)


def test_a_white_lambertian_patch_facing_a_coloured_light_takes_its_colour():
    colour = (1.0, 0.5, 0.2)
    towards_camera = (0.0, 0.0, -1.0)  # camera space: the light sits at the eye
    lit = Lighting(sky=(0, 0, 0), ground=(0, 0, 0), lights=(Light(towards_camera, colour),))
    expected = to_uint8(linear_to_srgb(np.array(colour))).astype(int)
    assert np.abs(_centre(lit) - expected).max() <= 1
    # Half the intensity, half the linear light; a light behind the patch adds nothing.
    half = Lighting(sky=(0, 0, 0), ground=(0, 0, 0), lights=(Light(towards_camera, colour, 0.5),))
    back = Lighting(sky=(0, 0, 0), ground=(0, 0, 0), lights=(Light((0, 0, 1), colour),))
    got = srgb_to_linear(_centre(half) / 255.0)
    assert np.allclose(got, 0.5 * np.array(colour), atol=0.01)
    assert (_centre(back) <= 1).all()


def test_a_uniform_environment_lights_every_normal_by_its_radiance():
    radiance = np.full((16, 32, 3), (0.3, 0.6, 0.9), np.float32)
    coeffs = environment_coefficients(radiance)
    normals = np.random.default_rng(0).normal(size=(50, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    assert np.allclose(environment_light(coeffs, normals), (0.3, 0.6, 0.9), rtol=5e-3)
    # The patch under it alone shows that colour.
    lit = Lighting(sky=(0, 0, 0), ground=(0, 0, 0), lights=(), environment=coeffs)
    expected = to_uint8(linear_to_srgb(np.array((0.3, 0.6, 0.9)))).astype(int)
    assert np.abs(_centre(lit) - expected).max() <= 1


def test_an_environment_lights_the_side_that_faces_its_bright_part():
    radiance = np.zeros((32, 64, 3), np.float32)
    radiance[12:20, 12:20] = 50.0  # left of the image: the camera's -x side
    coeffs = environment_coefficients(radiance)
    left, right, up = environment_light(coeffs, np.array([[-1.0, 0, 0], [1, 0, 0], [0, -1, 0]]))
    assert left[0] > 10 * max(right[0], 1e-3) and left[0] > up[0]


def test_the_environment_turns_with_the_camera():
    """What a camera sees of an environment: its centre column straight ahead."""
    radiance = np.zeros((32, 64, 3), np.float32)
    radiance[:, 30:34] = 1.0  # a vertical stripe at the centre column
    view = environment_view(radiance, CAM)
    assert view.shape == (32, 32, 3)
    assert view[16, 16].min() == 255 and view[16, 0].max() == 0


def test_environment_images_read_hdr_and_ldr(tmp_path):
    import cv2

    radiance = np.zeros((8, 16, 3), np.float32)
    radiance[..., 0] = 4.0  # brighter than an 8-bit image holds
    radiance[..., 2] = 0.25
    cv2.imwrite(str(tmp_path / "sky.hdr"), radiance[..., ::-1])
    back = read_environment(tmp_path / "sky.hdr")
    assert back.shape == (8, 16, 3) and np.allclose(back, radiance, rtol=0.02)
    png = np.full((8, 16, 3), 188, np.uint8)
    cv2.imwrite(str(tmp_path / "sky.png"), png)
    assert np.allclose(read_environment(tmp_path / "sky.png"), srgb_to_linear(188 / 255))
    lit = load_lighting(tmp_path / "sky.hdr")
    assert lit.name == "sky.hdr" and len(lit.environment) == 27 and lit.lights == ()


def test_bad_lights_name_the_problem(tmp_path):
    with pytest.raises(InputError, match="not found") as e:
        load_lighting(tmp_path / "gone.hdr")
    assert "gone.hdr" in str(e.value)
    (tmp_path / "broken.hdr").write_text("not an image")
    with pytest.raises(InputError, match="readable") as e:
        load_lighting(tmp_path / "broken.hdr")
    assert "broken.hdr" in str(e.value)
    with pytest.raises(InputError, match="unknown light preset"):
        load_lighting("sunset-ish")
    (tmp_path / "bad.json").write_text(json.dumps({"sky": [1, 2]}))
    with pytest.raises(InputError, match="lighting"):
        load_lighting(tmp_path / "bad.json")
    with pytest.raises(InputError, match="direction"):
        Lighting(lights=(Light((0, 0, 0)),))
    with pytest.raises(InputError, match="environment"):
        environment_coefficients(np.full((4, 8, 3), np.nan, np.float32))


def test_presets_and_files_round_trip(tmp_path):
    assert PRESETS["studio"] == Lighting() == ShadingConfig().lighting
    for name, lit in PRESETS.items():
        assert load_lighting(name) is lit
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(lit.to_dict()))
        assert load_lighting(path) == lit
    # The presets are unlike one another: a grey patch under each.
    grey = {name: _centre(lit) for name, lit in PRESETS.items()}
    assert grey["low-sun"][0] > grey["low-sun"][2] + 40  # warm
    assert grey["overcast"][2] > grey["overcast"][0]  # cold


def test_a_relit_views_backdrop(tmp_path):
    """An environment image is its own backdrop; its light saved as JSON, or a preset, is none."""
    import cv2

    from pipeline.finetune import lighting_backdrop

    radiance = np.zeros((16, 32, 3), np.float32)
    radiance[:, 14:18] = 1.0
    cv2.imwrite(str(tmp_path / "sky.hdr"), radiance[..., ::-1])
    lit = load_lighting(tmp_path / "sky.hdr")
    view = lighting_backdrop(tmp_path / "sky.hdr", lit, None, CAM)
    assert view.shape == (32, 32, 3) and view[16, 16].min() == 255
    (tmp_path / "sky.json").write_text(json.dumps(lit.to_dict()))
    assert (
        lighting_backdrop(tmp_path / "sky.json", load_lighting(tmp_path / "sky.json"), None, CAM)
        is None
    )
    assert lighting_backdrop("overcast", PRESETS["overcast"], None, CAM) is None


def test_a_large_environment_is_projected_from_its_average():
    """A panorama is averaged down before its projection, to the same light within 1%."""
    from core.lighting import _BAND_GAIN, ENVIRONMENT_ROWS, _shrink, equirect_directions, sh_basis

    h = 4 * ENVIRONMENT_ROWS
    lat = np.linspace(1, 0, h)[:, None, None]
    lon = np.linspace(0, 2 * np.pi, 2 * h)[None, :, None]
    radiance = (0.2 + lat**2 * (1.5 + np.cos(lon)) * np.array([1.0, 0.7, 0.4])).astype(np.float32)
    assert _shrink(radiance).shape == (ENVIRONMENT_ROWS, 2 * ENVIRONMENT_ROWS, 3)
    big = environment_light(environment_coefficients(radiance), np.eye(3))
    d, omega = equirect_directions(h, 2 * h)
    assert np.isclose(omega.sum(), 4 * np.pi, rtol=1e-3)
    full = (sh_basis(d.reshape(-1, 3)) * omega.reshape(-1, 1)).T @ radiance.reshape(-1, 3)
    exact = np.maximum(sh_basis(np.eye(3)) @ (full * _BAND_GAIN[:, None]), 0)
    assert np.allclose(big, exact, rtol=0.01)
