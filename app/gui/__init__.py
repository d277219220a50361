"""The garment studio window (``dng gui [PROJECT]``): Open3D GUI, model / view / controller.

- :mod:`app.gui.model`: settings and logic, no GUI import (unit-tested);
- :mod:`app.gui.window`: the widgets and the 3D scene (the view);
- the controllers: :class:`app.gui.controller.Studio` composes :class:`app.gui.player.Player`
  (the main area, the timeline, the live neural render) and one controller per tab in
  :mod:`app.gui.tabs` (``GarmentTab``, ``MotionTab``, ``PipelineTab``, ``ExportTab``), and
  holds what they share (settings, the open project, the workers, the main loop); their public
  methods are the driver API tests and scripts use;
- :mod:`app.gui.workers`: the worker threads.

Importing this package imports nothing heavy; :func:`run` does.
"""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

from core.errors import InputError

#: Filament's backend for the window (``DNG_GUI_BACKEND`` overrides it): ``vulkan`` or ``opengl``.
DEFAULT_BACKEND = "vulkan"
#: Open3D's ``rendering::RenderingType`` values (``FilamentEngine.h``: kDefault, kOpenGL,
#: kVulkan, kMetal).
_RENDERING_TYPES = {"default": 0, "opengl": 1, "vulkan": 2}
#: ``open3d::visualization::rendering::EngineInstance::SelectBackend(RenderingType)``.
_SELECT_BACKEND = (
    "_ZN6open3d13visualization9rendering14EngineInstance13SelectBackendENS1_13RenderingTypeE"
)


def select_backend(name: str) -> None:
    """Make Open3D create Filament's engine on ``name`` (``vulkan``, ``opengl`` or ``default``);
    call it before the first window.

    Open3D 0.20 has no Python call for it: ``EngineInstance::SelectBackend`` is called from its
    shared library (an exported C++ function taking the enum as an int). On Linux its default
    is Vulkan, also on Mesa's software device (lavapipe); ``opengl`` runs Filament on the X
    server's OpenGL (Mesa llvmpipe under Xvfb) instead.
    """
    import open3d  # heavy: only when a window is about to open

    try:
        value = _RENDERING_TYPES[name.lower()]
    except KeyError:
        raise InputError(
            f"DNG_GUI_BACKEND={name!r}: expected one of {', '.join(_RENDERING_TYPES)}"
        ) from None
    libs = sorted(Path(open3d.__file__).parent.glob("libOpen3D.so*"))
    try:
        select = getattr(ctypes.CDLL(str(libs[0])), _SELECT_BACKEND)
    except (IndexError, OSError, AttributeError):
        raise InputError(
            f"DNG_GUI_BACKEND={name!r}: this Open3D build exports no EngineInstance::SelectBackend"
        ) from None
    select(ctypes.c_int(value))


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


def run(project=None, *, width: int = 1500, height: int = 940) -> int:
    """Open the studio window (on ``project`` when given) and run until it is closed."""
    from app.gui.controller import Studio

    start_application()
    Studio(project, width=width, height=height).run_loop()
    return 0
