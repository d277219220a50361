"""``dng gui PROJECT --tour DIR``: drive the studio through its main flow with the driver API,
save a screenshot of each step and the measurements into ``DIR/tour.json``, then exit.

The GUI tests run it in a subprocess (under Xvfb) and check what it wrote; the screenshots in
``docs/`` come from it. Steps: open the window (timed), load a built-in garment, derive the
proxy and change its texture size (atlas only), an error dialog, open the project, load a
motion, the neural viewport (a drag, a scrub, play, the comparison view), relighting (a bad
environment image, an environment image, a preset; a fine-tune of ``RELIGHT_STEPS`` steps, the
relit render beside the reference under the same light), live neural render from two cameras, continuous play in the 3D view (with a screenshot after it), stepping frames
and the live render's frame rate at 128 px (on its worker), the simulated proxy beside
Joint2Coarse, camera keys at two frames with MP4 and GIF export along them, a cancelled export,
the path as JSON, OBJ export, settings saved and read back.
"""

from __future__ import annotations

import faulthandler
import json
import os
import signal
import sys
import time
import traceback
from pathlib import Path

import numpy as np

from app.gui import start_application
from app.gui.model import CameraPose, camera_from_gl, load_settings

#: Seconds of continuous play in the tour.
PLAY_SECONDS = 4.0
#: Steps of the tour's relighting fine-tune (the studio's default is 100).
RELIGHT_STEPS = 2
#: The light preset the tour fine-tunes to.
RELIGHT_PRESET = "low-sun"


def _png(path: Path, image: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(np.ascontiguousarray(image)).save(path)


def _mean_diff(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute difference of two images (the second resized to the first's size)."""
    from PIL import Image

    if a.shape != b.shape:
        b = np.asarray(Image.fromarray(b).resize((a.shape[1], a.shape[0])))
    return float(np.abs(a.astype(np.float32) - b.astype(np.float32)).mean())


def run_tour(project: str, out_dir: str, width: int = 1500, height: int = 940) -> int:
    """Run :func:`tour` and exit the GUI whatever happens (the report says what failed)."""
    if hasattr(signal, "SIGUSR1"):
        # A tour that hangs (the GUI tests kill it past their limit) prints the Python stack of
        # every thread on stderr first.
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    report: dict = {"project": str(project)}
    code = 0
    try:
        tour(project, out, report, width, height)
    except Exception:  # noqa: BLE001 - written into the report, exit status 1
        report["failure"] = traceback.format_exc()
        traceback.print_exc()
        code = 1
    (out / "tour.json").write_text(json.dumps(report, indent=1, default=float))
    # Open3D's GUI and its worker threads cannot be torn down reliably from here: leave now.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def tour(project: str, out: Path, report: dict, width: int, height: int) -> None:
    from app.gui.controller import Studio

    start = time.perf_counter()

    def note(step: str) -> None:
        """One progress line on stderr per step (tests show it when the tour fails)."""
        print(f"tour {time.perf_counter() - start:7.1f} s: {step}", file=sys.stderr, flush=True)

    app = start_application()
    studio = Studio(None, width=width, height=height)
    player, garment_tab, export_tab = studio.player, studio.garment_tab, studio.export_tab
    while studio.open_seconds is None:
        app.run_one_tick()
        studio.service()
    report["window_open_s"] = studio.open_seconds
    # first seconds: the mannequin shows before the built-in garment is generated (or read
    # from the cache: a second launch)
    studio.wait_idle()
    report["first_seconds"] = {
        "body_shown_s": garment_tab.body_shown_s,
        "garment_shown_s": garment_tab.garment_shown_s,
        "garment_from_cache": garment_tab.garment_from_cache,
    }
    t0 = time.perf_counter()

    # 1. a built-in garment, its proxy, a texture-size change (only the atlas re-runs)
    note("1. garment and proxy")
    garment_tab.load_garment("multilayer-skirt", resolution_mm=20.0)
    studio.wait_idle()
    report["garment_vertices"] = int(garment_tab.garment.num_vertices)
    report["proxy_first_plan"] = garment_tab.proxy_plan_ran
    studio.screenshot(out / "gui-garment.png")
    note("saved gui-garment.png")
    player.set_visibility(show_target=False, show_wireframe=True)
    garment_tab.derive_proxy(target_verts=400)
    studio.wait_idle()
    report["proxy_verts_plan"] = garment_tab.proxy_plan_ran
    garment_tab.derive_proxy(texture_size=512)
    studio.wait_idle()
    report["proxy_texture_plan"] = garment_tab.proxy_plan_ran
    report["proxy_report"] = {
        "vertices": garment_tab.proxy_result.report["proxy"]["vertices"],
        "hausdorff_mm": 1e3 * garment_tab.proxy_result.report["distance"]["hausdorff_m"],
        "stretch_mean": garment_tab.proxy_result.report["uv"]["stretch_mean"],
        "texture_size": garment_tab.proxy_result.report["uv"]["texture_size"],
    }
    studio.screenshot(out / "gui-proxy.png")
    note("saved gui-proxy.png")
    player.set_visibility(show_target=True, show_wireframe=False)
    report["garment_s"] = time.perf_counter() - t0

    # an error dialog; the window still works after OK
    garment_tab.load_garment("/nonexistent/garment.obj")
    studio.wait_idle()
    report["error_shown"] = studio.errors[-1] if studio.errors else None
    studio.screenshot(out / "gui-error.png")
    note("saved gui-error.png")
    studio.view.close_dialog()
    player.set_visibility(show_wireframe=True)
    studio.wait_idle()
    report["usable_after_error"] = (
        bool(studio.settings.show_wireframe) and garment_tab.garment is not None
    )
    player.set_visibility(show_wireframe=False)

    # 2. the project, a motion, the live neural render
    note("2. project, motion, live render")
    t1 = time.perf_counter()
    studio.open_project(project)
    studio.wait_idle(timeout=180)
    report["open_project_s"] = time.perf_counter() - t1
    report["opened_in_view"] = player.main_view()
    if player.main_view() != "neural":  # a project saved in another view by a user
        note("   (the project opened in its saved view: switching to the neural view)")
        player.set_view_mode("neural")
        studio.wait_idle()
    # 2b. the neural viewport (a project opens in it): a drag turns its camera, scrubbing changes the frame, play
    note("2b. neural viewport: drag, scrub, play, compare")
    report["neural_view"] = player.main_view()
    before = player.neural_image.copy()
    player.neural_drag(80, -20)
    studio.wait_idle()
    dragged = player.neural_image.copy()
    _png(out / "neural-a.png", before)
    _png(out / "neural-b.png", dragged)
    f0 = player.frame
    player.seek((f0 + player.num_frames // 2) % player.num_frames)
    studio.wait_idle()
    scrubbed = player.neural_image.copy()
    report["neural"] = {
        "shape": list(before.shape),
        "drag_diff": _mean_diff(before, dragged),
        "scrub_frames": [f0, player.frame],
        "scrub_diff": _mean_diff(dragged, scrubbed),
        "view_size": list(studio.view.main_size),
    }
    n_live, n_render = player.live_frames_shown, player.render_count
    player.play()
    t_play = time.perf_counter()
    studio.pump(PLAY_SECONDS)
    player.pause()
    played = time.perf_counter() - t_play
    studio.wait_idle()
    report["neural"]["play"] = {
        "seconds": played,
        "shown_fps": (player.live_frames_shown - n_live) / played,
        "render_fps": (player.render_count - n_render) / played,
        "render_size": list(player.neural_image.shape[:2]),
        "stats": studio.view.neural_stats.text,
    }
    studio.screenshot(out / "gui-neural.png")
    note("saved gui-neural.png")
    player.set_view_mode("compare")
    studio.wait_idle()
    report["compare_shape"] = list(player.neural_image.shape)
    studio.screenshot(out / "gui-compare.png")
    note("saved gui-compare.png")
    relight(studio, out, report, note)

    # the 3D view for the steps below; a switch back to the neural view froze software Vulkan
    # (docs/gui.md), so the export renders from the 3D view's camera without one
    player.set_view_mode("scene")
    studio.wait_idle()
    report["motion"] = player.motion_name
    report["num_frames"] = player.num_frames
    player.seek(min(10, player.num_frames - 1))
    studio.wait_idle()

    # the camera conversion against Open3D's own matrices
    pose = CameraPose((0.4, 1.1, 2.6), (0.0, 0.85, 0.0), (0.0, 1.0, 0.0), 35.0)
    player.set_camera(pose.eye, pose.target, pose.up, pose.fov_deg)
    studio.wait_idle()
    view, proj, fov = studio.view.gl_matrices()
    ours = camera_from_gl(view, proj, 128, 128)
    ref = pose.camera(128, 128)
    report["camera_check"] = {
        "fov_deg": fov,
        "max_K_diff": float(np.abs(ours.K - ref.K).max()),
        "max_extrinsic_diff": float(np.abs(ours.extrinsic - ref.extrinsic).max()),
    }
    report["live_a_frame"] = player.frame
    image_a = player.live_image.copy()
    _png(out / "live-a.png", image_a)
    player.set_camera((-1.6, 1.3, 1.9), (0.0, 0.85, 0.0), (0.0, 1.0, 0.0), 35.0)
    studio.wait_idle()
    image_b = player.live_image.copy()
    _png(out / "live-b.png", image_b)
    report["live_image_shape"] = list(image_a.shape)
    report["errors_so_far"] = list(studio.errors)

    # 3. play: the body, the proxy and the live render move; then stepping frames and the
    # live render's frame rate at 128 px (on the playback worker)
    note("3. play, step frames, live render frame rate")
    n3d, nlive, nrender, f0 = (
        player.play_frames_shown,
        player.live_frames_shown,
        player.render_count,
        player.frame,
    )
    player.play()
    t_play = time.perf_counter()
    studio.pump(PLAY_SECONDS)
    player.pause()
    played = time.perf_counter() - t_play
    studio.wait_idle()
    report["play"] = {
        "seconds": played,
        # Modulo the clip: 0 when play wrapped round to where it started (a 40-frame clip
        # at 30 fps for 4 s). frames_shown counts every change of frame.
        "frames_advanced": (player.frame - f0) % max(player.num_frames, 1),
        "frames_shown": player.play_frames_shown - n3d,
        "view_fps": (player.play_frames_shown - n3d) / played,
        "live_shown_fps": (player.live_frames_shown - nlive) / played,
        "live_render_fps": (player.render_count - nrender) / played,
    }
    t_shot = time.perf_counter()
    studio.screenshot(out / "gui-play.png")
    report["screenshot_after_play_s"] = time.perf_counter() - t_shot
    note("saved gui-play.png")
    player.set_show_ground_truth(True)
    studio.wait_idle()
    f0, n0 = player.frame, player.render_count
    for _ in range(3):
        player.step(1)
        studio.wait_idle()
    report["stepped"] = {
        "frames_advanced": (player.frame - f0) % max(player.num_frames, 1),
        "renders": player.render_count - n0,
    }
    player.benchmark_live(20)
    studio.wait_idle(timeout=180)
    report["live_benchmark"] = player.live_benchmark
    report["has_sim"] = player.sim_frames is not None

    # 4. export: camera keys at two frames, an MP4 and a GIF along the smooth path between
    # them (progress, atomic), a cancelled export (no file), the path as JSON, the proxy OBJ
    note("4. export")
    player.seek(0)
    export_tab.add_path_key()
    player.seek(5)
    player.set_camera((1.8, 1.2, 1.6), (0.0, 0.85, 0.0))
    export_tab.add_path_key()
    player.seek(0)
    export_tab.set_export_frames(6)
    export_tab.set_export_reference(True)
    export_tab.export_video(str(out / "path.mp4"), size=96)
    studio.wait_idle(timeout=120)
    report["export_label"] = studio.view.export_label.text
    studio.view.tabs.selected_tab_index = 3
    studio.screenshot(out / "gui-export.png")
    note("saved gui-export.png")
    export_tab.set_export_reference(False)
    export_tab.export_gif(str(out / "path.gif"), size=96)
    export_tab.set_export_frames(40)
    export_tab.export_video(str(out / "cancelled.mp4"), size=96)
    export_tab.cancel_export()  # queued behind the GIF: stops before its first frame
    studio.wait_idle(timeout=120)
    report["cancelled"] = {
        "label": studio.view.export_label.text,
        "file": (out / "cancelled.mp4").exists(),
        "leftovers": sorted(p.name for p in out.iterdir() if "cancelled" in p.name),
    }
    export_tab.save_camera_path(str(out / "path.json"))
    export_tab.export_proxy(str(out / "proxy.obj"))
    studio.wait_idle(timeout=120)
    studio.view.tabs.selected_tab_index = 0
    report["mp4"] = (out / "path.mp4").is_file()
    report["gif"] = (out / "path.gif").is_file()
    report["obj"] = (out / "proxy.obj").is_file()
    report["path_json"] = json.loads((out / "path.json").read_text())

    # 5. settings saved with the project (what a reopened window restores)
    note("5. settings saved")
    player.seek(3)
    studio.wait_idle()
    saved_pose = player.current_pose()
    # The view the project opened in is what its settings keep: the tour switched to the 3D
    # view for its own steps, and a second tour on the same folder opens where this one did.
    player.set(view_mode=report["opened_in_view"])
    studio.save_settings()
    saved = load_settings(project)
    report["saved_settings"] = saved.as_dict()
    restored = saved.camera_pose()
    report["restored"] = {
        "frame": saved.frame,
        "motion": saved.motion,
        "camera_path_keys": len(saved.camera_path),
        "eye_diff": float(np.abs(np.subtract(restored.eye, saved_pose.eye)).max()),
        "target_diff": float(np.abs(np.subtract(restored.target, saved_pose.target)).max()),
    }
    report["errors"] = list(studio.errors)
    report["total_s"] = time.perf_counter() - t0
    studio.on_close()


def relight(studio, out: Path, report: dict, note) -> None:
    """The relighting step, in the comparison view: a missing environment image (an error),
    an environment image (picked, not fine-tuned to), then the ``RELIGHT_PRESET`` preset,
    fine-tuned to in ``RELIGHT_STEPS`` steps; the relit render plays beside the reference
    under the same light (screenshot ``gui-relight.png``). Then back to the project's own
    renderer and light for the steps that follow."""
    player, motion_tab = studio.player, studio.motion_tab
    note("2c. relight: light picker, fine-tune, relit render beside the reference")
    before = player.neural_image.copy()
    frame = player.frame
    n_errors = len(studio.errors)
    motion_tab.set_light("/nonexistent/sky.hdr")
    studio.wait_idle()
    error = studio.errors[-1] if len(studio.errors) > n_errors else None
    studio.view.close_dialog()
    # an environment image: a sky above a dark ground, equirectangular (2:1)
    sky = np.zeros((32, 64, 3), np.uint8)
    sky[:16] = (150, 180, 230)
    sky[16:] = (60, 50, 40)
    _png(out / "sky.png", sky)
    motion_tab.set_light(str(out / "sky.png"))
    studio.wait_idle()
    environment = {
        "items": list(motion_tab.light_items),
        "chosen": motion_tab.light_spec,
        "label": studio.view.finetune_label.text,
    }
    motion_tab.set_light(RELIGHT_PRESET)
    studio.wait_idle()
    studio.view.tabs.selected_tab_index = 1
    t0 = time.perf_counter()
    motion_tab.finetune_light(steps=RELIGHT_STEPS)
    studio.wait_idle(timeout=240)
    seconds = time.perf_counter() - t0
    after = player.neural_image.copy()
    pb = player.playback  # the workers are idle: nothing else touches it now
    half = before.shape[1] // 2, after.shape[1] // 2
    report["relight"] = {
        "error": error,
        "environment": environment,
        "seconds": seconds,
        "label": studio.view.finetune_label.text,
        "model": str(motion_tab.renderer_path),
        "model_exists": motion_tab.renderer_path is not None and motion_tab.renderer_path.is_file(),
        "playback_renderer": str(pb.renderer_path),
        "lighting": pb.shading.lighting.name,
        "view": player.main_view(),
        "frames": [frame, player.frame],
        "compare_shape": list(after.shape),
        "neural_diff": _mean_diff(before[:, : half[0]], after[:, : half[1]]),
        "reference_diff": _mean_diff(before[:, half[0] :], after[:, half[1] :]),
        "stats": studio.view.neural_stats.text,
        "errors": studio.errors[n_errors:],
    }
    studio.screenshot(out / "gui-relight.png")
    note("saved gui-relight.png")
    studio.view.tabs.selected_tab_index = 0
    motion_tab.select_body("project body")  # the project's own renderer and light again
    studio.wait_idle(timeout=180)
    report["relight"]["restored_lighting"] = player.playback.shading.lighting.name
