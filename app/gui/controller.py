"""The studio's controller: :class:`Studio` composes one controller per part of the window and
runs the main loop.

- :class:`app.gui.player.Player`: the main area (3D view, neural viewport, comparison), the
  timeline and the live neural render;
- :class:`app.gui.tabs.garment.GarmentTab`, :class:`~app.gui.tabs.motion.MotionTab`,
  :class:`~app.gui.tabs.pipeline.PipelineTab`, :class:`~app.gui.tabs.export.ExportTab`: the
  four tabs, each owning its widgets' callbacks and the work it starts.

The model is :mod:`app.gui.model` (settings and logic, no GUI import); the view is
:class:`app.gui.window.StudioWindow`, whose widgets call the part they belong to. The studio
holds what they share: the settings, the open project, the worker threads, the inbox and the
errors shown.

Threads (STYLE #8): widgets are touched only on the main thread. Work runs on four workers:

- ``proxy``: garment loading and proxy derivation (slider changes coalesce: the last wins);
- ``playback``: every call into :class:`pipeline.playback.Playback` (it is not thread-safe):
  loading, motions, live neural renders (coalesced: the newest camera/frame wins), exports;
- ``jobs``: pipeline stages (simulation, data set, training), fine-tuning (a body, a
  background, a light); cancellable;
- ``plots``: loss-curve and preview pictures of a running job; the light picker's
  environment images, read before they are offered.

Results come back through :meth:`Studio.post` into an inbox that the main loop
(:meth:`Studio.run_loop`: ``run_one_tick`` then :meth:`Studio.service`) empties between ticks;
the play clock runs there too. Nothing calls back into Python from inside Open3D's tick but
input events: under software Vulkan, geometry and widget updates made from callbacks that
Open3D runs inside its tick (``post_to_main_thread``, ``set_on_tick_event``) stalled the window
for 5-230 s whenever another thread held the GIL (a live render, a proxy derivation); the
same updates made between ticks did not (docs/gui.md). The viewer meets the renderer through
one call, ``Playback.render(t, camera)`` (STYLE #9).

Driver API (tests, the tour, scripts): the parts' public methods (``studio.garment_tab.
load_garment``, ``studio.player.play``, ``studio.export_tab.export_video``, ...), and here
:meth:`Studio.open_project`, :meth:`Studio.save_settings`, :meth:`Studio.screenshot`, with
:meth:`Studio.wait_idle` / :meth:`Studio.pump` to let the event loop run in between.
"""

from __future__ import annotations

import os
import queue
import textwrap
import threading
import time
import traceback
from dataclasses import replace
from pathlib import Path

import open3d.visualization.gui as gui
from PIL import ImageGrab

from app.gui.model import Cancelled, GuiSettings, process_age
from app.gui.model import save_settings as write_settings
from app.gui.player import LIVE_REDRAW_HZ, PLAY_REDRAW_HZ, Player
from app.gui.tabs.export import ExportTab
from app.gui.tabs.garment import GarmentTab
from app.gui.tabs.motion import MotionTab
from app.gui.tabs.pipeline import PipelineTab
from app.gui.window import StudioWindow
from app.gui.workers import Worker
from core.errors import InputError
from core.fileio import atomic_path

#: Play-clock / job-progress updates per second at most (in :meth:`Studio.service`).
TICK_HZ = 30


class Studio:
    """The garment studio window: its parts, their shared state and the main loop."""

    def __init__(self, project: str | os.PathLike | None = None, width=1500, height=940):
        self.app = gui.Application.instance
        self.settings = GuiSettings()
        self.project: Path | None = None
        self.closed = False
        self._lock = threading.Lock()
        self._inbox: queue.SimpleQueue = queue.SimpleQueue()  # main-thread work (post)
        self._pending = 0
        self._last_tick = 0.0
        self._needs_redraw = True
        self._last_redraw = 0.0
        self.redraws = 0  # window redraws asked for by :meth:`service` (tests read it)
        self.errors: list[str] = []  # every error shown (tests read it)
        self.open_seconds: float | None = None
        # the parts (the view's widgets call them, so they exist before it)
        self.player = Player(self)
        self.garment_tab = GarmentTab(self)
        self.motion_tab = MotionTab(self)
        self.pipeline_tab = PipelineTab(self)
        self.export_tab = ExportTab(self)
        self.view = StudioWindow(self, width, height)
        self.proxy_worker = Worker(self.post, "proxy")
        self.play_worker = Worker(self.post, "playback")
        self.job_worker = Worker(self.post, "jobs")
        self.misc_worker = Worker(self.post, "plots")

        self.apply_settings()
        self.post(self._mark_open)
        self.view.scene.set_on_mouse(self.player.on_mouse)
        self.garment_tab.show_mannequin()
        if project is not None:
            self.open_project(project)
        else:
            self.garment_tab.load_garment(self.settings.garment)

    @property
    def workers(self) -> tuple[Worker, ...]:
        return (self.proxy_worker, self.play_worker, self.job_worker, self.misc_worker)

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
            self._needs_redraw = True  # a result changes widgets or the scene
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
        if self.closed:
            return
        if now - self._last_tick >= 1.0 / TICK_HZ:
            self._last_tick = now
            if self.player.tick(now):
                self._needs_redraw = True
            if self.pipeline_tab.job_running:
                before = (self.view.job_label.text, self.view.progress.value)
                self.pipeline_tab.update_widgets()
                if (self.view.job_label.text, self.view.progress.value) != before:
                    self._needs_redraw = True
            if self.garment_tab.loading is not None:
                what, since = self.garment_tab.loading
                text = f"{what} ... {now - since:.0f} s"
                if text != self.view.status.text:
                    self.view.status.text = text
                    self._needs_redraw = True
        # A redraw that renders the 3D view anew is paced at PLAY_REDRAW_HZ (Filament draws
        # every frame it is asked for, and a software 3D frame costs 0.1-0.6 s); one that only
        # changes widgets and images, at LIVE_REDRAW_HZ.
        scene_frame = self.view.scene_dirty and self.player.main_view() == "scene"
        hz = PLAY_REDRAW_HZ if scene_frame else LIVE_REDRAW_HZ
        if self._needs_redraw and now - self._last_redraw >= 1.0 / hz:
            self._needs_redraw = False
            self._last_redraw = now
            self.redraws += 1
            self.view.redraw()

    def run_loop(self) -> None:
        """The window's main loop (``dng gui``): Open3D's tick, then :meth:`service`, until
        the window is closed."""
        while self.app.run_one_tick():
            self.service()

    def _mark_open(self) -> None:
        self.open_seconds = process_age()

    @property
    def idle(self) -> bool:
        with self._lock:
            pending = self._pending
        return pending == 0 and all(w.idle for w in self.workers)

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

    # ------------------------------------------------------------------ errors

    def show_error(self, exc: BaseException) -> None:
        """A dialog naming the problem (an :class:`InputError`'s message; other errors with
        their type); the window stays usable. A cancelled job only says so."""
        if isinstance(exc, Cancelled):
            self.view.status.text = "cancelled"
            return
        if isinstance(exc, InputError):
            title, message = "Problem", str(exc)
        else:
            title, message = "Error", f"{type(exc).__name__}: {exc}"
        self.errors.append(message)
        self.view.status.text = f"error: {message}"[:120]
        self.view.show_error(title, textwrap.fill(message, 70) or message)

    # ------------------------------------------------------------------ project and settings

    def open_project(self, path: str | os.PathLike) -> None:
        """Open a project folder (the Motion tab's "Open project...")."""
        self.motion_tab.open_project(path)

    def apply_settings(self) -> None:
        """Put :attr:`settings` into every part's widgets."""
        for part in (self.player, self.garment_tab, self.motion_tab, self.export_tab):
            part.apply_settings()

    def save_settings(self) -> None:
        """Write the window's settings into the project's ``project.json`` (key ``gui``)."""
        if self.project is None:
            self.view.status.text = "no project open: settings are not saved"
            return
        self.settings = replace(
            self.settings,
            camera=self.player.current_pose().as_dict(),
            frame=int(self.player.frame),
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
        for w in self.workers:
            w.stop()
        if self.pipeline_tab.job_token is not None:
            self.pipeline_tab.job_token.cancel()
        return True

    # ------------------------------------------------------------------ screenshots

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
