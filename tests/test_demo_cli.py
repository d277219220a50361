"""``dng demo --garment``: your own garment in, refused early when it is not one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from app.commands.demo import _garment
from core.mesh import load_mesh, save_mesh
from core.project import Project
from pipeline.config import preset
from pipeline.stages.garment import stage_garment
from templates.garments import make_garment


def test_a_builtin_name_stays_a_name_and_a_file_becomes_its_absolute_path(tmp_path, monkeypatch):
    assert _garment("slit-skirt") == "slit-skirt"
    mesh = tmp_path / "mine.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0.1\nf 1 2 3\nf 2 4 3\n")
    monkeypatch.chdir(tmp_path)
    assert _garment("mine.obj") == str(mesh.resolve())


@pytest.mark.parametrize(
    "name, content, problem",
    [
        ("nope", None, "no built-in garment"),
        ("missing.obj", None, "no such file"),
        ("empty.obj", "", "empty"),
        ("nan.obj", "v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN"),
    ],
)
def test_a_bad_garment_is_refused_by_name_before_the_run_starts(
    dng, tmp_path, name, content, problem
):
    path = tmp_path / name
    if content is not None:
        path.write_text(content)
    out = tmp_path / "project"
    code, _, err = dng("demo", "--preset", "smoke", "--garment", path if path.suffix else name,
                       "--out", out)  # fmt: skip
    assert code == 2, err
    assert problem.lower() in err.lower() and name in err
    assert not out.exists(), "a refused run must not start a project"
    assert len(err.strip().splitlines()) == 1, "one line, not a traceback"


def test_a_garment_file_in_centimetres_lands_in_metres_on_the_mannequin(tmp_path):
    """The target is read in the unit the proxy stage reads it in, so the two agree."""
    config = preset("smoke")
    skirt = make_garment("slit-skirt", None, config.body, 0)
    save_mesh(tmp_path / "cm.obj", dataclasses.replace(skirt, vertices=skirt.vertices * 100))
    config = dataclasses.replace(config, garment=str(tmp_path / "cm.obj"))
    lines: list[str] = []
    target, _ = load_mesh(stage_garment(Project(tmp_path / "p"), config, lines.append))
    assert np.abs(target.vertices - skirt.vertices).max() < 1e-5
    assert any("read as cm" in line for line in lines)
