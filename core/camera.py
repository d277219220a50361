"""Pinhole cameras in the OpenCV convention, random camera rigs, orbit paths and JSON files.

Conventions
-----------
- World: metres, Y up, right-handed (see DESIGN).
- Camera space (OpenCV): x right, y down, z forward; a point in front of the camera has z > 0.
- ``extrinsic`` is the 4x4 world-to-camera transform ``[R | t]``: ``x_cam = R @ x_world + t``.
- ``K`` is the 3x3 intrinsic matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels.
- Image coordinates are continuous with the top-left *corner* of pixel ``(row 0, col 0)`` at
  ``(0, 0)``: pixel ``(i, j)`` covers ``[j, j + 1) x [i, i + 1)`` and its centre is
  ``(j + 0.5, i + 0.5)``. This is what ``open3d.t.geometry.RaycastingScene.create_rays_pinhole``
  does (tested), so ``K`` and ``extrinsic`` can be handed to it directly. With this convention
  a resize scales ``K`` exactly and a crop only shifts ``(cx, cy)``.

Camera matrices are float64 (not float32): they are tiny, and projection of points metres away
onto sub-pixel positions is where float32 rounding shows first.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.errors import InputError
from core.fileio import write_json

#: Written into camera files; :func:`load_cameras` refuses other formats.
CAMERA_FILE_FORMAT = "garment-studio/cameras"
CAMERA_FILE_VERSION = 1
#: Largest deviation of ``R @ R.T`` from the identity accepted for a rotation.
ROTATION_TOLERANCE = 1e-5


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    Attributes
    ----------
    K : (3, 3) float64
        Intrinsics in pixels, ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (no skew).
    extrinsic : (4, 4) float64
        World-to-camera rigid transform, last row ``[0, 0, 0, 1]``.
    width, height : int
        Image size in pixels.
    """

    K: np.ndarray
    extrinsic: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        k = np.asarray(self.K, np.float64)
        e = np.asarray(self.extrinsic, np.float64)
        object.__setattr__(self, "K", k)
        object.__setattr__(self, "extrinsic", e)
        _check_camera(k, e, self.width, self.height)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def R(self) -> np.ndarray:
        """World-to-camera rotation: (3, 3) float64."""
        return self.extrinsic[:3, :3]

    @property
    def t(self) -> np.ndarray:
        """World-to-camera translation: (3,) float64."""
        return self.extrinsic[:3, 3]

    @property
    def center(self) -> np.ndarray:
        """Camera position in world space: (3,) float64."""
        return -self.R.T @ self.t

    @property
    def forward(self) -> np.ndarray:
        """Viewing direction (camera +z) in world space: (3,) float64, unit length."""
        return self.R[2].copy()

    @property
    def fov_y_deg(self) -> float:
        """Vertical field of view in degrees (for a centred principal point)."""
        return math.degrees(2.0 * math.atan(0.5 * self.height / self.fy))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Camera):
            return NotImplemented
        return (
            self.width == other.width
            and self.height == other.height
            and np.array_equal(self.K, other.K)
            and np.array_equal(self.extrinsic, other.extrinsic)
        )

    __hash__ = None  # arrays inside: equal cameras need not hash alike


def _check_camera(K: np.ndarray, E: np.ndarray, width: int, height: int) -> None:
    if not (isinstance(width, (int, np.integer)) and isinstance(height, (int, np.integer))):
        raise InputError(f"camera size must be integers, got {width!r} x {height!r}")
    if width <= 0 or height <= 0:
        raise InputError(f"camera size must be positive, got {width} x {height}")
    if K.shape != (3, 3) or E.shape != (4, 4):
        raise InputError(f"camera K must be (3, 3) and extrinsic (4, 4), got {K.shape}, {E.shape}")
    if not (np.isfinite(K).all() and np.isfinite(E).all()):
        raise InputError("camera matrices hold NaN or inf")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError(f"focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
    if K[0, 1] != 0 or K[1, 0] != 0 or not np.array_equal(K[2], [0.0, 0.0, 1.0]):
        raise InputError(f"K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
    if not np.array_equal(E[3], [0.0, 0.0, 0.0, 1.0]):
        raise InputError(f"extrinsic last row must be [0, 0, 0, 1], got {E[3].tolist()}")
    R = E[:3, :3]
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > ROTATION_TOLERANCE or np.linalg.det(R) <= 0:
        raise InputError(
            f"extrinsic rotation is not a proper rotation (|R R^T - I| = {err:.2g}, "
            f"det = {np.linalg.det(R):.3g})"
        )


def intrinsics_from_fov(fov_y_deg: float, width: int, height: int) -> np.ndarray:
    """K (3, 3) float64 for a vertical field of view, square pixels, centred principal point."""
    if not (0.0 < fov_y_deg < 180.0):
        raise InputError(f"field of view must be in (0, 180) degrees, got {fov_y_deg}")
    if width <= 0 or height <= 0:
        raise InputError(f"image size must be positive, got {width} x {height}")
    f = 0.5 * height / math.tan(math.radians(fov_y_deg) / 2.0)
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


def look_at(eye: Sequence[float], target: Sequence[float], up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """World-to-camera extrinsic (4, 4) float64 of a camera at ``eye`` looking at ``target``.

    The camera's image "up" (its -y axis) is the projection of ``up`` on the image plane.
    Raises ``InputError`` when ``eye == target`` or the view direction is parallel to ``up``.
    """
    eye = np.asarray(eye, np.float64)
    target = np.asarray(target, np.float64)
    up = np.asarray(up, np.float64)
    if eye.shape != (3,) or target.shape != (3,) or up.shape != (3,):
        raise InputError("look_at takes three 3-vectors")
    if not (np.isfinite(eye).all() and np.isfinite(target).all() and np.isfinite(up).all()):
        raise InputError("look_at: NaN or inf in eye, target or up")
    z = target - eye
    n = np.linalg.norm(z)
    if n < 1e-12:
        raise InputError("look_at: eye and target coincide")
    z /= n
    x = np.cross(z, up)
    nx = np.linalg.norm(x)
    if nx < 1e-9 * max(np.linalg.norm(up), 1e-300):
        raise InputError("look_at: view direction is parallel to the up vector")
    x /= nx
    y = np.cross(z, x)
    E = np.eye(4)
    E[:3, :3] = np.stack([x, y, z])
    E[:3, 3] = -E[:3, :3] @ eye
    return E


def make_camera(
    eye: Sequence[float],
    target: Sequence[float],
    *,
    fov_y_deg: float = 40.0,
    width: int = 512,
    height: int = 512,
    up=(0.0, 1.0, 0.0),
) -> Camera:
    """A camera at ``eye`` looking at ``target`` with a vertical field of view."""
    return Camera(
        intrinsics_from_fov(fov_y_deg, width, height), look_at(eye, target, up), width, height
    )


def resize_camera(camera: Camera, width: int, height: int) -> Camera:
    """The same view at another resolution (each axis scaled on its own).

    Exact under the pixel-corner convention: pixel edges of the new image lie on the same rays
    as the corresponding fractions of the old one. Supersampling by ``k`` is
    ``resize_camera(cam, k * cam.width, k * cam.height)``.
    """
    if width <= 0 or height <= 0:
        raise InputError(f"image size must be positive, got {width} x {height}")
    sx, sy = width / camera.width, height / camera.height
    K = camera.K.copy()
    K[0] *= sx
    K[1] *= sy
    return Camera(K, camera.extrinsic.copy(), int(width), int(height))


def crop_camera(camera: Camera, x0: int, y0: int, width: int, height: int) -> Camera:
    """The camera that renders the window ``[x0, x0 + width) x [y0, y0 + height)`` of ``camera``.

    Pixel ``(i, j)`` of the crop sees exactly what pixel ``(y0 + i, x0 + j)`` of the original
    sees. The window may extend past the original image (it is a camera, not an image crop).
    """
    if width <= 0 or height <= 0:
        raise InputError(f"crop size must be positive, got {width} x {height}")
    K = camera.K.copy()
    K[0, 2] -= x0
    K[1, 2] -= y0
    return Camera(K, camera.extrinsic.copy(), int(width), int(height))


def world_to_camera(points: np.ndarray, camera: Camera) -> np.ndarray:
    """Points (N, 3) in world space to camera space: (N, 3) float64."""
    p = _points(points)
    return p @ camera.R.T + camera.t


def project(points: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Project world points into the image.

    Parameters
    ----------
    points : (N, 3) float
        World positions.

    Returns
    -------
    uv : (N, 2) float64
        Continuous image coordinates ``(x right, y down)``; the point falls in pixel
        ``(row, col) = (floor(uv[:, 1]), floor(uv[:, 0]))``. Points with ``depth <= 0`` get NaN.
    depth : (N,) float64
        Camera-space z (the rasterizer's depth).
    """
    pc = world_to_camera(points, camera)
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(z > 0, 1.0 / np.where(z > 0, z, 1.0), np.nan)
    uv = np.stack(
        [camera.fx * pc[:, 0] * inv + camera.cx, camera.fy * pc[:, 1] * inv + camera.cy], 1
    )
    return uv, z


def unproject(uv: np.ndarray, depth: np.ndarray, camera: Camera) -> np.ndarray:
    """Inverse of :func:`project`: image coordinates (N, 2) and depths (N,) to world (N, 3)."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    depth = np.asarray(depth, np.float64).reshape(-1)
    pc = np.stack(
        [
            (uv[:, 0] - camera.cx) / camera.fx * depth,
            (uv[:, 1] - camera.cy) / camera.fy * depth,
            depth,
        ],
        1,
    )
    return (pc - camera.t) @ camera.R


def pixel_rays(camera: Camera, uv: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rays through image positions, in world space.

    Parameters
    ----------
    uv : (N, 2) float or None
        Continuous image coordinates; None means every pixel centre in row-major order
        (N = height * width), the same rays as ``create_rays_pinhole``.

    Returns
    -------
    origin : (3,) float64
        The camera centre (all rays start there).
    directions : (N, 3) float64
        Not normalised: each has camera-space z = 1, so a hit at ray parameter ``t`` has
        depth ``t``.
    """
    if uv is None:
        j, i = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
        uv = np.stack([j.ravel() + 0.5, i.ravel() + 0.5], 1)
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    d = np.stack(
        [(uv[:, 0] - camera.cx) / camera.fx, (uv[:, 1] - camera.cy) / camera.fy, np.ones(len(uv))],
        1,
    )
    return camera.center, d @ camera.R


def _points(points: np.ndarray) -> np.ndarray:
    p = np.asarray(points, np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"points must be (N, 3), got shape {p.shape}")
    return p


# --------------------------------------------------------------------------------------------
# Camera rigs


@dataclass(frozen=True)
class CameraRigConfig:
    """Where the data-set cameras go: on a circle around the body, looking at it."""

    width: int = 512
    """Image width in pixels."""
    height: int = 512
    """Image height in pixels."""
    fov_y_deg: float = 40.0
    """Vertical field of view in degrees."""
    target: tuple[float, float, float] = (0.0, 0.9, 0.0)
    """Point the cameras look at (metres; by default about the hips of a standing body)."""
    radius_range: tuple[float, float] = (2.6, 3.2)
    """Horizontal distance from the target, metres, drawn uniformly."""
    elevation_deg_range: tuple[float, float] = (-5.0, 20.0)
    """Angle of the eye above the target's horizontal plane, degrees, drawn uniformly."""
    target_jitter: float = 0.05
    """Each camera looks at ``target`` plus a uniform offset in ``[-jitter, jitter]^3`` metres."""

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"rig image size must be positive, got {self.width} x {self.height}")
        if not 0.0 < self.fov_y_deg < 180.0:
            raise InputError(f"rig field of view must be in (0, 180), got {self.fov_y_deg}")
        r0, r1 = self.radius_range
        if not (0.0 < r0 <= r1 and math.isfinite(r1)):
            raise InputError(f"radius_range must satisfy 0 < lo <= hi, got {self.radius_range}")
        e0, e1 = self.elevation_deg_range
        if not (-89.0 <= e0 <= e1 <= 89.0):
            raise InputError(
                f"elevation_deg_range must lie in [-89, 89] with lo <= hi, got {self.elevation_deg_range}"
            )
        if not (0.0 <= self.target_jitter < r0):
            raise InputError(f"target_jitter must be in [0, radius), got {self.target_jitter}")


def orbit_eye(target, radius: float, azimuth_rad: float, elevation_rad: float) -> np.ndarray:
    """Eye position (3,) float64 on a sphere around ``target``; azimuth 0 is on +Z (the front)."""
    target = np.asarray(target, np.float64)
    c = math.cos(elevation_rad)
    return target + radius * np.array(
        [c * math.sin(azimuth_rad), math.sin(elevation_rad), c * math.cos(azimuth_rad)]
    )


def follow_camera(
    root: Sequence[float],
    target_y: float,
    radius: float,
    fov_y_deg: float,
    width: int,
    height: int,
    azimuth_deg: float = 0.0,
    elevation_deg: float = 10.0,
    distance_scale: float = 1.075,
) -> Camera:
    """A camera that follows a character: it looks at height ``target_y`` above the root's
    (3,) horizontal position from ``radius * distance_scale`` metres, at ``azimuth_deg`` (0:
    the front, +Z) and ``elevation_deg``, with a vertical field of view ``fov_y_deg``. What
    the player's default view is (the data set's framing: ``pipeline.stages.dataset.dataset_rig``)."""
    target = np.array([root[0], target_y, root[2]], np.float64)
    eye = orbit_eye(
        target, radius * distance_scale, np.radians(azimuth_deg), np.radians(elevation_deg)
    )
    K = intrinsics_from_fov(fov_y_deg, int(width), int(height))
    return Camera(K, look_at(eye, target), int(width), int(height))


def orbit_view(
    eye: Sequence[float], target: Sequence[float], d_azimuth_rad: float, d_elevation_rad: float
) -> np.ndarray:
    """The eye (3,) float64 after turning it ``d_azimuth_rad`` around the vertical through
    ``target`` and ``d_elevation_rad`` up, at the same distance (elevation kept within
    +-85 degrees so the view never flips over the pole). What a drag does in a viewer."""
    eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
    d = eye - target
    radius = float(np.linalg.norm(d))
    if radius <= 0.0 or not math.isfinite(radius):
        raise InputError("the eye must differ from the target")
    azimuth = math.atan2(d[0], d[2]) + d_azimuth_rad
    elevation = math.asin(max(-1.0, min(1.0, d[1] / radius))) + d_elevation_rad
    limit = math.radians(85.0)
    return orbit_eye(target, radius, azimuth, max(-limit, min(limit, elevation)))


def pan_view(
    eye: Sequence[float], target: Sequence[float], right_m: float, up_m: float, up=(0.0, 1.0, 0.0)
) -> tuple[np.ndarray, np.ndarray]:
    """Eye and target (3,) float64 both moved ``right_m`` along the view's right and ``up_m``
    along its up (a pan: the view direction is kept)."""
    eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
    R = look_at(eye, target, up)[:3, :3]  # rows: camera x (right), y (down), z (forward)
    shift = right_m * R[0] - up_m * R[1]
    return eye + shift, target + shift


def dolly_view(eye: Sequence[float], target: Sequence[float], factor: float) -> np.ndarray:
    """The eye (3,) float64 moved along the view so its distance to ``target`` is multiplied
    by ``factor`` (> 0; < 1 zooms in), kept between 0.2 m and 50 m."""
    eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
    if not factor > 0.0:
        raise InputError(f"zoom factor must be > 0, got {factor}")
    d = eye - target
    radius = float(np.linalg.norm(d))
    new = min(max(radius * factor, 0.2), 50.0)
    return target + d * (new / radius)


def spherical_path(
    eyes: np.ndarray, targets: np.ndarray, times: np.ndarray, at: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Eyes and targets of a keyed camera path at times ``at``, interpolated smoothly.

    Each key's eye is written in spherical coordinates around its target (azimuth,
    elevation, log distance); those and the targets are interpolated with a monotone cubic
    (Fritsch-Carlson, so nothing overshoots the keys) over the key times, azimuth unwrapped
    so the eye turns the short way round. The eye thus moves on a surface around the body
    and never through it (its distance to the target stays between the keys' distances).

    Parameters
    ----------
    eyes, targets : (K, 3) float
        Key eyes and targets, world metres; K >= 1.
    times : (K,) float
        Key times, strictly increasing (seconds or frames).
    at : (N,) float
        Times to evaluate; clamped to the keys' span.

    Returns
    -------
    (N, 3) float64 eyes, (N, 3) float64 targets.
    """
    eyes = np.asarray(eyes, np.float64).reshape(-1, 3)
    targets = np.asarray(targets, np.float64).reshape(-1, 3)
    times = np.asarray(times, np.float64).reshape(-1)
    at = np.asarray(at, np.float64).reshape(-1)
    k = len(eyes)
    if k == 0 or len(targets) != k or len(times) != k:
        raise InputError(f"a camera path needs K >= 1 keys with eyes, targets and times, got {k}")
    if not (np.isfinite(eyes).all() and np.isfinite(targets).all() and np.isfinite(times).all()):
        raise InputError("camera path keys contain NaN or infinite values")
    if k > 1 and not (np.diff(times) > 0).all():
        raise InputError("camera path key times must be strictly increasing")
    d = eyes - targets
    r = np.linalg.norm(d, axis=1)
    if (r <= 0).any():
        raise InputError("a camera path key has its eye on its target")
    if k == 1:
        return np.repeat(eyes, len(at), 0), np.repeat(targets, len(at), 0)
    az = np.unwrap(np.arctan2(d[:, 0], d[:, 2]))
    el = np.arcsin(np.clip(d[:, 1] / r, -1.0, 1.0))
    x = np.clip(at, times[0], times[-1])
    channels = np.column_stack([az, el, np.log(r), targets])
    out = np.column_stack([_monotone_cubic(times, c, x) for c in channels.T])
    eye = np.stack(
        [
            orbit_eye(tg, math.exp(lr), a, e)
            for a, e, lr, tg in zip(out[:, 0], out[:, 1], out[:, 2], out[:, 3:])
        ]
    )
    return eye.reshape(-1, 3), out[:, 3:]


#: ``"format"`` of a keyed camera path file (``dng render --camera PATH.json``, the studio).
CAMERA_PATH_FORMAT = "garment-studio/camera-path"


@dataclass(frozen=True)
class CameraKey:
    """A key view of a camera path: at motion frame ``frame`` the camera is at ``eye`` looking
    at ``target`` (world metres) with vertical field of view ``fov_deg``."""

    frame: float
    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    fov_deg: float = 40.0

    def as_dict(self) -> dict:
        return {
            "frame": self.frame,
            "eye": list(self.eye),
            "target": list(self.target),
            "fov_deg": self.fov_deg,
        }


def camera_keys_from_dict(data: dict, path: str | os.PathLike | None = None) -> list[CameraKey]:
    """The keys of a camera path dict ``{"format": CAMERA_PATH_FORMAT, "keys": [{"frame",
    "eye", "target", "fov_deg"?}, ...]}``, sorted by frame; ``InputError`` naming ``path``
    on anything malformed (no keys, a repeated frame, NaN, the eye on the target)."""
    if not isinstance(data, dict) or not isinstance(data.get("keys"), list):
        raise InputError('a camera path needs a "keys" list', path)
    keys = []
    for i, k in enumerate(data["keys"]):
        try:
            key = CameraKey(
                float(k["frame"]),
                tuple(float(x) for x in k["eye"]),
                tuple(float(x) for x in k["target"]),
                float(k.get("fov_deg", 40.0)),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise InputError(f"camera path key {i} is malformed ({exc!r})", path) from None
        values = np.array([key.frame, *key.eye, *key.target, key.fov_deg])
        if len(key.eye) != 3 or len(key.target) != 3 or not np.isfinite(values).all():
            raise InputError(f"camera path key {i}: eye/target need 3 finite numbers", path)
        if not 1.0 <= key.fov_deg <= 170.0 or np.allclose(key.eye, key.target):
            raise InputError(f"camera path key {i}: fov outside [1, 170] or eye on target", path)
        keys.append(key)
    if not keys:
        raise InputError("the camera path has no keys", path)
    keys.sort(key=lambda k: k.frame)
    if len({k.frame for k in keys}) != len(keys):
        raise InputError("two camera path keys share a frame", path)
    return keys


def camera_path_to_dict(keys: Sequence[CameraKey]) -> dict:
    """The JSON-ready dict of a keyed camera path (inverse of :func:`camera_keys_from_dict`)."""
    return {"format": CAMERA_PATH_FORMAT, "keys": [k.as_dict() for k in keys]}


def path_cameras(
    keys: Sequence[CameraKey], frames: Sequence[float], width: int, height: int
) -> list[Camera]:
    """The cameras of a keyed path at ``frames`` (:func:`spherical_path` for eye and target,
    the field of view interpolated linearly; held before the first key and after the last)."""
    if not keys:
        raise InputError("the camera path has no keys")
    times = np.array([k.frame for k in keys], np.float64)
    at = np.asarray(frames, np.float64)
    eyes, targets = spherical_path(
        np.array([k.eye for k in keys]), np.array([k.target for k in keys]), times, at
    )
    fov = np.interp(at, times, [k.fov_deg for k in keys])
    K = [intrinsics_from_fov(f, width, height) for f in fov]
    return [Camera(k, look_at(e, t), width, height) for k, e, t in zip(K, eyes, targets)]


def _monotone_cubic(x: np.ndarray, y: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Fritsch-Carlson monotone cubic Hermite interpolation of (x, y) at ``at`` (within x)."""
    h = np.diff(x)
    delta = np.diff(y) / h
    m = np.zeros_like(y)
    m[0], m[-1] = delta[0], delta[-1]
    for i in range(1, len(y) - 1):
        if delta[i - 1] * delta[i] > 0:
            w1, w2 = 2 * h[i] + h[i - 1], h[i] + 2 * h[i - 1]
            m[i] = (w1 + w2) / (w1 / delta[i - 1] + w2 / delta[i])
    i = np.clip(np.searchsorted(x, at, side="right") - 1, 0, len(x) - 2)
    s = (at - x[i]) / h[i]
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * y[i] + h10 * h[i] * m[i] + h01 * y[i + 1] + h11 * h[i] * m[i + 1]


def random_cameras(
    n: int, seed: int | Sequence[int], config: CameraRigConfig = CameraRigConfig()
) -> list[Camera]:
    """``n`` cameras on a circle around the body (the paper: 10 per frame).

    Azimuth is uniform in [0, 360) degrees; radius, elevation and target jitter are uniform in
    the config's ranges. ``seed`` goes to ``numpy.random.default_rng``: pass ``(base_seed,
    frame)`` to get different, reproducible cameras per frame.
    """
    if n < 0:
        raise InputError(f"number of cameras must be >= 0, got {n}")
    rng = np.random.default_rng(seed)
    az = rng.uniform(0.0, 2.0 * math.pi, n)
    radius = rng.uniform(*config.radius_range, n)
    el = np.radians(rng.uniform(*config.elevation_deg_range, n))
    jitter = rng.uniform(-config.target_jitter, config.target_jitter, (n, 3))
    K = intrinsics_from_fov(config.fov_y_deg, config.width, config.height)
    cams = []
    for a, r, e, j in zip(az, radius, el, jitter):
        target = np.asarray(config.target, np.float64) + j
        eye = orbit_eye(target, r, a, e)
        cams.append(Camera(K.copy(), look_at(eye, target), config.width, config.height))
    return cams


def orbit_path(
    n: int,
    config: CameraRigConfig = CameraRigConfig(),
    *,
    radius: float | None = None,
    elevation_deg: float | None = None,
    start_deg: float = 0.0,
    turns: float = 1.0,
) -> list[Camera]:
    """``n`` cameras evenly spaced along ``turns`` orbits around ``config.target``.

    Radius and elevation default to the middle of the config's ranges; ``start_deg`` is the
    first azimuth (0 = in front of the body, on +Z). With ``turns = 1`` the path closes without
    repeating its first camera.
    """
    if n < 0:
        raise InputError(f"number of cameras must be >= 0, got {n}")
    radius = float(np.mean(config.radius_range)) if radius is None else float(radius)
    elevation_deg = (
        float(np.mean(config.elevation_deg_range)) if elevation_deg is None else elevation_deg
    )
    if radius <= 0 or not -89.0 <= elevation_deg <= 89.0:
        raise InputError(
            f"orbit needs radius > 0 and elevation in [-89, 89], got {radius}, {elevation_deg}"
        )
    K = intrinsics_from_fov(config.fov_y_deg, config.width, config.height)
    target = np.asarray(config.target, np.float64)
    cams = []
    for i in range(n):
        az = math.radians(start_deg) + 2.0 * math.pi * turns * i / max(n, 1)
        eye = orbit_eye(target, radius, az, math.radians(elevation_deg))
        cams.append(Camera(K.copy(), look_at(eye, target), config.width, config.height))
    return cams


# --------------------------------------------------------------------------------------------
# JSON


def camera_to_dict(camera: Camera) -> dict:
    """A JSON-ready dict: ``{"width", "height", "K": 3x3 list, "extrinsic": 4x4 list}``."""
    return {
        "width": int(camera.width),
        "height": int(camera.height),
        "K": camera.K.tolist(),
        "extrinsic": camera.extrinsic.tolist(),
    }


def camera_from_dict(data: dict, path: str | os.PathLike | None = None) -> Camera:
    """Inverse of :func:`camera_to_dict`; ``InputError`` (naming ``path``) on anything malformed."""
    if not isinstance(data, dict):
        raise InputError(f"a camera must be a JSON object, got {type(data).__name__}", path)
    missing = [k for k in ("width", "height", "K", "extrinsic") if k not in data]
    if missing:
        raise InputError(f"camera is missing {', '.join(missing)}", path)
    w, h = data["width"], data["height"]
    if (
        not (isinstance(w, int) and isinstance(h, int))
        or isinstance(w, bool)
        or isinstance(h, bool)
    ):
        raise InputError(f"camera width/height must be integers, got {w!r}, {h!r}", path)
    try:
        K = np.array(data["K"], np.float64)
        E = np.array(data["extrinsic"], np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"camera matrices are not numeric arrays ({exc})", path) from None
    try:
        return Camera(K, E, w, h)
    except InputError as exc:
        raise InputError(exc.problem, path) from None


def save_cameras(path: str | os.PathLike, cameras: Sequence[Camera]) -> None:
    """Write cameras to a JSON file, atomically."""
    write_json(
        path,
        {
            "format": CAMERA_FILE_FORMAT,
            "version": CAMERA_FILE_VERSION,
            "cameras": [camera_to_dict(c) for c in cameras],
        },
    )


def load_cameras(path: str | os.PathLike) -> list[Camera]:
    """Read a file written by :func:`save_cameras`; ``InputError`` naming the file if malformed."""
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"not valid JSON ({exc})", path) from None
    if not isinstance(data, dict) or data.get("format") != CAMERA_FILE_FORMAT:
        raise InputError(f"not a camera file (expected format {CAMERA_FILE_FORMAT!r})", path)
    if data.get("version") != CAMERA_FILE_VERSION:
        raise InputError(f"unsupported camera file version {data.get('version')!r}", path)
    cams = data.get("cameras")
    if not isinstance(cams, list):
        raise InputError("'cameras' must be a list", path)
    out = []
    for i, c in enumerate(cams):
        try:
            out.append(camera_from_dict(c))
        except InputError as exc:
            raise InputError(f"camera {i}: {exc.problem}", path) from None
    return out
