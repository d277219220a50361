"""Ground-truth renders: the detailed garment on the body, and the body alone, from a camera.

What the neural renderer learns to reproduce, so it must be deterministic and consistent across
views. Lighting (:mod:`core.lighting`) is fixed relative to the camera (as in the paper), so
every view is lit the same way: a hemispherical ambient term (sky above, ground below, in image
space), soft directional lights given in camera space, and an environment's diffuse light. Surfaces are two-sided (the inside of a skirt is lit
like its outside), normals are smooth (interpolated vertex normals), and a faint fabric sheen
brightens grazing angles. Colours are given in sRGB, shaded in linear RGB, averaged over
``k x k`` ray samples per pixel (box filter) and written back as sRGB uint8.

Everything goes through :mod:`core.raster`: one combined scene (garment + body) and one body-only
scene per frame, reused for all the frame's cameras (:func:`render_views`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from core.camera import Camera, resize_camera, world_to_camera
from core.color import linear_to_srgb, srgb_to_linear, to_uint8
from core.errors import InputError
from core.features import interpolate
from core.fileio import atomic_path
from core.lighting import Lighting, environment_light
from core.mesh import Mesh, vertex_normals
from core.raster import MeshScene, RasterConfig, check_mesh_arrays

PATTERNS = ("solid", "checker", "stripes")


@dataclass(frozen=True)
class Material:
    """A diffuse fabric: a colour, optionally a procedural pattern in UV space."""

    color: tuple[float, float, float] = (0.62, 0.13, 0.18)
    """Base colour, sRGB in [0, 1]."""
    pattern: str = "solid"
    """``solid``, ``checker`` or ``stripes`` (needs UVs)."""
    pattern_color: tuple[float, float, float] = (0.93, 0.88, 0.78)
    """Second colour of the pattern, sRGB in [0, 1]."""
    pattern_scale: float = 12.0
    """Pattern cells per unit of UV."""
    sheen: float = 0.2
    """Strength of the grazing-angle brightening of fabric (0 turns it off)."""

    def __post_init__(self) -> None:
        if self.pattern not in PATTERNS:
            raise InputError(f"pattern must be one of {PATTERNS}, got {self.pattern!r}")
        for name in ("color", "pattern_color"):
            c = np.asarray(getattr(self, name), np.float64)
            if c.shape != (3,) or not ((c >= 0) & (c <= 1)).all():
                raise InputError(f"{name} must be 3 numbers in [0, 1], got {getattr(self, name)}")
        if not (np.isfinite(self.pattern_scale) and self.pattern_scale > 0):
            raise InputError(f"pattern_scale must be positive, got {self.pattern_scale}")
        if not (0.0 <= self.sheen <= 1.0):
            raise InputError(f"sheen must be in [0, 1], got {self.sheen}")


@dataclass(frozen=True)
class ShadingConfig:
    """How ground-truth images are rendered."""

    supersample: int = 3
    """Ray samples per pixel along each axis (k x k, box-filtered); 1 turns antialiasing off."""
    background: tuple[float, float, float] = (0.86, 0.87, 0.89)
    """Colour where no surface is seen, sRGB in [0, 1]."""
    garment: Material = field(default_factory=Material)
    """The garment's fabric."""
    body: Material = field(default_factory=lambda: Material(color=(0.78, 0.66, 0.58), sheen=0.0))
    """The body's material."""
    lighting: Lighting = field(default_factory=Lighting)
    """The light, fixed to the camera (:mod:`core.lighting`; default: the ``studio`` rig)."""
    wrap: float = 0.35
    """Diffuse wrap (0 = Lambert): softens the terminator like cloth's subsurface scattering."""
    threads: int = 0
    """Ray-casting threads (:attr:`core.raster.RasterConfig.threads`; 0: every core). The images
    are the same whatever the number: each ray is cast alone."""

    def __post_init__(self) -> None:
        if not (isinstance(self.supersample, int) and 1 <= self.supersample <= 8):
            raise InputError(f"supersample must be an integer in [1, 8], got {self.supersample!r}")
        bg = np.asarray(self.background, np.float64)
        if bg.shape != (3,) or not ((bg >= 0) & (bg <= 1)).all():
            raise InputError(f"background must be 3 numbers in [0, 1], got {self.background}")
        if not 0.0 <= self.wrap <= 1.0:
            raise InputError(f"wrap must be in [0, 1], got {self.wrap}")
        if not (isinstance(self.threads, int) and self.threads >= 0):
            raise InputError(f"threads must be an integer >= 0, got {self.threads!r}")


@dataclass(frozen=True)
class GroundTruth:
    """One ground-truth view.

    Attributes
    ----------
    image : (H, W, 3) uint8
        Garment on body over the background colour (sRGB).
    mask : (H, W) bool
        Pixels where the visible garment covers at least half the samples.
    coverage : (H, W) float32
        Fraction of the pixel's samples that see the garment (soft mask, in [0, 1]).
    background : (H, W, 3) uint8
        The body alone from the same camera (the renderer composites over it).
    """

    image: np.ndarray
    mask: np.ndarray
    coverage: np.ndarray
    background: np.ndarray


def headlight_shading(
    fragments, vertices: np.ndarray, faces: np.ndarray, camera, ambient: float = 0.2
) -> np.ndarray:
    """Plain grey shading of a mesh lit from the camera: (H, W) float32 in [0, 1], 0 off it.

    Lambert with a light at the eye, two-sided (|n . view|), smooth vertex normals interpolated
    with the fragments' barycentrics. This is the "shaded proxy render" the Pix2Pix baseline
    starts from; it carries the proxy's shape and silhouette and nothing of the target.

    Parameters
    ----------
    fragments : core.raster.Fragments of ``vertices``/``faces`` seen by ``camera``
    vertices : (V, 3) float world positions; faces : (F, 3) int
    camera : core.camera.Camera
    ambient : shade of a surface seen edge-on
    """
    normals = vertex_normals(vertices, faces).astype(np.float32)
    normals = normals @ camera.R.T.astype(np.float32)  # camera space
    n = interpolate(fragments, faces, normals)  # (H, W, 3)
    h, w = fragments.face_id.shape
    # Direction to the eye of each pixel's surface point, in camera space.
    p = interpolate(fragments, faces, world_to_camera(vertices, camera).astype(np.float32))
    to_eye = -p / np.maximum(np.linalg.norm(p, axis=-1, keepdims=True), 1e-12)
    length = np.maximum(np.linalg.norm(n, axis=-1), 1e-12)
    cos = np.abs((n * to_eye).sum(-1)) / length
    shade = ambient + (1.0 - ambient) * np.clip(cos, 0.0, 1.0)
    return np.where(fragments.mask, shade, 0.0).astype(np.float32).reshape(h, w)


def _pattern_mix(material: Material, uv: np.ndarray) -> np.ndarray:
    """Weight (N,) of the pattern colour at UVs (N, 2)."""
    s = material.pattern_scale
    if material.pattern == "checker":
        cells = np.floor(uv[:, 0] * s) + np.floor(uv[:, 1] * s)
        return (np.mod(cells, 2.0) > 0.5).astype(np.float32)
    if material.pattern == "stripes":
        return (np.mod(np.floor(uv[:, 0] * s), 2.0) > 0.5).astype(np.float32)
    return np.zeros(len(uv), np.float32)


class _Part:
    """One mesh of a scene with what shading needs (normals, UVs, material)."""

    def __init__(self, mesh: Mesh, material: Material, name: str):
        self.vertices, self.faces = check_mesh_arrays(mesh.vertices, mesh.faces)
        if material.pattern != "solid" and mesh.uvs is None:
            raise InputError(f"the {name} material has a {material.pattern} pattern but no UVs")
        self.uvs = None if mesh.uvs is None else np.asarray(mesh.uvs, np.float32)
        self.material = material
        self.normals = vertex_normals(self.vertices, self.faces).astype(np.float32)
        v = self.vertices.astype(np.float64)
        f = self.faces
        fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        self.face_normals = (
            fn / np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-30)
        ).astype(np.float32)


def _combine(parts: Sequence[_Part]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Concatenate parts: vertices, faces, and the face offset where each part starts."""
    verts, faces, starts = [], [], [0]
    base = 0
    for p in parts:
        verts.append(p.vertices)
        faces.append(p.faces + base)
        base += len(p.vertices)
        starts.append(starts[-1] + len(p.faces))
    if not parts:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int64), np.array(starts)
    return np.concatenate(verts), np.concatenate(faces), np.array(starts)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of (N, 3) arrays (column arithmetic: much faster than sum(1))."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _interp(values: np.ndarray, corners: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Barycentric interpolation: values (V, C), corners (N, 3), bary (N, 3) -> (N, C)."""
    return np.matmul(bary[:, None, :], np.take(values, corners, axis=0))[:, 0]


def _shade_samples(
    pixels: np.ndarray,
    face_id: np.ndarray,
    barycentrics: np.ndarray,
    camera: Camera,
    parts: Sequence[_Part],
    starts: np.ndarray,
    config: ShadingConfig,
) -> np.ndarray:
    """Linear RGB (N, 3) float32 of N ray hits.

    Parameters
    ----------
    pixels : (N,) int64, flat pixel indices in ``camera``'s image (for the view direction)
    face_id : (N,) int64, faces numbered as in :func:`_combine` (all hits, no -1)
    barycentrics : (N, 3) float32
    """
    n = len(pixels)
    out = np.empty((n, 3), np.float32)
    i, j = np.divmod(pixels, camera.width)
    # Unit vector from the hit back to the camera, in camera space (depth cancels out).
    view = np.empty((n, 3), np.float32)
    view[:, 0] = -(j + 0.5 - camera.cx) / camera.fx
    view[:, 1] = -(i + 0.5 - camera.cy) / camera.fy
    view[:, 2] = -1.0
    view /= np.sqrt(_dot(view, view))[:, None]
    R = camera.R.astype(np.float32)
    lit = config.lighting
    sky = np.asarray(lit.sky, np.float32)
    ground = np.asarray(lit.ground, np.float32)
    lights = [
        (np.asarray(li.direction, np.float32) / np.float32(np.linalg.norm(li.direction)),
         np.asarray(li.color, np.float32) * np.float32(li.intensity))
        for li in lit.lights
    ]  # fmt: skip
    part_of = np.searchsorted(starts, face_id, side="right") - 1
    for k, part in enumerate(parts):
        sel = np.flatnonzero(part_of == k)
        if len(sel) == 0:
            continue
        # np.take everywhere: several times faster than fancy row indexing.
        f = np.take(face_id, sel) - starts[k]
        b = np.take(barycentrics, sel, axis=0)
        corners = np.take(part.faces, f, axis=0)
        normal = _interp(part.normals, corners, b) @ R.T
        face_normal = np.take(part.face_normals, f, axis=0) @ R.T
        v = np.take(view, sel, axis=0)
        # Two-sided: turn both normals towards the camera where the face looks away.
        flip = (1.0 - 2.0 * (_dot(face_normal, v) < 0)).astype(np.float32)[:, None]
        normal *= flip
        face_normal *= flip
        length = np.sqrt(_dot(normal, normal))[:, None]
        normal /= np.maximum(length, 1e-12)
        degenerate = np.flatnonzero(length[:, 0] <= 1e-6)  # opposite normals cancelled
        normal[degenerate] = face_normal[degenerate]
        # Albedo (linear), with the UV pattern.
        mat = part.material
        albedo = np.empty((len(sel), 3), np.float32)
        albedo[:] = srgb_to_linear(np.asarray(mat.color))
        if mat.pattern != "solid":
            uv = _interp(part.uvs, corners, b)
            mix = _pattern_mix(mat, uv)[:, None]
            albedo += mix * (srgb_to_linear(np.asarray(mat.pattern_color)) - albedo)
        # Hemispherical ambient (image up is camera -y), wrapped diffuse lights, sheen.
        up = 0.5 * (1.0 - normal[:, 1:2])
        light = ground + up * (sky - ground)
        for d, col in lights:
            wrapped = (normal @ d + np.float32(config.wrap)) / np.float32(1 + config.wrap)
            light += np.maximum(wrapped, 0)[:, None] * col
        if lit.environment:
            light += environment_light(lit.environment, normal)
        color = albedo * light
        if mat.sheen > 0:
            rim = 1.0 - np.clip(_dot(normal, v), 0.0, 1.0)
            rim = rim * rim * rim
            color += np.float32(mat.sheen) * rim[:, None] * (0.5 * albedo + 0.2 * light)
        out[sel] = color
    return out


def _box_down(x: np.ndarray, k: int) -> np.ndarray:
    """Mean over k x k blocks: (k H, k W, ...) -> (H, W, ...) float32."""
    if k == 1:
        return x.astype(np.float32, copy=False)
    acc = np.zeros((x.shape[0] // k, x.shape[1] // k) + x.shape[2:], np.float32)
    for a in range(k):
        for b in range(k):
            acc += x[a::k, b::k]
    acc *= np.float32(1.0 / (k * k))
    return acc


def _render(
    scene: MeshScene,
    parts: Sequence[_Part],
    starts: np.ndarray,
    camera: Camera,
    config: ShadingConfig,
    garment_faces: int,
    body_scene: MeshScene | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Render one view of ``scene``: sRGB image (H, W, 3) uint8, garment coverage (H, W)
    float32, and, with ``body_scene``, the body-only image (H, W, 3) uint8.

    The body-only image re-casts only the samples that hit the garment (against the body
    alone); every other sample sees the same thing with or without the garment.
    """
    k = config.supersample
    cam = resize_camera(camera, k * camera.width, k * camera.height)
    raster = RasterConfig(threads=config.threads)
    frags = scene.rasterize(cam, raster)
    fid = frags.face_id.reshape(-1)
    pix = np.flatnonzero(fid >= 0)
    face = np.take(fid, pix)
    lin = np.empty((fid.size, 3), np.float32)
    lin[:] = srgb_to_linear(np.asarray(config.background))
    lin[pix] = _shade_samples(
        pix,
        face,
        np.take(frags.barycentrics.reshape(-1, 3), pix, axis=0),
        cam,
        parts,
        starts,
        config,
    )
    garment = np.zeros(fid.size, np.float32)
    garment[pix[face < garment_faces]] = 1.0
    shape = (cam.height, cam.width)
    image = to_uint8(linear_to_srgb(_box_down(lin.reshape(*shape, 3), k)))
    coverage = _box_down(garment.reshape(shape), k)
    background = None
    if body_scene is not None:
        gp = pix[face < garment_faces]
        if len(gp):
            f, b, _ = body_scene.cast_pixels(cam, gp, raster)
            hit = np.flatnonzero(f >= 0)
            lin[gp[f < 0]] = srgb_to_linear(np.asarray(config.background))
            gh = np.take(gp, hit)
            lin[gh] = _shade_samples(
                gh,
                np.take(f, hit) + garment_faces,
                np.take(b, hit, axis=0),
                cam,
                parts,
                starts,
                config,
            )
        background = to_uint8(linear_to_srgb(_box_down(lin.reshape(*shape, 3), k)))
    return image, coverage, background


def render_views(
    garment: Mesh,
    body: Mesh | None,
    cameras: Sequence[Camera],
    config: ShadingConfig = ShadingConfig(),
) -> list[GroundTruth]:
    """Ground truth for several cameras of one frame (scenes built once, reused per camera).

    Parameters
    ----------
    garment : Mesh
        The target garment at this frame (UVs needed for a patterned material).
    body : Mesh or None
        The body at this frame; None renders the garment alone and a plain background.
    cameras : the views.
    """
    g = _Part(garment, config.garment, "garment")
    parts = [g] if body is None else [g, _Part(body, config.body, "body")]
    v, f, starts = _combine(parts)
    scene = MeshScene(v, f)
    body_scene = None if body is None else MeshScene(parts[1].vertices, parts[1].faces)
    out = []
    for cam in cameras:
        image, coverage, bg = _render(scene, parts, starts, cam, config, len(g.faces), body_scene)
        if bg is None:
            bg = np.empty((cam.height, cam.width, 3), np.uint8)
            bg[:] = to_uint8(np.asarray(config.background))
        out.append(GroundTruth(image, coverage >= 0.5, coverage, bg))
    return out


def render_ground_truth(
    garment: Mesh, body: Mesh | None, camera: Camera, config: ShadingConfig = ShadingConfig()
) -> GroundTruth:
    """Ground truth of one view: see :func:`render_views`."""
    return render_views(garment, body, [camera], config)[0]


def render_background(
    body: Mesh, camera: Camera, config: ShadingConfig = ShadingConfig()
) -> np.ndarray:
    """The body alone from ``camera``: (H, W, 3) uint8 sRGB (from its own scene)."""
    part = _Part(body, config.body, "body")
    scene = MeshScene(part.vertices, part.faces)
    image, _, _ = _render(scene, [part], np.array([0, len(part.faces)]), camera, config, 0)
    return image


# --------------------------------------------------------------------------------------------
# Images on disk and on screen


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an (H, W, 3) uint8 RGB image, or an (H, W) bool/uint8 mask, as PNG, atomically."""
    from PIL import Image

    a = np.asarray(image)
    if a.dtype == bool:
        a = a.astype(np.uint8) * 255
    if a.dtype != np.uint8 or not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] in (3, 4))):
        raise InputError(f"PNG needs (H, W), (H, W, 3) or (H, W, 4) uint8, got {a.shape} {a.dtype}")
    with atomic_path(path) as tmp:
        Image.fromarray(a).save(tmp, format="PNG")


def colorize_uv(uv: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """UV map (H, W, 2) to RGB uint8 (u red, v green, blue 0.25 so the background differs)."""
    uv = np.asarray(uv, np.float32)
    rgb = np.concatenate([np.clip(uv, 0, 1), np.full(uv.shape[:2] + (1,), 0.25, np.float32)], -1)
    if mask is not None:
        rgb[~mask] = 0.0
    return to_uint8(rgb)


def colorize_scalar(x: np.ndarray, lo: float = 0.0, hi: float = 1.0) -> np.ndarray:
    """A scalar map (H, W) to RGB uint8 with matplotlib's viridis."""
    from matplotlib import colormaps

    t = np.clip((np.asarray(x, np.float32) - lo) / max(hi - lo, 1e-12), 0, 1)
    return to_uint8(colormaps["viridis"](t)[..., :3])


def contact_sheet(
    tiles: Sequence[np.ndarray], labels: Sequence[str] = (), columns: int = 0
) -> np.ndarray:
    """Tiles (H, W, 3) uint8 (or (H, W) bool/uint8) side by side with labels: (H', W', 3) uint8."""
    from PIL import Image, ImageDraw

    if not tiles:
        raise InputError("contact sheet needs at least one tile")
    rgb = []
    for t in tiles:
        a = np.asarray(t)
        if a.dtype == bool:
            a = a.astype(np.uint8) * 255
        if a.ndim == 2:
            a = np.repeat(a[..., None], 3, -1)
        rgb.append(a.astype(np.uint8))
    columns = columns or len(rgb)
    th = max(a.shape[0] for a in rgb)
    tw = max(a.shape[1] for a in rgb)
    rows = -(-len(rgb) // columns)
    pad, text_h = 4, 14
    sheet = np.full(
        (rows * (th + text_h + pad) + pad, columns * (tw + pad) + pad, 3), 255, np.uint8
    )
    img = Image.fromarray(sheet)
    draw = ImageDraw.Draw(img)
    for n, a in enumerate(rgb):
        r, c = divmod(n, columns)
        y, x = pad + r * (th + text_h + pad), pad + c * (tw + pad)
        img.paste(Image.fromarray(a), (x, y + text_h))
        if n < len(labels):
            draw.text((x, y), labels[n], fill=(0, 0, 0))
    return np.asarray(img)
