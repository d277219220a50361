"""The studio window's state and the logic behind it, with no Open3D GUI import (unit-testable).

- :class:`GuiSettings`: everything the window remembers, saved under the ``"gui"`` key of the
  project's ``project.json`` (other keys are kept) and restored on reopen.
- :class:`CameraPose`: a viewpoint (eye, target, up, vertical field of view), what camera paths
  are made of; :func:`camera_from_gl` turns the 3D view's OpenGL matrices into a
  :class:`core.camera.Camera` (OpenCV pinhole, y down).
- Proxy planning: :func:`proxy_plan` says what a slider change re-runs; :func:`reatlas` redoes
  only the UV atlas when only the texture size changed.
- Pictures for image widgets: :func:`atlas_image`, :func:`checker_texture`, :func:`loss_plot`.
- :class:`Eta` (time left of a running job), :class:`RateMeter` (frames per second).
- :func:`pipeline_jobs`: the pipeline stage functions the window's buttons run, in order.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from core.body.shape import BodyShape
from core.camera import Camera, CameraKey, make_camera, orbit_eye, project
from core.errors import InputError
from core.fileio import atomic_path
from core.mesh import (
    Mesh,
    unique_edges,  # noqa: F401  (re-exported for the GUI controller)
)
from core.progress import StageEta as Eta  # noqa: F401  (the GUI's name for it)
from core.project import Project
from core.proxy.atlas import uv_atlas, uv_stats
from pipeline.config import available_test_motions
from pipeline.stages.dataset import stage_dataset
from pipeline.stages.garment import stage_garment
from pipeline.stages.joint2coarse import stage_joint2coarse
from pipeline.stages.motions import stage_motions
from pipeline.stages.proxy import stage_proxy
from pipeline.stages.renderer import stage_renderer
from pipeline.stages.simulate import stage_simulate
from training.csvlog import read_loss_log

#: Key of the window's settings inside ``project.json``.
SETTINGS_KEY = "gui"
#: Sizes the proxy's texture (atlas) may be packed for.
TEXTURE_SIZES = (128, 256, 512, 1024, 2048)
#: Slider limits of the proxy's vertex budget.
PROXY_VERTS_RANGE = (50, 4000)
#: Slider limits of the detail scale (metres).
DETAIL_SCALE_RANGE = (0.0, 0.1)
#: Live neural-render sizes offered.
RENDER_SIZES = (64, 128, 256, 512)
#: What the main area shows: (label, mode). ``neural``: the neural render at the view's size;
#: ``scene``: the 3D view (body, proxy, simulated reference); ``compare``: the neural render
#: beside the reference (the simulated target when the motion has one).
VIEW_MODES = (("neural", "neural"), ("3D scene", "scene"), ("compare", "compare"))
#: Play speeds offered on the timeline.
PLAY_SPEEDS = (0.25, 0.5, 1.0, 1.5, 2.0)
#: Image heights (px) the neural viewport renders at on CPU, upscaled to the view; it picks
#: the largest the machine sustains at ``NEURAL_TARGET_FPS``.
CPU_RENDER_HEIGHTS = (128, 160, 192, 224, 256)
NEURAL_TARGET_FPS = 12.0


def adapt_render_height(
    current: int,
    ms_per_frame: float,
    view_height: int,
    gpu: bool = False,
    target_fps: float = NEURAL_TARGET_FPS,
    heights: Sequence[int] = CPU_RENDER_HEIGHTS,
) -> int:
    """The neural viewport's next render height (px).

    On a GPU: the view's height (full size). On CPU: one step of ``heights`` down when a frame
    takes longer than the frame budget ``1000 / target_fps`` ms, one step up when the next
    size (cost taken as proportional to its pixels) would still take under 80% of it; never
    above the view's height.
    """
    if gpu:
        return max(int(view_height), 16)
    allowed = [h for h in heights if h <= max(view_height, heights[0])]
    i = int(np.argmin([abs(h - current) for h in allowed]))
    budget = 1000.0 / target_fps
    if ms_per_frame > budget and i > 0:
        i -= 1
    elif i + 1 < len(allowed) and ms_per_frame * (allowed[i + 1] / allowed[i]) ** 2 < 0.8 * budget:
        i += 1
    return int(allowed[i])


def view_image_size(height: int, aspect: float) -> tuple[int, int]:
    """(width, height) of an image ``height`` px high with the view's ``aspect`` (w / h);
    the width a multiple of 4 (at least 16)."""
    return max(16, int(round(height * max(aspect, 0.1) / 4.0)) * 4), int(height)


# ------------------------------------------------------------------------------------- cameras


@dataclass(frozen=True)
class CameraPose:
    """A viewpoint: eye and target in world metres, up vector, vertical field of view."""

    eye: tuple[float, float, float] = (0.0, 1.0, 3.0)
    target: tuple[float, float, float] = (0.0, 0.9, 0.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov_deg: float = 40.0

    def camera(self, width: int, height: int):
        """The OpenCV pinhole :class:`core.camera.Camera` of this pose at ``width x height``."""
        return make_camera(
            self.eye, self.target, fov_y_deg=self.fov_deg, width=width, height=height, up=self.up
        )

    def as_dict(self) -> dict:
        return {
            "eye": list(self.eye),
            "target": list(self.target),
            "up": list(self.up),
            "fov_deg": self.fov_deg,
        }

    @classmethod
    def from_dict(cls, data: dict) -> CameraPose:
        try:
            pose = cls(
                tuple(float(x) for x in data["eye"]),
                tuple(float(x) for x in data["target"]),
                tuple(float(x) for x in data.get("up", (0.0, 1.0, 0.0))),
                float(data.get("fov_deg", 40.0)),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"malformed camera in the GUI settings ({exc})") from None
        if len(pose.eye) != 3 or len(pose.target) != 3 or len(pose.up) != 3:
            raise InputError("malformed camera in the GUI settings (eye/target/up need 3 values)")
        if not 1.0 <= pose.fov_deg <= 170.0:
            raise InputError(f"camera field of view {pose.fov_deg} is outside [1, 170] degrees")
        return pose


#: OpenGL camera axes (x right, y up, looking down -z) to OpenCV's (x right, y down, +z).
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def camera_from_gl(view: np.ndarray, projection: np.ndarray, width: int, height: int):
    """The OpenCV :class:`core.camera.Camera` seeing what an OpenGL camera sees.

    Parameters
    ----------
    view : (4, 4) float
        World-to-camera matrix in the OpenGL convention (Open3D's
        ``rendering.Camera.get_view_matrix()``): camera looks down -z, y up.
    projection : (4, 4) float
        OpenGL perspective projection (``get_projection_matrix()``).
    width, height : int
        Size of the image to make. The vertical field of view is kept and pixels are square,
        so an image of another aspect than the view shows more or less at the sides.

    Returns
    -------
    core.camera.Camera
        ``extrinsic = diag(1, -1, -1, 1) @ view`` (rotation re-orthonormalised: the GL matrices
        are float32); ``fy = P[1, 1] * height / 2``, ``fx = fy``; the principal point keeps the
        projection's off-centre terms (zero for Open3D's symmetric frusta).
    """
    view = np.asarray(view, np.float64)
    p = np.asarray(projection, np.float64)
    if view.shape != (4, 4) or p.shape != (4, 4):
        raise InputError(f"view and projection must be 4x4, got {view.shape}, {p.shape}")
    if abs(p[3, 3]) > 1e-9 or abs(p[3, 2] + 1.0) > 1e-6:
        raise InputError("only perspective projections convert to a pinhole camera")
    e = GL_TO_CV @ view
    u, _, vt = np.linalg.svd(e[:3, :3])
    e[:3, :3] = u @ vt
    e[3] = (0.0, 0.0, 0.0, 1.0)
    fy = p[1, 1] * height / 2.0
    k = np.array(
        [
            [fy, 0.0, width / 2.0 * (1.0 - p[0, 2])],
            [0.0, fy, height / 2.0 * (1.0 + p[1, 2])],
            [0.0, 0.0, 1.0],
        ]
    )
    return Camera(k, e, int(width), int(height))


def pose_from_camera(camera, distance: float = 2.5) -> CameraPose:
    """A :class:`CameraPose` of a camera (target ``distance`` metres along its view)."""
    eye = camera.center
    up = -camera.R[1]  # image up (-y) in world space
    return CameraPose(
        tuple(float(x) for x in eye),
        tuple(float(x) for x in eye + distance * camera.forward),
        tuple(float(x) for x in up),
        float(camera.fov_y_deg),
    )


#: Framing: the camera's azimuth round the subject (degrees from +z towards +x), its elevation
#: (degrees above the target) and the margin left round the subject (1.1: a tenth of the view).
FRAME_AZIMUTH_DEG = 20.0
FRAME_ELEVATION_DEG = 8.0
FRAME_MARGIN = 1.1
#: A restored camera is kept while it shows at least this share of the body's or the
#: garment's vertices; below it for both, it shows neither and the view is framed anew.
MIN_SHOWN_SHARE = 0.2


def framing_pose(
    points: np.ndarray,
    aspect: float,
    fov_deg: float = 40.0,
    azimuth_deg: float = FRAME_AZIMUTH_DEG,
    elevation_deg: float = FRAME_ELEVATION_DEG,
    margin: float = FRAME_MARGIN,
) -> CameraPose:
    """The pose that frames ``points`` (N, 3), world metres, y up: looking at the centre of
    their bounding box from ``azimuth_deg`` / ``elevation_deg``, as close as keeps every point
    inside a view of vertical field of view ``fov_deg`` and ``aspect`` (width / height), with
    ``margin`` (> 1) to spare."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(1)]
    if len(pts) == 0:
        return CameraPose(fov_deg=float(fov_deg))
    target = 0.5 * (pts.min(0) + pts.max(0))
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    back = np.array([math.sin(az) * math.cos(el), math.sin(el), math.cos(az) * math.cos(el)])
    right = np.cross((0.0, 1.0, 0.0), back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    rel = pts - target
    x, y, z = np.abs(rel @ right), np.abs(rel @ up), rel @ back  # z: towards the camera
    tan_v = math.tan(math.radians(fov_deg) / 2.0)
    tan_h = tan_v * max(float(aspect), 1e-3)
    distance = float(np.max(z + margin * np.maximum(x / tan_h, y / tan_v)))
    distance = max(distance, 0.3)
    eye = target + distance * back
    return CameraPose(
        tuple(float(v) for v in eye),
        tuple(float(v) for v in target),
        (0.0, 1.0, 0.0),
        float(fov_deg),
    )


def shown_share(pose: CameraPose, points: np.ndarray, aspect: float) -> float:
    """The share of ``points`` (N, 3) in front of ``pose``'s camera and inside its view of
    ``aspect`` (width / height); 0 for no finite point."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(1)]
    if len(pts) == 0:
        return 0.0
    h = 100
    w = max(1, int(round(h * max(float(aspect), 1e-3))))
    uv, depth = project(pts, pose.camera(w, h))
    inside = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    return float(inside.mean())


def orbit_poses(
    n: int, target: Sequence[float], radius: float, elevation_deg: float = 10.0, fov: float = 40.0
) -> list[CameraPose]:
    """``n`` poses once around ``target`` (azimuth 0 on +Z, the front)."""
    t = np.asarray(target, np.float64)
    out = []
    for i in range(n):
        eye = orbit_eye(t, radius, 2.0 * math.pi * i / max(n, 1), math.radians(elevation_deg))
        out.append(CameraPose(tuple(map(float, eye)), tuple(map(float, t)), (0.0, 1.0, 0.0), fov))
    return out


# ------------------------------------------------------------------------------ garment cache

#: Source folders whose code shapes a built-in garment: a change to any file there is a new
#: code version, so cached garments made by older code are not used.
GARMENT_CODE = ("templates/garments", "core/body")


def garment_cache_dir() -> Path:
    """Where generated built-in garments are kept: ``$XDG_CACHE_HOME/garment-studio/garments``
    (``~/.cache`` when the variable is not set)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "garment-studio" / "garments"


def _code_version() -> str:
    root = Path(__file__).resolve().parents[2]
    h = hashlib.sha1()
    for folder in GARMENT_CODE:
        for f in sorted((root / folder).glob("*.py")):
            h.update(f.name.encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:12]


def garment_cache_key(name: str, resolution_mm: float, shape) -> str:
    """The cache file name of a built-in garment: name, resolution, body shape and the
    version of the code that makes it (:data:`GARMENT_CODE`)."""
    params = json.dumps(
        {"resolution_mm": float(resolution_mm), "body": asdict(shape)}, sort_keys=True
    )
    digest = hashlib.sha1(f"{params}|{_code_version()}".encode()).hexdigest()[:16]
    return f"{name}-{digest}.npz"


def cached_builtin_garment(name: str, resolution_mm: float, shape, make: Callable):
    """The built-in garment ``make(name, resolution_mm, shape)`` (a ``core.mesh.Mesh``),
    read from :func:`garment_cache_dir` when an equal one was made before, else made and
    written there (atomically). An unreadable cache file is made again.

    Returns ``(mesh, from_cache)``.
    """
    path = garment_cache_dir() / garment_cache_key(name, resolution_mm, shape)
    if path.is_file():
        try:
            with np.load(path) as z:
                uvs = z["uvs"] if "uvs" in z.files else None
                return Mesh(z["vertices"], z["faces"], uvs), True
        except (OSError, ValueError, KeyError):
            pass  # a damaged file: make it again
    mesh = make(name, resolution_mm, shape)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {"vertices": mesh.vertices, "faces": mesh.faces}
        if mesh.uvs is not None:
            arrays["uvs"] = mesh.uvs
        with atomic_path(path) as tmp:
            np.savez(tmp, **arrays)
    except OSError:
        pass  # a read-only cache only costs the next launch the time
    return mesh, False


# ------------------------------------------------------------------------------------ settings


@dataclass(frozen=True)
class GuiSettings:
    """What the window remembers per project (``project.json["gui"]``)."""

    garment: str = "multilayer-skirt"
    """Built-in garment name or mesh path shown in the garment panel."""
    garment_resolution_mm: float = 20.0
    """Resolution of a built-in garment (coarse keeps the window responsive)."""
    proxy_verts: int = 600
    """Proxy vertex budget (slider)."""
    detail_scale: float = 0.02
    """Proxy detail scale in metres (slider)."""
    texture_size: int = 256
    """Texture size the proxy atlas is packed for."""
    show_target: bool = True
    show_wireframe: bool = False
    show_proxy: bool = True
    show_body: bool = True
    show_sim: bool = False
    """Show the simulated proxy beside Joint2Coarse's (when a cache exists)."""
    motion: str = "dance"
    """A procedural kind, a project motion name or a BVH path."""
    motion_frames: int = 60
    """Frames of a procedural motion."""
    body: dict = field(default_factory=dict)
    """Body shape overrides (``core.body.shape.BodyShape`` field -> value)."""
    frame: int = 0
    render_size: int = 128
    live_render: bool = True
    show_ground_truth: bool = True
    camera: dict | None = None
    """The 3D view's last :class:`CameraPose` (as a dict)."""
    camera_path: list = field(default_factory=list)
    """Key poses of the export camera path (dicts); empty: an orbit."""
    export_frames: int = 24
    export_fps: float = 12.0
    export_reference: bool = False
    """Put the reference beside the neural render in exported videos."""
    view_mode: str = "neural"
    """What the main area shows when a motion plays (``VIEW_MODES``)."""
    play_speed: float = 1.0
    loop: bool = True

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict | None) -> GuiSettings:
        """Settings from a saved dict; unknown keys are ignored, values of the wrong type are
        reset to their default (a hand-edited file never stops the window from opening)."""
        if not isinstance(data, dict):
            return cls()
        default = cls()
        kwargs = {}
        for f in fields(cls):
            if f.name not in data:
                continue
            value, ref = data[f.name], getattr(default, f.name)
            if f.name == "camera":
                ok = value is None or isinstance(value, dict)
            elif isinstance(ref, bool):
                ok = isinstance(value, bool)
            elif isinstance(ref, int):
                ok = isinstance(value, int) and not isinstance(value, bool)
            elif isinstance(ref, float):
                ok = isinstance(value, (int, float)) and not isinstance(value, bool)
                value = float(value) if ok else value
            else:
                ok = isinstance(value, type(ref))
            if ok:
                kwargs[f.name] = value
        s = replace(default, **kwargs)
        if s.texture_size not in TEXTURE_SIZES:
            s = replace(s, texture_size=default.texture_size)
        if s.view_mode not in [m for _label, m in VIEW_MODES]:
            s = replace(s, view_mode=default.view_mode)
        if s.play_speed not in PLAY_SPEEDS:
            s = replace(s, play_speed=default.play_speed)
        return s

    def camera_pose(self) -> CameraPose | None:
        try:
            return None if self.camera is None else CameraPose.from_dict(self.camera)
        except InputError:
            return None

    def path_keys(self) -> list:
        """The camera path's :class:`core.camera.CameraKey` s by frame (malformed keys and
        keys repeating a frame are dropped; a key saved without a frame sits at its index)."""
        out = {}
        for i, d in enumerate(self.camera_path):
            try:
                pose = CameraPose.from_dict(d)
                frame = float(d.get("frame", i))
            except (InputError, TypeError, ValueError, AttributeError):
                continue
            out.setdefault(frame, CameraKey(frame, pose.eye, pose.target, pose.fov_deg))
        return [out[f] for f in sorted(out)]

    def body_shape(self):
        """The :class:`core.body.shape.BodyShape` of ``body`` (InputError if out of range)."""
        names = {f.name for f in fields(BodyShape)}
        return BodyShape(**{k: float(v) for k, v in self.body.items() if k in names})


def load_settings(project_root: str | Path) -> GuiSettings:
    """The window's settings saved in a project folder (defaults when there are none)."""
    return GuiSettings.from_dict(Project(project_root).settings().get(SETTINGS_KEY))


def save_settings(project_root: str | Path, settings: GuiSettings) -> None:
    """Write ``settings`` under ``"gui"`` in ``project.json``, keeping every other key."""
    project = Project(project_root)
    data = project.settings()
    data[SETTINGS_KEY] = settings.as_dict()
    project.save_settings(data)


# ------------------------------------------------------------------------------------- proxies


def proxy_plan(old, new) -> str:
    """What a change of :class:`core.proxy.ProxyConfig` re-runs: ``"none"``, ``"atlas"`` (only
    the texture size or padding changed: the surface stays, only the UV atlas is redone) or
    ``"full"`` (anything that changes the surface)."""
    if old is None:
        return "full"
    if old == new:
        return "none"
    if replace(old, texture_size=new.texture_size, padding=new.padding) == new:
        return "atlas"
    return "full"


def reatlas(result, texture_size: int, padding: int | None = None):
    """``result`` (a :class:`core.proxy.ProxyResult`) with a new UV atlas for another texture
    size; positions, correspondence and distances are unchanged (the surface is the same)."""
    pad = result.report["config"]["padding"] if padding is None else padding
    start = time.perf_counter()
    pos = result.positions
    atlas = uv_atlas(pos.vertices, pos.faces, texture_size, pad)
    proxy = Mesh(pos.vertices[atlas.seam_map], atlas.faces.astype(np.int64), atlas.uvs)
    uv = uv_stats(proxy.vertices, proxy.faces, proxy.uvs, atlas.chart)
    uv.update(
        utilization=atlas.utilization,
        texture_size=texture_size,
        padding=pad,
        uv_vertices=int(len(atlas.seam_map)),
    )
    report = dict(result.report)
    report["uv"] = uv
    report["config"] = {**report["config"], "texture_size": texture_size, "padding": pad}
    report["timings_s"] = {**report["timings_s"], "atlas": round(time.perf_counter() - start, 4)}
    report["atlas_only"] = True
    return replace(result, proxy=proxy, seam_map=atlas.seam_map, report=report)


def proxy_summary(report: dict) -> list[tuple[str, str]]:
    """The report numbers the proxy panel shows, as (label, value) rows."""
    d, uv, p = report["distance"], report["uv"], report["proxy"]
    return [
        ("vertices", f"{p['vertices']} ({uv['uv_vertices']} UV)"),
        ("faces", f"{p['faces']}"),
        ("layers", str(report["layers"].get("used", "?"))),
        ("Hausdorff", f"{d['hausdorff_m'] * 1e3:.1f} mm ({d['hausdorff_rel']:.1%})"),
        ("mean dist", f"{d['target_to_proxy_mean_m'] * 1e3:.1f} mm"),
        ("stretch", f"{uv['stretch_mean']:.3f} (max {uv['stretch_max']:.2f})"),
        ("charts", f"{uv['charts']}, {uv['utilization']:.0%} used"),
        ("time", f"{sum(report['timings_s'].values()):.2f} s"),
    ]


# -------------------------------------------------------------------------------------- images


def checker_texture(size: int = 256, squares: int = 16) -> np.ndarray:
    """A two-tone checkerboard (size, size, 3) uint8 with a colour ramp so orientation shows."""
    i = np.arange(size)
    cell = (i * squares) // size
    board = (cell[:, None] + cell[None, :]) % 2
    u = np.linspace(0.0, 1.0, size)
    img = np.empty((size, size, 3), np.float32)
    img[..., 0] = 0.55 + 0.4 * u[None, :]
    img[..., 1] = 0.45 + 0.3 * u[::-1, None]
    img[..., 2] = 0.85
    img *= np.where(board[..., None] == 1, 1.0, 0.55)
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def atlas_image(
    uvs: np.ndarray, faces: np.ndarray, size: int = 256, chart: np.ndarray | None = None
) -> np.ndarray:
    """The UV atlas as a picture (size, size, 3) uint8: the checker texture inside the charts,
    dark grey outside, triangle edges drawn. ``uvs`` (V, 2) in [0, 1] with v up (OBJ)."""
    from PIL import Image, ImageDraw

    uv = np.asarray(uvs, np.float64)
    px = np.stack([uv[:, 0] * (size - 1), (1.0 - uv[:, 1]) * (size - 1)], 1)
    mask = Image.new("L", (size, size), 0)
    draw = ImageDraw.Draw(mask)
    tris = px[np.asarray(faces, np.int64)]
    for t in tris:
        draw.polygon([tuple(p) for p in t], fill=255)
    m = np.asarray(mask) > 0
    out = np.full((size, size, 3), 40, np.uint8)
    out[m] = checker_texture(size)[m]
    img = Image.fromarray(out)
    draw = ImageDraw.Draw(img)
    for t in tris:
        draw.line([tuple(p) for p in (*t, t[0])], fill=(30, 30, 30), width=1)
    return np.asarray(img)


def loss_plot(
    logs: dict[str, str | Path], width: int = 360, height: int = 200
) -> np.ndarray | None:
    """Loss curves of training CSV logs (first column the step) as (H, W, 3) uint8, or None when
    no log has rows yet. Plots ``train_loss`` / ``val_loss`` (Joint2Coarse) and ``loss_g`` /
    ``l1`` (the renderer), whichever the file has, on a log scale."""
    series = []
    for label, path in logs.items():
        path = Path(path)
        if not path.is_file():
            continue
        rows = read_loss_log(path)
        for col in ("train_loss", "val_loss", "loss_g", "l1"):
            pts = [
                (r["step"], r[col])
                for r in rows
                if "step" in r and col in r and math.isfinite(r[col]) and r[col] > 0
            ]
            if pts:
                series.append((f"{label} {col}", np.array(pts)))
    if not series:
        return None
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width / 100, height / 100), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(111)
    for label, pts in series:
        ax.plot(pts[:, 0], pts[:, 1], label=label, linewidth=1)
    ax.set_yscale("log")
    ax.set_xlabel("step", fontsize=7)
    ax.tick_params(labelsize=6)
    ax.legend(fontsize=6, loc="upper right")
    fig.tight_layout(pad=0.3)
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()


def side_by_side(images: Sequence[np.ndarray], gap: int = 4) -> np.ndarray:
    """Images of the same height next to each other, white gaps between: (H, W, 3) uint8."""
    h = max(im.shape[0] for im in images)
    parts = []
    for k, im in enumerate(images):
        if im.shape[0] != h:
            pad = np.full((h - im.shape[0], im.shape[1], 3), 255, np.uint8)
            im = np.concatenate([im, pad])
        if k:
            parts.append(np.full((h, gap, 3), 255, np.uint8))
        parts.append(np.asarray(im, np.uint8)[..., :3])
    return np.ascontiguousarray(np.concatenate(parts, 1))


# ---------------------------------------------------------------------------------- job timing


def format_seconds(s: float | None) -> str:
    if s is None or not math.isfinite(s):
        return "--"
    s = int(round(s))
    return f"{s // 60}:{s % 60:02d}" if s >= 60 else f"{s} s"


def process_age() -> float:
    """Seconds since this process started (Linux /proc; 0 elsewhere)."""
    try:
        ticks = os.sysconf("SC_CLK_TCK")
        with open("/proc/self/stat") as f:
            start = int(f.read().rsplit(")", 1)[1].split()[19]) / ticks
        with open("/proc/uptime") as f:
            return float(f.read().split()[0]) - start
    except (OSError, ValueError, IndexError):
        return 0.0


class RateMeter:
    """Events per second over the last ``window`` events (live render fps)."""

    def __init__(self, window: int = 20, clock: Callable[[], float] = time.perf_counter):
        self.clock = clock
        self.times: deque[float] = deque(maxlen=window)

    def tick(self) -> None:
        self.times.append(self.clock())

    @property
    def rate(self) -> float:
        if len(self.times) < 2:
            return 0.0
        span = self.times[-1] - self.times[0]
        return (len(self.times) - 1) / span if span > 0 else 0.0


# ------------------------------------------------------------------------------------ pipeline


class Cancelled(Exception):
    """Raised inside a job when the user pressed Cancel (stops at the next progress report)."""


@dataclass(frozen=True)
class StageJob:
    """One step of a pipeline run: ``run(project, config, log, progress)``."""

    label: str
    run: Callable


def pipeline_jobs(config, which: str) -> list[StageJob]:
    """The stage functions of :mod:`pipeline` a window button runs, in order.

    ``which``: ``"simulate"`` (every motion's proxy, then the training motion's target),
    ``"dataset"``, ``"joint2coarse"``, ``"renderer"`` (when the pipeline has
    ``stage_renderer``) or ``"all"`` (motions, garment, proxy and everything above).
    """
    # deferred: the stages load torch and open3d; the window opens before they are needed

    tests = [m.name for m in available_test_motions(config)]
    train = config.train_motion.name
    jobs: dict[str, list[StageJob]] = {}

    def sim(m: str, w: str) -> StageJob:
        return StageJob(
            f"simulate {m} ({w})",
            lambda p, c, log, prog: stage_simulate(p, c, m, w, log, prog),
        )

    jobs["setup"] = [
        StageJob("motions", lambda p, c, log, prog: stage_motions(p, c, log)),
        StageJob("garment", lambda p, c, log, prog: stage_garment(p, c, log)),
        StageJob("proxy", lambda p, c, log, prog: stage_proxy(p, c, log)),
    ]
    sims = [sim(train, "proxy")]
    if config.simulate_target:
        sims.append(sim(train, "target"))
    sims += [sim(name, "proxy") for name in tests]
    jobs["simulate"] = sims
    jobs["dataset"] = [
        StageJob("dataset", lambda p, c, log, prog: stage_dataset(p, c, log)),
    ]
    jobs["joint2coarse"] = [
        StageJob(
            "joint2coarse", lambda p, c, log, prog: stage_joint2coarse(p, c, log, progress=False)
        ),
    ]
    jobs["renderer"] = [
        StageJob("renderer", lambda p, c, log, prog: stage_renderer(p, c, log, prog)),
    ]
    if which == "all":
        return [
            *jobs["setup"],
            *jobs["simulate"],
            *jobs["dataset"],
            *jobs["joint2coarse"],
            *jobs["renderer"],
        ]
    if which not in jobs:
        raise InputError(f"unknown pipeline step {which!r}; choose from {', '.join(jobs)}, all")
    if not jobs[which]:
        raise InputError(f"this version of the pipeline has no {which} stage")
    return jobs[which]


def training_logs(project_root: str | Path) -> dict[str, Path]:
    """The loss logs a project's training writes (they may not exist yet)."""
    root = Path(project_root)
    return {
        "joint2coarse": root / "joint2coarse" / "joint2coarse_loss.csv",
        "renderer": root / "renderer" / "renderer_loss.csv",
    }


def latest_preview(project_root: str | Path) -> Path | None:
    """The newest preview picture of a project's training (renderer previews, Joint2Coarse
    comparisons, data-set sheets), or None."""
    root = Path(project_root)
    found = [
        *root.glob("renderer/previews/*.png"),
        *root.glob("joint2coarse/compare-*.png"),
    ]
    if not found:
        return None
    return max(found, key=lambda p: p.stat().st_mtime)
