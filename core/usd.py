"""Animated meshes out as USD (``.usd``, ``.usda``, ``.usdc``) for Blender, Marvelous Designer,
CLO, Houdini and the like, with ``usd-core``.

The stage is metres (``metersPerUnit = 1``), Y up, ``timeCodesPerSecond = framesPerSecond =
fps``; frame ``k`` is time code ``k`` (``startTimeCode = 0``, ``endTimeCode = T - 1``). Every mesh
is a ``UsdGeom.Mesh`` under the default prim ``/GarmentStudio``: constant triangle topology
(``faceVertexCounts`` all 3, ``faceVertexIndices``), ``subdivisionScheme = none`` (the triangles
are the surface; USD's default would subdivide them), ``points`` and ``extent`` sampled at every
frame and, when given, UVs as the face-varying, indexed primvar ``st``. The extension picks the
encoding: ``.usda`` text, ``.usdc`` and ``.usd`` binary (crate).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.errors import InputError
from core.fileio import atomic_path

#: Extensions :func:`write_usd` writes (``.usdz`` packages are not written).
USD_SUFFIXES: tuple[str, ...] = (".usd", ".usda", ".usdc")
#: The stage's default prim; every mesh is its child.
ROOT_PRIM = "/GarmentStudio"


@dataclass(frozen=True)
class UsdMesh:
    """One animated triangle mesh of a USD stage.

    Attributes
    ----------
    name : str
        Prim name under :data:`ROOT_PRIM` (a USD identifier: letters, digits, ``_``; not starting
        with a digit).
    positions : (T, V, 3) float
        Vertex positions per frame, metres, Y up.
    faces : (F, 3) int
        Triangles, counter-clockwise seen from outside (USD's ``rightHanded`` orientation).
    uvs : (U, 2) float or None
        Texture coordinates, v up.
    uv_faces : (F, 3) int or None
        For each face corner, its row of ``uvs`` (so seams need no split vertices); required
        with ``uvs``.
    double_sided : bool
        Render both sides (cloth); a closed body is single-sided.
    """

    name: str
    positions: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None = None
    uv_faces: np.ndarray | None = None
    double_sided: bool = False


def write_usd(path: str | os.PathLike, meshes: Sequence[UsdMesh], fps: float) -> None:
    """Write ``meshes`` animated at ``fps`` as one USD stage, atomically.

    Parameters
    ----------
    path : ``.usd``, ``.usda`` or ``.usdc`` file (the extension picks the encoding)
    meshes : one or more :class:`UsdMesh`, all with the same number of frames T
    fps : frames per second (> 0)

    Raises
    ------
    InputError
        Naming ``path``: an unknown extension, no meshes, a bad or repeated name, frame counts
        that differ, positions that are not (T, V, 3) or not finite, faces that are not (F, 3)
        integers within [0, V), UVs that are not (U, 2) finite or whose ``uv_faces`` do not
        match; nothing is written then.
    """
    path = Path(path)
    checked = _check(path, meshes, fps)
    # usd-core is imported here: a few hundred ms that only USD output pays.
    from pxr import Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    frames = checked[0].positions.shape[0]
    stage.SetTimeCodesPerSecond(float(fps))
    stage.SetFramesPerSecond(float(fps))
    stage.SetStartTimeCode(0.0)
    stage.SetEndTimeCode(float(frames - 1))
    root = UsdGeom.Xform.Define(stage, ROOT_PRIM)
    stage.SetDefaultPrim(root.GetPrim())
    for m in checked:
        mesh = UsdGeom.Mesh.Define(stage, f"{ROOT_PRIM}/{m.name}")
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
        mesh.CreateDoubleSidedAttr(bool(m.double_sided))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(m.faces), 3, np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(m.faces.reshape(-1)))
        points, extent = mesh.CreatePointsAttr(), mesh.CreateExtentAttr()
        lo, hi = m.positions.min(axis=1), m.positions.max(axis=1)
        for k in range(frames):
            points.Set(Vt.Vec3fArray.FromNumpy(m.positions[k]), float(k))
            extent.Set(Vt.Vec3fArray.FromNumpy(np.stack([lo[k], hi[k]])), float(k))
        if m.uvs is not None:
            st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
                "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
            )
            st.Set(Vt.Vec2fArray.FromNumpy(m.uvs))
            st.SetIndices(Vt.IntArray.FromNumpy(m.uv_faces.reshape(-1)))
    with atomic_path(path) as tmp:  # keeps the extension, which picks the file format
        if not stage.GetRootLayer().Export(str(tmp)):
            raise InputError("usd-core could not write the file", path)


def _check(path: Path, meshes: Sequence[UsdMesh], fps: float) -> list[UsdMesh]:
    """The meshes validated and converted (float32 positions/UVs, int32 indices)."""
    from pxr import Sdf  # see write_usd

    if path.suffix.lower() not in USD_SUFFIXES:
        raise InputError(
            f"unknown USD type {path.suffix!r}; use one of {', '.join(USD_SUFFIXES)}", path
        )
    if not (isinstance(fps, (int, float)) and np.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be positive, got {fps}", path)
    if not meshes:
        raise InputError("nothing to write: no meshes", path)
    out, names, frames = [], set(), None
    for m in meshes:
        what = f"mesh {m.name!r}"
        if not Sdf.Path.IsValidIdentifier(m.name) or m.name in names:
            raise InputError(f"{what}: not a valid, unique USD prim name", path)
        names.add(m.name)
        p = np.asarray(m.positions)
        if p.ndim != 3 or p.shape[2] != 3 or p.shape[0] < 1 or p.shape[1] < 1:
            raise InputError(f"{what}: positions must be (T, V, 3), got {p.shape}", path)
        if not np.issubdtype(p.dtype, np.number):
            raise InputError(f"{what}: positions must be numbers, got {p.dtype}", path)
        if not np.isfinite(p).all():
            bad = ~np.isfinite(p).all(axis=(1, 2))
            raise InputError(
                f"{what}: positions hold NaN or inf (first at frame {int(np.argmax(bad))})", path
            )
        if frames is not None and p.shape[0] != frames:
            raise InputError(f"{what}: {p.shape[0]} frames, the others have {frames}", path)
        frames = p.shape[0]
        f = _indices(m.faces, p.shape[1], f"{what}: faces", path)
        uvs = uv_faces = None
        if m.uvs is not None or m.uv_faces is not None:
            if m.uvs is None or m.uv_faces is None:
                raise InputError(f"{what}: uvs and uv_faces go together", path)
            uvs = np.asarray(m.uvs)
            if uvs.ndim != 2 or uvs.shape[1] != 2 or not np.isfinite(uvs).all():
                raise InputError(f"{what}: uvs must be (U, 2) finite, got {uvs.shape}", path)
            uv_faces = _indices(m.uv_faces, len(uvs), f"{what}: uv_faces", path)
            if uv_faces.shape != f.shape:
                raise InputError(
                    f"{what}: uv_faces {uv_faces.shape} must match faces {f.shape}", path
                )
            uvs = uvs.astype(np.float32)
        out.append(UsdMesh(m.name, p.astype(np.float32), f, uvs, uv_faces, bool(m.double_sided)))
    return out


def _indices(a, limit: int, what: str, path: Path) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim != 2 or a.shape[1] != 3 or len(a) < 1 or not np.issubdtype(a.dtype, np.integer):
        raise InputError(
            f"{what} must be (F, 3) integers with F >= 1, got {a.shape} {a.dtype}", path
        )
    if a.min() < 0 or a.max() >= limit:
        raise InputError(f"{what} index up to {a.max()}, outside [0, {limit})", path)
    return a.astype(np.int32)
