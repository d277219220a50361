"""Building blocks of the garment generators: grid surfaces, folds, parts and the Garment record.

Every piece of cloth is a grid of vertices ``(rows, cols)``: rows run down the garment (or
along a ribbon), columns around it (or across). Triangles are wound so that the normal
``(down) x (around)`` points away from the body.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core.mesh import Mesh, count_components


@dataclass(frozen=True)
class Part:
    """One named piece of a garment.

    Attributes
    ----------
    name : str
    vertices : (V, 3) float64
    faces : (F, 3) int64
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray


@dataclass(frozen=True)
class Garment:
    """A generated garment: its mesh and which part every face belongs to.

    Attributes
    ----------
    name : str
        Registry name.
    mesh : Mesh
        All parts in one mesh; vertices float32, faces int64.
    parts : tuple of str
        Part names (a part may hold several connected pieces, e.g. both straps).
    face_parts : (F,) int32
        Index into ``parts`` per face.
    resolution_mm : float
        Target edge length the garment was built at.
    """

    name: str
    mesh: Mesh
    parts: tuple[str, ...]
    face_parts: np.ndarray
    resolution_mm: float

    @property
    def num_components(self) -> int:
        """Connected pieces of cloth in the mesh."""
        return count_components(self.mesh.num_vertices, self.mesh.faces)


def assemble(name: str, parts: list[Part], resolution_mm: float) -> Garment:
    """Concatenate parts into one :class:`Garment` (float32 vertices)."""
    vs, fs, labels, off = [], [], [], 0
    for k, p in enumerate(parts):
        vs.append(p.vertices)
        fs.append(p.faces + off)
        labels.append(np.full(len(p.faces), k, np.int32))
        off += len(p.vertices)
    mesh = Mesh(np.concatenate(vs).astype(np.float32), np.concatenate(fs).astype(np.int64))
    return Garment(
        name=name,
        mesh=mesh,
        parts=tuple(p.name for p in parts),
        face_parts=np.concatenate(labels),
        resolution_mm=float(resolution_mm),
    )


def grid_faces(n_rows: int, n_cols: int, periodic: bool) -> np.ndarray:
    """Triangles of a grid of ``n_rows x n_cols`` vertices (index ``i * n_cols + j``).

    ``periodic`` closes the grid around (column ``n_cols - 1`` meets column 0).
    Winding: the normal is (row direction) x (column direction). Returns (F, 3) int64.
    """
    idx = np.arange(n_rows * n_cols).reshape(n_rows, n_cols)
    right = np.roll(idx, -1, axis=1) if periodic else idx[:, 1:]
    left = idx if periodic else idx[:, :-1]
    a, c = left[:-1], right[:-1]
    b, d = left[1:], right[1:]
    t1 = np.stack([a, b, c], -1).reshape(-1, 3)
    t2 = np.stack([b, d, c], -1).reshape(-1, 3)
    return np.concatenate([t1, t2]).astype(np.int64)


def grid_part(name: str, points: np.ndarray, periodic: bool) -> Part:
    """A :class:`Part` from a grid of points (R, C, 3) (see :func:`grid_faces`)."""
    r, c = points.shape[:2]
    return Part(name, points.reshape(-1, 3).astype(np.float64), grid_faces(r, c, periodic))


def cylinder_points(
    theta: np.ndarray, y: np.ndarray, radius: np.ndarray, axis_z: float
) -> np.ndarray:
    """Points at angle ``theta``, height ``y``, radius ``radius`` (broadcast): (..., 3)."""
    theta, y, radius = np.broadcast_arrays(theta, y, radius)
    return np.stack([radius * np.sin(theta), y, axis_z + radius * np.cos(theta)], axis=-1)


def grid_size(points: np.ndarray, resolution: float, periodic: bool) -> tuple[int, int]:
    """Rows and columns that give edges of about ``resolution`` on a densely sampled surface.

    Parameters
    ----------
    points : (R, C, 3) float
        The surface sampled densely (rows down, columns around).
    """
    around = np.diff(points, axis=1)
    perim = np.linalg.norm(around, axis=2).sum(axis=1)
    if periodic:
        perim = perim + np.linalg.norm(points[:, 0] - points[:, -1], axis=1)
    down = np.linalg.norm(np.diff(points, axis=0), axis=2).sum(axis=0)
    cols = max(3 if periodic else 2, math.ceil(perim.max() / resolution) + (0 if periodic else 1))
    rows = max(2, math.ceil(down.max() / resolution) + 1)
    return rows, cols


@dataclass(frozen=True)
class Folds:
    """Radial folds of gathered cloth around a circle: ``fold(theta, depth) -> [0, 1]``.

    Attributes
    ----------
    count : int
        Number of folds around.
    phase_harmonics : (H, 2) float64
        Amplitude and phase of the smooth phase jitter per harmonic (irregular fold widths).
    strength : (H2, 2) float64
        Amplitude and phase of the smooth fold-depth modulation.
    twist : float
        Phase change per metre of depth (folds that lean).
    sharpness : float
        Exponent > 1 narrows the valleys into creases.
    """

    count: int
    phase_harmonics: np.ndarray
    strength: np.ndarray
    twist: float
    sharpness: float

    @staticmethod
    def make(count: int, rng: np.random.Generator, twist: float = 0.0, sharpness: float = 1.3):
        k = np.arange(1, 6)
        phase = np.stack([rng.normal(size=5) * 1.2 / k, rng.uniform(0, 2 * np.pi, 5)], 1)
        strength = np.stack([rng.normal(size=3) * 0.25, rng.uniform(0, 2 * np.pi, 3)], 1)
        return Folds(max(int(count), 0), phase, strength, twist, sharpness)

    def __call__(self, theta: np.ndarray, depth: np.ndarray | float = 0.0) -> np.ndarray:
        """Fold height in [0, 1] at angles ``theta`` and depths (m) below the top (broadcast)."""
        theta = np.asarray(theta, np.float64)
        if self.count == 0:
            return np.zeros(np.broadcast(theta, np.asarray(depth)).shape)
        jitter = sum(
            a * np.sin((k + 1) * theta + p) for k, (a, p) in enumerate(self.phase_harmonics)
        )
        mod = 1.0 + sum(a * np.sin((k + 1) * theta + p) for k, (a, p) in enumerate(self.strength))
        wave = 0.5 + 0.5 * np.sin(self.count * theta + jitter + self.twist * np.asarray(depth))
        return np.clip(mod, 0.4, 1.0) * wave**self.sharpness


def max_folds(perimeter: float, resolution: float, samples_per_fold: float = 6.0) -> int:
    """Most folds a ring of ``perimeter`` can show with edges of ``resolution``."""
    return int(perimeter / (resolution * samples_per_fold))


def ribbon_points(
    centre: np.ndarray, across: np.ndarray, widths: np.ndarray, n_across: int
) -> np.ndarray:
    """A ribbon: rows along ``centre`` (R, 3), columns across ``across`` (R, 3) unit vectors.

    ``widths`` (R,) is the full width per row. Returns (R, n_across, 3).
    """
    s = np.linspace(-0.5, 0.5, n_across)
    return centre[:, None, :] + (widths[:, None] * s[None, :])[..., None] * across[:, None, :]


def orient_away(part: Part, centre: np.ndarray) -> Part:
    """Flip the part's winding if its area-weighted normals point towards ``centre`` (3,)."""
    v, f = part.vertices, part.faces
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    out = v[f].mean(axis=1) - centre
    if np.einsum("fk,fk->", n, out) < 0:
        return Part(part.name, v, f[:, ::-1].copy())
    return part


def weld_columns(n_rows: int, n_cols: int, faces: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Faces of a non-periodic grid with the last column welded onto the first in ``rows``.

    Parameters
    ----------
    faces : (F, 3) int64 of an ``n_rows x n_cols`` grid
    rows : (n_rows,) bool
        Rows whose last vertex is the same point as their first.
    Returns the remapped faces (unreferenced vertices are left for the caller to drop).
    """
    remap = np.arange(n_rows * n_cols)
    i = np.nonzero(rows)[0]
    remap[i * n_cols + n_cols - 1] = i * n_cols
    return remap[faces]


def drop_unused(part: Part) -> Part:
    """Remove vertices no face uses."""
    used = np.zeros(len(part.vertices), bool)
    used[part.faces.ravel()] = True
    remap = np.cumsum(used) - 1
    return Part(part.name, part.vertices[used], remap[part.faces])
