"""USD out: animated meshes written with core.usd, read back with usd-core (pxr) itself."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from core.body.mannequin import make_body
from core.body.skinning import pose_body
from core.errors import InputError
from core.motion.procedural import make_motion
from core.sim.cache import SimCache, export_cache
from core.usd import ROOT_PRIM, UsdMesh, write_usd
from tests.conftest import assert_close

FPS = 24.0


def _grid(n: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A flat n x n vertex cloth: vertices (V, 3), triangles (F, 3), per-vertex uvs (V, 2)."""
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="xy")
    verts = np.stack([u.ravel() - 0.5, 1.2 + 0 * u.ravel(), v.ravel() * 0.4], axis=1)
    quads = [
        (r * n + c, r * n + c + 1, (r + 1) * n + c + 1, (r + 1) * n + c)
        for r in range(n - 1)
        for c in range(n - 1)
    ]
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], np.int64)
    return verts, faces, np.stack([u.ravel(), v.ravel()], axis=1)


@pytest.fixture(scope="module")
def scene():
    """A posed mannequin (12 frames of a twirl) and a cloth sheet waving above it."""
    body = make_body(resolution=2000)
    motion = make_motion("twirl", 12, FPS, 0, body.shape)
    body_frames = pose_body(body, motion)
    verts, faces, uvs = _grid()
    t = np.arange(12)[:, None, None] / FPS
    cloth = (verts[None] + np.sin(6.0 * t + verts[None, :, :1]) * [0.0, 0.05, 0.0]).astype(
        np.float32
    )
    return {
        "body": UsdMesh("Body", body_frames, body.faces),
        "cloth": UsdMesh("Proxy", cloth, faces, uvs, faces, double_sided=True),
    }


def _read_mesh(stage: Usd.Stage, name: str) -> tuple[UsdGeom.Mesh, np.ndarray]:
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath(f"{ROOT_PRIM}/{name}"))
    assert mesh, name
    points = mesh.GetPointsAttr()
    times = points.GetTimeSamples()
    frames = np.stack([np.asarray(points.Get(t), np.float32) for t in times])
    return mesh, frames


@pytest.mark.parametrize("suffix", [".usda", ".usd", ".usdc"])
def test_round_trip_every_frame(scene, tmp_path, suffix):
    path = tmp_path / f"take{suffix}"
    write_usd(path, [scene["cloth"], scene["body"]], FPS)
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no temporary left
    head = path.read_bytes()[:8]
    assert head.startswith(b"#usda") if suffix == ".usda" else head == b"PXR-USDC"

    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetTimeCodesPerSecond() == FPS and stage.GetFramesPerSecond() == FPS
    assert stage.GetStartTimeCode() == 0.0 and stage.GetEndTimeCode() == 11.0
    assert stage.GetDefaultPrim().GetPath() == ROOT_PRIM
    for key in ("cloth", "body"):
        want = scene[key]
        mesh, frames = _read_mesh(stage, want.name)
        assert mesh.GetPointsAttr().GetTimeSamples() == [float(k) for k in range(12)]
        assert np.array_equal(frames, want.positions), key  # float32 in, float32 out: exact
        assert list(mesh.GetFaceVertexCountsAttr().Get()) == [3] * len(want.faces)
        idx = np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
        assert np.array_equal(idx, want.faces)
        assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
        assert mesh.GetDoubleSidedAttr().Get() == want.double_sided
        ext = np.asarray(mesh.GetExtentAttr().Get(5.0))
        assert_close(ext, [want.positions[5].min(0), want.positions[5].max(0)], what="extent")
    cloth, _ = _read_mesh(stage, "Proxy")
    st = UsdGeom.PrimvarsAPI(cloth).GetPrimvar("st")
    assert st.GetInterpolation() == UsdGeom.Tokens.faceVarying
    assert_close(np.asarray(st.Get()), scene["cloth"].uvs, atol=1e-7, what="st values")
    assert np.array_equal(np.asarray(st.GetIndices()).reshape(-1, 3), scene["cloth"].faces)
    assert not UsdGeom.PrimvarsAPI(
        UsdGeom.Mesh(stage.GetPrimAtPath(f"{ROOT_PRIM}/Body"))
    ).HasPrimvar("st")


def test_sim_cache_exports_as_usd(scene, tmp_path):
    """``dng simulate --export X.usda`` and ``dng predict proxy --out X.usd`` go through here."""
    cloth = scene["cloth"]
    cache = SimCache(cloth.positions, cloth.faces, 30.0)
    export_cache(tmp_path / "cache.usda", cache)
    stage = Usd.Stage.Open(str(tmp_path / "cache.usda"))
    assert stage.GetTimeCodesPerSecond() == 30.0
    _, frames = _read_mesh(stage, "Garment")
    assert np.array_equal(frames, cache.positions)


def test_bad_input_writes_nothing(scene, tmp_path):
    cloth = scene["cloth"]
    nan = cloth.positions.copy()
    nan[3, 7, 1] = np.nan
    cases = [
        ("a.usda", [UsdMesh("Proxy", nan, cloth.faces)], FPS, "NaN or inf \\(first at frame 3\\)"),
        (
            "b.usda",
            [UsdMesh("Proxy", cloth.positions[0], cloth.faces)],
            FPS,
            "must be \\(T, V, 3\\)",
        ),
        ("c.usda", [UsdMesh("Proxy", cloth.positions, cloth.faces[:, :2])], FPS, "faces must be"),
        (
            "d.usda",
            [UsdMesh("Proxy", cloth.positions, cloth.faces + 100)],
            FPS,
            "outside \\[0, 36\\)",
        ),
        ("e.fbx", [cloth], FPS, "unknown USD type '.fbx'"),
        ("f.usdz", [cloth], FPS, "unknown USD type '.usdz'"),
        ("g.usda", [cloth], 0.0, "fps must be positive"),
        ("h.usda", [], FPS, "no meshes"),
        (
            "i.usda",
            [cloth, UsdMesh("Body", scene["body"].positions[:5], scene["body"].faces)],
            FPS,
            "5 frames, the others have 12",
        ),
        ("j.usda", [UsdMesh("2nd take", cloth.positions, cloth.faces)], FPS, "not a valid"),
        (
            "k.usda",
            [UsdMesh("P", cloth.positions, cloth.faces, cloth.uvs, None)],
            FPS,
            "go together",
        ),
    ]
    for name, meshes, fps, message in cases:
        with pytest.raises(InputError, match=message) as info:
            write_usd(tmp_path / name, meshes, fps)
        assert str(tmp_path / name) in str(info.value)
    assert list(tmp_path.iterdir()) == []
    # A failed write leaves an earlier good file as it was.
    good = tmp_path / "good.usda"
    write_usd(good, [cloth], FPS)
    before = good.read_bytes()
    with pytest.raises(InputError):
        write_usd(good, [UsdMesh("Proxy", nan, cloth.faces)], FPS)
    assert good.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["good.usda"]


def test_cli_body_needs_a_usd_out(dng, tmp_path):
    code, out, err = dng(
        "predict", "proxy", tmp_path, "--motion", "x.bvh", "--out", tmp_path / "p.npz", "--body"
    )
    assert code == 2 and not out and err.count("\n") == 1 and "--body needs a USD --out" in err
    assert not (tmp_path / "p.npz").exists()


def test_predict_proxy_to_usd_from_a_gltf_motion(smoke_project, dng, tmp_path):
    """glTF motion in, USD out: the USD's proxy is the .npz cache of the same command, every
    frame, with the proxy's UVs; the posed mannequin is beside it."""
    from core.sim.cache import load_cache
    from tests.test_gltf_motion import motion_to_gltf, save

    clip = save(motion_to_gltf(make_motion("walk", 20, 30.0, 1)), tmp_path / "walk.glb", "glb")
    base = ["predict", "proxy", smoke_project, "--motion", clip]
    code, _, err = dng(*base, "--out", tmp_path / "walk.npz")
    assert code == 0, err
    code, out, err = dng(*base, "--out", tmp_path / "walk.usda", "--body")
    assert code == 0 and "walk.usda" in out, err
    cache = load_cache(tmp_path / "walk.npz")
    stage = Usd.Stage.Open(str(tmp_path / "walk.usda"))
    assert stage.GetTimeCodesPerSecond() == cache.fps
    proxy, frames = _read_mesh(stage, "Proxy")
    assert np.array_equal(frames, cache.positions)
    assert UsdGeom.PrimvarsAPI(proxy).GetPrimvar("st").GetInterpolation() == "faceVarying"
    _, body = _read_mesh(stage, "Body")
    assert body.shape[0] == cache.num_frames and body.shape[1] > 1000
    assert np.isfinite(body).all() and 1.4 < float(np.ptp(body[0][:, 1])) < 2.0
