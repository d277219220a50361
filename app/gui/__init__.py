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

from app.gui.backend import hide_anisotropy, select_backend, software_rendering, window_backend


def start_application():
    """Initialise Open3D's GUI application once and return it (every window entry point: the
    studio, its tour, the play benchmark).

    The backend is :func:`app.gui.backend.window_backend`'s. Mesa's environment is set before
    ``initialize``, where it is read; a user's own setting wins, and hardware drivers ignore it:
    - under software rendering, anisotropic filtering hidden
      (:func:`app.gui.backend.hide_anisotropy`): with it, llvmpipe froze the window whenever a
      sliver of the garment was drawn edge-on;
    - ``LP_NUM_THREADS=0``: llvmpipe rasterizes on the submitting thread instead of two threads
      of its own (a tour on 2 cores ran as fast: 35-37 s against 42 s).
    """
    os.environ.setdefault("LP_NUM_THREADS", "0")
    if software_rendering():
        hide_anisotropy()
    import open3d.visualization.gui as gui

    select_backend(window_backend())
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
