"""What every controller of a part of the window shares: the studio it belongs to, its view and
settings, and the one way to change a setting."""

from __future__ import annotations

from dataclasses import replace


class Part:
    """A controller of one part of the studio window (:class:`app.gui.player.Player`, the tabs
    of :mod:`app.gui.tabs`); ``studio`` is the :class:`app.gui.controller.Studio` that holds the
    shared state."""

    def __init__(self, studio):
        self.studio = studio

    @property
    def settings(self):
        """The studio's :class:`app.gui.model.GuiSettings` (frozen; change with :meth:`set`)."""
        return self.studio.settings

    @property
    def view(self):
        """The studio's :class:`app.gui.window.StudioWindow`."""
        return self.studio.view

    def set(self, **changes) -> None:
        """Change settings fields (a new frozen record)."""
        self.studio.settings = replace(self.studio.settings, **changes)
