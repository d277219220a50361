"""The studio window while playing: what reaches the screen, and whether frames queue up.

Usage (needs a display; under Xvfb this measures Mesa's software OpenGL, llvmpipe)::

    DISPLAY=:99 python benchmarks/gui_play.py PROJECT [--seconds 20] [--view neural] [--burn]

Opens the studio on a trained project (``dng demo`` output), plays its motion for
``--seconds`` with the live neural render on, then pauses and times a screenshot and an error
dialog. Frames the window asked Filament for but that were not drawn yet show up there: the
screenshot (three forced redraws, about 3.5 s when nothing is queued) and the dialog wait
behind them. Prints the 3D-view and live-image frames shown per second, the neural renders
made per second on the playback worker, the longest main-loop tick, and both waits.
``--view`` picks what the main area shows (``neural``: the neural viewport, its render size
adapting to the machine; ``scene``: the 3D view with the 128 px live thumbnail; ``compare``);
the neural viewport's render size (image pixels, and the view's size they are upscaled to) is
printed with the frames shown. ``--burn`` adds a thread that holds the GIL in a Python loop (what a proxy derivation does),
the condition under which callbacks from inside Open3D's tick stalled the window
(docs/gui.md). ``DNG_GUI_PLAY_HZ`` / ``DNG_GUI_LIVE_HZ`` set the redraw limits being measured.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("project", help="a trained project folder (dng demo output)")
    parser.add_argument("--seconds", type=float, default=20.0, help="seconds of play")
    parser.add_argument("--burn", action="store_true", help="a GIL-holding thread beside it")
    parser.add_argument(
        "--view", choices=("neural", "scene", "compare"), default="neural", help="main area"
    )
    args = parser.parse_args()

    from app.gui import start_application
    from app.gui.controller import Studio
    from app.gui.player import LIVE_REDRAW_HZ, PLAY_REDRAW_HZ

    app = start_application()
    studio = Studio(None)
    player = studio.player
    while studio.open_seconds is None:
        app.run_one_tick()
        studio.service()
    studio.open_project(args.project)
    studio.wait_idle(timeout=600)
    if not player.num_frames:
        raise SystemExit(f"{args.project}: no motion loaded (is it a trained project?)")
    player.set_live_render(True)
    player.set_view_mode(args.view)
    studio.wait_idle()
    if args.burn:

        def burn() -> None:
            while not studio.closed:
                sum(i * i for i in range(200_000))

        threading.Thread(target=burn, daemon=True).start()

    n3d, nlive, nrender = player.play_frames_shown, player.live_frames_shown, player.render_count
    longest = 0.0
    player.play()
    start = time.perf_counter()
    while time.perf_counter() - start < args.seconds:
        t = time.perf_counter()
        app.run_one_tick()
        studio.service()
        longest = max(longest, time.perf_counter() - t)
        time.sleep(0.002)
    played = time.perf_counter() - start
    player.pause()
    studio.wait_idle()
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        studio.screenshot(Path(tmp) / "after-play.png")
        shot = time.perf_counter() - t
    t = time.perf_counter()
    studio.view.show_error("benchmark", "a dialog after playing")
    studio.pump(0.5)
    studio.view.close_dialog()
    studio.wait_idle()
    dialog = time.perf_counter() - t
    print(f"project {args.project}, motion {player.motion_name}, {player.num_frames} frames")
    print(
        f"redraw limits while playing: 3D view {PLAY_REDRAW_HZ:g} Hz, live image "
        f"{LIVE_REDRAW_HZ:g} Hz; GIL-holding thread: {args.burn}"
    )
    print(f"played {played:.1f} s, main area: {player.main_view()}:")
    if player.neural_image is not None and player.main_view() != "scene":
        h, w = player.neural_image.shape[:2]
        vw, vh = studio.view.main_size
        print(f"  neural viewport        {w}x{h} px upscaled to {vw}x{vh} (render size at the end)")
    shown = "3D view frames shown  " if player.main_view() == "scene" else "frames advanced       "
    print(f"  {shown} {(player.play_frames_shown - n3d) / played:6.1f} /s")
    print(f"  live images shown      {(player.live_frames_shown - nlive) / played:6.1f} /s")
    print(f"  neural renders made    {(player.render_count - nrender) / played:6.1f} /s")
    print(f"  longest main-loop tick {longest:6.2f} s")
    print(f"screenshot after play    {shot:6.2f} s (about 3.5 s when no frames are queued)")
    print(f"dialog after play        {dialog:6.2f} s")
    os._exit(0)  # Open3D's GUI threads cannot be torn down reliably from here


if __name__ == "__main__":
    main()
