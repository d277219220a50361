"""Simulation caches: exact round trips (npz, OBJ sequences, PC2, MDD), malformed files refused."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from core.errors import InputError
from core.sim.cache import (
    SimCache,
    export_cache,
    import_cache,
    load_cache,
    read_mdd,
    read_obj_sequence,
    read_pc2,
    save_cache,
    write_mdd,
    write_obj_sequence,
    write_pc2,
)
from tests.sim_helpers import frustum_skirt


@pytest.fixture
def cache(rng) -> SimCache:
    mesh = frustum_skirt(10, 5)
    t = 4
    # Awkward float32 values: large, tiny, negative, many significant digits.
    noise = rng.standard_normal((t, mesh.num_vertices, 3)).astype(np.float32)
    pos = mesh.vertices[None] + noise * np.float32(0.1)
    pos[0, 0] = (1e-7, -123.456789, 3.4028e10)
    return SimCache(pos.astype(np.float32), mesh.faces, 24.0, {"what": "test"})


def test_npz_round_trip_is_exact(tmp_path, cache):
    save_cache(tmp_path / "c.npz", cache)
    back = load_cache(tmp_path / "c.npz")
    assert back.positions.dtype == np.float32
    assert np.array_equal(back.positions, cache.positions)
    assert np.array_equal(back.faces, cache.faces)
    assert back.fps == 24.0 and back.params == {"what": "test"}


def test_obj_sequence_round_trip_is_exact(tmp_path, cache):
    paths = write_obj_sequence(tmp_path / "seq", cache)
    assert [p.name for p in paths] == [f"frame_{i:04d}.obj" for i in range(4)]
    back = read_obj_sequence(tmp_path / "seq", fps=24.0)
    assert np.array_equal(back.positions, cache.positions)
    assert np.array_equal(back.faces, cache.faces)


def test_pc2_and_mdd_round_trips_are_exact(tmp_path, cache):
    write_pc2(tmp_path / "c.pc2", cache)
    back = read_pc2(tmp_path / "c.pc2", cache.faces, fps=24.0)
    assert np.array_equal(back.positions, cache.positions)
    write_mdd(tmp_path / "c.mdd", cache)
    back = read_mdd(tmp_path / "c.mdd", cache.faces)
    assert np.array_equal(back.positions, cache.positions)
    assert back.fps == pytest.approx(24.0, rel=1e-5)


def test_export_import_by_extension(tmp_path, cache):
    for name in ("a.npz", "a.pc2", "a.mdd", "frames"):
        export_cache(tmp_path / name, cache)
        back = import_cache(tmp_path / name, faces=cache.faces, fps=24.0)
        assert np.array_equal(back.positions, cache.positions), name
    with pytest.raises(InputError, match="unknown cache type"):
        export_cache(tmp_path / "a.abc", cache)
    with pytest.raises(InputError, match="hold no faces"):
        import_cache(tmp_path / "a.pc2")


def test_obj_sequence_topology_change_is_refused(tmp_path, cache):
    write_obj_sequence(tmp_path / "seq", cache)
    third = tmp_path / "seq" / "frame_0002.obj"
    lines = third.read_text().splitlines()
    third.write_text("\n".join(ln for i, ln in enumerate(lines) if i != 1) + "\n")  # drop a v
    with pytest.raises(InputError, match="topology changes") as err:
        read_obj_sequence(tmp_path / "seq")
    assert "frame_0002.obj" in str(err.value)
    # Same vertex count, different faces.
    write_obj_sequence(tmp_path / "seq2", cache)
    second = tmp_path / "seq2" / "frame_0001.obj"
    second.write_text(second.read_text().replace("f 1 ", "f 2 ", 1))
    with pytest.raises(InputError, match="faces differ"):
        read_obj_sequence(tmp_path / "seq2")


def test_truncated_and_padded_pc2_are_refused(tmp_path, cache):
    write_pc2(tmp_path / "c.pc2", cache)
    data = (tmp_path / "c.pc2").read_bytes()
    (tmp_path / "short.pc2").write_bytes(data[:-5])
    with pytest.raises(InputError, match="truncated") as err:
        read_pc2(tmp_path / "short.pc2", cache.faces)
    assert "short.pc2" in str(err.value)
    (tmp_path / "long.pc2").write_bytes(data + b"\0\0\0\0")
    with pytest.raises(InputError, match="trailing"):
        read_pc2(tmp_path / "long.pc2", cache.faces)
    (tmp_path / "bad.pc2").write_bytes(b"NOTAPC2CACHE" + data[12:])
    with pytest.raises(InputError, match="signature"):
        read_pc2(tmp_path / "bad.pc2", cache.faces)
    (tmp_path / "tiny.pc2").write_bytes(data[:10])
    with pytest.raises(InputError, match="header"):
        read_pc2(tmp_path / "tiny.pc2", cache.faces)


def test_truncated_mdd_and_wrong_topology_are_refused(tmp_path, cache):
    write_mdd(tmp_path / "c.mdd", cache)
    data = (tmp_path / "c.mdd").read_bytes()
    (tmp_path / "short.mdd").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="truncated"):
        read_mdd(tmp_path / "short.mdd", cache.faces)
    # A garment with more vertices than the cache holds.
    bigger = np.array([[0, 1, cache.num_vertices + 3]])
    with pytest.raises(InputError, match="topology mismatch"):
        read_mdd(tmp_path / "c.mdd", bigger)
    (tmp_path / "zero.mdd").write_bytes(struct.pack(">ii", 0, 5))
    with pytest.raises(InputError, match="0 frames"):
        read_mdd(tmp_path / "zero.mdd", cache.faces)


def test_non_finite_caches_are_never_written_or_trusted(tmp_path, cache):
    bad = cache.positions.copy()
    bad[2, 3, 1] = np.nan
    garbage = SimCache(bad, cache.faces, cache.fps)
    with pytest.raises(InputError, match="NaN"):
        save_cache(tmp_path / "g.npz", garbage)
    assert not (tmp_path / "g.npz").exists()
    write_pc2(tmp_path / "g.pc2", garbage)  # a foreign tool could write this...
    with pytest.raises(InputError, match="frame 2"):  # ...we refuse to read it
        read_pc2(tmp_path / "g.pc2", cache.faces)


def test_damaged_npz_is_refused(tmp_path, cache):
    save_cache(tmp_path / "c.npz", cache)
    data = (tmp_path / "c.npz").read_bytes()
    (tmp_path / "d.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="d.npz"):
        load_cache(tmp_path / "d.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(InputError, match="missing"):
        load_cache(tmp_path / "other.npz")
