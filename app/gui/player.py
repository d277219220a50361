"""The main area's controller: the 3D view, the neural viewport, the timeline and the live
neural render, all on one frame of one motion seen through one camera.

:class:`Player` holds what is playing (the motion's per-frame body, Joint2Coarse proxy and
simulated proxy, predicted by the Motion tab), the play clock, the camera both views share and
the live render requests to the playback worker. The viewer meets the renderer through one call,
``Playback.render(t, camera)`` (STYLE #9), always on the ``playback`` worker.
"""

from __future__ import annotations

import os
import time
from dataclasses import replace

import numpy as np
import open3d.visualization.gui as gui

from app.gui.model import (
    CPU_RENDER_HEIGHTS,
    MIN_SHOWN_SHARE,
    PLAY_SPEEDS,
    RENDER_SIZES,
    CameraPose,
    RateMeter,
    adapt_render_height,
    camera_from_gl,
    framing_pose,
    pose_from_camera,
    shown_share,
    side_by_side,
    view_image_size,
)
from app.gui.part import Part
from app.gui.window import COLOURS
from core.camera import dolly_view, orbit_view, pan_view
from core.errors import InputError

#: While playing, the 3D view is redrawn at most this often (frames per second). Filament
#: draws every frame it is given and never drops one; under software Vulkan (Mesa lavapipe)
#: a frame of the playback scene costs 0.1-0.3 s on 2 busy cores, and frames
#: asked for faster than that queue up: 20 s of play at 15 Hz left 127 s of frames to draw,
#: paid at the next dialog. No fence is possible from Python without a callback inside
#: Open3D's tick, which stalls (see :mod:`app.gui.controller`). Neural renders run as fast as
#: the playback worker makes them; the newest is shown. ``DNG_GUI_PLAY_HZ`` overrides it (a GPU
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


class Player(Part):
    """The main area and the timeline: view mode, visibility, play clock, camera, live render.

    ``studio`` is the :class:`app.gui.controller.Studio` it belongs to (settings, view,
    workers). State written on the main thread only, but :attr:`playback`, which the Motion
    tab's loading job sets on the playback worker and only that worker uses.
    """

    def __init__(self, studio):
        super().__init__(studio)
        self.mode = "garment"  # "garment" (Garment tab's scene) or "play" (a motion)
        # the project's trained networks (pipeline.playback.Playback): playback worker only
        self.playback = None
        self.gpu = False  # the playback worker renders on CUDA
        self.live_disabled_reason = ""
        # the motion
        self.num_frames = 0
        self.fps = 30.0
        self.frame = 0
        self.playing = False
        self.play_when_loaded = False  # ``dng gui --play``: play the first motion loaded
        self._play_start = (0.0, 0)
        self.body_frames = None
        self.body_faces = None
        self.proxy_frames = None
        self.proxy_faces = None
        self.proxy_uvs = None
        self.sim_frames = None
        self.sim_edges = None
        self.motion_name = ""
        # the live render
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
        self.play_frames_shown = 0  # 3D-view frames shown while playing (tests, benchmarks)
        self.live_frames_shown = 0  # live neural renders put on the screen
        self._shown_live = None  # newest live render not shown yet (while playing)
        # the neural viewport (main area)
        self.neural_height = CPU_RENDER_HEIGHTS[0]
        self.neural_image: np.ndarray | None = None  # the newest image shown there
        self._frame_ms: float | None = None  # smoothed ms per neural render
        self._last_adapt = 0.0
        self._scene_stale = False  # the 3D view's meshes lag the frame (hidden meanwhile)
        self._followed: np.ndarray | None = None  # the body's floor centre the camera follows

    def apply_settings(self) -> None:
        """Put the settings into the timeline's and the live panel's widgets."""
        s, v = self.settings, self.view
        v.live_check.checked = s.live_render
        v.gt_check.checked = s.show_ground_truth
        if s.render_size in RENDER_SIZES:
            v.size_combo.selected_index = RENDER_SIZES.index(s.render_size)
        if s.play_speed in PLAY_SPEEDS:
            v.speed_combo.selected_index = PLAY_SPEEDS.index(s.play_speed)
        v.loop_check.checked = s.loop
        v.show_target.checked = s.show_target
        v.show_wire.checked = s.show_wireframe
        v.show_proxy.checked = s.show_proxy
        v.show_body.checked = s.show_body
        v.show_sim.checked = s.show_sim

    # ------------------------------------------------------------------ the play clock

    def tick(self, now: float) -> bool:
        """Show the play clock's frame at most ``PLAY_REDRAW_HZ`` times a second and the
        newest live render at most ``LIVE_REDRAW_HZ`` times a second (from the studio's
        service, between Open3D ticks). True when something shown changed (the window needs a
        redraw)."""
        if not (self.playing and self.num_frames):
            return False
        if not self.settings.loop and self.play_position() >= self.num_frames - 1:
            self.show_frame(self.num_frames - 1)
            self.pause()
            return True
        changed = False
        neural = self.main_view() != "scene"
        if neural or now - self._last_redraw >= 1.0 / PLAY_REDRAW_HZ:
            t = self.play_position()
            if t != self.frame:
                self._last_redraw = now
                self.show_frame(t)
                self.play_frames_shown += 1
                changed = True
        if self._shown_live is not None and now - self._last_live >= 1.0 / LIVE_REDRAW_HZ:
            self._last_live = now
            self._show_live(*self._shown_live)
            self._shown_live = None
            changed = True
        return changed

    def play_position(self) -> int:
        """The frame the play clock is at now (at the play speed; looping, or held on the
        last frame)."""
        elapsed = time.perf_counter() - self._play_start[0]
        t = self._play_start[1] + int(elapsed * self.fps * self.settings.play_speed)
        n = max(self.num_frames, 1)
        return t % n if self.settings.loop else min(t, n - 1)

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

    def toggle_play(self) -> None:
        self.pause() if self.playing else self.play()

    def step(self, n: int = 1) -> None:
        self.pause()
        if self.num_frames:
            self.show_frame((self.frame + n) % self.num_frames)

    def seek(self, t: int) -> None:
        if self.num_frames and int(t) != self.frame:
            if self.playing:
                self._play_start = (time.perf_counter(), int(t))
            self.show_frame(int(t))

    def set_play_speed(self, speed: float) -> None:
        if self.playing:
            self._play_start = (time.perf_counter(), self.frame)
        self.set(play_speed=float(speed))

    def set_loop(self, on: bool) -> None:
        self.set(loop=bool(on))

    # ------------------------------------------------------------------ what is shown

    def main_view(self) -> str:
        """What the main area shows now: ``scene`` in the garment mode or without a trained
        renderer, else the chosen view mode (``neural``, ``scene``, ``compare``)."""
        if self.mode != "play" or self.live_disabled_reason or not self.settings.live_render:
            return "scene"
        return self.settings.view_mode

    def set_view_mode(self, mode: str) -> None:
        """Show the neural render (``neural``), the 3D scene (``scene``) or the neural render
        beside the reference (``compare``) in the main area."""
        if mode not in ("neural", "scene", "compare"):
            raise InputError(f"unknown view mode {mode!r}")
        self.set(view_mode=mode)
        self.update_main_view()
        self.render_now(force_reference=True)

    def update_main_view(self) -> None:
        shown = self.main_view()
        if shown == "scene" and self._scene_stale:
            self._scene_stale = False
            self.show_frame(self.frame, render=False)
        self.view.show_view_mode(shown)

    def set_visibility(self, **flags) -> None:
        """Show or hide parts of the 3D view (``show_target``, ``show_wireframe``,
        ``show_proxy``, ``show_body``, ``show_sim``); the Garment and Motion tabs' boxes."""
        self.set(**flags)
        v = self.view
        for key, box in (
            ("show_target", v.show_target),
            ("show_wireframe", v.show_wire),
            ("show_proxy", v.show_proxy),
            ("show_body", v.show_body),
            ("show_sim", v.show_sim),
        ):
            box.checked = bool(getattr(self.settings, key))
        self.apply_visibility()
        if "show_sim" in flags and self.mode == "play":
            self.show_frame(self.frame)

    def enter_mode(self, mode: str) -> None:
        """``garment``: the Garment tab's target, wireframes and rest body; ``play``: the
        motion's body, Joint2Coarse proxy and simulated proxy."""
        self.mode = mode
        self.apply_visibility()
        self.update_main_view()

    def apply_visibility(self) -> None:
        s, v = self.settings, self.view
        garment = self.mode == "garment"
        v.show("target", garment and s.show_target)
        v.show("target_wire", garment and s.show_wireframe)
        v.show("proxy_wire", garment and s.show_proxy)
        v.show("rest_body", garment and s.show_body)
        v.show("body", not garment and s.show_body)
        v.show("j2c", not garment and s.show_proxy)
        v.show("sim", not garment and s.show_sim)

    def set_motion(self, r: dict, restore: bool = False) -> None:
        """Play what the Motion tab loaded: ``r`` holds the frame count ``n``, ``fps``, the
        per-frame ``body`` (n, Vb, 3) and ``proxy`` (n, Vp, 3) float32 vertices with their
        faces, the proxy's ``proxy_uvs``, ``sim`` (n, Vs, 3) or None with ``sim_edges`` and the
        motion's ``name``. ``restore``: the saved camera (kept while it shows the body or the
        garment) and frame; otherwise the camera frames both."""
        self.pause()
        self.num_frames, self.fps = r["n"], r["fps"]
        self.body_frames, self.body_faces = r["body"], r["body_faces"]
        self.proxy_frames, self.proxy_faces = r["proxy"], r["proxy_faces"]
        self.proxy_uvs = r["proxy_uvs"]
        self.sim_frames, self.sim_edges = r["sim"], r["sim_edges"]
        self.motion_name = r["name"]
        self.enter_mode("play")
        self._followed = None
        start = min(max(self.settings.frame if restore else 0, 0), self.num_frames - 1)
        pose = self.settings.camera_pose() if restore else None
        if pose is not None and not self._shows_subject(pose, start):
            self.view.status.text = "the saved camera showed neither body nor garment: view reset"
            pose = None
        if pose is None:
            pose = self.framing(start)
        self.set_camera(pose.eye, pose.target, pose.up, pose.fov_deg)
        self.show_frame(start)
        if self.play_when_loaded:
            self.play_when_loaded = False
            self.play()

    def main_aspect(self) -> float:
        """Width over height of the image the main area shows (half of it for each image of
        the comparison)."""
        w, h = self.view.main_size
        return w / max(h, 1) / (2.0 if self.main_view() == "compare" else 1.0)

    def framing(self, t: int) -> CameraPose:
        """The pose that frames the body and the garment (Joint2Coarse's proxy) at frame
        ``t`` in the main area."""
        points = np.concatenate([self.body_frames[t], self.proxy_frames[t]])
        fov = self.view.gl_matrices()[2] or 40.0
        return framing_pose(points, self.main_aspect(), fov_deg=fov)

    def _shows_subject(self, pose: CameraPose, t: int) -> bool:
        aspect = self.main_aspect()
        return (
            max(
                shown_share(pose, self.body_frames[t], aspect),
                shown_share(pose, self.proxy_frames[t], aspect),
            )
            >= MIN_SHOWN_SHARE
        )

    def reset_view(self) -> None:
        """Frame the body and the garment at the current frame ("Reset view", key R); in the
        garment mode, the Garment tab's garment and rest body."""
        if self.mode == "play" and self.num_frames:
            pose = self.framing(self.frame)
            self.set_camera(pose.eye, pose.target, pose.up, pose.fov_deg)
        else:
            self.studio.garment_tab.frame_view()

    def show_frame(self, t: int, render: bool = True) -> None:
        if not self.num_frames:
            return
        t = int(t) % self.num_frames
        self.frame = t
        self._follow(t)
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
        self.apply_visibility()
        if render:
            self.render_now()

    # ------------------------------------------------------------------ the camera

    def _follow(self, t: int) -> None:
        """Move the camera with the body's travel over the floor (x, z of its bounding box's
        centre) since the last frame shown, so that a dance that crosses the room stays in
        view; the user's orbit, pan and zoom are kept relative to the body."""
        box = self.body_frames[t]
        centre = 0.5 * (box.min(0) + box.max(0)) * np.array([1.0, 0.0, 1.0])
        if self._followed is not None and np.any(centre != self._followed):
            shift = centre - self._followed
            pose = self.current_pose()
            self.view.look_at(
                np.add(pose.eye, shift), np.add(pose.target, shift), pose.up, pose.fov_deg
            )
        self._followed = centre

    def on_mouse(self, event) -> object:
        """Camera moves in the 3D view re-render the live view (after Open3D moved it)."""
        if event.type in (
            gui.MouseEvent.Type.DRAG,
            gui.MouseEvent.Type.WHEEL,
            gui.MouseEvent.Type.BUTTON_UP,
        ):
            self.view.scene_changed()  # Open3D moves the camera: render the 3D view anew
            self.studio.post(self._camera_moved)
        return gui.Widget.EventCallbackResult.IGNORED

    def _camera_moved(self) -> None:
        view = self.view.gl_matrices()[0]
        if self._last_view is None or not np.allclose(view, self._last_view, atol=1e-7):
            self._last_view = view
            self.render_now()

    def set_camera(self, eye, target, up=(0.0, 1.0, 0.0), fov: float | None = None) -> None:
        """Point the 3D view's camera (and so the live render) at ``target`` from ``eye``."""
        fov = fov or self.view.gl_matrices()[2] or 40.0
        self.view.look_at(eye, target, up, fov)
        self.render_now()

    def current_pose(self) -> CameraPose:
        """The 3D view's viewpoint as a :class:`CameraPose`."""
        view, proj, fov = self.view.gl_matrices()
        cam = camera_from_gl(view, proj, 64, 64)
        centre = np.asarray(self.view.scene.center_of_rotation, np.float64)
        distance = float(np.linalg.norm(cam.center - centre)) or 2.5
        return replace(pose_from_camera(cam, distance), fov_deg=fov)

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

    def live_camera(self):
        """The 3D view's camera as a :class:`core.camera.Camera`: at the live render size
        (square) when the 3D view is shown, else at the neural viewport's render height with
        the view's aspect (half of it for each image of the comparison)."""
        view, proj, _ = self.view.gl_matrices()
        if self.main_view() == "scene":
            size = self.settings.render_size
            return camera_from_gl(view, proj, size, size)
        size = view_image_size(self.neural_height, self.main_aspect())
        return camera_from_gl(view, proj, *size)

    # ------------------------------------------------------------------ the live render

    def set_live_render(self, on: bool) -> None:
        self.set(live_render=bool(on))
        self.update_main_view()
        self.render_now()

    def set_show_ground_truth(self, on: bool) -> None:
        self.set(show_ground_truth=bool(on))
        self.render_now(force_reference=True)

    def set_render_size(self, size: int) -> None:
        self.set(render_size=int(size))
        self.render_now(force_reference=True)

    def render_now(self, force_reference: bool = False) -> None:
        """Ask the playback worker for a live neural render of the current frame and view
        (the newest request replaces a waiting one)."""
        if (
            self.mode != "play"
            or not self.settings.live_render
            or not self.num_frames
            or self.live_disabled_reason
        ):
            return
        t = self.play_position() if self.playing else self.frame
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

        self.studio.play_worker.submit(job, self._rendered, self._render_failed, key="render")

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
        self.live_disabled_reason = str(exc)
        self.update_main_view()
        self.view.live_label.text = "live render off: see the message"
        self.studio.show_error(exc)

    def benchmark_live(self, frames: int = 20) -> None:
        """Time the live neural render on the playback worker (``frames`` consecutive frames
        from the current one, the 3D view's camera at the live render size, no drawing);
        the result lands in :attr:`live_benchmark` (frames, seconds, fps, size)."""
        if self.mode != "play" or not self.num_frames:
            self.studio.show_error(InputError("load a motion of a trained project first"))
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

        self.studio.play_worker.submit(job, done, self.studio.show_error)
