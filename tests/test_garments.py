"""Built-in garments: they build, are clean open manifolds facing out, fit bodies, scale."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.body.shape import BodyShape
from core.errors import InputError
from core.mesh import boundary_loops, load_mesh, validate_mesh
from templates.garments import (
    DEFAULT_TARGET,
    GARMENTS,
    build_garment,
    make_garment,
)
from templates.garments.fit import body_fit, body_mesh
from templates.garments.skirts import PleatConfig, build_pleated_skirt
from templates.garments.surface import assemble

DETAILED = [n for n, s in GARMENTS.items() if s.kind == "detailed"]
COARSE = [n for n, s in GARMENTS.items() if s.kind == "coarse"]
THIN = BodyShape(chest=0.80, waist=0.60, hip=0.86, build=-1.0)
HEAVY = BodyShape(chest=1.12, waist=1.05, hip=1.20, build=1.0)
#: Least distance (m) any garment vertex keeps from the body (the generators aim for 7 mm).
MIN_CLEARANCE = 0.005


def coarsest(name: str) -> float:
    return GARMENTS[name].resolution_range_mm[1]


@pytest.fixture(scope="module")
def coarse_garments():
    """Every garment at its coarsest resolution on the default body."""
    return {name: build_garment(name, coarsest(name)) for name in GARMENTS}


class BodyDistance:
    """Signed distance (positive outside) and closest points of a closed body mesh."""

    def __init__(self, shape: BodyShape):
        import open3d as o3d

        v, f = body_mesh(shape)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32))
        )
        self._o3d = o3d

    def signed(self, points: np.ndarray) -> np.ndarray:
        q = self._o3d.core.Tensor(np.asarray(points, np.float32))
        return self.scene.compute_signed_distance(q).numpy()

    def closest(self, points: np.ndarray) -> np.ndarray:
        q = self._o3d.core.Tensor(np.asarray(points, np.float32))
        return self.scene.compute_closest_points(q)["points"].numpy()


@pytest.fixture(scope="module")
def default_body():
    return BodyDistance(BodyShape())


def assert_clean_open_manifold(vertices: np.ndarray, faces: np.ndarray, what: str) -> None:
    mesh, report = validate_mesh(vertices, faces)
    assert report.merged_vertices == 0, f"{what}: {report.merged_vertices} duplicate vertices"
    assert report.degenerate_faces == 0, f"{what}: {report.degenerate_faces} degenerate faces"
    assert report.duplicate_faces == 0, f"{what}: duplicate faces"
    assert report.unreferenced_vertices == 0, f"{what}: unreferenced vertices"
    assert report.non_manifold_edges == 0, f"{what}: {report.non_manifold_edges} non-manifold edges"
    assert report.boundary_edges > 0, f"{what}: closed, expected an open surface"
    # Consistent orientation: every directed edge at most once (a flipped neighbour repeats one).
    directed = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    _, counts = np.unique(directed, axis=0, return_counts=True)
    assert counts.max() == 1, f"{what}: inconsistently oriented faces"
    # Every vertex on a boundary or surrounded by a single fan (no bow-ties): Euler check per
    # piece is implied by the edge tests above for grid-built surfaces; check vertex fans here.
    v_count = len(vertices)
    e_all = np.sort(directed, axis=1)
    uniq, counts = np.unique(e_all, axis=0, return_counts=True)
    b = uniq[counts == 1]
    deg = np.bincount(b.ravel(), minlength=v_count)
    assert deg.max() <= 2, f"{what}: a vertex joins more than two boundary edges (bow-tie)"


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    v = vertices.astype(np.float64)
    return np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])


# --- building, topology, orientation ---------------------------------------------------------


@pytest.mark.parametrize("name", list(GARMENTS))
def test_garment_parts_are_clean_open_manifolds(coarse_garments, name):
    g = coarse_garments[name]
    mesh = g.mesh
    assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.int64
    assert np.isfinite(mesh.vertices).all()
    assert len(g.face_parts) == mesh.num_faces
    assert set(np.unique(g.face_parts)) == set(range(len(g.parts)))
    assert_clean_open_manifold(mesh.vertices, mesh.faces, name)
    for k, part in enumerate(g.parts):
        f = mesh.faces[g.face_parts == k]
        # Tubes and ribbons alike: every piece has boundary loops (waist and hem, or edges).
        assert len(boundary_loops(f)) >= 1, f"{name}/{part}: no boundary"


def test_parts_listed_per_garment(coarse_garments):
    parts = {n: coarse_garments[n].parts for n in GARMENTS}
    assert parts["multilayer-skirt"] == (
        "layer-1", "layer-2", "layer-3", "frill-1", "frill-2", "frill-3", "waistband",
    )  # fmt: skip
    assert parts["double-skirt"] == ("layer-1", "layer-2", "waistband")
    assert parts["tango-skirt"] == ("layer-1", "waistband")
    assert parts["pleated-skirt"] == ("pleats", "waistband")
    assert parts["dress"] == ("dress", "straps", "sash", "bow")
    # The dress: body, 2 straps, sash, 2 loops + knot + 2 tails.
    assert coarse_garments["dress"].num_components == 1 + 2 + 1 + 5
    for name in ("multilayer-skirt", "double-skirt", "pleated-skirt"):
        assert coarse_garments[name].num_components == len(parts[name])
    # Single-layer garments: one piece of cloth each, straps and sleeves sewn in.
    for name in ("tank-top", "t-shirt", "sleeveless-dress", "slip-dress", "slit-skirt"):
        assert coarse_garments[name].num_components == 1
    assert parts["tank-top"] == parts["t-shirt"] == ("top",)
    assert parts["sleeveless-dress"] == parts["slip-dress"] == ("dress",)
    assert parts["slit-skirt"] == ("layer-1",)


@pytest.mark.parametrize(
    ("name", "loops"),
    [
        ("tank-top", 4),
        ("t-shirt", 4),
        ("sleeveless-dress", 4),
        ("slip-dress", 4),
        ("slit-skirt", 2),
    ],
)
def test_single_layer_garments_have_their_openings(coarse_garments, name, loops):
    """Hem, neckline and two armholes (or cuffs); a skirt's waist and its hem up the slit."""
    g = coarse_garments[name]
    assert len(boundary_loops(g.mesh.faces)) == loops
    if name == "t-shirt":  # the sleeves reach down the arms, past the shoulders
        x = np.abs(g.mesh.vertices[:, 0])
        assert x.max() > BodyShape().shoulder_width / 2 + 0.1


@pytest.mark.parametrize("name", COARSE)
def test_coarse_templates_are_single_tubes(coarse_garments, name):
    spec = GARMENTS[name]
    g = build_garment(name)  # default resolution
    assert g.parts in (("layer-1",), ("dress",))
    assert g.num_components == 1
    assert len(boundary_loops(g.mesh.faces)) == 2  # waist (or neckline) and hem
    assert 300 <= g.mesh.num_vertices <= 5000, f"{name}: {g.mesh.num_vertices} vertices"
    assert spec.resolution_range_mm[0] <= g.resolution_mm <= spec.resolution_range_mm[1]


def test_tango_skirt_slit_joins_hem_into_one_boundary(coarse_garments):
    g = coarse_garments["tango-skirt"]
    f = g.mesh.faces[g.face_parts == 0]
    # Without the slit the layer would have a waist loop and a hem loop; with it, still two
    # loops, but the hem loop runs up the slit: its highest vertex is near the slit's top.
    assert len(boundary_loops(f)) == 2
    e = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    bverts = np.unique(uniq[counts == 1])
    y = g.mesh.vertices[bverts, 1]
    waist_y = y.max()
    hem_side = y[y < waist_y - 0.1]
    slit_top = GARMENTS["tango-skirt"].config.slit_top * BodyShape().height
    assert abs(hem_side.max() - slit_top) < 0.03
    # Asymmetric hem: the lowest hem vertex is well below the highest non-slit hem vertex.
    assert hem_side.max() - hem_side.min() > 0.2


def test_normals_point_away_from_body(coarse_garments, default_body):
    for name, g in coarse_garments.items():
        v, f = g.mesh.vertices, g.mesh.faces
        n = face_normals(v, f)
        area = np.linalg.norm(n, axis=1)
        c = v[f].mean(axis=1)
        away = c - default_body.closest(c)
        outward = np.einsum("fk,fk->f", n, away) > 0
        for k, part in enumerate(g.parts):
            sel = g.face_parts == k
            frac = area[sel & outward].sum() / area[sel].sum()
            # Pleats fold under: the middle layer (a third of the cloth) faces the body. Bow
            # loops and knot are rings facing out of themselves: their backs face the body.
            least = {"pleats": 0.55, "bow": 0.6}.get(part, 0.9)
            assert frac > least, f"{name}/{part}: only {frac:.2f} of the area faces away"


def test_box_pleats_build_clean_and_clear(default_body):
    cfg = PleatConfig(kind="box", pleats=12, fold_under=0.5)
    g = assemble("box-pleats", build_pleated_skirt(cfg, 0.014, body_fit(BodyShape()), 0), 14)
    assert_clean_open_manifold(g.mesh.vertices, g.mesh.faces, "box pleats")
    assert default_body.signed(g.mesh.vertices).min() >= MIN_CLEARANCE
    with pytest.raises(InputError, match="pleat kind"):
        PleatConfig(kind="accordion")


@pytest.mark.parametrize("hanging", [True, False])
def test_profile_encloses_body_surface(hanging):
    """Reference check of the slicing: points sampled on the torso/leg faces lie inside."""
    import trimesh

    fit = body_fit(BodyShape())
    clearance = 0.007
    h = BodyShape().height
    top, bottom = 0.66 * h, 0.35 * h
    prof = fit.profile(top, bottom, clearance, hanging=hanging)
    faces = fit.faces[fit.kept[fit.faces].all(axis=1)]
    tm = trimesh.Trimesh(fit.vertices, faces, process=False)
    pts, _ = trimesh.sample.sample_surface(tm, 60_000, seed=0)
    pts = pts[(pts[:, 1] <= top) & (pts[:, 1] >= bottom)]
    x, z = pts[:, 0], pts[:, 2] - fit.axis_z
    theta, r = np.arctan2(x, z), np.hypot(x, z)
    rng = np.random.default_rng(1)
    for y in rng.uniform(bottom, top, 25):
        sel = (pts[:, 1] >= y) if hanging else (np.abs(pts[:, 1] - y) < 0.001)
        need = r[sel] + clearance
        have = prof(np.full(sel.sum(), y), theta[sel])
        assert (have >= need - 1e-4).all(), f"y={y:.3f}: {(need - have).max() * 1000:.2f} mm short"
    # And not absurdly loose: at the hip the profile is within 3 cm of the body.
    y = 0.5 * h
    sel = np.abs(pts[:, 1] - y) < 0.002
    have = prof(np.full(sel.sum(), y), theta[sel])
    assert np.median(have - r[sel]) < 0.03


# --- fit: no penetration ---------------------------------------------------------------------


def assert_clear_of(body: BodyDistance, g, what: str) -> None:
    d = body.signed(g.mesh.vertices)
    worst = int(np.argmin(d))
    part = g.parts[g.face_parts[np.nonzero((g.mesh.faces == worst).any(axis=1))[0][0]]]
    assert d.min() >= MIN_CLEARANCE, (
        f"{what}: vertex {worst} of {part} is {d.min() * 1000:.1f} mm from the body "
        f"at {g.mesh.vertices[worst]}"
    )


@pytest.mark.parametrize("name", list(GARMENTS))
def test_no_penetration_default_body(coarse_garments, default_body, name):
    assert_clear_of(default_body, coarse_garments[name], name)


@pytest.mark.parametrize("shape", [THIN, HEAVY], ids=["thin", "heavy"])
@pytest.mark.parametrize("name", ["multilayer-skirt", "dress", "pleated-skirt"])
def test_no_penetration_thin_and_heavy(shape, name):
    g = build_garment(name, coarsest(name), shape)
    assert_clear_of(BodyDistance(shape), g, f"{name} on {shape}")


@pytest.mark.slow
@pytest.mark.parametrize("shape", [THIN, HEAVY, BodyShape(height=1.9, shoulder_width=0.46)])
@pytest.mark.parametrize("name", list(GARMENTS))
def test_no_penetration_other_bodies_all_garments(shape, name):
    g = build_garment(name, coarsest(name), shape)
    assert_clear_of(BodyDistance(shape), g, f"{name} on {shape}")


def test_skirts_hang_from_the_waist_and_fit_the_shape(coarse_garments):
    h = BodyShape().height
    for name in ("multilayer-skirt", "double-skirt", "long-skirt"):
        y = coarse_garments[name].mesh.vertices[:, 1]
        top = GARMENTS[name].config.top * h
        assert abs(y.max() - top) < 0.02, f"{name}: top at {y.max():.3f}, waist at {top:.3f}"
    # A heavier body gets a wider waistband.
    wb = []
    for shape in (BodyShape(), HEAVY):
        g = build_garment("multilayer-skirt", coarsest("multilayer-skirt"), shape)
        v = g.mesh.vertices[np.unique(g.mesh.faces[g.face_parts == g.parts.index("waistband")])]
        wb.append(np.hypot(v[:, 0], v[:, 2]).mean())
    assert wb[1] > wb[0] * 1.2


# --- resolution, determinism, errors ---------------------------------------------------------


def test_vertex_count_scales_with_resolution():
    counts = [build_garment("pleated-skirt", r).mesh.num_vertices for r in (14.0, 10.0, 7.0)]
    assert counts[0] < counts[1] < counts[2]
    # Edge length halves -> about four times the vertices.
    ratio = counts[2] / counts[0]
    assert 0.6 * (14 / 7) ** 2 < ratio < 1.4 * (14 / 7) ** 2, counts


@pytest.mark.slow
@pytest.mark.parametrize("name", DETAILED)
def test_detailed_span_5k_to_60k_vertices(name):
    lo, hi = GARMENTS[name].resolution_range_mm
    fine = build_garment(name, lo).mesh.num_vertices
    coarse = build_garment(name, hi).mesh.num_vertices
    assert 45_000 <= fine <= 75_000, f"{name} at {lo} mm: {fine}"
    assert 3_500 <= coarse <= 8_000, f"{name} at {hi} mm: {coarse}"


def test_detailed_coarsest_is_a_few_thousand_vertices(coarse_garments):
    for name in DETAILED:
        n = coarse_garments[name].mesh.num_vertices
        assert 1_500 <= n <= 8_000, f"{name}: {n}"


def test_deterministic_and_seeded():
    a = make_garment("multilayer-skirt", 25.0, seed=3)
    b = make_garment("multilayer-skirt", 25.0, seed=3)
    c = make_garment("multilayer-skirt", 25.0, seed=4)
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    # Another seed moves the folds (and the measured arc lengths, so maybe the grid size).
    if a.vertices.shape == c.vertices.shape:
        assert np.abs(a.vertices - c.vertices).max() > 0.002
    else:
        assert abs(a.num_vertices - c.num_vertices) < 0.05 * a.num_vertices


def test_default_target_is_registered():
    assert DEFAULT_TARGET == "multilayer-skirt" and DEFAULT_TARGET in GARMENTS
    assert set(DETAILED) == {
        "multilayer-skirt",
        "double-skirt",
        "tango-skirt",
        "pleated-skirt",
        "dress",
        "tank-top",
        "t-shirt",
        "sleeveless-dress",
        "slip-dress",
        "slit-skirt",
    }
    assert set(COARSE) == {"long-skirt", "short-skirt", "simple-dress"}


def test_bad_input_raises_input_error():
    with pytest.raises(InputError, match="built-in garments: multilayer-skirt"):
        make_garment("ball-gown")
    for bad in (1.0, 500.0, math.nan, math.inf, "10"):
        with pytest.raises(InputError, match="resolution"):
            make_garment("dress", bad)
    with pytest.raises(InputError, match="seed"):
        make_garment("dress", 20.0, seed=-1)
    with pytest.raises(InputError, match="BodyShape"):
        make_garment("dress", 20.0, shape={"height": 1.7})


# --- CLI -------------------------------------------------------------------------------------


def test_cli_make_and_list(tmp_path, capsys):
    from app.cli import main

    out = tmp_path / "skirt.obj"
    # The heavy shape, as --shape pairs (its body is cached by the tests above).
    rc = main(["garment", "make", "short-skirt", "--resolution", "40", "--shape", "chest=1.12",
               "waist=1.05", "hip=1.2", "build=1", "--seed", "2", "--out", str(out)])  # fmt: skip
    assert rc == 0
    printed = capsys.readouterr().out
    mesh, report = load_mesh(out)
    assert f"{mesh.num_vertices} vertices" in printed and f"{mesh.num_faces} faces" in printed
    assert "1 components" in printed
    assert report.non_manifold_edges == 0
    expected = make_garment("short-skirt", 40, HEAVY, 2)
    assert mesh.num_vertices == expected.num_vertices
    assert np.abs(mesh.vertices - expected.vertices).max() < 1e-5
    assert main(["garment", "list"]) == 0
    listing = capsys.readouterr().out
    for name in GARMENTS:
        assert name in listing


@pytest.mark.parametrize(
    "args",
    [
        ["garment", "make", "ball-gown"],
        ["garment", "make", "dress", "--resolution", "0.5"],
        ["garment", "make", "dress", "--shape", "height=9"],
        ["garment", "make", "dress", "--shape", "girth"],
    ],
)
def test_cli_bad_input_exits_2_and_writes_nothing(tmp_path, capsys, args):
    from app.cli import main

    out = tmp_path / "g.obj"
    assert main(args + ["--out", str(out)]) == 2
    assert "error" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_cli_bad_extension_exits_2(tmp_path, capsys):
    from app.cli import main

    assert main(["garment", "make", "dress", "--out", str(tmp_path / "g.xyz")]) == 2
    assert list(tmp_path.iterdir()) == []


# --- contact sheet (look at it) --------------------------------------------------------------


@pytest.mark.slow
def test_contact_sheet(tmp_path):
    """Render every garment on the default body, front/side/back, to garments.png in tmp_path."""
    import pyvista as pv  # heavy (VTK): only this slow test draws

    pv.OFF_SCREEN = True
    bv, bf = body_mesh(BodyShape())

    def poly(v, f):
        return pv.PolyData(np.asarray(v), np.hstack([np.full((len(f), 1), 3), f]).ravel())

    body = poly(bv, bf)
    names = list(GARMENTS)
    plotter = pv.Plotter(
        off_screen=True, shape=(len(names), 3), window_size=(1200, 470 * len(names))
    )
    cams = [(0, 0.95, 3.2), (2.6, 1.1, 1.8), (-1.2, 0.6, -3.0)]
    for i, name in enumerate(names):
        g = build_garment(name)
        gm = poly(g.mesh.vertices, g.mesh.faces)
        gm.cell_data["part"] = g.face_parts
        for j, cam in enumerate(cams):
            plotter.subplot(i, j)
            plotter.add_mesh(body, color="tan", smooth_shading=True)
            plotter.add_mesh(gm, scalars="part", cmap="tab10", show_scalar_bar=False)
            plotter.camera_position = [cam, (0, 0.95, 0), (0, 1, 0)]
            if j == 0:
                plotter.add_text(f"{name} V={g.mesh.num_vertices}", font_size=9)
    out = tmp_path / "garments.png"
    plotter.screenshot(str(out))
    plotter.close()
    assert out.stat().st_size > 10_000
