"""Simulation caches: the :class:`SimCache` record and its files, ours and other tools'.

Formats
-------
``.npz``      ours: positions, faces, fps and the parameters that made it (JSON).
folder/       an OBJ sequence: one ``frame_NNNN.obj`` per frame, same topology in every file.
``.pc2``      Blender/3ds Max point cache 2: little-endian header (``POINTCACHE2\\0``, version 1,
              point count, start frame, sample rate, sample count) then float32 xyz per point.
``.mdd``      LightWave MDD: big-endian frame count, point count, float32 times, float32 xyz.
              Coordinates are stored as given (exporters differ on axis conventions).
``.usd``      USD (also ``.usda`` text, ``.usdc``), written only: a ``Garment`` mesh with points
              sampled at the cache's fps, metres, Y up (:mod:`core.usd`).

PC2 and MDD hold no faces: reading them needs the garment's topology. Every reader checks that
the data is complete, finite and of one topology, and raises ``InputError`` naming the file.
"""

from __future__ import annotations

import io
import json
import os
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from core.errors import InputError
from core.fileio import atomic_open, json_default
from core.usd import USD_SUFFIXES, UsdMesh, write_usd

CACHE_SUFFIXES = (".npz", ".pc2", ".mdd")
_PC2_MAGIC = b"POINTCACHE2\0"
_PC2_HEADER = struct.Struct("<12siiffi")


@dataclass(frozen=True)
class SimCache:
    """A garment's vertex positions over a clip.

    Attributes
    ----------
    positions : (T, V, 3) float32
        Vertex positions per frame, metres.
    faces : (F, 3) int64
        Triangles, the same for every frame.
    fps : float
        Frames per second.
    params : dict
        What made the cache (simulation settings, body shape, motion, garment), JSON-able.
    """

    positions: np.ndarray
    faces: np.ndarray
    fps: float
    params: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        p, f = self.positions, self.faces
        if p.ndim != 3 or p.shape[2] != 3 or p.shape[0] < 1:
            raise ValueError(f"positions must be (T, V, 3) with T >= 1, got {p.shape}")
        if p.dtype != np.float32:
            raise ValueError(f"positions must be float32, got {p.dtype}")
        if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
            raise ValueError(f"faces must be (F, 3) integers, got {f.shape} {f.dtype}")
        if len(f) and (f.min() < 0 or f.max() >= p.shape[1]):
            raise ValueError(f"face indices out of range [0, {p.shape[1]})")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"fps must be positive, got {self.fps}")

    @property
    def num_frames(self) -> int:
        return self.positions.shape[0]

    @property
    def num_vertices(self) -> int:
        return self.positions.shape[1]


def unweld_cache(cache: SimCache, index: np.ndarray, faces: np.ndarray) -> SimCache:
    """A cache of a welded mesh (:func:`core.mesh.weld`) mapped back to the split vertices.

    Parameters
    ----------
    cache : positions (T, W, 3) of the welded mesh
    index : (V,) int, the welded vertex of each split vertex
    faces : (F, 3) int, the split mesh's faces

    Returns
    -------
    SimCache with positions (T, V, 3) in the split mesh's vertex order; ``pinned_indices``
    (when present) name every split vertex of a pinned welded vertex.
    """
    index = np.asarray(index, np.int64)
    params = dict(cache.params)
    if "pinned_indices" in params:
        pinned = np.isin(index, np.asarray(params["pinned_indices"], np.int64))
        params["pinned_indices"] = np.flatnonzero(pinned).tolist()
    params["welded_vertices"] = cache.num_vertices
    return SimCache(
        np.ascontiguousarray(cache.positions[:, index]), np.asarray(faces, np.int64), cache.fps,
        params,
    )  # fmt: skip


def _checked(positions: np.ndarray, faces: np.ndarray, fps: float, params: dict, path) -> SimCache:
    positions = np.asarray(positions)
    faces = np.asarray(faces)
    if positions.ndim != 3 or positions.shape[2] != 3 or positions.shape[0] < 1:
        raise InputError(f"cache positions must be (T, V, 3), got shape {positions.shape}", path)
    if not np.isfinite(positions).all():
        t = int(np.argmax(~np.isfinite(positions).all(axis=(1, 2))))
        raise InputError(f"cache holds NaN or inf positions (first at frame {t})", path)
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise InputError(f"cache faces must be (F, 3) integers, got {faces.shape}", path)
    if len(faces) and (faces.min() < 0 or faces.max() >= positions.shape[1]):
        raise InputError(
            f"faces index vertices up to {faces.max()} but frames have {positions.shape[1]}", path
        )
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"cache fps must be positive, got {fps}", path)
    return SimCache(positions.astype(np.float32), faces.astype(np.int64), float(fps), params)


# ---------------------------------------------------------------------------- ours (.npz)


def save_cache(path: str | os.PathLike, cache: SimCache) -> None:
    """Write ``cache`` as ``.npz`` (atomically)."""
    path = Path(path)
    if path.suffix.lower() != ".npz":
        raise InputError("our cache format is .npz; use export_cache for other formats", path)
    if not np.isfinite(cache.positions).all():
        raise InputError("refusing to write a cache with NaN or inf positions", path)
    buf = io.BytesIO()
    np.savez_compressed(
        buf,
        positions=cache.positions,
        faces=cache.faces,
        fps=np.float64(cache.fps),
        params=np.array(json.dumps(cache.params, default=json_default)),
    )
    with atomic_open(path, "wb") as f:
        f.write(buf.getvalue())


def load_cache(path: str | os.PathLike) -> SimCache:
    """Read an ``.npz`` cache written by :func:`save_cache`."""
    path = Path(path)
    if not path.is_file():
        raise InputError("no such cache file", path)
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = {"positions", "faces", "fps"} - set(z.files)
            if missing:
                raise InputError(f"not a simulation cache: missing {sorted(missing)}", path)
            positions, faces, fps = z["positions"], z["faces"], float(z["fps"])
            params = json.loads(str(z["params"])) if "params" in z.files else {}
    except InputError:
        raise
    except Exception as exc:  # zipfile/pickle/json errors on damaged files
        raise InputError(f"unreadable cache ({type(exc).__name__}: {exc})", path) from None
    return _checked(positions, faces, fps, params, path)


# ---------------------------------------------------------------------------- OBJ sequences


def write_obj_sequence(
    folder: str | os.PathLike, cache: SimCache, prefix: str = "frame_"
) -> list[Path]:
    """One OBJ per frame (``frame_0000.obj``...), 9 significant digits: exact for float32."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    faces = "".join(f"f {a} {b} {c}\n" for a, b, c in cache.faces + 1)
    width = max(4, len(str(cache.num_frames - 1)))
    paths = []
    for t, frame in enumerate(cache.positions):
        p = folder / f"{prefix}{t:0{width}d}.obj"
        verts = "".join(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in frame.tolist())
        with atomic_open(p, "w", encoding="utf-8") as f:
            f.write(f"# garment studio cache frame {t}\n{verts}{faces}")
        paths.append(p)
    return paths


def _parse_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float32 (parsed straight to float32) and triangles (fan-split polygons)."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputError(f"unreadable OBJ ({exc})", path) from None
    verts, faces = [], []
    for n, line in enumerate(text.splitlines(), 1):
        if line.startswith("v "):
            parts = line.split()
            if len(parts) < 4:
                raise InputError(f"line {n}: vertex with fewer than 3 coordinates", path)
            verts.append(parts[1:4])
        elif line.startswith("f "):
            idx = [int(tok.split("/")[0]) for tok in line.split()[1:]]
            if len(idx) < 3:
                raise InputError(f"line {n}: face with fewer than 3 vertices", path)
            faces.extend((idx[0], idx[i], idx[i + 1]) for i in range(1, len(idx) - 1))
    if not verts:
        raise InputError("OBJ holds no vertices", path)
    try:
        v = np.array(verts, dtype=np.float32)
    except ValueError:
        raise InputError("OBJ has a vertex coordinate that is not a number", path) from None
    f = np.array(faces, np.int64).reshape(-1, 3)
    f = np.where(f < 0, f + len(v), f - 1)  # negative (relative) indices
    return v, f


def read_obj_sequence(
    folder: str | os.PathLike, fps: float = 30.0, faces: np.ndarray | None = None
) -> SimCache:
    """Read one OBJ per frame from ``folder`` (sorted by the last number in the file name).

    Every file must have the same vertex count and the same faces (or, for vertex-only files,
    ``faces`` must be given). Raises ``InputError`` naming the first file that differs.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("no such folder of OBJ frames", folder)
    files = [p for p in folder.iterdir() if p.suffix.lower() == ".obj"]
    if not files:
        raise InputError("folder holds no .obj frames", folder)

    def key(p: Path):
        nums = re.findall(r"\d+", p.stem)
        return (int(nums[-1]) if nums else -1, p.name)

    files.sort(key=key)
    frames, ref_faces = [], None
    for p in files:
        v, f = _parse_obj(p)
        if frames and len(v) != frames[0].shape[0]:
            raise InputError(
                f"topology changes: {len(v)} vertices here, {frames[0].shape[0]} in {files[0].name}",
                p,
            )
        if ref_faces is None:
            ref_faces = f
        elif len(f) and not np.array_equal(f, ref_faces):
            raise InputError(f"topology changes: faces differ from {files[0].name}", p)
        frames.append(v)
    if ref_faces is None or not len(ref_faces):
        if faces is None:
            raise InputError("OBJ frames hold no faces; give the garment mesh for topology", folder)
        ref_faces = np.asarray(faces, np.int64)
    return _checked(
        np.stack(frames), ref_faces, fps, {"source": str(folder), "format": "obj"}, folder
    )


# ---------------------------------------------------------------------------- PC2


def write_pc2(path: str | os.PathLike, cache: SimCache, start_frame: float = 0.0) -> None:
    """Write a PC2 point cache (sample rate 1: one sample per frame)."""
    t, v, _ = cache.positions.shape
    header = _PC2_HEADER.pack(_PC2_MAGIC, 1, v, float(start_frame), 1.0, t)
    with atomic_open(path, "wb") as f:
        f.write(header)
        f.write(np.ascontiguousarray(cache.positions, "<f4").tobytes())


def read_pc2(path: str | os.PathLike, faces: np.ndarray, fps: float = 30.0) -> SimCache:
    """Read a PC2 point cache; ``faces`` (F, 3) is the garment's topology."""
    path = Path(path)
    data = _read_bytes(path)
    if len(data) < _PC2_HEADER.size:
        raise InputError(f"truncated PC2: {len(data)} bytes, shorter than the header", path)
    magic, version, v, _start, rate, t = _PC2_HEADER.unpack_from(data)
    if magic != _PC2_MAGIC:
        raise InputError("not a PC2 file (no POINTCACHE2 signature)", path)
    if v <= 0 or t <= 0:
        raise InputError(f"PC2 header has {v} points and {t} samples", path)
    expected = _PC2_HEADER.size + t * v * 12
    if len(data) != expected:
        what = "truncated" if len(data) < expected else "has trailing bytes"
        raise InputError(
            f"PC2 {what}: {len(data)} bytes, header promises {t} samples x {v} points = {expected}",
            path,
        )
    pos = np.frombuffer(data, "<f4", offset=_PC2_HEADER.size).reshape(t, v, 3)
    _check_faces(faces, v, path)
    params = {"source": str(path), "format": "pc2", "pc2_sample_rate": rate}
    return _checked(pos.astype(np.float32), faces, fps, params, path)


# ---------------------------------------------------------------------------- MDD


def write_mdd(path: str | os.PathLike, cache: SimCache) -> None:
    """Write a LightWave MDD (big-endian; frame times i / fps)."""
    t, v, _ = cache.positions.shape
    times = (np.arange(t) / cache.fps).astype(">f4")
    with atomic_open(path, "wb") as f:
        f.write(struct.pack(">ii", t, v))
        f.write(times.tobytes())
        f.write(np.ascontiguousarray(cache.positions, ">f4").tobytes())


def read_mdd(path: str | os.PathLike, faces: np.ndarray, fps: float | None = None) -> SimCache:
    """Read an MDD; ``fps`` defaults to the file's frame times (30 if it has one frame)."""
    path = Path(path)
    data = _read_bytes(path)
    if len(data) < 8:
        raise InputError("truncated MDD: shorter than its header", path)
    t, v = struct.unpack_from(">ii", data)
    if t <= 0 or v <= 0:
        raise InputError(f"MDD header has {t} frames and {v} points", path)
    expected = 8 + 4 * t + t * v * 12
    if len(data) != expected:
        what = "truncated" if len(data) < expected else "has trailing bytes"
        raise InputError(
            f"MDD {what}: {len(data)} bytes, header promises {t} frames x {v} points = {expected}",
            path,
        )
    times = np.frombuffer(data, ">f4", count=t, offset=8).astype(np.float64)
    pos = np.frombuffer(data, ">f4", offset=8 + 4 * t).reshape(t, v, 3).astype(np.float32)
    if fps is None:
        step = np.diff(times)
        fps = float(1.0 / np.median(step)) if t > 1 and np.median(step) > 0 else 30.0
    _check_faces(faces, v, path)
    return _checked(pos, faces, fps, {"source": str(path), "format": "mdd"}, path)


# ---------------------------------------------------------------------------- by extension


def export_cache(path: str | os.PathLike, cache: SimCache) -> None:
    """Write ``cache`` by extension: ``.npz``, ``.pc2``, ``.mdd``, ``.usd``/``.usda``/``.usdc``,
    or a folder (OBJ sequence)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in USD_SUFFIXES:
        write_usd(
            path, [UsdMesh("Garment", cache.positions, cache.faces, double_sided=True)], cache.fps
        )
    elif suffix == ".npz":
        save_cache(path, cache)
    elif suffix == ".pc2":
        write_pc2(path, cache)
    elif suffix == ".mdd":
        write_mdd(path, cache)
    elif suffix == "":
        write_obj_sequence(path, cache)
    else:
        raise InputError(
            f"unknown cache type {suffix!r}; use .npz, .pc2, .mdd, .usd, .usda or a folder for "
            "OBJ frames",
            path,
        )


def import_cache(
    path: str | os.PathLike, faces: np.ndarray | None = None, fps: float | None = None
) -> SimCache:
    """Read a cache by extension (see :func:`export_cache`); PC2/MDD need ``faces``."""
    path = Path(path)
    suffix = path.suffix.lower()
    if path.is_dir():
        return read_obj_sequence(path, fps or 30.0, faces)
    if suffix == ".npz":
        return load_cache(path)
    if suffix in (".pc2", ".mdd"):
        if faces is None:
            raise InputError(f"{suffix} caches hold no faces: give the garment mesh", path)
        if suffix == ".pc2":
            return read_pc2(path, faces, fps or 30.0)
        return read_mdd(path, faces, fps)
    if not path.exists():
        raise InputError("no such cache", path)
    raise InputError(
        f"unknown cache type {suffix!r}; use .npz, .pc2, .mdd or a folder of OBJ frames", path
    )


def _read_bytes(path: Path) -> bytes:
    if not path.is_file():
        raise InputError("no such cache file", path)
    return path.read_bytes()


def _check_faces(faces: np.ndarray, num_vertices: int, path) -> None:
    faces = np.asarray(faces)
    if faces.size and faces.max() >= num_vertices:
        raise InputError(
            f"topology mismatch: the garment has vertex {faces.max()} but the cache "
            f"holds {num_vertices} points",
            path,
        )
