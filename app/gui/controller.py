"""The studio's controller: state, worker threads, and the programmatic driver API.

Threads (STYLE #8): widgets are touched only on the main thread. Work runs on four workers:

- ``proxy``: garment loading and proxy derivation (slider changes coalesce: the last wins);
- ``playback``: every call into :class:`pipeline.playback.Playback` (it is not thread-safe):
  loading, motions, live neural renders (coalesced: the newest camera/frame wins), exports;
- ``jobs``: pipeline stages (simulation, data set, training), fine-tuning; cancellable;
- ``plots``: loss-curve and preview pictures of a running job.

Results come back through :meth:`Studio.post` into an inbox that the main loop
(:meth:`Studio.run_loop`: ``run_one_tick`` then :meth:`Studio.service`) empties between ticks;
the play clock runs there too. Nothing calls back into Python from inside Open3D's tick but
input events: under software Vulkan, geometry and widget updates made from callbacks that
Open3D runs inside its tick (``post_to_main_thread``, ``set_on_tick_event``) stalled the window
for 5-230 s whenever another thread held the GIL (a live render, a proxy derivation); the
same updates made between ticks did not (docs/gui.md). The viewer meets the renderer through
one call, ``Playback.render(t, camera)`` (STYLE #9).

Driver API (tests, the tour, scripts): :meth:`open_project`, :meth:`load_garment`,
:meth:`derive_proxy`, :meth:`load_motion`, :meth:`play`, :meth:`pause`, :meth:`step`,
:meth:`seek`, :meth:`set_camera`, :meth:`render_now`, :meth:`run_pipeline`, :meth:`cancel`,
:meth:`export_gif`, :meth:`export_proxy`, :meth:`save_settings`, :meth:`screenshot`, with
:meth:`wait_idle` / :meth:`pump` to let the event loop run (``run_one_tick``) in between.
"""

from __future__ import annotations

import os
import queue
import threading
import time
import traceback
from dataclasses import replace
from pathlib import Path

import numpy as np
import open3d.visualization.gui as gui
from PIL import ImageGrab

from app.gui.model import (
    CPU_RENDER_HEIGHTS,
    PLAY_SPEEDS,
    CameraPose,
    Cancelled,
    Eta,
    GuiSettings,
    RateMeter,
    adapt_render_height,
    atlas_image,
    cached_builtin_garment,
    camera_from_gl,
    format_seconds,
    latest_preview,
    load_settings,
    loss_plot,
    pipeline_jobs,
    pose_from_camera,
    proxy_plan,
    proxy_summary,
    reatlas,
    side_by_side,
    training_logs,
    unique_edges,
    view_image_size,
)
from app.gui.model import save_settings as write_settings
from app.gui.window import COLOURS, StudioWindow
from app.gui.workers import CancelToken, Worker
from core.camera import dolly_view, orbit_view, pan_view
from core.errors import InputError
from core.fileio import atomic_path

#: Play-clock / job-progress updates per second at most (in :meth:`Studio.service`).
TICK_HZ = 30
#: While playing, the 3D view is redrawn at most this often (frames per second). Filament
#: draws every frame it is given and never drops one; under software Vulkan (Mesa lavapipe)
#: a frame of the playback scene costs 0.1-0.3 s on 2 busy cores, and frames
#: asked for faster than that queue up: 20 s of play at 15 Hz left 127 s of frames to draw,
#: paid at the next dialog. No fence is possible from Python without a callback inside
#: Open3D's tick, which stalls (see the module docstring). Neural renders run as fast as the
#: playback worker makes them; the newest is shown. ``DNG_GUI_PLAY_HZ`` overrides it (a GPU
#: draws far faster).
PLAY_REDRAW_HZ = float(os.environ.get("DNG_GUI_PLAY_HZ", "4"))
#: While playing, the live neural image is replaced at most this often. A window redraw that
#: only changes the image is cheap (20 s at 10 Hz left nothing queued: the screenshot after
#: it took its usual 3.5 s), so it need not wait for the 3D view.
LIVE_REDRAW_HZ = float(os.environ.get("DNG_GUI_LIVE_HZ", "15"))
#: While playing, the reference (ground-truth) image is redrawn at most this often (s), but in
#: the comparison view, where it follows every frame.
REFERENCE_EVERY_S = 0.5
#: The neural viewport's render height is re-chosen at most this often (s).
ADAPT_EVERY_S = 1.0
#: Camera turn per pixel dragged on the neural view (radians).
ORBIT_RAD_PER_PX = 0.01
#: Procedural kinds offered in the motion list (``core.motion.procedural.PROCEDURAL_KINDS``;
#: written out so the window opens without importing the motion code).
PROCEDURAL = ("dance", "twirl", "walk", "circle-walk", "idle", "jump")
#: Geometry names of the two modes of the 3D view.
GARMENT_GEOMETRY = ("target", "target_wire", "proxy_wire", "rest_body")
PLAY_GEOMETRY = ("body", "j2c", "sim")


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


class Studio:
    """The garment studio window and its state."""

    def __init__(self, project: str | os.PathLike | None = None, width=1500, height=940):
        self.app = gui.Application.instance
        self.settings = GuiSettings()
        self.project: Path | None = None
        self.closed = False
        self._lock = threading.Lock()
        self._inbox: queue.SimpleQueue = queue.SimpleQueue()  # main-thread work (post)
        self._motion_items: list[str] = []
        self._body_items: list[str] = []
        self.job_name = ""
        self._pending = 0
        self.errors: list[str] = []  # every error shown (tests read it)
        self.view = StudioWindow(self, width, height)
        self.proxy_worker = Worker(self.post, "proxy")
        self.play_worker = Worker(self.post, "playback")
        self.job_worker = Worker(self.post, "jobs")
        self.misc_worker = Worker(self.post, "plots")

        # garment / proxy state (written on the main thread from worker results)
        self.garment = None  # core.mesh.Mesh
        self.garment_name = ""
        self._garment_id = 0
        self._proxy_cache = None  # (garment id, ProxyConfig, ProxyResult): proxy worker only
        self.proxy_result = None
        self.proxy_plan_ran = ""
        self.mode = "garment"

        # playback state
        self.playback = None  # touched on the playback worker only
        self.playback_root: Path | None = None
        self.renderer_path: Path | None = None
        self.backdrop = None
        self.num_frames = 0
        self.fps = 30.0
        self.frame = 0
        self.playing = False
        self._play_start = (0.0, 0)
        self.body_frames = None
        self.body_faces = None
        self.proxy_frames = None
        self.proxy_faces = None
        self.proxy_uvs = None
        self.sim_frames = None
        self.sim_edges = None
        self.motion_name = ""
        self.live_image: np.ndarray | None = None
        self.reference_image: np.ndarray | None = None
        self.reference_label = ""
        self.render_meter = RateMeter(20)
        self.render_count = 0
        self.last_timings: dict[str, float] = {}
        self.live_benchmark: dict | None = None
        self._last_view = None
        self._last_reference = 0.0
        self._last_redraw = 0.0
        self._last_live = 0.0
        self._last_tick = 0.0
        self.play_frames_shown = 0  # 3D-view frames shown while playing (tests, benchmarks)
        self.live_frames_shown = 0  # live neural renders put on the screen
        self._shown_live = None  # newest live render not shown yet (while playing)
        self._live_disabled_reason = ""
        # the neural viewport (main area)
        self.gpu = False  # the playback worker renders on CUDA
        self.neural_height = CPU_RENDER_HEIGHTS[0]
        self.neural_image: np.ndarray | None = None  # the newest image shown there
        self._frame_ms: float | None = None  # smoothed ms per neural render
        self._last_adapt = 0.0
        self._scene_stale = False  # the 3D view's meshes lag the frame (hidden meanwhile)
        self.export_token: CancelToken | None = None

        # jobs
        self.job_token: CancelToken | None = None
        self.job_eta: Eta | None = None
        self.job_label = ""
        self.job_log: list[str] = []
        self.job_running = False
        self.job_config = None
        self.last_job_result = None
        self._last_plot = 0.0

        self.open_seconds: float | None = None
        self._apply_settings_to_widgets()
        self.post(self._mark_open)
        self.view.scene.set_on_mouse(self._on_mouse)
        self.body_shown_s: float | None = None  # when the mannequin first showed (process age)
        self.garment_from_cache: bool | None = None
        self.garment_shown_s: float | None = None  # when the first garment showed
        self._loading: tuple[str, float] | None = None  # (what, since): status shows progress
        self.show_mannequin()
        if project is not None:
            self.open_project(project)
        else:
            self.load_garment(self.settings.garment)

    # ------------------------------------------------------------------ threads and the loop

    def post(self, fn) -> None:
        """Run ``fn`` on the main thread at the next :meth:`service` (any thread may call
        this); an exception becomes an error dialog."""
        with self._lock:
            self._pending += 1
        self._inbox.put(fn)

    def service(self) -> None:
        """Main-thread work between two Open3D ticks: what workers posted, then the play
        clock and job progress (at most ``TICK_HZ`` times a second)."""
        while True:
            try:
                fn = self._inbox.get_nowait()
            except queue.Empty:
                break
            try:
                if not self.closed:
                    fn()
            except Exception as exc:  # noqa: BLE001 - shown to the user
                traceback.print_exc()
                self.show_error(exc)
            finally:
                with self._lock:
                    self._pending -= 1
        now = time.perf_counter()
        if self.closed or now - self._last_tick < 1.0 / TICK_HZ:
            return
        self._last_tick = now
        if self.playing and self.num_frames:
            self._play_tick(now)
        if self.job_running:
            self._update_job_widgets()
        if self._loading is not None:
            what, since = self._loading
            self.view.status.text = f"{what} ... {now - since:.0f} s"

    def run_loop(self) -> None:
        """The window's main loop (``dng gui``): Open3D's tick, then :meth:`service`, until
        the window is closed."""
        while self.app.run_one_tick():
            self.service()

    def _mark_open(self) -> None:
        self.open_seconds = process_age()

    def _play_tick(self, now: float) -> None:
        """Show the play clock's frame at most ``PLAY_REDRAW_HZ`` times a second and the
        newest live render at most ``LIVE_REDRAW_HZ`` times a second."""
        if not self.settings.loop and self._play_position() >= self.num_frames - 1:
            self._show_frame(self.num_frames - 1)
            self.pause()
            return
        neural = self.main_view() != "scene"
        if neural or now - self._last_redraw >= 1.0 / PLAY_REDRAW_HZ:
            t = self._play_position()
            if t != self.frame:
                self._last_redraw = now
                self._show_frame(t)
                self.play_frames_shown += 1
        if self._shown_live is not None and now - self._last_live >= 1.0 / LIVE_REDRAW_HZ:
            self._last_live = now
            self._show_live(*self._shown_live)
            self._shown_live = None

    def _play_position(self) -> int:
        """The frame the play clock is at now (at the play speed; looping, or held on the
        last frame)."""
        elapsed = time.perf_counter() - self._play_start[0]
        t = self._play_start[1] + int(elapsed * self.fps * self.settings.play_speed)
        n = max(self.num_frames, 1)
        return t % n if self.settings.loop else min(t, n - 1)

    def _on_mouse(self, event) -> object:
        """Camera moves in the 3D view re-render the live view (after Open3D moved it)."""
        if event.type in (
            gui.MouseEvent.Type.DRAG,
            gui.MouseEvent.Type.WHEEL,
            gui.MouseEvent.Type.BUTTON_UP,
        ):
            self.post(self._camera_moved)
        return gui.Widget.EventCallbackResult.IGNORED

    def _camera_moved(self) -> None:
        view = self.view.gl_matrices()[0]
        if self._last_view is None or not np.allclose(view, self._last_view, atol=1e-7):
            self._last_view = view
            self.render_now()

    # ------------------------------------------------------------------ the neural viewport

    def main_view(self) -> str:
        """What the main area shows now: ``scene`` in the garment mode or without a trained
        renderer, else the chosen view mode (``neural``, ``scene``, ``compare``)."""
        if self.mode != "play" or self._live_disabled_reason or not self.settings.live_render:
            return "scene"
        return self.settings.view_mode

    def set_view_mode(self, mode: str) -> None:
        """Show the neural render (``neural``), the 3D scene (``scene``) or the neural render
        beside the reference (``compare``) in the main area."""
        if mode not in ("neural", "scene", "compare"):
            raise InputError(f"unknown view mode {mode!r}")
        self.settings = replace(self.settings, view_mode=mode)
        self._update_main_view()
        self.render_now(force_reference=True)

    def _update_main_view(self) -> None:
        shown = self.main_view()
        if shown == "scene" and self._scene_stale:
            self._scene_stale = False
            self._show_frame(self.frame, render=False)
        self.view.show_view_mode(shown)

    def set_play_speed(self, speed: float) -> None:
        if self.playing:
            self._play_start = (time.perf_counter(), self.frame)
        self.settings = replace(self.settings, play_speed=float(speed))

    def set_loop(self, on: bool) -> None:
        self.settings = replace(self.settings, loop=bool(on))

    def neural_drag(self, dx_px: float, dy_px: float, pan: bool = False) -> None:
        """A drag of (dx, dy) pixels on the neural view: orbit the camera around its target
        (or pan it), as the 3D view does; both views keep one camera."""
        pose = self.current_pose()
        if pan:
            h = max(self.view.main_size[1], 1)
            distance = float(np.linalg.norm(np.subtract(pose.eye, pose.target)))
            per_px = 2.0 * distance * np.tan(np.radians(pose.fov_deg) / 2.0) / h
            eye, target = pan_view(pose.eye, pose.target, -dx_px * per_px, dy_px * per_px)
        else:
            eye = orbit_view(
                pose.eye, pose.target, -dx_px * ORBIT_RAD_PER_PX, dy_px * ORBIT_RAD_PER_PX
            )
            target = pose.target
        self.set_camera(eye, target, (0.0, 1.0, 0.0), pose.fov_deg)

    def neural_zoom(self, steps: float) -> None:
        """Zoom the neural view's camera: ``steps`` > 0 moves it closer (wheel notches)."""
        pose = self.current_pose()
        eye = dolly_view(pose.eye, pose.target, 0.9 ** float(steps))
        self.set_camera(eye, pose.target, (0.0, 1.0, 0.0), pose.fov_deg)

    @property
    def idle(self) -> bool:
        with self._lock:
            pending = self._pending
        workers = (self.proxy_worker, self.play_worker, self.job_worker, self.misc_worker)
        return pending == 0 and all(w.idle for w in workers)

    def pump(self, seconds: float) -> None:
        """Run the event loop for ``seconds`` (driver API)."""
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            self.app.run_one_tick()
            self.service()
            time.sleep(0.002)

    def wait_idle(self, timeout: float = 120.0, settle: float = 0.1) -> None:
        """Run the event loop until every worker is done and every result is shown."""
        end = time.perf_counter() + timeout
        quiet_since = None
        while time.perf_counter() < end:
            self.app.run_one_tick()
            self.service()
            if self.idle:
                quiet_since = quiet_since or time.perf_counter()
                if time.perf_counter() - quiet_since >= settle:
                    return
            else:
                quiet_since = None
            time.sleep(0.002)
        raise TimeoutError(f"the studio was still busy after {timeout} s")

    # ------------------------------------------------------------------------ errors

    def show_error(self, exc: BaseException) -> None:
        if isinstance(exc, Cancelled):
            self.view.status.text = "cancelled"
            return
        if isinstance(exc, InputError):
            title, message = "Problem", str(exc)
        else:
            title, message = "Error", f"{type(exc).__name__}: {exc}"
        self.errors.append(message)
        self.view.status.text = f"error: {message}"[:120]
        self.view.show_error(title, _wrap(message))

    def _fail(self, exc: BaseException) -> None:
        self.show_error(exc)

    # ------------------------------------------------------------------------ settings

    def _apply_settings_to_widgets(self) -> None:
        s, v = self.settings, self.view
        v.show_target.checked = s.show_target
        v.show_wire.checked = s.show_wireframe
        v.show_proxy.checked = s.show_proxy
        v.show_body.checked = s.show_body
        v.show_sim.checked = s.show_sim
        v.live_check.checked = s.live_render
        v.gt_check.checked = s.show_ground_truth
        v.verts_slider.int_value = s.proxy_verts
        v.detail_slider.double_value = s.detail_scale
        from app.gui.model import RENDER_SIZES, TEXTURE_SIZES

        v.texture_combo.selected_index = TEXTURE_SIZES.index(s.texture_size)
        if s.render_size in RENDER_SIZES:
            v.size_combo.selected_index = RENDER_SIZES.index(s.render_size)
        v.motion_frames.int_value = s.motion_frames
        if s.play_speed in PLAY_SPEEDS:
            v.speed_combo.selected_index = PLAY_SPEEDS.index(s.play_speed)
        v.loop_check.checked = s.loop
        v.export_frames.int_value = s.export_frames
        v.export_reference.checked = s.export_reference
        names = self.builtin_garments()
        if s.garment in names:
            v.garment_combo.selected_index = names.index(s.garment)
        for name, slider in v.body_sliders.items():
            if name in s.body:
                slider.double_value = float(s.body[name])
        self._update_path_label()

    def current_pose(self) -> CameraPose:
        """The 3D view's viewpoint as a :class:`CameraPose`."""
        view, proj, fov = self.view.gl_matrices()
        cam = camera_from_gl(view, proj, 64, 64)
        centre = np.asarray(self.view.scene.center_of_rotation, np.float64)
        distance = float(np.linalg.norm(cam.center - centre)) or 2.5
        return replace(pose_from_camera(cam, distance), fov_deg=fov)

    def save_settings(self) -> None:
        """Write the window's settings into the project's ``project.json`` (key ``gui``)."""
        if self.project is None:
            self.view.status.text = "no project open: settings are not saved"
            return
        self.settings = replace(
            self.settings,
            camera=self.current_pose().as_dict(),
            frame=int(self.frame),
        )
        write_settings(self.project, self.settings)
        self.view.status.text = f"settings saved to {self.project / 'project.json'}"

    def on_close(self) -> bool:
        try:
            if self.project is not None:
                self.save_settings()
        except Exception:  # noqa: BLE001 - closing must not fail
            traceback.print_exc()
        self.closed = True
        for w in (self.proxy_worker, self.play_worker, self.job_worker, self.misc_worker):
            w.stop()
        if self.job_token is not None:
            self.job_token.cancel()
        return True

    # ------------------------------------------------------------------------ garment/proxy

    @staticmethod
    def builtin_garments() -> list[str]:
        return [
            "multilayer-skirt",
            "double-skirt",
            "tango-skirt",
            "pleated-skirt",
            "dress",
        ]

    def show_mannequin(self) -> None:
        """Show the rest body at once (before any garment is ready), framed by the camera."""
        shape = self.settings.body_shape()

        def job():
            from core.body.mannequin import make_body

            b = make_body(shape)
            return b.vertices, b.faces

        def done(out) -> None:
            bv, bf = out
            if self.garment is None:
                self.view.set_mesh("rest_body", bv, bf, COLOURS["body"])
                self.view.frame_camera(bv.min(0) - 0.1, bv.max(0) + 0.1)
                self._apply_visibility()
            self.body_shown_s = process_age()

        self.proxy_worker.submit(job, done, self._fail, key="mannequin")

    def load_garment(self, name_or_path: str, resolution_mm: float | None = None) -> None:
        """Load a built-in garment by name or a mesh file, show it and derive its proxy."""
        name = str(name_or_path)
        res = resolution_mm or self.settings.garment_resolution_mm
        self.settings = replace(self.settings, garment=name, garment_resolution_mm=res)
        body = self.settings.body_shape()
        builtin = not Path(name).suffix
        what = f"generating {name} (first time; cached after)" if builtin else f"loading {name}"
        self._loading = (what, time.perf_counter())
        self.view.status.text = f"{what} ..."

        def job():
            from_cache = None
            if not builtin:
                from core.mesh import load_mesh

                mesh, _ = load_mesh(name)
            else:
                from templates.garments import make_garment

                try:
                    mesh, from_cache = cached_builtin_garment(name, res, body, make_garment)
                except (KeyError, ValueError) as exc:
                    raise InputError(f"garment {name!r}: {exc}") from None
            from core.body.mannequin import make_body

            b = make_body(body)
            return mesh, (b.vertices, b.faces), from_cache

        def failed(exc: BaseException) -> None:
            self._loading = None
            self._fail(exc)

        self.proxy_worker.submit(job, self._garment_loaded, failed, key="garment")

    def _garment_loaded(self, result) -> None:
        mesh, (bv, bf), self.garment_from_cache = result
        self._loading = None
        self.garment_shown_s = self.garment_shown_s or process_age()
        self.garment = mesh
        self._garment_id += 1
        self.garment_name = self.settings.garment
        self.view.garment_label.text = (
            f"{Path(self.garment_name).name}: {mesh.num_vertices} vertices, {mesh.num_faces} faces"
        )
        self._enter_mode("garment")
        v = self.view
        v.set_mesh("target", mesh.vertices, mesh.faces, COLOURS["target"])
        v.set_lines("target_wire", mesh.vertices, unique_edges(mesh.faces), COLOURS["target_wire"])
        v.set_mesh("rest_body", bv, bf, COLOURS["body"])
        self._apply_visibility()
        lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
        v.frame_camera(lo - 0.1, hi + 0.1)
        self.view.status.text = f"loaded {Path(self.garment_name).name}"
        self.derive_proxy()

    def proxy_config(self):
        from core.proxy import ProxyConfig

        s = self.settings
        return ProxyConfig(
            target_verts=int(s.proxy_verts),
            detail_scale=float(s.detail_scale),
            texture_size=int(s.texture_size),
        )

    def derive_proxy(self, target_verts=None, detail_scale=None, texture_size=None) -> None:
        """Derive (or update) the proxy of the loaded garment in the proxy worker. Only what a
        change affects re-runs: the texture size alone redoes the atlas, not the surface."""
        changes = {}
        if target_verts is not None:
            changes["proxy_verts"] = int(target_verts)
        if detail_scale is not None:
            changes["detail_scale"] = float(detail_scale)
        if texture_size is not None:
            changes["texture_size"] = int(texture_size)
        self.settings = replace(self.settings, **changes)
        v = self.view
        v.verts_slider.int_value = self.settings.proxy_verts
        v.detail_slider.double_value = self.settings.detail_scale
        from app.gui.model import TEXTURE_SIZES

        if self.settings.texture_size in TEXTURE_SIZES:
            v.texture_combo.selected_index = TEXTURE_SIZES.index(self.settings.texture_size)
        if self.garment is None:
            return
        try:
            cfg = self.proxy_config()
        except InputError as exc:
            self.show_error(exc)
            return
        mesh, gid = self.garment, self._garment_id
        path = self.garment_name if Path(self.garment_name).suffix else None
        self.view.status.text = "deriving the proxy ..."

        def job():
            from core.proxy import derive_proxy

            prev = self._proxy_cache
            plan = "full" if prev is None or prev[0] != gid else proxy_plan(prev[1], cfg)
            if plan == "none":
                result = prev[2]
            elif plan == "atlas":
                result = reatlas(prev[2], cfg.texture_size, cfg.padding)
            else:
                result = derive_proxy(mesh, cfg, path=path)
            self._proxy_cache = (gid, cfg, result)
            image = atlas_image(result.proxy.uvs, result.proxy.faces, 160)
            return plan, result, image

        self.proxy_worker.submit(job, self._proxy_done, self._fail, key="proxy")

    def _proxy_done(self, out) -> None:
        plan, result, image = out
        self.proxy_result = result
        self.proxy_plan_ran = plan
        v = self.view
        pos = result.positions
        v.set_lines("proxy_wire", pos.vertices, unique_edges(pos.faces), COLOURS["proxy_wire"])
        v.set_image(v.atlas_image, image)
        rows = proxy_summary(result.report)
        ran = {"full": "whole derivation", "atlas": "UV atlas only", "none": "nothing"}[plan]
        v.report_label.text = "\n".join(f"{k}: {val}" for k, val in rows) + f"\nre-ran: {ran}"
        v.window.set_needs_layout()
        self._apply_visibility()
        v.status.text = f"proxy: {result.proxy.num_vertices} vertices ({ran})"

    def apply_proxy_to_project(self) -> None:
        """Write the garment and proxy settings into the project's pipeline settings and run
        the garment and proxy stages (downstream stages then see their inputs changed)."""
        if self.project is None:
            self.show_error(InputError("open a project first (Motion tab)"))
            return
        from core.project import Project
        from pipeline.config import project_config

        project = Project(self.project)
        s = self.settings
        config = replace(
            project_config(project),
            garment=s.garment,
            garment_resolution_mm=None if Path(s.garment).suffix else s.garment_resolution_mm,
            proxy_verts=s.proxy_verts,
            proxy_texture=s.texture_size,
        )
        data = project.settings()
        data["pipeline"] = config.as_params()
        project.save_settings(data)
        self.run_pipeline("setup")

    # ------------------------------------------------------------------------ visibility

    def set_visibility(self, **flags) -> None:
        self.settings = replace(self.settings, **flags)
        v = self.view
        for key, box in (
            ("show_target", v.show_target),
            ("show_wireframe", v.show_wire),
            ("show_proxy", v.show_proxy),
            ("show_body", v.show_body),
            ("show_sim", v.show_sim),
        ):
            box.checked = bool(getattr(self.settings, key))
        self._apply_visibility()
        if "show_sim" in flags and self.mode == "play":
            self._show_frame(self.frame)

    def _enter_mode(self, mode: str) -> None:
        self.mode = mode
        self._apply_visibility()
        self._update_main_view()

    def _apply_visibility(self) -> None:
        s, v = self.settings, self.view
        garment = self.mode == "garment"
        v.show("target", garment and s.show_target)
        v.show("target_wire", garment and s.show_wireframe)
        v.show("proxy_wire", garment and s.show_proxy)
        v.show("rest_body", garment and s.show_body)
        v.show("body", not garment and s.show_body)
        v.show("j2c", not garment and s.show_proxy)
        v.show("sim", not garment and s.show_sim)

    # ------------------------------------------------------------------------ project

    def open_project(self, path: str | os.PathLike) -> None:
        """Open a project folder: restore its window settings, load its garment, proxy and
        trained networks (Playback), and its saved motion and camera."""
        from core.project import Project

        root = Path(path)
        if not (root / "project.json").is_file():
            self.show_error(InputError("not a garment project (no project.json)", root))
            return
        try:
            self.settings = load_settings(root)
            config = Project(root).settings().get("pipeline", {})
        except InputError as exc:
            self.show_error(exc)
            return
        self.project = root
        self.view.project_label.text = str(root)
        self._apply_settings_to_widgets()
        self._fill_motion_list()
        self._fill_body_list()
        target = root / "garment" / "target.obj"
        if target.is_file():
            if not self.settings.camera and "proxy_verts" in config:
                self.settings = replace(
                    self.settings,
                    proxy_verts=int(config["proxy_verts"]),
                    texture_size=int(config.get("proxy_texture", self.settings.texture_size)),
                )
                self._apply_settings_to_widgets()
            self.load_garment(str(target))
        self._open_playback(root)

    def _fill_motion_list(self) -> None:
        combo = self.view.motion_combo
        combo.clear_items()
        names = []
        if self.project is not None:
            names = sorted(p.stem for p in (self.project / "motions").glob("*.bvh"))
        self._motion_items = [*names, *[k for k in PROCEDURAL if k not in names]]
        for name in self._motion_items:
            combo.add_item(name)

    def _fill_body_list(self) -> None:
        combo = self.view.body_combo
        combo.clear_items()
        self._body_items = ["project body"]
        if self.project is not None:
            self._body_items += sorted(
                p.name
                for p in (self.project / "finetune").glob("body-*")
                if (p / "renderer" / "renderer.pt").is_file()
            )
        for name in self._body_items:
            combo.add_item(name)

    def _open_playback(
        self, root: Path, renderer_path: Path | None = None, backdrop=None, motion=None
    ) -> None:
        self.playback_root = root
        self.renderer_path = renderer_path
        self.view.status.text = f"loading {root.name} (Joint2Coarse, body) ..."
        motion = motion or self.settings.motion

        def job():
            import torch

            from pipeline.playback import Playback

            torch.set_num_threads(1)
            device = "cuda" if torch.cuda.is_available() else "cpu"
            pb = Playback(root, renderer_path=renderer_path, device=device)
            if backdrop is not None:
                pb.set_backdrop(backdrop)
            self.playback = pb
            return pb.has_renderer(), device == "cuda"

        def done(out) -> None:
            has_renderer, self.gpu = out
            self._live_disabled_reason = "" if has_renderer else "no trained renderer yet"
            self.view.status.text = f"opened {root}" + (
                "" if has_renderer else " (no trained renderer: live render off)"
            )
            self.load_motion(motion, restore=True)

        self.play_worker.submit(job, done, self._fail, key="open")

    # ------------------------------------------------------------------------ motion

    def set_motion_frames(self, n: int) -> None:
        self.settings = replace(self.settings, motion_frames=int(n))

    def load_motion(self, name_or_path: str, frames: int | None = None, restore=False) -> None:
        """Load a project motion, a procedural kind or a BVH file and predict its proxy."""
        if self.playback_root is None:
            self.show_error(InputError("open a trained project first to play motions"))
            return
        name = str(name_or_path)
        kind_frames = frames or self.settings.motion_frames
        self.settings = replace(self.settings, motion=name)
        self.view.status.text = f"loading motion {Path(name).name} ..."

        def job():
            from pipeline.playback import load_motion_for

            pb = self.playback
            is_kind = name in PROCEDURAL and not pb.project.path("motions", f"{name}.bvh").is_file()
            motion = load_motion_for(pb.project, name, frames=kind_frames if is_kind else frames)
            pb.set_motion(motion)
            n = pb.num_frames
            body = np.stack([pb.body_vertices(t) for t in range(n)])
            proxy = np.stack([pb.proxy_vertices(t) for t in range(n)])
            sim = pb.simulated_proxy()
            if sim is not None and len(sim) < n:
                sim = None
            faces = None
            if sim is not None:
                from core.mesh import load_mesh

                faces = load_mesh(pb.project.path("proxy", "positions.obj"))[0].faces
            return {
                "n": n,
                "fps": pb.fps,
                "body": body,
                "body_faces": pb.body_faces,
                "proxy": proxy,
                "proxy_faces": pb.proxy_faces,
                "proxy_uvs": pb.proxy_uvs,
                "sim": sim,
                "sim_edges": None if faces is None else unique_edges(faces),
                "name": motion.name,
                "j2c_ms": pb.joint2coarse_ms,
                "camera": pb.default_camera(0, 64, 64, azimuth_deg=20.0),
            }

        def done(r) -> None:
            self.pause()
            self.num_frames, self.fps = r["n"], r["fps"]
            self.body_frames, self.body_faces = r["body"], r["body_faces"]
            self.proxy_frames, self.proxy_faces = r["proxy"], r["proxy_faces"]
            self.proxy_uvs = r["proxy_uvs"]
            self.sim_frames, self.sim_edges = r["sim"], r["sim_edges"]
            self.motion_name = r["name"]
            sim = "simulation cache: yes" if r["sim"] is not None else "no simulation cache"
            self.view.motion_label.text = (
                f"{r['name']}: {r['n']} frames at {r['fps']:g} fps, Joint2Coarse "
                f"{r['j2c_ms']:.1f} ms/frame; {sim}"
            )
            self.view.show_sim.enabled = r["sim"] is not None
            if name in self._motion_items:
                self.view.motion_combo.selected_index = self._motion_items.index(name)
            self._enter_mode("play")
            pose = self.settings.camera_pose() if restore else None
            if pose is None:
                pose = pose_from_camera(r["camera"], 2.5)
            self.set_camera(pose.eye, pose.target, pose.up, pose.fov_deg)
            start = self.settings.frame if restore else 0
            self._show_frame(min(max(start, 0), self.num_frames - 1))
            self.view.status.text = f"motion {r['name']} ready"

        self.play_worker.submit(job, done, self._fail, key="motion")

    def _show_frame(self, t: int, render: bool = True) -> None:
        if not self.num_frames:
            return
        t = int(t) % self.num_frames
        self.frame = t
        v = self.view
        v.set_frame(t, self.num_frames, self.fps)
        if self.main_view() != "scene":
            # the 3D view is hidden: its meshes catch up when it is shown again
            self._scene_stale = True
            if render:
                self.render_now()
            return
        v.set_mesh("body", self.body_frames[t], self.body_faces, COLOURS["body"])
        v.set_mesh(
            "j2c", self.proxy_frames[t], self.proxy_faces, COLOURS["j2c"], uvs=self.proxy_uvs
        )
        if self.sim_frames is not None and self.settings.show_sim:
            v.set_lines("sim", self.sim_frames[t], self.sim_edges, COLOURS["sim_wire"])
        else:
            v.remove("sim")
        self._apply_visibility()
        if render:
            self.render_now()

    def play(self) -> None:
        if not self.num_frames:
            return
        self.playing = True
        self._play_start = (time.perf_counter(), self.frame)
        self.view.set_playing(True)

    def pause(self) -> None:
        self.playing = False
        self.view.set_playing(False)
        if self._shown_live is not None:
            self._show_live(*self._shown_live)
            self._shown_live = None

    def benchmark_live(self, frames: int = 20) -> None:
        """Time the live neural render on the playback worker (``frames`` consecutive frames
        from the current one, the 3D view's camera at the live render size, no drawing);
        the result lands in :attr:`live_benchmark` (frames, seconds, fps, size)."""
        if self.mode != "play" or not self.num_frames:
            self.show_error(InputError("load a motion of a trained project first"))
            return
        start, cam, n = self.frame, self.live_camera(), int(frames)

        def job():
            pb = self.playback
            pb.render(start, cam)  # warm up
            t0 = time.perf_counter()
            for i in range(n):
                pb.render((start + i) % pb.num_frames, cam)
            secs = time.perf_counter() - t0
            return {"frames": n, "seconds": secs, "fps": n / secs, "size": cam.width}

        def done(result) -> None:
            self.live_benchmark = result

        self.play_worker.submit(job, done, self._fail)

    def toggle_play(self) -> None:
        self.pause() if self.playing else self.play()

    def step(self, n: int = 1) -> None:
        self.pause()
        if self.num_frames:
            self._show_frame((self.frame + n) % self.num_frames)

    def seek(self, t: int) -> None:
        if self.num_frames and int(t) != self.frame:
            if self.playing:
                self._play_start = (time.perf_counter(), int(t))
            self._show_frame(int(t))

    # ------------------------------------------------------------------------ camera, live view

    def set_camera(self, eye, target, up=(0.0, 1.0, 0.0), fov: float | None = None) -> None:
        """Point the 3D view's camera (and so the live render) at ``target`` from ``eye``."""
        fov = fov or self.view.gl_matrices()[2] or 40.0
        self.view.look_at(eye, target, up, fov)
        self.render_now()

    def live_camera(self):
        """The 3D view's camera as a :class:`core.camera.Camera`: at the live render size
        (square) when the 3D view is shown, else at the neural viewport's render height with
        the view's aspect (half of it for each image of the comparison)."""
        view, proj, _ = self.view.gl_matrices()
        shown = self.main_view()
        if shown == "scene":
            size = self.settings.render_size
            return camera_from_gl(view, proj, size, size)
        w, h = self.view.main_size
        aspect = w / max(h, 1) / (2.0 if shown == "compare" else 1.0)
        return camera_from_gl(view, proj, *view_image_size(self.neural_height, aspect))

    def set_live_render(self, on: bool) -> None:
        self.settings = replace(self.settings, live_render=bool(on))
        self._update_main_view()
        self.render_now()

    def set_show_ground_truth(self, on: bool) -> None:
        self.settings = replace(self.settings, show_ground_truth=bool(on))
        self.render_now(force_reference=True)

    def set_render_size(self, size: int) -> None:
        self.settings = replace(self.settings, render_size=int(size))
        self.render_now(force_reference=True)

    def render_now(self, force_reference: bool = False) -> None:
        """Ask the playback worker for a live neural render of the current frame and view
        (the newest request replaces a waiting one)."""
        if (
            self.mode != "play"
            or not self.settings.live_render
            or not self.num_frames
            or self._live_disabled_reason
        ):
            return
        t = self._play_position() if self.playing else self.frame
        cam = self.live_camera()
        now = time.perf_counter()
        compare = self.main_view() == "compare"
        want_ref = compare or (
            self.settings.show_ground_truth
            and (
                force_reference
                or not self.playing
                or now - self._last_reference > REFERENCE_EVERY_S
            )
        )
        if want_ref:
            self._last_reference = now

        def job():
            pb = self.playback
            image = pb.render(t, cam)
            timings = dict(pb.last_timings)
            ref = pb.reference_image(t, cam) if want_ref else None
            return t, image, timings, ref

        self.play_worker.submit(job, self._rendered, self._render_failed, key="render")

    def _rendered(self, out) -> None:
        t, image, timings, ref = out
        self.live_image = image
        self.render_meter.tick()
        self.render_count += 1
        self.last_timings = timings
        ms = float(timings.get("total", 0.0))
        self._frame_ms = ms if self._frame_ms is None else 0.7 * self._frame_ms + 0.3 * ms
        now = time.perf_counter()
        if self.main_view() != "scene" and now - self._last_adapt > ADAPT_EVERY_S:
            self._last_adapt = now
            self.neural_height = adapt_render_height(
                self.neural_height, self._frame_ms, self.view.main_size[1], gpu=self.gpu
            )
        if ref is not None:
            self.reference_image, self.reference_label = ref
        if self.playing:
            # shown by the next play tick (at most LIVE_REDRAW_HZ); meanwhile keep rendering
            self._shown_live = (t, image, timings)
            self.render_now()
            return
        self._show_live(t, image, timings)

    def _show_live(self, t, image, timings) -> None:
        self.live_frames_shown += 1
        main = self.main_view()
        if main != "scene":
            pair = [image]
            ref = self.reference_image
            if main == "compare" and ref is not None and ref.shape == image.shape:
                pair.append(ref)
            self.neural_image = side_by_side(pair) if len(pair) > 1 else image
            self.view.set_image(self.view.neural, self.neural_image)
            w, h = self.view.main_size
            what = f"neural | {self.reference_label}" if len(pair) > 1 else "neural"
            self.view.neural_stats.text = (
                f"{what}  frame {t}: {image.shape[1]}x{image.shape[0]} px -> {w}x{h}, "
                f"{timings.get('total', 0):.0f} ms/frame, {self.render_meter.rate:.1f} fps"
                f"{' (GPU)' if self.gpu else ''}"
            )
        shown = [image]
        if self.settings.show_ground_truth and self.reference_image is not None:
            if self.reference_image.shape == image.shape:
                shown.append(self.reference_image)
        self.view.set_image(self.view.live_image, side_by_side(shown))
        ref_text = f" | {self.reference_label}" if len(shown) > 1 else ""
        self.view.live_label.text = (
            f"neural{ref_text}  frame {t}: {timings.get('total', 0):.0f} ms "
            f"(background {timings.get('background', 0):.0f}, raster+net "
            f"{timings.get('raster+network', 0):.0f}), {self.render_meter.rate:.1f} fps"
        )

    def _render_failed(self, exc: BaseException) -> None:
        self._live_disabled_reason = str(exc)
        self._update_main_view()
        self.view.live_label.text = "live render off: see the message"
        self.show_error(exc)

    # ------------------------------------------------------------------------ body shapes

    def set_body_param(self, name: str, value: float) -> None:
        self.settings = replace(self.settings, body={**self.settings.body, name: float(value)})

    def select_body(self, item: str) -> None:
        """Play on the project's body or a fine-tuned body sub-project's."""
        if self.project is None:
            return
        root = self.project if item == "project body" else self.project / "finetune" / item
        self._open_playback(root, motion=self.settings.motion)

    def finetune_body(self) -> None:
        if self.project is None:
            self.show_error(InputError("open a trained project first"))
            return
        try:
            shape = self.settings.body_shape()
        except InputError as exc:
            self.show_error(exc)
            return
        name = "-".join(f"{k}{v:g}" for k, v in sorted(self.settings.body.items())) or "default"
        root = self.project

        def run(project, config, log, progress):
            from pipeline.finetune import finetune_body_shape

            return finetune_body_shape(root, shape, name, log=log, progress=False)

        self._start_job(f"fine-tune body {name}", [("fine-tune body", run)], refresh=True)

    def finetune_background(self, image_path: str) -> None:
        if self.project is None:
            self.show_error(InputError("open a trained project first"))
            return
        root, path = self.project, Path(image_path)

        def run(project, config, log, progress):
            from core.compositing import load_image
            from pipeline.finetune import finetune_background_images

            result = finetune_background_images(root, [path], path.stem, log=log, progress=False)
            return result, load_image(path)

        def after(out) -> None:
            result, image = out
            self.view.finetune_label.text = f"background model: {result.model_path}"
            self._open_playback(root, renderer_path=result.model_path, backdrop=image)

        self._start_job("fine-tune background", [("fine-tune background", run)], after=after)

    # ------------------------------------------------------------------------ pipeline jobs

    def run_pipeline(self, which: str) -> None:
        """Run pipeline stages (``simulate``, ``dataset``, ``joint2coarse``, ``renderer``,
        ``all``, or ``setup``: motions, garment, proxy) on the open project."""
        if self.project is None:
            self.show_error(InputError("open a project first"))
            return
        if self.job_running:
            self.show_error(InputError("a job is already running: cancel it first"))
            return
        from core.project import Project
        from pipeline.config import project_config

        try:
            config = project_config(Project(self.project))
            if which == "setup":
                jobs = pipeline_jobs(config, "all")[:3]
            else:
                jobs = pipeline_jobs(config, which)
        except InputError as exc:
            self.show_error(exc)
            return
        self.job_config = config
        trains = which in ("joint2coarse", "renderer", "all", "setup")
        self._start_job(which, [(j.label, j.run) for j in jobs], refresh=trains)

    def _start_job(self, name: str, steps: list, refresh: bool = False, after=None) -> None:
        from core.project import Project

        project = Project(self.project)
        config = self.job_config
        token = CancelToken()
        eta = Eta(len(steps))
        self.job_token, self.job_eta, self.job_running = token, eta, True
        self.job_log = []
        self.job_name = name
        self.view.job_label.text = f"{name}: starting"

        def log(message: str) -> None:
            self.job_log.append(message.strip())
            token.check()

        def progress(done: int, total: int) -> None:
            eta.update(done, total)
            token.check()

        def job():
            results = []
            for label, run in steps:
                token.check()
                self.job_label = label
                results.append(run(project, config, log, progress))
                eta.stage_done()
            return results[-1] if results else None

        def done(result) -> None:
            self.job_running = False
            self.last_job_result = result
            self._update_job_widgets(final=f"{name}: done")
            if after is not None:
                after(result)
            elif refresh and self.project is not None:
                self._fill_body_list()
                self._open_playback(self.project)

        def failed(exc: BaseException) -> None:
            self.job_running = False
            self._update_job_widgets(
                final=f"{name}: cancelled" if isinstance(exc, Cancelled) else f"{name}: failed"
            )
            self.show_error(exc)

        self.job_worker.submit(job, done, failed, key="job")

    def cancel(self) -> None:
        """Stop the running job at its next progress report (simulation frames) or between
        stages; a stage stopped half way leaves no record, so it runs again next time."""
        if self.job_token is not None and self.job_running:
            self.job_token.cancel()
            self.view.job_label.text = f"cancelling {self.job_label} ..."

    def _stage_steps(self, label: str) -> int | None:
        from pipeline.config import joint2coarse_config, renderer_config

        try:
            if label == "joint2coarse":
                c = joint2coarse_config(self.job_config)
                return c.autoencoder_steps + c.motion_steps + c.finetune_steps
            if label == "renderer":
                return int(renderer_config(self.job_config).steps)
        except Exception:  # noqa: BLE001 - progress is best effort
            return None
        return None

    def _update_job_widgets(self, final: str | None = None) -> None:
        eta, v = self.job_eta, self.view
        if eta is None:
            return
        if self.job_running and self.job_label in ("joint2coarse", "renderer"):
            total = self._stage_steps(self.job_label)
            step = _last_step(training_logs(self.project)[self.job_label])
            if total and step is not None:
                eta.update(step, total)
        v.progress.value = 1.0 if final and "done" in final else eta.progress
        v.job_label.text = final or (
            f"{self.job_name}: {self.job_label} ({eta.done_stages + 1}/{eta.stages}), "
            f"{eta.progress:.0%}, about {format_seconds(eta.seconds_left())} left"
        )
        v.log_label.text = "\n".join(self.job_log[-3:])[-300:]
        now = time.perf_counter()
        if final or now - self._last_plot > 1.0:
            self._last_plot = now
            root = self.project

            def plots():
                loss = loss_plot(training_logs(root), 220, 140)
                preview = latest_preview(root)
                prev = None
                if preview is not None:
                    from PIL import Image

                    with Image.open(preview) as im:
                        im = im.convert("RGB")
                        im.thumbnail((220, 140))
                        prev = np.asarray(im)
                return loss, prev

            def show(out) -> None:
                loss, prev = out
                if loss is not None:
                    v.set_image(v.loss_image, loss)
                if prev is not None:
                    v.set_image(v.preview_image, prev)

            self.misc_worker.submit(plots, show, self._fail, key="plots")

    # ------------------------------------------------------------------------ export

    def add_path_key(self) -> None:
        """Key the 3D view's camera at the current frame (a key already there is replaced)."""
        key = {**self.current_pose().as_dict(), "frame": int(self.frame)}
        keys = [k for k in self.settings.camera_path if k.get("frame") != key["frame"]]
        keys = sorted([*keys, key], key=lambda k: k.get("frame", 0))
        self.settings = replace(self.settings, camera_path=keys)
        self._update_path_label()

    def clear_path(self) -> None:
        self.settings = replace(self.settings, camera_path=[])
        self._update_path_label()

    def _update_path_label(self) -> None:
        keys = self.settings.path_keys()
        frames = ", ".join(f"{k.frame:g}" for k in keys)
        self.view.path_label.text = (
            f"camera path: {len(keys)} key(s) at frame(s) {frames}"
            if keys
            else "camera path: orbit (no key views)"
        )

    def set_export_frames(self, n: int) -> None:
        self.settings = replace(self.settings, export_frames=int(n))

    def set_export_reference(self, on: bool) -> None:
        self.settings = replace(self.settings, export_reference=bool(on))

    def save_camera_path(self, path: str) -> Path:
        """Write the keyed camera path as JSON (what ``dng render --camera PATH.json`` reads)."""
        from core.camera import camera_path_to_dict
        from core.fileio import write_json

        keys = self.settings.path_keys()
        if not keys:
            raise InputError("the camera path is empty: add a key view first")
        out = Path(path)
        write_json(out, camera_path_to_dict(keys))
        self.view.export_label.text = f"wrote {out}"
        return out

    def export_video(self, path: str, size: int | None = None) -> None:
        """Neural renders from the current frame on (``export_frames`` frames) along the keyed
        camera path (an orbit when there are no keys), the reference beside them when
        ``export_reference`` is set, written as MP4 or GIF (by the suffix) atomically. The
        export label shows progress and time left; :meth:`cancel_export` stops it and leaves
        no file."""
        from core.camera import path_cameras
        from pipeline.playback import FrameWriter

        if not self.num_frames:
            self.show_error(InputError("load a motion of a trained project first"))
            return
        n = self.settings.export_frames
        size = size or max(self.settings.render_size, 128)
        keys = self.settings.path_keys()
        start, fps = self.frame, self.settings.export_fps
        beside = self.settings.export_reference
        out = Path(path)
        if out.suffix.lower() not in (".gif", ".mp4"):
            out = out.with_suffix(".mp4")
        frames = [(start + i) % self.num_frames for i in range(n)]
        cams = path_cameras(keys, frames, size, size) if keys else None
        token, eta = CancelToken(), Eta(1)
        self.export_token = token
        self.view.export_label.text = f"exporting {n} frames to {out.name} ..."

        def progress(done: int) -> None:
            eta.update(done, n)
            left = format_seconds(eta.seconds_left())
            self.view.export_label.text = (
                f"exporting {out.name}: {done}/{n} frames, {eta.progress:.0%}, about {left} left"
            )
            self.view.export_progress.value = eta.progress

        def job():
            pb = self.playback
            with FrameWriter(out, fps) as writer:
                for i, t in enumerate(frames):
                    token.check()
                    cam = (
                        cams[i]
                        if cams is not None
                        else pb.default_camera(t, size, size, azimuth_deg=360.0 * i / n)
                    )
                    image = pb.render(t, cam)
                    if beside:
                        image = side_by_side([image, pb.reference_image(t, cam)[0]])
                    writer.append(image)
                    self.post(lambda d=i + 1: progress(d))
            return out

        def done(p) -> None:
            self.export_token = None
            self.view.export_progress.value = 1.0
            self.view.export_label.text = f"wrote {p}"

        def failed(exc: BaseException) -> None:
            self.export_token = None
            if isinstance(exc, Cancelled):
                self.view.export_label.text = f"export cancelled: {out.name} not written"
                return
            self._fail(exc)

        self.play_worker.submit(job, done, failed)

    #: The export button of older scripts: an animated GIF along the path.
    def export_gif(self, path: str, size: int | None = None) -> None:
        self.export_video(str(Path(path).with_suffix(".gif")), size)

    def cancel_export(self) -> None:
        """Stop a running video export before its next frame (no file is written)."""
        if self.export_token is not None:
            self.export_token.cancel()

    def export_proxy(self, path: str) -> None:
        """Write the derived proxy (with its UVs) as OBJ."""
        if self.proxy_result is None:
            self.show_error(InputError("derive a proxy first (Garment tab)"))
            return
        from core.mesh import save_mesh

        out = Path(path)
        if out.suffix.lower() != ".obj":
            out = out.with_suffix(".obj")
        save_mesh(out, self.proxy_result.proxy)
        self.view.export_label.text = f"wrote {out}"

    # ------------------------------------------------------------------------ screenshots

    def screenshot(self, path: str | os.PathLike) -> Path:
        """Save the whole window, panels included, as PNG.

        The window's rectangle is read from the X server by Pillow's own XCB client (no outside
        program); ``$DISPLAY`` is passed explicitly so that Pillow never falls back to running a
        desktop screenshot tool. Open3D's ``render_to_image`` would give the 3D view only.
        """
        self.wait_idle()
        for _ in range(3):  # let slow software frames (first use of a shader) reach the screen
            self.view.redraw()
            self.pump(1.0)
        self.wait_idle()
        display = os.environ.get("DISPLAY")
        if not display:
            raise InputError("a screenshot needs an X display: DISPLAY is not set")
        f = self.view.window.os_frame
        image = ImageGrab.grab(bbox=(f.x, f.y, f.x + f.width, f.y + f.height), xdisplay=display)
        out = Path(path)
        with atomic_path(out) as tmp:
            image.save(tmp, format="PNG")
        return out


def _wrap(text: str, width: int = 70) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width)) or text


def _last_step(path: Path) -> int | None:
    """The step of the last row of a CSV loss log (None when there is none)."""
    try:
        with open(path, "rb") as f:
            f.seek(0, 2)
            f.seek(max(f.tell() - 512, 0))
            last = f.read().decode("utf-8", "replace").strip().splitlines()[-1]
        return int(last.split(",")[0])
    except (OSError, IndexError, ValueError):
        return None
