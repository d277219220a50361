"""The garment studio window (``dng gui [PROJECT]``): Open3D GUI, model / view / controller.

- :mod:`app.gui.model`: settings and logic, no GUI import (unit-tested);
- :mod:`app.gui.window`: the widgets and the 3D scene (the view);
- :mod:`app.gui.controller`: :class:`~app.gui.controller.Studio`, state, worker threads and the
  driver API tests and scripts use;
- :mod:`app.gui.workers`: the worker threads.

Importing this package imports nothing heavy; :func:`run` does.
"""

from __future__ import annotations


def run(project=None, *, width: int = 1500, height: int = 940) -> int:
    """Open the studio window (on ``project`` when given) and run until it is closed."""
    import open3d.visualization.gui as gui

    from app.gui.controller import Studio

    app = gui.Application.instance
    app.initialize()
    Studio(project, width=width, height=height).run_loop()
    return 0
