"""Shared fixtures: real motion capture from Debian's assimp-testmodels, small made-up data."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

#: Where Debian's assimp-testmodels puts its BVH files (the test setup installs the package).
CMU_BVH_DIR = Path("/usr/share/assimp/models/BVH")


def pytest_collection_modifyitems(config, items):
    """Skip ``gpu`` tests without CUDA and ``gui`` tests without a display."""
    has_gpu = torch.cuda.is_available()
    for item in items:
        if "gpu" in item.keywords and not has_gpu:
            item.add_marker(pytest.mark.skip(reason="no CUDA GPU on this machine"))
        if "gui" in item.keywords and not os.environ.get("DISPLAY"):
            item.add_marker(pytest.mark.skip(reason="no display (./studio test starts Xvfb)"))


@pytest.fixture(scope="session")
def deepmimic_dir() -> Path:
    """pybullet's DeepMimic motion capture (``pybullet_data/data/motions``); pybullet is a dev
    dependency: missing, it is a setup error, not a skip."""
    try:
        import pybullet_data
    except ImportError:
        pytest.fail("pybullet missing: run ./studio setup (it ships DeepMimic's motion capture)")
    return Path(pybullet_data.getDataPath()) / "data" / "motions"


@pytest.fixture(scope="session")
def bvh_dir() -> Path:
    """The CMU motion-capture folder; a missing package is a setup error, not a skip."""
    if not (CMU_BVH_DIR / "01_01.bvh").is_file():
        pytest.fail(f"{CMU_BVH_DIR} missing: run ./studio setup (installs assimp-testmodels)")
    return CMU_BVH_DIR


@pytest.fixture
def dng(capsys):
    """``dng(*args) -> (exit code, stdout, stderr)``: the command line run in this process
    (arguments may be paths or numbers)."""
    from app.cli import main

    def run(*argv) -> tuple[int, str, str]:
        code = main([str(a) for a in argv])
        out, err = capsys.readouterr()
        return code, out, err

    return run


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)


def assert_motion_file_refused(dng, folder: Path, path: Path, content, action: str, problem: str):
    """``dng motion info|retarget`` on a bad motion file: ``content`` (str, bytes, or None for a
    missing file) written to ``path``; exit 2, one line naming the file and ``problem``, and
    nothing written (``retarget``'s output goes under ``folder / "out"``)."""
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content)
    out_path = folder / "out" / "x.bvh"
    argv = ["info", path] if action == "info" else ["retarget", path, "--out", out_path]
    code, out, err = dng("motion", *argv)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert str(path) in lines[0] and problem in lines[0], lines[0]
    assert not out_path.exists() and not (folder / "out").exists()


def run_benchmark(script: str, *args) -> subprocess.CompletedProcess:
    """``python benchmarks/SCRIPT ARGS...`` as a user runs it (arguments turned to text), its
    output captured."""
    path = Path(__file__).resolve().parents[1] / "benchmarks" / script
    return subprocess.run(
        [sys.executable, str(path), *map(str, args)], capture_output=True, text=True
    )


def load_benchmark(script: str):
    """``benchmarks/SCRIPT`` imported as a module, to call its functions directly."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "benchmarks" / script
    spec = importlib.util.spec_from_file_location(Path(script).stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def assert_close(actual, expected, atol=1e-6, rtol=0.0, what="arrays"):
    """``np.allclose`` that says where the largest difference is (PyTorch3D style)."""
    actual, expected = np.asarray(actual, np.float64), np.asarray(expected, np.float64)
    assert actual.shape == expected.shape, f"{what}: shape {actual.shape} != {expected.shape}"
    diff = np.abs(actual - expected)
    tol = atol + rtol * np.abs(expected)
    if not (diff <= tol).all():
        idx = np.unravel_index(np.argmax(diff - tol), diff.shape)
        raise AssertionError(
            f"{what}: max difference {diff[idx]:.3g} at {idx} "
            f"(actual {actual[idx]:.6g}, expected {expected[idx]:.6g}, atol {atol}, rtol {rtol})"
        )


@pytest.fixture(scope="session")
def smoke_project(tmp_path_factory, bvh_dir) -> Path:
    """A project made by the ``smoke`` preset of ``dng demo`` (every stage, the neural renderer
    and the evaluation included), shared by the whole session: treat it as read-only (write
    only into subfolders of your own, like ``finetune/NAME``)."""
    from pipeline.config import PRESETS
    from pipeline.demo import run_demo

    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("smoke-project")
    run_demo(PRESETS["smoke"], out, preset_name="smoke")
    return out
