"""Welding split UV seams for the simulation: one cloth, the cache in the file's vertex order."""

from __future__ import annotations

import json

import numpy as np

from core.mesh import Mesh, load_mesh, save_mesh, weld, weld_mesh
from core.motion.bvh import write_bvh
from core.proxy import ProxyConfig, derive_proxy
from core.sim.cache import load_cache
from tests.sim_helpers import frustum_skirt, spin_motion


def seam_split_skirt(around: int = 24, rings: int = 8) -> tuple[Mesh, np.ndarray]:
    """The frustum skirt with a UV seam down its front: the column of vertices at angle 0 is
    duplicated and the faces that close the loop use the copies. Also returns the seam's
    vertex pairs (S, 2): (original, copy)."""
    skirt = frustum_skirt(around, rings)
    column = np.arange(rings) * around
    copies = skirt.num_vertices + np.arange(rings)
    faces = skirt.faces.copy()
    # Faces touching the last column close the loop onto column 0: use the copies there.
    closing = np.isin(faces, column + around - 1).any(axis=1)
    for c, k in zip(column, copies):
        faces[closing[:, None] & (faces == c)] = k
    vertices = np.concatenate([skirt.vertices, skirt.vertices[column]])
    i = np.arange(skirt.num_vertices) % around
    u = np.concatenate([i / around, np.ones(rings)])
    v = np.concatenate([np.arange(skirt.num_vertices) // around, np.arange(rings)]) / rings
    uvs = np.stack([u, v], axis=1).astype(np.float32)
    return Mesh(vertices.astype(np.float32), faces, uvs), np.stack([column, copies], axis=1)


def test_weld_joins_a_split_seam_and_maps_back():
    mesh, pairs = seam_split_skirt()
    skirt = frustum_skirt(24, 8)
    v, f, index = weld(mesh.vertices, mesh.faces)
    assert len(v) == skirt.num_vertices and index.shape == (mesh.num_vertices,)
    assert np.array_equal(index[pairs[:, 0]], index[pairs[:, 1]])
    assert np.array_equal(v[index], mesh.vertices)  # every split vertex maps to its place
    # Same surface as the skirt that never had a seam (same order: first occurrence kept).
    assert np.array_equal(v, skirt.vertices) and np.array_equal(f, skirt.faces)


def test_weld_tolerance_is_relative_and_keeps_distinct_vertices():
    mesh, pairs = seam_split_skirt()
    v = mesh.vertices.astype(np.float64).copy()
    v[pairs[:, 1]] += 2e-7  # float noise from a file written with 7 digits: still one vertex
    assert len(weld(v, mesh.faces)[0]) == frustum_skirt(24, 8).num_vertices
    v[pairs[:, 1]] += 1e-3  # a millimetre apart: two vertices (a real gap in the cloth)
    assert len(weld(v, mesh.faces)[0]) == mesh.num_vertices
    # In millimetres (scale x1000) the same seam still welds.
    assert len(weld(mesh.vertices * 1000.0, mesh.faces)[0]) == frustum_skirt(24, 8).num_vertices


def test_welded_proxy_is_the_seam_free_positions():
    target = frustum_skirt(48, 16)
    result = derive_proxy(target, ProxyConfig(target_verts=200, texture_size=128))
    assert result.proxy.num_vertices > result.positions.num_vertices  # it has split seams
    welded, index = weld_mesh(result.proxy)
    assert welded.num_vertices == result.positions.num_vertices
    assert welded.num_faces == result.positions.num_faces
    assert np.array_equal(welded.vertices[index], result.proxy.vertices)


def test_cli_simulates_a_split_seam_as_one_cloth(tmp_path, capsys):
    from app.cli import main

    mesh, pairs = seam_split_skirt()
    save_mesh(tmp_path / "seams.obj", mesh)
    loaded, _ = load_mesh(tmp_path / "seams.obj")
    assert loaded.num_vertices == mesh.num_vertices  # the file keeps its split seam
    motion = spin_motion(4)
    write_bvh(tmp_path / "spin.bvh", motion)
    args = [
        "simulate", "--garment", str(tmp_path / "seams.obj"), "--motion", str(tmp_path / "spin.bvh"),
        "--substeps", "2", "--iterations", "4", "--transition", "0.2", "--json",
        "--out", str(tmp_path / "c.npz"),
    ]  # fmt: skip
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["vertices"] == mesh.num_vertices
    assert report["welded_vertices"] == mesh.num_vertices - len(pairs)
    cache = load_cache(tmp_path / "c.npz")
    assert cache.positions.shape == (4, mesh.num_vertices, 3)
    assert np.array_equal(cache.faces, loaded.faces)
    gap = np.linalg.norm(cache.positions[:, pairs[:, 0]] - cache.positions[:, pairs[:, 1]], axis=-1)
    assert gap.max() < 1e-6
    # The seam did move: the cloth is simulated, not left at rest.
    assert np.linalg.norm(cache.positions[-1] - mesh.vertices, axis=1).max() > 0.01
    # A detailed garment embeds in the split proxy's cache (welded the same way).
    fine = frustum_skirt(48, 16)
    save_mesh(tmp_path / "fine.obj", fine)
    embed_args = [
        "simulate", "--garment", str(tmp_path / "fine.obj"), "--embed-in",
        str(tmp_path / "seams.obj"), str(tmp_path / "c.npz"), "--out", str(tmp_path / "f.npz"),
        "--json",
    ]  # fmt: skip
    assert main(embed_args) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["frames"] == 4 and report["vertices"] == fine.num_vertices
    assert report["torn_edges"] == 0 and report["stretch_max"] <= 0.3
    assert load_cache(tmp_path / "f.npz").positions.shape == (4, fine.num_vertices, 3)
    assert report["contact"] is None  # no motion given: the body is not known
    # With the proxy's motion it is kept out of the body too.
    assert main([*embed_args, "--motion", str(tmp_path / "spin.bvh")]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["contact"]["margin"] > 0 and report["penetration_max_mm"] == 0.0
    assert report["torn_edges"] == 0
    assert main([*embed_args, "--motion", str(tmp_path / "spin.bvh"), "--no-contact"]) == 0
    measured = json.loads(capsys.readouterr().out)
    assert measured["contact"] is None and "penetration_max_mm" in measured
    assert main([*embed_args, "--no-contact"]) == 2  # nothing to measure without the motion
    assert "--no-contact goes with --embed-in and --motion" in capsys.readouterr().err
    write_bvh(tmp_path / "spin6.bvh", spin_motion(6))
    assert main([*embed_args, "--motion", str(tmp_path / "spin6.bvh")]) == 2
    assert "6 frames, the proxy's cache 4" in capsys.readouterr().err
    # A cache of another mesh is refused, naming the file.
    save_mesh(tmp_path / "other.obj", frustum_skirt(20, 12))
    embed_args[4] = str(tmp_path / "other.obj")
    assert main(embed_args) == 2
    assert "topology mismatch" in capsys.readouterr().err
