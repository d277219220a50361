"""The garment studio window (``dng gui [PROJECT]``): Open3D GUI, model / view / controller.

- :mod:`app.gui.model`: settings and logic, no GUI import (unit-tested);
- :mod:`app.gui.window`: the widgets and the 3D scene (the view);
- the controllers: :class:`app.gui.controller.Studio` composes :class:`app.gui.player.Player`
  (the main area, the timeline, the live neural render) and one controller per tab in
  :mod:`app.gui.tabs` (``GarmentTab``, ``MotionTab``, ``PipelineTab``, ``ExportTab``), and
  holds what they share (settings, the open project, the workers, the main loop); their public
  methods are the driver API tests and scripts use;
- :mod:`app.gui.workers`: the worker threads.
- :mod:`app.gui.backend`: Filament's backend (``DNG_GUI_BACKEND``) and what differs on each.

Importing this package imports nothing heavy; :func:`run` does.
"""

from __future__ import annotations

import os

from app.gui.backend import DEFAULT_BACKEND, select_backend


def start_application():
    """Initialise Open3D's GUI application once and return it (every window entry point: the
    studio, its tour, the play benchmark).

    Mesa's software Vulkan (lavapipe, what Xvfb machines have) rasterizes on its own llvmpipe
    threads by default. Windows froze for good with those two threads spinning at 100% CPU and
    the main thread waiting in Filament's ``SyncThreads`` (see ``tests/hang.py``'s reports).
    ``LP_NUM_THREADS=0`` makes it rasterize on the submitting thread: there are no such threads,
    and a tour on 2 cores ran as fast (35-37 s against 42 s; live neural images shown 11.0/s
    against 10.0/s). It does not remove the freeze: one tour in about six still froze with it,
    the submitting thread spinning in llvmpipe's generated code (no symbols; -inf floats on its
    stack) and the main thread again in ``SyncThreads``. The cause is not known. Hardware
    drivers ignore the variable, and a user's own setting wins. It is read when the Vulkan
    device is made, so it is set before ``initialize``.
    """
    os.environ.setdefault("LP_NUM_THREADS", "0")
    import open3d.visualization.gui as gui

    select_backend(os.environ.get("DNG_GUI_BACKEND", DEFAULT_BACKEND))
    app = gui.Application.instance
    app.initialize()
    return app


def run(project=None, *, width: int = 1500, height: int = 940, play: bool = False) -> int:
    """Open the studio window (on ``project`` when given) and run until it is closed;
    ``play``: start playing the project's motion once it is loaded."""
    from app.gui.controller import Studio

    start_application()
    studio = Studio(project, width=width, height=height)
    if play:
        studio.player.play_when_loaded = True
    studio.run_loop()
    return 0
