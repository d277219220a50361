"""Rasterization by ray casting: which triangle each pixel sees, where, and how far.

The fast path casts one ray per pixel centre with ``open3d.t.geometry.RaycastingScene``
(Embree). Rays are cast only for pixels in screen tiles that some triangle's projected bounding
box touches, so a garment filling a tenth of the view costs about a tenth of the rays.
:func:`rasterize_reference` is the slow, obvious numpy version (homogeneous edge functions and
a z-buffer) that the tests compare against.

Both are two-sided (garments are open surfaces: a ray hits a triangle from either side), sample
pixel ``(i, j)`` at image position ``(j + 0.5, i + 0.5)`` (see :mod:`core.camera`), and return a
:class:`Fragments` record.

Embree builds its BVH when a scene is first queried; a scene cannot be refitted through Open3D,
so moving vertices (every frame of a simulation) need a new :class:`MeshScene`. Render all the
cameras of one frame from one scene.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.camera import Camera
from core.errors import InputError

#: Open3D's "no hit" id (uint32 max).
_INVALID_ID = np.uint32(0xFFFFFFFF)


@dataclass(frozen=True)
class Fragments:
    """Per-pixel result of rasterizing one mesh from one camera (PyTorch3D's ``Fragments``).

    Attributes
    ----------
    face_id : (H, W) int64
        Index of the triangle seen at each pixel centre, -1 for background.
    barycentrics : (H, W, 3) float32
        Weights of the triangle's three corners ``faces[face_id]`` at the hit point; each
        in [0, 1], summing to 1. Zeros for background.
    depth : (H, W) float32
        Camera-space z of the hit point (metres), inf for background.
    """

    face_id: np.ndarray
    barycentrics: np.ndarray
    depth: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: pixels that see a triangle."""
        return self.face_id >= 0

    @property
    def height(self) -> int:
        return self.face_id.shape[0]

    @property
    def width(self) -> int:
        return self.face_id.shape[1]


@dataclass(frozen=True)
class RasterConfig:
    """Options of :func:`rasterize`."""

    near: float = 0.0
    """Surfaces at camera-space depth <= near are not seen (metres)."""
    tile: int = 8
    """Screen tile size (pixels) for skipping rays that cannot hit; 0 casts every pixel."""
    threads: int = 0
    """Threads for Embree; 0 lets Open3D choose (all cores)."""

    def __post_init__(self) -> None:
        if not (np.isfinite(self.near) and self.near >= 0):
            raise InputError(f"near must be >= 0, got {self.near}")
        if self.tile < 0 or self.threads < 0:
            raise InputError(f"tile and threads must be >= 0, got {self.tile}, {self.threads}")


def check_mesh_arrays(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validate and convert: vertices (V, 3) float32 finite, faces (F, 3) int64 in range."""
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"vertices must be (V, 3), got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise InputError(f"faces must be (F, 3), got shape {f.shape}")
    if f.size and not np.issubdtype(f.dtype, np.integer):
        raise InputError(f"faces must be integers, got {f.dtype}")
    v = np.ascontiguousarray(v, np.float32)
    f = np.ascontiguousarray(f, np.int64)
    if not np.isfinite(v).all():
        raise InputError("vertices hold NaN or inf")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise InputError(f"face indices out of range [0, {len(v)})")
    return v, f


class MeshScene:
    """One mesh (one frame's vertex positions) ready to be rasterized from many cameras.

    Building costs a BVH construction (done on the first cast); reuse the object for all the
    cameras of a frame. It is immutable: new vertex positions need a new ``MeshScene``.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.vertices, self.faces = check_mesh_arrays(vertices, faces)
        self._scene = None

    @property
    def scene(self):
        """The ``open3d.t.geometry.RaycastingScene`` (built on first use)."""
        if self._scene is None:
            import open3d as o3d

            scene = o3d.t.geometry.RaycastingScene()
            if len(self.faces):
                scene.add_triangles(
                    o3d.core.Tensor(self.vertices),
                    o3d.core.Tensor(self.faces.astype(np.uint32)),
                )
            self._scene = scene
        return self._scene

    def build(self) -> MeshScene:
        """Build the BVH now (Embree commits on the first query) and return ``self``."""
        import open3d as o3d

        self.scene.cast_rays(o3d.core.Tensor(np.zeros((1, 6), np.float32)), nthreads=1)
        return self

    def cast(
        self, origins: np.ndarray, directions: np.ndarray, threads: int = 0
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First hits of rays (two-sided).

        Parameters
        ----------
        origins : (N, 3) or (3,) float
        directions : (N, 3) float, need not be unit length

        Returns
        -------
        t : (N,) float32
            Ray parameter of the hit in units of the direction's length, inf on a miss.
        face_id : (N,) int64, -1 on a miss
        barycentrics : (N, 3) float32, zeros on a miss
        """
        d = np.asarray(directions, np.float32).reshape(-1, 3)
        rays = np.empty((len(d), 6), np.float32)
        rays[:, :3] = np.asarray(origins, np.float32)
        rays[:, 3:] = d
        return self._cast_rays(rays, threads)

    def _cast_rays(
        self, rays: np.ndarray, threads: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`cast` of packed rays (N, 6) float32 ``[origin, direction]``."""
        import open3d as o3d

        n = len(rays)
        if n == 0 or len(self.faces) == 0:
            return (
                np.full(n, np.inf, np.float32),
                np.full(n, -1, np.int64),
                np.zeros((n, 3), np.float32),
            )
        out = self.scene.cast_rays(o3d.core.Tensor(rays), nthreads=threads)
        prim = out["primitive_ids"].numpy()
        hit = prim != _INVALID_ID
        face = np.where(hit, prim.astype(np.int64), -1)
        uv = out["primitive_uvs"].numpy()
        bary = np.empty((n, 3), np.float32)
        bary[:, 1:] = uv
        bary[:, 0] = 1.0 - uv[:, 0] - uv[:, 1]
        np.clip(bary, 0.0, 1.0, out=bary)
        total = bary[:, 0] + bary[:, 1] + bary[:, 2]  # column sums: faster than sum(axis=1)
        bary /= np.maximum(total, 1e-12)[:, None]  # float32 rounding and clipping: sum ~1
        bary[np.flatnonzero(~hit)] = 0.0
        return out["t_hit"].numpy(), face, bary

    def rasterize(self, camera: Camera, config: RasterConfig = RasterConfig()) -> Fragments:
        """Rasterize this mesh from ``camera``: see :func:`rasterize`."""
        h, w = camera.height, camera.width
        pix = candidate_pixels(self.vertices, self.faces, camera, config)
        face_id = np.full(h * w, -1, np.int64)
        bary = np.zeros((h * w, 3), np.float32)
        depth = np.full(h * w, np.inf, np.float32)
        if len(pix):
            f, b, t = self.cast_pixels(camera, pix, config)
            # np.take with indices: several times faster than boolean or fancy row indexing.
            hit = np.flatnonzero(f >= 0)
            hp = np.take(pix, hit)
            face_id[hp] = np.take(f, hit)
            bary[hp] = np.take(b, hit, axis=0)
            depth[hp] = np.take(t, hit)
        return Fragments(face_id.reshape(h, w), bary.reshape(h, w, 3), depth.reshape(h, w))

    def cast_pixels(
        self, camera: Camera, pixels: np.ndarray, config: RasterConfig = RasterConfig()
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First hits of the rays through the centres of some pixels of ``camera``.

        Parameters
        ----------
        pixels : (N,) int
            Flat (row-major) pixel indices.

        Returns
        -------
        face_id : (N,) int64, -1 on a miss
        barycentrics : (N, 3) float32, zeros on a miss
        depth : (N,) float32, camera-space z, inf on a miss
        """
        i, j = np.divmod(np.asarray(pixels, np.int64), camera.width)
        x = ((j + 0.5 - camera.cx) / camera.fx).astype(np.float32)
        y = ((i + 0.5 - camera.cy) / camera.fy).astype(np.float32)
        R = camera.R.astype(np.float32)
        # Rays packed straight into Open3D's (N, 6) layout: origin, then
        # direction = R^T @ (x, y, 1), whose camera-space z is 1, so t is the depth.
        rays = np.empty((len(x), 6), np.float32)
        for k in range(3):
            col = rays[:, 3 + k]
            np.multiply(x, R[0, k], out=col)
            col += y * R[1, k]
            col += R[2, k]
        rays[:, :3] = camera.center.astype(np.float32)
        if config.near > 0:
            rays[:, :3] += np.float32(config.near) * rays[:, 3:]
        t, f, b = self._cast_rays(rays, config.threads)
        if config.near > 0:
            t = t + np.float32(config.near)
        return f, b, t


def candidate_pixels(
    vertices: np.ndarray, faces: np.ndarray, camera: Camera, config: RasterConfig = RasterConfig()
) -> np.ndarray:
    """Flat indices (N,) int64 of the pixels whose rays may hit a triangle (a superset).

    Unordered (grouped by tile). ``config.tile = 1`` keeps exactly the pixels inside some
    triangle's (widened) bounding box; larger tiles are coarser but cheaper to expand.

    A triangle entirely in front of the camera projects inside the bounding box of its
    projected corners; the screen tiles those boxes touch are kept. A triangle entirely behind
    ``near`` is dropped; one that crosses it projects without bound, so every pixel is kept.
    """
    h, w = camera.height, camera.width
    nothing = np.zeros(0, np.int64)
    if config.tile == 0:
        return np.arange(h * w, dtype=np.int64)
    if len(faces) == 0:
        return nothing
    pc = vertices.astype(np.float64) @ camera.R.T + camera.t
    z = pc[:, 2]
    front = z > max(config.near, 1e-9)
    # Column-wise min/max: numpy's axis-1 reductions over 3 columns are ~10x slower.
    f0, f1, f2 = faces[:, 0], faces[:, 1], faces[:, 2]
    n_front = front[f0].astype(np.int8) + front[f1] + front[f2]
    if ((n_front > 0) & (n_front < 3)).any():
        return np.arange(h * w, dtype=np.int64)  # a triangle straddles the near plane
    keep_faces = n_front == 3
    if not keep_faces.any():
        return nothing
    inv = 1.0 / np.where(front, z, 1.0)
    u = camera.fx * pc[:, 0] * inv + camera.cx
    v = camera.fy * pc[:, 1] * inv + camera.cy
    f0, f1, f2 = f0[keep_faces], f1[keep_faces], f2[keep_faces]
    umin = np.minimum(np.minimum(u[f0], u[f1]), u[f2])
    umax = np.maximum(np.maximum(u[f0], u[f1]), u[f2])
    vmin = np.minimum(np.minimum(v[f0], v[f1]), v[f2])
    vmax = np.maximum(np.maximum(v[f0], v[f1]), v[f2])
    # Pixel j's centre is j + 0.5: a box [a, b] covers pixels ceil(a - 0.5) .. floor(b - 0.5).
    # Widened by a pixel each side: Embree's watertight test and float32 rays may disagree
    # with float64 projection right at the border.
    x0 = np.floor(umin - 0.5)
    x1 = np.floor(umax - 0.5) + 1
    y0 = np.floor(vmin - 0.5)
    y1 = np.floor(vmax - 0.5) + 1
    keep = (x1 >= 0) & (x0 <= w - 1) & (y1 >= 0) & (y0 <= h - 1)
    if not keep.any():
        return nothing
    ts = config.tile
    nty, ntx = -(-h // ts), -(-w // ts)
    # Clip in float before converting: far off-screen corners can exceed int64.
    tx0 = (np.clip(x0[keep], 0, w - 1) // ts).astype(np.int64)
    tx1 = (np.clip(x1[keep], 0, w - 1) // ts).astype(np.int64)
    ty0 = (np.clip(y0[keep], 0, h - 1) // ts).astype(np.int64)
    ty1 = (np.clip(y1[keep], 0, h - 1) // ts).astype(np.int64)
    # 2D difference array of the tile boxes (bincount is much faster than np.add.at).
    stride = ntx + 1
    idx = np.concatenate(
        [
            ty0 * stride + tx0,
            ty0 * stride + tx1 + 1,
            (ty1 + 1) * stride + tx0,
            (ty1 + 1) * stride + tx1 + 1,
        ]
    )
    n = len(tx0)
    weights = np.repeat(np.array([1.0, -1.0, -1.0, 1.0]), n)
    diff = np.bincount(idx, weights, minlength=(nty + 1) * stride).reshape(nty + 1, stride)
    tiles = diff.cumsum(0).cumsum(1)[:nty, :ntx] > 0.5
    if ts == 1:
        return np.flatnonzero(tiles)
    ty, tx = np.nonzero(tiles)
    # All pixels of the kept tiles, clipped to the image, tile by tile (coherent rays).
    oy, ox = np.divmod(np.arange(ts * ts), ts)
    py = (ty[:, None] * ts + oy[None]).ravel()
    px = (tx[:, None] * ts + ox[None]).ravel()
    if h % ts or w % ts:
        inside = (py < h) & (px < w)
        py, px = py[inside], px[inside]
    return py * w + px


def rasterize(
    vertices: np.ndarray,
    faces: np.ndarray,
    camera: Camera,
    config: RasterConfig = RasterConfig(),
    *,
    scene: MeshScene | None = None,
) -> Fragments:
    """Rasterize a triangle mesh: one ray per pixel centre, first hit, both sides of triangles.

    Parameters
    ----------
    vertices : (V, 3) float
        World positions (metres).
    faces : (F, 3) int
    camera : Camera
        Any resolution; the output is ``(camera.height, camera.width)``.
    scene : MeshScene or None
        A scene already built from these vertices and faces (reuse it for the other cameras
        of the same frame); built here when None.

    Returns
    -------
    Fragments
        ``face_id`` (H, W) int64 (-1 background), ``barycentrics`` (H, W, 3) float32,
        ``depth`` (H, W) float32 (camera-space z, inf background), ``mask`` (H, W) bool.
    """
    if scene is None:
        scene = MeshScene(vertices, faces)
    return scene.rasterize(camera, config)


def rasterize_reference(
    vertices: np.ndarray, faces: np.ndarray, camera: Camera, near: float = 0.0
) -> Fragments:
    """Slow, obvious rasterizer: per triangle, homogeneous edge functions and a z-buffer.

    For the ray ``d = K^-1 (x, y, 1)`` of a pixel centre and a triangle with camera-space
    corners ``P0, P1, P2``, the edge functions ``e_i = d . (P_j x P_k)`` are proportional to the
    barycentrics of the ray's hit on the triangle's plane (Olano & Greer's 2D homogeneous
    rasterization), which also handles triangles crossing behind the camera without clipping.
    The pixel is covered when all three have one sign (either: two-sided), and the hit depth is
    ``det(P0, P1, P2) / sum(e)``, kept when it beats the z-buffer and exceeds ``near``.
    Same output as :func:`rasterize`.
    """
    v, f = check_mesh_arrays(vertices, faces)
    h, w = camera.height, camera.width
    pc = v.astype(np.float64) @ camera.R.T + camera.t
    jj, ii = np.meshgrid(np.arange(w), np.arange(h))
    dx = (jj + 0.5 - camera.cx) / camera.fx
    dy = (ii + 0.5 - camera.cy) / camera.fy
    zbuf = np.full((h, w), np.inf)
    face_id = np.full((h, w), -1, np.int64)
    bary = np.zeros((h, w, 3))
    for fi, (a, b, c) in enumerate(f):
        p = pc[[a, b, c]]
        if (p[:, 2] <= near).all():
            continue
        det = np.linalg.det(p)
        if abs(det) < 1e-18:
            continue  # degenerate, or its plane passes through the camera (seen edge-on)
        if (p[:, 2] > near).all():
            # Bounding box of the projection, one pixel wider; otherwise the whole image.
            u = camera.fx * p[:, 0] / p[:, 2] + camera.cx
            vv = camera.fy * p[:, 1] / p[:, 2] + camera.cy
            x0 = int(np.clip(np.floor(u.min()) - 1, 0, w))
            x1 = int(np.clip(np.ceil(u.max()) + 1, 0, w))
            y0 = int(np.clip(np.floor(vv.min()) - 1, 0, h))
            y1 = int(np.clip(np.ceil(vv.max()) + 1, 0, h))
        else:
            x0, x1, y0, y1 = 0, w, 0, h
        if x0 >= x1 or y0 >= y1:
            continue
        d = np.stack([dx[y0:y1, x0:x1], dy[y0:y1, x0:x1], np.ones((y1 - y0, x1 - x0))], -1)
        e = np.stack(
            [d @ np.cross(p[1], p[2]), d @ np.cross(p[2], p[0]), d @ np.cross(p[0], p[1])], -1
        )
        s = e.sum(-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = e / s[..., None]
            z = det / s
        inside = (lam >= 0).all(-1) & np.isfinite(z) & (z > near)
        closer = inside & (z < zbuf[y0:y1, x0:x1])
        if not closer.any():
            continue
        zbuf[y0:y1, x0:x1][closer] = z[closer]
        face_id[y0:y1, x0:x1][closer] = fi
        bary[y0:y1, x0:x1][closer] = lam[closer]
    return Fragments(face_id, bary.astype(np.float32), zbuf.astype(np.float32))
