"""``dng proxy`` and ``dng bench proxy`` end to end (small synthetic garments)."""

from __future__ import annotations

import json

import numpy as np

from core.mesh import save_mesh, validate_mesh
from core.proxy.testing import skirt_tube, tshirt

COUNT_TOL = 0.10


def as_mesh(vf):
    return validate_mesh(*vf)[0]


def test_cli_proxy_writes_mesh_report_and_correspondence(tmp_path, capsys):
    from app.cli import main
    from core.mesh import load_mesh

    src = tmp_path / "shirt.obj"
    save_mesh(src, as_mesh(tshirt(n_around=32, n_along=20)))
    out = tmp_path / "proxy.obj"
    code = main(["proxy", str(src), "--out", str(out), "--target-verts", "500", "--json"])
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    for key in ("vertices", "faces", "components", "edge_manifold", "boundary_loops"):
        assert key in report["proxy"]
    for key in ("hausdorff_m", "hausdorff_rel"):
        assert key in report["distance"]
    for key in ("charts", "utilization", "stretch_max", "stretch_mean", "flipped"):
        assert key in report["uv"]
    assert set(report["timings_s"]) == {
        "units",
        "clean",
        "layers",
        "smooth",
        "decimate",
        "atlas",
        "measure",
    }
    assert json.loads((tmp_path / "proxy.json").read_text()) == report
    proxy, _ = load_mesh(out)
    assert proxy.uvs is not None and (proxy.uvs >= 0).all() and (proxy.uvs <= 1).all()
    assert abs(report["proxy"]["vertices"] - 500) <= 50
    corr = np.load(tmp_path / "proxy.corr.npz")
    assert len(corr["face"]) == report["target"]["vertices"]


def test_cli_proxy_bad_input_exits_2(tmp_path, capsys):
    from app.cli import main

    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    assert main(["proxy", str(bad), "--out", str(tmp_path / "p.obj")]) == 2
    assert "bad.obj" in capsys.readouterr().err
    assert main(["proxy", str(tmp_path / "missing.obj"), "--out", str(tmp_path / "p.obj")]) == 2
    src = tmp_path / "skirt.obj"
    save_mesh(src, as_mesh(skirt_tube(n_around=16, n_along=6)))
    assert main(["proxy", str(src), "--out", str(tmp_path / "p.obj"), "--target-verts", "2"]) == 2


def test_cli_bench_proxy_writes_table_and_plot(tmp_path, capsys):
    from app.cli import main

    code = main(
        [
            "bench", "proxy", "--synthetic", "--garments", "synthetic-pleated-skirt",
            "--targets", "250,500", "--out", str(tmp_path), "--json",
        ]
    )  # fmt: skip
    assert code == 0
    table = json.loads((tmp_path / "proxy.json").read_text())
    assert [r["target_verts"] for r in table["rows"]] == [250, 500]
    for row in table["rows"]:
        assert abs(row["count_error"]) <= COUNT_TOL
        assert row["uv_flipped"] == 0 and row["uv_in_unit_square"]
        assert row["hausdorff_rel"] > 0 and row["proxy_s"] > 0
    png = (tmp_path / "proxy.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads(capsys.readouterr().out) == table


def test_cli_proxy_with_builtin_template(tmp_path, capsys):
    from app.cli import main
    from templates.garments import make_garment

    src = tmp_path / "skirt.obj"
    save_mesh(src, as_mesh(skirt_tube(n_around=96, n_along=40, folds=16, fold_depth=0.01)))
    out = tmp_path / "fitted.obj"
    code = main(["proxy", str(src), "--out", str(out), "--template", "long-skirt", "--json"])
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    template = make_garment("long-skirt")
    assert report["layers"]["used"] == "template" and report["template"] == "long-skirt"
    assert report["proxy"]["faces"] == template.num_faces
    assert report["uv"]["flipped"] == 0 and report["uv"]["in_unit_square"]
    assert main(["proxy", str(src), "--out", str(out), "--template", "no-such-skirt"]) == 2
