"""Play any motion through a trained project: the one narrow object the CLI and the GUI use.

:class:`Playback` loads a project's settings, body, proxy and Joint2Coarse once; ``set_motion``
predicts the proxy for every frame of a motion (Joint2Coarse, batch) and poses the body; then
each frame can be drawn from any camera as the body-only background, the shaded proxy or the
neural render (the renderer model is loaded on the first :meth:`Playback.render`, so proxy-only
playback works in a project whose renderer is not trained yet)::

    pb = Playback("out/demo")
    pb.set_motion(load_motion_for(pb.project, "walk", frames=90))
    cam = pb.default_camera(0, 256, 256, azimuth_deg=30)
    image = pb.render(0, cam)        # (256, 256, 3) uint8
    pb.last_timings                  # {"joint2coarse": ms, "background": ms, ...}

Rendering consecutive frames from the same camera streams: the renderer keeps frame t-1's
encoder latent, so each frame is encoded once (:class:`training.renderer.inference.NeuralRenderer`).
One Playback is not thread-safe: a GUI drives it from one worker thread.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from core.body.mannequin import make_body
from core.body.skinning import pose_body
from core.camera import Camera, follow_camera
from core.compositing import fit_image, recomposite, surface_coverage
from core.errors import InputError
from core.features import FeatureConfig, joint_window
from core.fileio import atomic_path
from core.mesh import Mesh, load_mesh
from core.motion.mapping import canonical_positions
from core.motion.procedural import PROCEDURAL_KINDS, make_motion
from core.motion.retarget import retarget
from core.project import Project
from core.shading import render_background, render_views
from core.sim import load_cache
from pipeline.config import project_config
from pipeline.stages.dataset import dataset_rig, project_shading
from pipeline.stages.motions import load_project_motion

#: Frames of a procedural motion when no count is given.
DEFAULT_PROCEDURAL_FRAMES = 90
#: Where a project's renderer model lives (``pipeline.stages.renderer.stage_renderer`` writes it).
RENDERER_MODEL = ("renderer", "renderer.pt")
#: Where a project's Joint2Coarse model lives.
JOINT2COARSE_MODEL = ("joint2coarse", "joint2coarse.pt")


def load_motion_for(
    project, path_or_kind: str | os.PathLike, *, frames: int | None = None, seed: int = 0
):
    """A motion on the project's mannequin, from a BVH file, a project motion or a procedural kind.

    Parameters
    ----------
    project : core.project.Project or a folder path
    path_or_kind : str or path
        In this order: an existing BVH, glTF/GLB or DeepMimic file (any rig: resampled to the
        project's fps and retargeted onto its body); the name of a motion of the project
        (``motions/NAME.bvh``, e.g. the training motion ``dance``); a procedural kind
        (:data:`core.motion.procedural.PROCEDURAL_KINDS`) made on the project's body.
    frames : int, optional
        Keep the first ``frames`` frames (files, project motions) or make that many
        (procedural; default :data:`DEFAULT_PROCEDURAL_FRAMES`).
    seed : int
        Seed of a procedural motion.

    Returns
    -------
    core.motion.motion.Motion on the mannequin's joints. ``meta["project_motion"]`` holds the
    project motion's name when it is one (so its simulation can be shown beside it).
    """
    from core.motion.load import MOTION_FILE_SUFFIXES, load_motion, resample

    project = project if isinstance(project, Project) else Project(project)
    config = project_config(project)
    if frames is not None and (isinstance(frames, bool) or int(frames) < 1):
        raise InputError(f"frames must be >= 1, got {frames!r}")
    text = os.fspath(path_or_kind)
    path = Path(text)
    if path.suffix.lower() in MOTION_FILE_SUFFIXES or path.is_file():
        if not path.is_file():
            raise InputError("motion file not found", path)
        source = resample(load_motion(path), config.fps)
        positions = canonical_positions(source)
        motion = retarget(positions, config.fps, config.body, name=path.stem)
        return _first_frames(motion, frames, path)
    own = project.path("motions", f"{text}.bvh")
    if own.is_file():
        motion = load_project_motion(project, text)
        motion = replace(motion, meta={**motion.meta, "project_motion": text})
        return _first_frames(motion, frames, own)
    if text in PROCEDURAL_KINDS:
        n = DEFAULT_PROCEDURAL_FRAMES if frames is None else int(frames)
        return make_motion(text, n, config.fps, seed, config.body)
    names = sorted(p.stem for p in project.stage_dir("motions").glob("*.bvh"))
    raise InputError(
        f"no such motion {text!r}: give a BVH file, a project motion ({', '.join(names) or 'none'})"
        f" or a procedural kind ({', '.join(PROCEDURAL_KINDS)})"
    )


def _first_frames(motion, frames: int | None, source):
    if frames is None:
        return motion
    if frames > motion.num_frames:
        raise InputError(f"{frames} frames wanted, the motion has {motion.num_frames}", source)
    return replace(
        motion,
        rotations=motion.rotations[:frames],
        root_positions=motion.root_positions[:frames],
    )


class Playback:
    """A trained project playing one motion at a time.

    Parameters
    ----------
    project_root : the project folder (``dng demo`` layout, see :mod:`pipeline`)
    device : torch device of the neural renderer ("cpu", "cuda"); Joint2Coarse runs on CPU
    renderer_path : renderer model file (default ``renderer/renderer.pt``; a fine-tuned one,
        e.g. ``finetune/background-NAME/renderer.pt``, can be given)
    joint2coarse_path : Joint2Coarse model file (default ``joint2coarse/joint2coarse.pt``)
    shading : core.shading.ShadingConfig of the body-only background (default: the data set's)

    Attributes
    ----------
    project : core.project.Project; config : pipeline.config.PipelineConfig
    body : core.body.mannequin.Body
    body_faces : (Fb, 3) int64
    proxy_faces : (Fp, 3) int64 over the UV-split proxy vertices
    proxy_uvs : (Vp, 2) float32
    seam_map : (Vp,) int64, UV vertex -> seam-free vertex (Joint2Coarse's vertices)
    stretch : the strain limit Joint2Coarse's predictions keep
        (:func:`training.joint2coarse.prediction_stretch_limit` of the seam-free proxy)
    motion : the current Motion (None before :meth:`set_motion`)
    last_timings : dict of str -> float, milliseconds per part of the last :meth:`render`
    """

    def __init__(
        self,
        project_root: str | os.PathLike,
        *,
        device: str = "cpu",
        renderer_path: str | os.PathLike | None = None,
        joint2coarse_path: str | os.PathLike | None = None,
        shading=None,
    ):
        from training.joint2coarse import load_model, prediction_stretch_limit

        root = Path(project_root)
        if not root.is_dir():
            raise InputError("project folder not found", root)
        self.project = Project(root)
        self.config = project_config(self.project)
        self.device = device
        self.shading = project_shading(self.config, 0) if shading is None else shading
        self.body = make_body(self.config.body)
        self.body_faces = self.body.faces
        proxy_file = self.project.path("proxy", "proxy.obj")
        seams_file = self.project.path("proxy", "seams.npz")
        for f in (proxy_file, seams_file):
            if not f.is_file():
                raise InputError("no proxy: run the proxy stage (dng demo) first", f)
        proxy, _ = load_mesh(proxy_file)
        if proxy.uvs is None:
            raise InputError("proxy has no UVs", proxy_file)
        self.proxy_faces = proxy.faces
        self.proxy_uvs = proxy.uvs
        self.seam_map = np.load(seams_file)["seam_map"].astype(np.int64)
        rest = np.zeros((self.seam_map.max() + 1, 3), np.float64)
        rest[self.seam_map] = proxy.vertices
        self.stretch = prediction_stretch_limit(rest, self.seam_map[proxy.faces])
        j2c = (
            Path(joint2coarse_path) if joint2coarse_path else self.project.path(*JOINT2COARSE_MODEL)
        )
        if not j2c.is_file():
            raise InputError("no trained Joint2Coarse: run dng train joint2coarse first", j2c)
        self.joint2coarse = load_model(j2c)
        if self.joint2coarse.n_vertices <= self.seam_map.max():
            raise InputError(
                f"Joint2Coarse predicts {self.joint2coarse.n_vertices} vertices, the proxy has "
                f"{self.seam_map.max() + 1}",
                j2c,
            )
        self.renderer_path = (
            Path(renderer_path) if renderer_path else self.project.path(*RENDERER_MODEL)
        )
        self._renderer = None
        self._garment_box: tuple[np.ndarray, np.ndarray] | None = None
        self.backdrop: np.ndarray | None = None
        self.motion = None
        self.positions: np.ndarray | None = None
        self.joints: np.ndarray | None = None
        self._body_frames: np.ndarray | None = None
        self._j2c_ms = 0.0
        self._last: tuple | None = None  # (t, camera, FrameState) of the last render
        self._sim_targets: dict = {}  # motion name -> SimCache or None
        self.last_timings: dict[str, float] = {}

    # -- the motion --------------------------------------------------------------------------

    def set_motion(self, motion) -> None:
        """Play ``motion`` (a Motion on the mannequin, e.g. from :func:`load_motion_for`).

        Predicts the proxy of every frame with Joint2Coarse (one batch) and poses the body;
        resets the renderer's stream.
        """
        from training.joint2coarse import joint2coarse_inputs, predict_proxy

        if motion.num_frames < 1:
            raise InputError("the motion has no frames", motion.name or None)
        body_frames = pose_body(self.body, motion)  # checks the motion is on the mannequin
        joints, root_rot = joint2coarse_inputs(motion)
        start = time.perf_counter()
        positions = predict_proxy(
            self.joint2coarse, joints, root_rot, source=motion.name, stretch=self.stretch
        )
        self._j2c_ms = 1e3 * (time.perf_counter() - start) / len(positions)
        self.motion = motion
        self.positions = positions
        self.joints = joints[:, 1:]  # the 19 canonical joints (what the features use)
        self._body_frames = body_frames
        self._last = None
        if self._renderer is not None:
            self._renderer.reset()

    def _need_motion(self) -> None:
        if self.motion is None:
            raise InputError("no motion: call set_motion first")

    def _frame(self, t: int) -> int:
        self._need_motion()
        if isinstance(t, bool) or not 0 <= int(t) < self.num_frames:
            raise InputError(f"frame {t} out of range [0, {self.num_frames})")
        return int(t)

    @property
    def num_frames(self) -> int:
        """Frames of the current motion (0 before :meth:`set_motion`)."""
        return 0 if self.motion is None else int(self.motion.num_frames)

    @property
    def fps(self) -> float:
        """Frame rate of the current motion (the project's before :meth:`set_motion`)."""
        return float(self.config.fps if self.motion is None else self.motion.fps)

    @property
    def joint2coarse_ms(self) -> float:
        """Joint2Coarse time per frame of the last :meth:`set_motion` (batch, amortised)."""
        return self._j2c_ms

    def body_vertices(self, t: int) -> np.ndarray:
        """The posed body at frame t: (Vb, 3) float32."""
        return self._body_frames[self._frame(t)]

    def proxy_positions(self, t: int) -> np.ndarray:
        """Joint2Coarse's seam-free proxy at frame t: (Vs, 3) float32."""
        return self.positions[self._frame(t)]

    def proxy_vertices(self, t: int) -> np.ndarray:
        """The UV-split proxy at frame t (what is rasterized): (Vp, 3) float32."""
        return self.positions[self._frame(t)][self.seam_map]

    def joint_window(self, t: int) -> np.ndarray:
        """Joints at the feature frame offsets before t: (K, 19, 3) float32."""
        return joint_window(self.joints, self._frame(t), FeatureConfig().frame_offsets)

    def simulated_proxy(self, name: str | None = None) -> np.ndarray | None:
        """The simulated seam-free proxy (T, Vs, 3) float32 of a project motion, or None.

        ``name`` defaults to the current motion's project name (None for other motions).
        """
        name = name or (None if self.motion is None else self.motion.meta.get("project_motion"))
        if not name:
            return None
        cache = self.project.path(f"sim/{name}-proxy", "cache.npz")
        if not cache.is_file():
            return None
        return np.load(cache)["positions"].astype(np.float32)

    def simulated_target(self, name: str | None = None):
        """The simulated detailed target of a project motion (core.sim.SimCache), or None."""
        name = name or (None if self.motion is None else self.motion.meta.get("project_motion"))
        if not name:
            return None
        if name not in self._sim_targets:  # read once: a detailed cache is 100+ MB
            cache = self.project.path(f"sim/{name}-target", "cache.npz")
            self._sim_targets[name] = load_cache(cache) if cache.is_file() else None
        return self._sim_targets[name]

    # -- cameras and images ------------------------------------------------------------------

    def garment_box(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) (3,) float64 corners of the rest target garment's box (the data set frames it)."""
        if self._garment_box is None:
            target = self.project.path("garment", "target.obj")
            if target.is_file():
                v = load_mesh(target)[0].vertices
            else:  # a project without its target: the proxy is close enough for framing
                v = self.positions[0] if self.positions is not None else self.body.vertices
            v = np.asarray(v, np.float64)
            self._garment_box = (v.min(0), v.max(0))
        return self._garment_box

    def default_camera(
        self,
        t: int,
        width: int,
        height: int,
        azimuth_deg: float = 0.0,
        elevation_deg: float = 10.0,
        distance_scale: float = 1.075,
    ) -> Camera:
        """A camera that frames the garment like the data set's cameras, following the root.

        Field of view, look-at height and distance come from
        :func:`pipeline.stages.dataset.dataset_rig` (distance: ``distance_scale`` times its nearest
        radius, the middle of its range by default); azimuth 0 looks at the front (+Z);
        the target moves with the root's horizontal position at frame t.
        """
        t = self._frame(t)
        lo, hi = self.garment_box()
        rig = dataset_rig(self.config, np.stack([lo, hi]))
        return follow_camera(
            self.motion.root_positions[t], rig.target[1], rig.radius_range[0], rig.fov_y_deg,
            width, height, azimuth_deg, elevation_deg, distance_scale,
        )  # fmt: skip

    def set_backdrop(self, image: np.ndarray | None) -> None:
        """Composite the body over ``image`` ((H, W, 3) uint8, resized/cropped to each
        camera) instead of the plain studio colour; None goes back to the plain colour.
        For renderers fine-tuned to a background (``dng finetune --background``)."""
        if image is not None:
            image = np.asarray(image)
            if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
                raise InputError(f"backdrop must be (H, W, 3) uint8, got {image.shape}")
        self.backdrop = image
        self._last = None

    def background(self, t: int, camera: Camera) -> np.ndarray:
        """The body alone at frame t from ``camera``: (H, W, 3) uint8 (the data set's look)."""
        body = Mesh(self.body_vertices(t), self.body_faces)
        image = render_background(body, camera, self.shading)
        if self.backdrop is None:
            return image

        coverage = surface_coverage(body.vertices, body.faces, camera, self.shading.supersample)
        backdrop = fit_image(self.backdrop, camera.width, camera.height)
        return recomposite(image, coverage, self.shading.background, backdrop)

    def proxy_image(self, t: int, camera: Camera) -> np.ndarray:
        """Joint2Coarse's proxy shaded on the body at frame t: (H, W, 3) uint8."""
        proxy = Mesh(self.proxy_vertices(t), self.proxy_faces, self.proxy_uvs)
        body = Mesh(self.body_vertices(t), self.body_faces)
        return render_views(proxy, body, [camera], self.shading)[0].image

    def reference_image(self, t: int, camera: Camera) -> tuple[np.ndarray, str]:
        """What to show beside the neural render: the simulated detailed target (ground
        truth) for a project motion that has one, else the Joint2Coarse proxy on the body.
        Returns ((H, W, 3) uint8, label)."""
        t = self._frame(t)
        sim = self.simulated_target()
        if sim is not None and sim.num_frames >= self.num_frames:
            garment = Mesh(np.asarray(sim.positions[t], np.float32), sim.faces)
            body = Mesh(self.body_vertices(t), self.body_faces)
            return render_views(garment, body, [camera], self.shading)[0].image, "simulation"
        return self.proxy_image(t, camera), "Joint2Coarse proxy"

    # -- neural rendering --------------------------------------------------------------------

    @property
    def renderer(self):
        """The :class:`NeuralRenderer` (loaded on first use; InputError naming a missing file)."""
        if self._renderer is None:
            from training.renderer.inference import NeuralRenderer

            if not self.renderer_path.is_file():
                raise InputError(
                    "no trained renderer: train one first (dng train renderer)",
                    self.renderer_path,
                )
            self._renderer = NeuralRenderer.from_file(
                self.renderer_path, self.proxy_faces, self.proxy_uvs, device=self.device
            )
        return self._renderer

    def has_renderer(self) -> bool:
        """Whether the renderer model file is there (render() would load it)."""
        return self._renderer is not None or self.renderer_path.is_file()

    def render(self, t: int, camera: Camera) -> np.ndarray:
        """The neural render of frame t from ``camera`` over the background: (H, W, 3) uint8.

        Consecutive frames from one camera stream (frame t-1's latent is reused); any other
        call encodes t-1 again, so the pixels never depend on the order of calls.
        Sets :attr:`last_timings` (ms): ``joint2coarse`` (batch, per frame), ``background``,
        ``raster+network``, ``total``.
        """
        from training.renderer.inference import FrameState

        renderer = self.renderer
        t = self._frame(t)
        t0 = time.perf_counter()
        frame = FrameState(self.proxy_vertices(t), self.joint_window(t), self.background(t, camera))
        t1 = time.perf_counter()
        last = self._last
        if t == 0:
            previous = frame
        elif last is not None and last[0] == t - 1 and last[1] == camera:
            previous = last[2]  # the object the renderer saw: its latent is reused
        else:
            previous = FrameState(
                self.proxy_vertices(t - 1), self.joint_window(t - 1), frame.background
            )
        image = renderer.render(camera, frame, previous)
        t2 = time.perf_counter()
        self._last = (t, camera, frame)
        self.last_timings = {
            "joint2coarse": self._j2c_ms,
            "background": 1e3 * (t1 - t0),
            "raster+network": 1e3 * (t2 - t1),
            "total": self._j2c_ms + 1e3 * (t2 - t0),
        }
        return image


# ---------------------------------------------------------------------------------- output

#: Output kinds of :class:`FrameWriter`, by suffix ("" is a folder of PNG frames).
VIDEO_SUFFIXES = (".mp4", ".gif")


class FrameWriter:
    """Write frames to an MP4 (H.264 via imageio-ffmpeg), an animated GIF (PIL) or a folder of
    numbered PNGs (``frame_00000.png``), atomically: nothing appears at ``path`` until
    :meth:`close` succeeds; an error (or :meth:`abort`) leaves ``path`` as it was.

    Use as a context manager::

        with FrameWriter("clip.mp4", fps=30) as out:
            for t in range(pb.num_frames):
                out.append(pb.render(t, cam))

    Not imageio's writers: imageio-ffmpeg (which imageio itself would wrap) already writes the
    MP4, and PIL, a dependency for every PNG the studio writes, writes the GIF.

    Parameters
    ----------
    path : ``.mp4``, ``.gif``, or a folder (an existing folder, a path ending in ``/``, or a
        path with no suffix)
    fps : frames per second of a video
    """

    def __init__(self, path: str | os.PathLike, fps: float):
        self.path = Path(path)
        self.folder = (
            str(path).endswith(("/", os.sep)) or self.path.is_dir() or not self.path.suffix
        )
        self.kind = "png" if self.folder else self.path.suffix.lower()
        if self.kind not in ("png", *VIDEO_SUFFIXES):
            raise InputError(
                f"unsupported output {self.path.suffix!r}: use .mp4, .gif or a folder for PNGs",
                self.path,
            )
        if not (fps > 0 and np.isfinite(fps)):
            raise InputError(f"fps must be positive, got {fps}")
        self.fps = float(fps)
        self.count = 0
        self.size: tuple[int, int] | None = None
        self._frames: list[np.ndarray] = []  # GIF frames
        self._ffmpeg = None
        self._tmp: Path | None = None
        self._atomic = None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.kind == "png":
            self._tmp = Path(
                tempfile.mkdtemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent)
            )
        else:
            self._atomic = atomic_path(self.path)
            self._tmp = self._atomic.__enter__()

    def append(self, image: np.ndarray) -> None:
        """Add one (H, W, 3) uint8 frame; every frame must have the first one's size."""
        image = np.asarray(image)
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise InputError(f"frames must be (H, W, 3) uint8, got {image.shape} {image.dtype}")
        if self.size is None:
            self.size = image.shape[:2]
        elif image.shape[:2] != self.size:
            raise InputError(f"frame of size {image.shape[:2]}, the first was {self.size}")
        if self.kind == "png":
            from PIL import Image

            Image.fromarray(image).save(self._tmp / f"frame_{self.count:05d}.png")
        elif self.kind == ".gif":
            self._frames.append(image)
        else:
            self._mp4(image)
        self.count += 1

    def _mp4(self, image: np.ndarray) -> None:
        # H.264 in yuv420p needs even sizes: pad the last row / column by repeating it.
        h, w = image.shape[:2]
        image = np.pad(image, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        if self._ffmpeg is None:
            try:
                import imageio_ffmpeg
            except ImportError:
                raise InputError(
                    "MP4 output needs imageio-ffmpeg (pip install imageio-ffmpeg); "
                    "or write a .gif or a folder of PNGs",
                    self.path,
                ) from None
            self._ffmpeg = imageio_ffmpeg.write_frames(
                str(self._tmp),
                (image.shape[1], image.shape[0]),
                fps=self.fps,
                codec="libx264",
                quality=8,
                macro_block_size=1,
                ffmpeg_log_level="error",
                output_params=["-f", "mp4"],
            )
            self._ffmpeg.send(None)
        self._ffmpeg.send(np.ascontiguousarray(image))

    def close(self) -> Path:
        """Finish the file (or folder) and move it into place; returns the path."""
        if self.count == 0:
            self.abort()
            raise InputError("no frames to write", self.path)
        if self.kind == ".gif":
            from PIL import Image

            first, *rest = [Image.fromarray(f) for f in self._frames]
            first.save(
                self._tmp,
                format="GIF",
                save_all=True,
                append_images=rest,
                duration=max(1, round(1000 / self.fps)),
                loop=0,
            )
        elif self.kind == ".mp4":
            self._ffmpeg.close()
            self._ffmpeg = None
        if self.kind == "png":
            self._place_folder()
        else:
            self._atomic.__exit__(None, None, None)
            self._atomic = None
        return self.path

    def _place_folder(self) -> None:

        target = self.path
        if target.is_dir() and not any(target.iterdir()):
            target.rmdir()
        if not target.exists():
            mask = os.umask(0)
            os.umask(mask)
            os.chmod(self._tmp, 0o777 & ~mask)  # mkdtemp makes 0700; give the usual mode
            os.replace(self._tmp, target)
        else:  # a folder already there: replace its frames, drop stale ones beyond the new end
            new = {p.name for p in self._tmp.iterdir()}
            for name in sorted(new):
                os.replace(self._tmp / name, target / name)
            for old in target.glob("frame_*.png"):
                if old.name not in new:
                    old.unlink()
            shutil.rmtree(self._tmp, ignore_errors=True)
        self._tmp = None

    def abort(self) -> None:
        """Drop what was written; ``path`` stays as it was."""
        if self._ffmpeg is not None:
            try:
                self._ffmpeg.close()
            except Exception:  # noqa: BLE001 - the partial file is removed anyway
                pass
            self._ffmpeg = None
        if self._atomic is not None:
            try:
                self._atomic.__exit__(RuntimeError, RuntimeError("aborted"), None)
            except RuntimeError:
                pass
            self._atomic = None
        elif self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def __enter__(self) -> FrameWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
