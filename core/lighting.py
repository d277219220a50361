"""Light for the ground-truth renders: named rigs and environment images, fixed to the camera.

A :class:`Lighting` is what :mod:`core.shading` lights a view with: a hemispherical ambient
(``sky`` above, ``ground`` below, in image space), directional :class:`Light` s, and optionally
an environment's diffuse light as 9 spherical-harmonic coefficients per colour channel
(Ramamoorthi and Hanrahan 2001, "An efficient representation for irradiance environment maps").
Everything is given in camera space (x right, y down, z forward): as in the paper, the light
turns with the camera, so every view of a frame is lit the same way.

An environment image is equirectangular: its top row looks up (camera -y), its centre column
looks where the camera looks (+z), its left and right edges behind the camera. An LDR image
(PNG, JPEG) is read as sRGB; an HDR image (Radiance ``.hdr``, OpenEXR ``.exr``) as linear
radiance. Pure functions and records; the reader is the only I/O.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from core.color import linear_to_srgb, srgb_to_linear, to_uint8
from core.errors import InputError

#: File suffixes read as linear (high dynamic range) radiance.
HDR_SUFFIXES = (".hdr", ".exr")


@dataclass(frozen=True)
class Light:
    """A directional light fixed to the camera."""

    direction: tuple[float, float, float]
    """Towards the light, in camera space (x right, y down, z forward); normalised on use."""
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Linear RGB."""
    intensity: float = 1.0


def _studio_lights() -> tuple[Light, ...]:
    return (
        Light((-0.45, -0.65, -0.6), (1.0, 0.97, 0.92), 0.75),  # key: upper left, behind camera
        Light((0.7, -0.2, -0.45), (0.85, 0.9, 1.0), 0.3),  # fill: right
    )


@dataclass(frozen=True)
class Lighting:
    """The light of a view: ambient, directional lights and an environment, in camera space.

    A surface of albedo ``a`` with unit normal ``n`` (camera space) takes, in linear RGB,
    ``a * (ambient(n) + sum of wrapped lights + environment(n))``: a white surface facing a
    light of colour ``c`` and intensity 1 alone shows ``c``.
    """

    name: str = "studio"
    """What the user called it: a preset's name or the environment file's."""
    sky: tuple[float, float, float] = (0.42, 0.44, 0.48)
    """Ambient light from above in the image (linear RGB)."""
    ground: tuple[float, float, float] = (0.16, 0.15, 0.14)
    """Ambient light from below in the image (linear RGB)."""
    lights: tuple[Light, ...] = field(default_factory=_studio_lights)
    """Directional lights fixed to the camera."""
    environment: tuple[float, ...] = ()
    """An environment's diffuse light: 27 numbers, the 9 spherical-harmonic coefficients of
    irradiance / pi for each of R, G, B (:func:`environment_coefficients`); () for none."""

    def __post_init__(self) -> None:
        for key in ("sky", "ground"):
            c = np.asarray(getattr(self, key), np.float64)
            if c.shape != (3,) or not (np.isfinite(c).all() and (c >= 0).all()):
                raise InputError(f"{key} must be 3 numbers >= 0, got {getattr(self, key)}")
        for li in self.lights:
            d = np.asarray(li.direction, np.float64)
            c = np.asarray(li.color, np.float64)
            if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) < 1e-9:
                raise InputError(f"a light's direction must be 3 numbers, not 0: {li.direction}")
            if c.shape != (3,) or not (np.isfinite(c).all() and (c >= 0).all()):
                raise InputError(f"a light's colour must be 3 numbers >= 0, got {li.color}")
            if not (math.isfinite(li.intensity) and li.intensity >= 0):
                raise InputError(f"a light's intensity must be >= 0, got {li.intensity}")
        e = np.asarray(self.environment, np.float64)
        if e.size not in (0, 27) or not np.isfinite(e).all():
            raise InputError(f"environment must be 27 finite numbers or none, got {e.size}")

    def to_dict(self) -> dict:
        """A JSON-ready dict (:meth:`from_dict` reads it back)."""
        d = asdict(self)
        d["environment"] = list(self.environment)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Lighting:
        try:
            lights = tuple(
                Light(tuple(li["direction"]), tuple(li["color"]), float(li["intensity"]))
                for li in d.get("lights", ())
            )
            return cls(
                name=str(d.get("name", "custom")),
                sky=tuple(d["sky"]),
                ground=tuple(d["ground"]),
                lights=lights,
                environment=tuple(float(x) for x in d.get("environment", ())),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"not a lighting description ({exc})") from None


#: The named rigs. ``studio`` is the project's default (every data set is rendered under it
#: unless its settings say otherwise). ``low-sun``: a warm sun low on the left and a dim blue
#: sky. ``overcast``: no sun, a bright cold sky from above.
PRESETS: dict[str, Lighting] = {
    "studio": Lighting(),
    "low-sun": Lighting(
        name="low-sun",
        sky=(0.10, 0.13, 0.22),
        ground=(0.10, 0.07, 0.04),
        lights=(Light((-0.95, -0.1, -0.3), (1.0, 0.55, 0.25), 1.3),),
    ),
    "overcast": Lighting(
        name="overcast",
        sky=(0.62, 0.70, 0.82),
        ground=(0.14, 0.15, 0.17),
        lights=(Light((0.0, -1.0, -0.2), (0.80, 0.87, 1.0), 0.2),),
    ),
}


# ----------------------------------------------------------------------- spherical harmonics


def sh_basis(directions, xp=np):
    """The 9 real spherical harmonics of bands 0 to 2 at unit directions (..., 3): (..., 9).

    ``xp`` is the array module (numpy, or torch for the torch-only render path)."""
    x, y, z = directions[..., 0], directions[..., 1], directions[..., 2]
    return xp.stack(
        [
            x * 0 + 0.282095,
            0.488603 * y,
            0.488603 * z,
            0.488603 * x,
            1.092548 * x * y,
            1.092548 * y * z,
            0.315392 * (3 * z * z - 1),
            1.092548 * x * z,
            0.546274 * (x * x - y * y),
        ],
        -1,
    )


#: Clamped-cosine convolution per band, divided by pi: irradiance / pi from radiance.
_BAND_GAIN = np.array([1.0] + [2.0 / 3.0] * 3 + [0.25] * 5)


def equirect_directions(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera-space unit directions (H, W, 3) of an equirectangular image's pixel centres, and
    each pixel's solid angle (H, W) (they sum to 4 pi)."""
    lat = np.pi * (0.5 - (np.arange(height) + 0.5) / height)  # +pi/2 at the top row
    lon = 2 * np.pi * ((np.arange(width) + 0.5) / width - 0.5)  # 0 at the centre column
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    d = np.stack([np.sin(lo) * np.cos(la), -np.sin(la), np.cos(lo) * np.cos(la)], -1)
    omega = (2 * np.pi / width) * (np.pi / height) * np.cos(la)
    return d, omega


#: Rows an environment is averaged down to before its projection: bands 0 to 2 change over
#: tens of degrees, so a 4k panorama's 8 M pixels (600 MB of basis values) add nothing.
ENVIRONMENT_ROWS = 64


def _shrink(radiance: np.ndarray) -> np.ndarray:
    """An equirectangular image averaged over square blocks down to about
    :data:`ENVIRONMENT_ROWS` rows (the last partial rows and columns dropped)."""
    f = radiance.shape[0] // ENVIRONMENT_ROWS
    if f < 2:
        return radiance
    h, w = radiance.shape[0] // f * f, radiance.shape[1] // f * f
    return radiance[:h, :w].reshape(h // f, f, w // f, f, 3).mean(axis=(1, 3))


def environment_coefficients(radiance: np.ndarray) -> tuple[float, ...]:
    """An equirectangular environment's diffuse light as :attr:`Lighting.environment`.

    Parameters
    ----------
    radiance : (H, W, 3) float, linear RGB radiance (finite, >= 0)

    Returns
    -------
    27 floats: for each of R, G, B, the 9 coefficients c such that a unit normal n takes
    ``sh_basis(n) @ c`` = irradiance(n) / pi (a uniform environment of radiance L gives L).
    """
    r = np.asarray(radiance, np.float64)
    if r.ndim != 3 or r.shape[2] != 3 or min(r.shape[:2]) < 2:
        raise InputError(f"an environment must be an (H, W, 3) image, got {r.shape}")
    if not np.isfinite(r).all() or (r < 0).any():
        raise InputError("an environment's radiance must be finite and >= 0")
    r = _shrink(r)
    d, omega = equirect_directions(*r.shape[:2])
    y = sh_basis(d.reshape(-1, 3)) * omega.reshape(-1, 1)  # (P, 9)
    coeffs = y.T @ r.reshape(-1, 3)  # (9, 3): projection of the radiance
    coeffs *= _BAND_GAIN[:, None]
    return tuple(float(c) for c in coeffs.T.reshape(-1))  # R's nine, G's, B's


def environment_light(environment: tuple[float, ...], normals: np.ndarray) -> np.ndarray:
    """Irradiance / pi (N, 3) float32 of :attr:`Lighting.environment` at unit normals (N, 3)."""
    return np.maximum(
        sh_basis(np.asarray(normals, np.float32)) @ environment_matrix(environment), 0
    )


def environment_matrix(environment: tuple[float, ...]) -> np.ndarray:
    """:attr:`Lighting.environment` as a (9, 3) float32 matrix: ``sh_basis(n) @ it``."""
    return np.asarray(environment, np.float32).reshape(3, 9).T.copy()


# ----------------------------------------------------------------------------------- reading


def read_environment(path: str | os.PathLike) -> np.ndarray:
    """An equirectangular environment image as linear radiance (H, W, 3) float32.

    ``.hdr`` and ``.exr`` are read as linear (OpenCV's reader); other images (PNG, JPEG, ...)
    as sRGB and linearised. InputError naming the file when it is missing or unreadable.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("environment image not found", path)
    if path.suffix.lower() == ".exr":  # OpenCV reads OpenEXR only when asked to
        os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
    import cv2

    bgr = cv2.imread(str(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_COLOR)
    if bgr is None or bgr.ndim != 3:
        raise InputError("not a readable image", path)
    rgb = np.ascontiguousarray(bgr[..., ::-1], np.float32)
    if path.suffix.lower() not in HDR_SUFFIXES:  # 8 or 16 bits of sRGB
        rgb = srgb_to_linear(rgb / (255.0 if bgr.dtype == np.uint8 else 65535.0))
    if not np.isfinite(rgb).all() or (rgb < 0).any():
        raise InputError("the environment has negative or non-finite pixels", path)
    if min(rgb.shape[:2]) < 2:
        raise InputError(f"the environment is too small ({rgb.shape[1]} x {rgb.shape[0]})", path)
    return rgb


def environment_lighting(path: str | os.PathLike) -> Lighting:
    """The light of an environment image alone: no ambient rig, no directional lights."""
    return Lighting(
        name=Path(path).name,
        sky=(0.0, 0.0, 0.0),
        ground=(0.0, 0.0, 0.0),
        lights=(),
        environment=environment_coefficients(read_environment(path)),
    )


def load_lighting(spec: str | os.PathLike) -> Lighting:
    """A preset's name (:data:`PRESETS`), an environment image, or a JSON file written by
    :meth:`Lighting.to_dict`; InputError naming the problem otherwise."""
    s = str(spec)
    if s in PRESETS:
        return PRESETS[s]
    path = Path(s)
    if path.suffix.lower() == ".json":
        if not path.is_file():
            raise InputError("lighting file not found", path)
        try:
            return Lighting.from_dict(json.loads(path.read_text()))
        except (ValueError, InputError) as exc:
            raise InputError(f"not a lighting description ({exc})", path) from None
    if not path.exists() and path.suffix == "":
        raise InputError(f"unknown light preset {s!r}: use one of {', '.join(PRESETS)} or an image")
    return environment_lighting(path)


def environment_view(radiance: np.ndarray, camera) -> np.ndarray:
    """What the camera sees of an environment behind everything: (H, W, 3) uint8 sRGB.

    The environment turns with the camera, so this depends on the camera's intrinsics only.
    radiance : (He, We, 3) linear; camera : core.camera.Camera.
    """
    h, w = camera.height, camera.width
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    d = np.stack([(jj - camera.cx) / camera.fx, (ii - camera.cy) / camera.fy, np.ones_like(jj)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    lon = np.arctan2(d[..., 0], d[..., 2])
    lat = np.arcsin(np.clip(-d[..., 1], -1, 1))
    he, we = radiance.shape[:2]
    u = np.clip(((lon / (2 * np.pi) + 0.5) * we).astype(int), 0, we - 1)
    v = np.clip(((0.5 - lat / np.pi) * he).astype(int), 0, he - 1)
    return to_uint8(linear_to_srgb(radiance[v, u]))
