"""Triangle meshes: loading, validation and repair, atomic saving.

Every stage that takes a mesh from a user goes through :func:`load_mesh`, so a bad file is
refused in one place with a message naming the file and the problem.
"""

from __future__ import annotations

import os
from collections import defaultdict
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from core.constants import DEGENERATE_AREA_M2, MERGE_TOLERANCE_M, WELD_TOLERANCE_REL
from core.errors import InputError
from core.fileio import atomic_path

#: File types :func:`load_mesh` reads (by extension).
MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".off", ".stl")


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh with optional per-vertex UVs.

    Attributes
    ----------
    vertices : (V, 3) float32
        Positions in metres.
    faces : (F, 3) int64
        Counter-clockwise triangles (outward normals by the right-hand rule).
    uvs : (V, 2) float32 or None
        Texture coordinates in [0, 1], one per vertex (seams are split vertices).
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None = None

    def __post_init__(self) -> None:
        v, f = self.vertices, self.faces
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValueError(f"vertices must be (V, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3:
            raise ValueError(f"faces must be (F, 3), got {f.shape}")
        if self.uvs is not None and self.uvs.shape != (len(v), 2):
            raise ValueError(f"uvs must be ({len(v)}, 2), got {self.uvs.shape}")

    @property
    def num_vertices(self) -> int:
        return len(self.vertices)

    @property
    def num_faces(self) -> int:
        return len(self.faces)

    def to_trimesh(self):
        import trimesh

        visual = None
        if self.uvs is not None:
            visual = trimesh.visual.TextureVisuals(uv=self.uvs)
        return trimesh.Trimesh(self.vertices, self.faces, visual=visual, process=False)


@dataclass(frozen=True)
class RepairReport:
    """What :func:`validate_mesh` found and fixed."""

    merged_vertices: int = 0
    degenerate_faces: int = 0
    duplicate_faces: int = 0
    unreferenced_vertices: int = 0
    non_manifold_edges: int = 0
    boundary_edges: int = 0
    components: int = 0
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def validate_mesh(
    vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray | None = None, *, path=None
) -> tuple[Mesh, RepairReport]:
    """Check and repair raw arrays into a :class:`Mesh`.

    Rejects (``InputError``): wrong shapes, NaN/inf, out-of-range indices, empty meshes,
    nothing left after repair. Repairs: merges duplicate vertices (within
    ``MERGE_TOLERANCE_M``, keeping UV seams apart), drops degenerate and duplicate faces and
    unreferenced vertices. Reports, without changing: non-manifold and boundary edges, and
    the number of connected components.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    uvs : (V, 2) float or None
    path : the file the arrays came from, for messages
    """
    vertices = np.asarray(vertices)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise InputError(f"vertices must be (V, 3), got shape {vertices.shape}", path)
    if len(vertices) == 0 or faces.size == 0:
        raise InputError("empty mesh: no vertices or no faces", path)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(f"faces must be triangles (F, 3), got shape {faces.shape}", path)
    if not np.issubdtype(faces.dtype, np.integer):
        raise InputError(f"face indices must be integers, got {faces.dtype}", path)
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        raise InputError(
            f"{int(bad.sum())} vertices have NaN or inf coordinates (first: vertex {int(np.argmax(bad))})",
            path,
        )
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError(
            f"face indices out of range [0, {len(vertices)}): min {faces.min()}, max {faces.max()}",
            path,
        )
    if uvs is not None:
        uvs = np.asarray(uvs, np.float64)
        if uvs.shape != (len(vertices), 2) or not np.isfinite(uvs).all():
            uvs = None  # unusable UVs are dropped, not trusted
    v = vertices.astype(np.float64)
    f = faces.astype(np.int64)
    notes: list[str] = []

    # Merge duplicate vertices: quantise position (and UV, to keep seams) on a tolerance grid.
    key = np.round(v / MERGE_TOLERANCE_M).astype(np.int64)
    if uvs is not None:
        key = np.concatenate([key, np.round(uvs * 1e6).astype(np.int64)], axis=1)
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    first, inverse = _first_occurrence(inverse.reshape(-1))
    merged = len(v) - len(first)
    v, f = v[first], inverse[f]
    uvs = None if uvs is None else uvs[first]

    # Degenerate faces: repeated index or (near) zero area.
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    degenerate = repeated | (area <= DEGENERATE_AREA_M2)
    f = f[~degenerate]
    # Duplicate faces (same three vertices in any order).
    _, keep = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    duplicates = len(f) - len(keep)
    f = f[np.sort(keep)]
    if len(f) == 0:
        raise InputError("no faces left after removing degenerate ones", path)

    used = np.zeros(len(v), bool)
    used[f.ravel()] = True
    unreferenced = int((~used).sum())
    remap = np.cumsum(used) - 1
    v, f = v[used], remap[f]
    uvs = None if uvs is None else uvs[used]

    edges = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    non_manifold = int((counts > 2).sum())
    boundary = int((counts == 1).sum())
    components = count_components(len(v), f)
    if non_manifold:
        notes.append(f"{non_manifold} non-manifold edges (shared by more than two faces)")
    mesh = Mesh(
        v.astype(np.float32), f, None if uvs is None else np.clip(uvs, 0, 1).astype(np.float32)
    )
    report = RepairReport(
        merged_vertices=merged,
        degenerate_faces=int(degenerate.sum()),
        duplicate_faces=duplicates,
        unreferenced_vertices=unreferenced,
        non_manifold_edges=non_manifold,
        boundary_edges=boundary,
        components=components,
        notes=notes,
    )
    return mesh, report


def _first_occurrence(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Renumber group ``labels`` (V,) int in order of each group's first vertex, so merged
    vertices keep the file's order (same-topology files stay in correspondence).

    Returns ``first`` (W,) int64, the first vertex of each group, and ``inverse`` (V,) int64,
    each vertex's group.
    """
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return first[order].astype(np.int64), rank[inverse.reshape(-1)].astype(np.int64)


def weld(
    vertices: np.ndarray, faces: np.ndarray, tolerance: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Join coincident vertices, whatever their UVs: a mesh whose UV seams are split into
    separate vertices becomes one connected cloth (what cloth tools do on import).

    Vertices within ``tolerance`` metres of each other (chained) become one, placed at the
    first of them; the welded vertices keep the order of their first occurrence. Faces that
    collapse (two corners welded together) are dropped. A simulation of the welded mesh maps
    back to the file's vertices as ``positions[..., index, :]``.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    tolerance : metres; default ``WELD_TOLERANCE_REL`` times the bounding-box diagonal

    Returns
    -------
    welded : (W, 3) float32, W <= V
    welded_faces : (F', 3) int64, indices into ``welded``
    index : (V,) int64, the welded vertex of each input vertex
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or not len(v) or not np.isfinite(v).all():
        raise ValueError(f"vertices must be finite (V, 3), got {v.shape}")
    if tolerance is None:
        tolerance = WELD_TOLERANCE_REL * float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    pairs = cKDTree(v).query_pairs(max(tolerance, 0.0), output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(v),) * 2)
    _, labels = connected_components(graph, directed=False)
    first, index = _first_occurrence(labels)
    wf = index[f]
    keep = (wf[:, 0] != wf[:, 1]) & (wf[:, 1] != wf[:, 2]) & (wf[:, 0] != wf[:, 2])
    return v[first].astype(np.float32), wf[keep], index


def weld_mesh(mesh: Mesh) -> tuple[Mesh, np.ndarray]:
    """:func:`weld` on a :class:`Mesh`: the welded mesh (no UVs) and ``index`` (V,) int64."""
    v, f, index = weld(mesh.vertices, mesh.faces)
    return Mesh(v, f), index


def count_components(num_vertices: int, faces: np.ndarray) -> int:
    """Number of connected components of the face graph (isolated vertices not counted)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    e = faces[:, [0, 1, 1, 2]].reshape(-1, 2)
    adj = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(num_vertices,) * 2)
    _, labels = connected_components(adj, directed=False)
    return len(np.unique(labels[np.unique(faces)]))


def unique_edges(faces: np.ndarray) -> np.ndarray:
    """Undirected edges of a triangle mesh.

    Parameters
    ----------
    faces : (F, 3) int

    Returns
    -------
    (E, 2) int64
        Each edge once, as a sorted pair; rows in lexicographic order.
    """
    e = np.asarray(faces, np.int64)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    return np.unique(np.sort(e, axis=1), axis=0)


def edge_counts(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undirected edges ``(E, 2)`` int64 (sorted pairs) and how many faces use each, ``(E,)``."""
    e = np.sort(np.asarray(faces, np.int64)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    n = int(e.max()) + 1 if len(e) else 1
    keys, counts = np.unique(e[:, 0] * n + e[:, 1], return_counts=True)
    return np.stack([keys // n, keys % n], axis=1), counts


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Boundary loops as vertex index arrays (edges used by exactly one face), longest first.

    Works on non-manifold input: a boundary vertex with several outgoing boundary edges is
    walked greedily, so every boundary edge lands in exactly one loop.
    """
    edges, counts = edge_counts(faces)
    b = edges[counts == 1]
    if len(b) == 0:
        return []

    nbrs: dict[int, list[int]] = defaultdict(list)
    for a, c in b:
        nbrs[int(a)].append(int(c))
        nbrs[int(c)].append(int(a))
    used: set[tuple[int, int]] = set()
    loops = []
    for a, c in b:
        key = (int(a), int(c))
        if key in used:
            continue
        used.add(key)
        loop = [int(a), int(c)]
        while True:
            cur, prev = loop[-1], loop[-2]
            nxt = None
            for n in nbrs[cur]:
                k = (min(cur, n), max(cur, n))
                if k not in used and n != prev:
                    nxt = n
                    break
            if nxt is None:
                break
            used.add((min(cur, nxt), max(cur, nxt)))
            if nxt == loop[0]:
                break
            loop.append(nxt)
        loops.append(np.array(loop, np.int64))
    loops.sort(key=len, reverse=True)
    return loops


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int, counter-clockwise seen from outside

    Returns
    -------
    (V, 3) float64
        Unit length; zero for vertices no face uses. Each vertex sums its faces' (twice-area)
        normals in face order, first as corner 0, then 1, then 2.
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    corners = f.T.reshape(-1)  # corner 0 of every face, then corner 1, then corner 2
    out = np.stack(
        [np.bincount(corners, np.tile(n[:, c], 3), minlength=len(v)) for c in range(3)], axis=1
    )
    return out / np.maximum(np.linalg.norm(out, axis=-1, keepdims=True), 1e-12)


def load_mesh(path: str | os.PathLike) -> tuple[Mesh, RepairReport]:
    """Read OBJ/PLY/GLB/glTF/OFF/STL with trimesh, triangulate, validate and repair.

    Scenes (GLB with several nodes) are flattened with their transforms applied.
    Raises ``InputError`` naming the file for a missing, unreadable or invalid mesh.
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(
            f"unsupported mesh type {path.suffix!r}; use one of {', '.join(MESH_SUFFIXES)}", path
        )
    if path.stat().st_size == 0:
        raise InputError("file is empty", path)
    try:
        loaded = trimesh.load(path, process=False, maintain_order=True)
    except Exception as exc:  # trimesh raises many types for bad files
        raise InputError(f"unreadable mesh ({type(exc).__name__}: {exc})", path) from None
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)]
        if not geoms:
            raise InputError("file holds no triangle mesh", path)
        loaded = trimesh.util.concatenate(geoms) if len(geoms) > 1 else geoms[0]
    if not isinstance(loaded, trimesh.Trimesh):
        raise InputError(f"file holds a {type(loaded).__name__}, not a triangle mesh", path)
    uvs = getattr(loaded.visual, "uv", None)
    return validate_mesh(np.asarray(loaded.vertices), np.asarray(loaded.faces), uvs, path=path)


def save_mesh(path: str | os.PathLike, mesh: Mesh) -> None:
    """Write ``mesh`` (with UVs when it has them) atomically; format by extension."""
    path = Path(path)
    if path.suffix.lower() == ".obj":
        _write_obj(path, mesh)
        return
    with atomic_path(path) as tmp:
        mesh.to_trimesh().export(tmp)


def _write_obj(path: Path, mesh: Mesh) -> None:
    """OBJ writer that keeps vertex order and per-vertex UVs exactly (``f a/a b/b c/c``)."""
    lines = ["# garment studio mesh"]
    lines += [f"v {x:.7g} {y:.7g} {z:.7g}" for x, y, z in mesh.vertices]
    f = mesh.faces + 1
    if mesh.uvs is not None:
        lines += [f"vt {u:.7g} {v:.7g}" for u, v in mesh.uvs]
        lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in f]
    else:
        lines += [f"f {a} {b} {c}" for a, b, c in f]
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")


def with_uvs(mesh: Mesh, uvs: np.ndarray) -> Mesh:
    return replace(mesh, uvs=np.asarray(uvs, np.float32))
