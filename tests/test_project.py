"""Project folders: stages rerun only when their parameters or input files change."""

from __future__ import annotations

import pytest

from core.errors import InputError
from core.fileio import write_json
from core.project import Project, fingerprint


def _stage(calls):
    def work(out):
        calls.append(out)
        write_json(out / "result.json", {"n": len(calls)})
        return ["result.json"]

    return work


def test_stage_reruns_only_when_inputs_change(tmp_path):
    proj = Project(tmp_path / "p")
    src = tmp_path / "garment.obj"
    src.write_text("v 0 0 0\n")
    calls: list = []
    rec, ran = proj.run_stage("proxy", {"verts": 2000}, [src], _stage(calls))
    assert ran and rec.outputs == ("result.json",) and len(calls) == 1
    _, ran = proj.run_stage("proxy", {"verts": 2000}, [src], _stage(calls))
    assert not ran and len(calls) == 1
    _, ran = proj.run_stage("proxy", {"verts": 1000}, [src], _stage(calls))
    assert ran and len(calls) == 2
    src.write_text("v 1 0 0\n")
    _, ran = proj.run_stage("proxy", {"verts": 1000}, [src], _stage(calls))
    assert ran and len(calls) == 3
    (proj.path("proxy", "result.json")).unlink()
    _, ran = proj.run_stage("proxy", {"verts": 1000}, [src], _stage(calls))
    assert ran, "a stage whose output vanished is not fresh"


def test_killed_stage_leaves_no_record_and_reruns(tmp_path):
    proj = Project(tmp_path)

    def dies(out):
        write_json(out / "partial.json", {})
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        proj.run_stage("sim", {}, [], dies)
    assert proj.record("sim") is None
    calls: list = []
    _, ran = proj.run_stage("sim", {}, [], _stage(calls))
    assert ran and proj.record("sim").outputs == ("result.json",)


def test_fingerprint_and_settings_errors(tmp_path):
    with pytest.raises(InputError, match="missing"):
        fingerprint({}, [tmp_path / "nope.bvh"])
    assert fingerprint({"a": 1, "b": 2}) == fingerprint({"b": 2, "a": 1})
    proj = Project(tmp_path)
    assert proj.settings() == {}
    proj.save_settings({"garment": "multilayer-skirt"})
    assert proj.settings()["garment"] == "multilayer-skirt"
    (tmp_path / "project.json").write_text("{broken")
    with pytest.raises(InputError, match="project.json: malformed"):
        proj.settings()


def test_resumable_files_survive_a_retry_but_not_a_change(tmp_path):
    from core.project import Project

    proj = Project(tmp_path)

    def crash(out):
        (out / "ckpt.pt").write_text("half way")
        raise KeyboardInterrupt

    def finish(out):
        assert (out / "ckpt.pt").read_text() == "half way"  # resumed from the checkpoint
        (out / "model.pt").write_text("done")
        return ["model.pt"]

    with pytest.raises(KeyboardInterrupt):
        proj.run_stage("train", {"steps": 10}, [], crash, resumable=["ckpt.pt"])
    proj.run_stage("train", {"steps": 10}, [], finish, resumable=["ckpt.pt"])

    def fresh(out):
        assert not (out / "ckpt.pt").exists()  # other settings: the stale checkpoint is gone
        (out / "model.pt").write_text("done again")
        return ["model.pt"]

    (proj.path("train", "ckpt.pt")).write_text("from 10 steps")
    _, ran = proj.run_stage("train", {"steps": 20}, [], fresh, resumable=["ckpt.pt"])
    assert ran and proj.path("train", "model.pt").read_text() == "done again"
