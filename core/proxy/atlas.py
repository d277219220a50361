"""UV atlas with xatlas, and the statistics that say whether it is any good."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import InputError
from core.proxy.config import STRETCH_EPS, UV_FLIP_AREA

#: Packing attempts, each at 80 % of the previous texel density, to fit one texture page.
ATLAS_ATTEMPTS = 8


@dataclass(frozen=True)
class Atlas:
    """An unwrapped mesh.

    Attributes
    ----------
    seam_map : (Vu,) int64
        Input vertex of each atlas vertex (seams split vertices).
    faces : (F, 3) int64
        Faces over the atlas vertices, same order and winding as the input faces.
    uvs : (Vu, 2) float32
        In [0, 1], v up (OBJ convention); every triangle counter-clockwise in UV.
    chart : (F,) int64
        Chart of each face.
    utilization : float
        Fraction of the texture covered by charts.
    """

    seam_map: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    chart: np.ndarray
    utilization: float


def uv_signed_areas(uvs: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Signed UV areas ``(F,)`` float64: positive for counter-clockwise triangles."""
    t = np.asarray(uvs, np.float64)[faces]
    a, b = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    return 0.5 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])


def uv_atlas(
    vertices: np.ndarray, faces: np.ndarray, texture_size: int = 512, padding: int = 4
) -> Atlas:
    """Unwrap and pack charts with xatlas for a ``texture_size`` square texture.

    Charts that xatlas returns mirrored are mirrored back within their own bounding box, which
    keeps packing and the [0, 1] range, so no triangle is flipped.

    Parameters
    ----------
    vertices : (V, 3) float, faces : (F, 3) int
    texture_size : int, pixels; padding : int, texels between charts
    """
    import xatlas

    pack = xatlas.PackOptions()
    pack.resolution = int(texture_size)
    pack.padding = int(padding)
    pack.bilinear = True
    pack.rotate_charts = True
    pack.blockAlign = False
    for _ in range(ATLAS_ATTEMPTS):
        atlas = xatlas.Atlas()
        atlas.add_mesh(
            np.ascontiguousarray(vertices, np.float32), np.ascontiguousarray(faces, np.uint32)
        )
        atlas.generate(xatlas.ChartOptions(), pack)
        if atlas.atlas_count <= 1:
            break
        # Charts spilled onto a second page: pack again at a smaller texel density.
        pack.texels_per_unit = 0.8 * float(atlas.texels_per_unit)
    else:
        raise InputError(
            f"texture {texture_size} px with padding {padding} is too small for the "
            f"{atlas.chart_count} UV charts: use a larger --texture-size or less --padding"
        )
    vmap, idx, uv = atlas.get_mesh(0)
    idx = np.asarray(idx, np.int64).reshape(-1, 3)
    uv = np.asarray(uv, np.float64).copy()
    n_atlas = atlas.atlas_count
    chart = np.full(len(idx), -1, np.int64)
    for c in range(atlas.get_mesh_chart_count(0)):
        chart[np.asarray(atlas.get_mesh_chart(0, c).faces, np.int64)] = c
    if (chart < 0).any():  # faces outside every chart (degenerate): give each its own id
        lone = np.flatnonzero(chart < 0)
        chart[lone] = chart.max() + 1 + np.arange(len(lone))
    uv[:, 1] = 1.0 - uv[:, 1]  # xatlas rows go down; OBJ v goes up
    _unmirror_charts(uv, idx, chart)
    util = float(atlas.get_utilization(0)) if n_atlas else 0.0
    return Atlas(
        seam_map=np.asarray(vmap, np.int64),
        faces=idx,
        uvs=np.clip(uv, 0.0, 1.0).astype(np.float32),
        chart=chart,
        utilization=util,
    )


def _unmirror_charts(uv: np.ndarray, faces: np.ndarray, chart: np.ndarray) -> None:
    """Mirror, in place, every chart whose UV area is mostly clockwise."""
    area = uv_signed_areas(uv, faces)
    net = np.bincount(chart, weights=area)
    for c in np.flatnonzero(net < 0):
        verts = np.unique(faces[chart == c])
        lo, hi = uv[verts, 0].min(), uv[verts, 0].max()
        uv[verts, 0] = lo + hi - uv[verts, 0]


def uv_stats(
    vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray, chart: np.ndarray | None = None
) -> dict:
    """UV quality for the report.

    Stretch is Sander et al.'s L2 stretch of the map UV -> surface after scaling the UVs so the
    total UV area equals the total surface area (1 is perfect): per triangle
    ``sqrt((s1**2 + s2**2) / 2)`` of the Jacobian's singular values; ``stretch_mean`` is the
    area-weighted root mean square, ``stretch_max`` the worst triangle.

    Parameters
    ----------
    vertices : (V, 3) float, faces : (F, 3) int, uvs : (V, 2) float, chart : (F,) int or None
    """
    p = np.asarray(vertices, np.float64)[faces]
    t = np.asarray(uvs, np.float64)[faces]
    signed = uv_signed_areas(uvs, faces)
    area3 = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    uv_area = np.abs(signed)
    scale = np.sqrt(area3.sum() / max(uv_area.sum(), STRETCH_EPS))
    du = (t[:, 1:] - t[:, :1]) * scale  # (F, 2, 2): rows are UV edges
    dp = p[:, 1:] - p[:, :1]  # (F, 2, 3)
    ok = uv_area * scale**2 > STRETCH_EPS * max(area3.max(initial=0.0), 1e-30)
    stretch = np.full(len(faces), np.inf)
    if ok.any():
        jac = np.linalg.solve(du[ok], dp[ok])  # (n, 2, 3): d p / d uv, transposed
        s = np.linalg.svd(jac, compute_uv=False)
        stretch[ok] = np.sqrt((s**2).sum(1) / 2)
    finite = np.isfinite(stretch)
    w = area3[finite]
    mean = float(np.sqrt((w * stretch[finite] ** 2).sum() / max(w.sum(), 1e-300)))
    return {
        "charts": int(len(np.unique(chart))) if chart is not None else None,
        "flipped": int((signed < UV_FLIP_AREA).sum()),
        "degenerate": int((~ok).sum()),
        "uv_min": float(np.min(uvs)) if len(uvs) else 0.0,
        "uv_max": float(np.max(uvs)) if len(uvs) else 0.0,
        "in_unit_square": bool(np.all((uvs >= 0) & (uvs <= 1))),
        "stretch_mean": mean,
        "stretch_max": float(stretch[finite].max()) if finite.any() else None,
    }
