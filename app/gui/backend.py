"""Which of Filament's backends the studio window draws with (``DNG_GUI_BACKEND``), and what
the widgets must do differently on each."""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

from core.errors import InputError

#: Filament's backend for the window with a GPU driver (``DNG_GUI_BACKEND`` overrides it).
DEFAULT_BACKEND = "vulkan"
#: ... and under software rendering: OpenGL, the one backend where Mesa's anisotropic texture
#: filtering can be switched off (:data:`NO_ANISOTROPY`).
SOFTWARE_BACKEND = "opengl"
#: Mesa's ``MESA_EXTENSION_OVERRIDE`` entries that hide anisotropic filtering from Filament.
#: Open3D samples every lit material's maps with 8x anisotropy, and llvmpipe's anisotropic
#: filter loops over every texel of a pixel's footprint: a sliver seen edge-on has a footprint
#: of millions of texels, and the window froze for minutes or for good (docs/gui.md, "The
#: software-rendering stall"). Vulkan (lavapipe) has no switch for it.
NO_ANISOTROPY = ("-GL_EXT_texture_filter_anisotropic", "-GL_ARB_texture_filter_anisotropic")
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
    server's OpenGL (Mesa llvmpipe under Xvfb) instead, where :func:`app.gui.window._image`
    flips the image widgets' pictures (Open3D shows them upside down there).
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
    _SELECTED["backend"] = name.lower()


#: The backend :func:`select_backend` chose last (``default`` until it runs: Open3D's choice).
_SELECTED = {"backend": "default"}


def window_backend() -> str:
    """The backend a window opens on: ``DNG_GUI_BACKEND`` when set, else
    :data:`SOFTWARE_BACKEND` under software rendering and :data:`DEFAULT_BACKEND` with a GPU."""
    forced = os.environ.get("DNG_GUI_BACKEND")
    if forced:
        return forced
    return SOFTWARE_BACKEND if software_rendering() else DEFAULT_BACKEND


def hide_anisotropy(environ=os.environ) -> None:
    """Add :data:`NO_ANISOTROPY` to ``MESA_EXTENSION_OVERRIDE`` (keeping what a user set there);
    Mesa reads it when the first OpenGL context is made, so call it before the window opens
    (:func:`app.gui.start_application` does, under software rendering only)."""
    entries = environ.get("MESA_EXTENSION_OVERRIDE", "").split()
    entries += [e for e in NO_ANISOTROPY if e not in entries and "+" + e[1:] not in entries]
    environ["MESA_EXTENSION_OVERRIDE"] = " ".join(entries)


def software_rendering() -> bool:
    """Whether the window most likely draws on a software rasterizer (Mesa's llvmpipe under
    Xvfb): no GPU device node (``/dev/dri/renderD*``, ``/dev/nvidia0``). ``DNG_GUI_SOFTWARE``
    (``1`` or ``0``) overrides the guess."""
    forced = os.environ.get("DNG_GUI_SOFTWARE")
    if forced in ("0", "1"):
        return forced == "1"
    return not (any(Path("/dev/dri").glob("renderD*")) or Path("/dev/nvidia0").exists())


def selected_backend() -> str:
    """``vulkan``, ``opengl`` or ``default``: what :func:`select_backend` last asked for."""
    return _SELECTED["backend"]
