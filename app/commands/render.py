"""``dng render PROJECT --motion M --out OUT``: neural renders of any motion, as a video or frames."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from core.camera import (
    CAMERA_PATH_FORMAT,
    CameraKey,
    camera_from_dict,
    camera_keys_from_dict,
    load_cameras,
    path_cameras,
    resize_camera,
)
from core.compositing import load_image
from core.errors import InputError
from core.lighting import load_lighting
from core.shading import ShadingConfig
from pipeline.finetune import saved_lighting
from pipeline.playback import FrameWriter, Playback, load_motion_for

#: Image size (pixels per side) of the built-in cameras when --size is not given.
DEFAULT_SIZE = 256
CAMERAS = ("orbit", "front")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "render",
        help="render a motion with a project's trained networks (MP4, GIF or PNG frames)",
        description=(
            "Play a motion through the project: Joint2Coarse predicts the proxy of every "
            "frame, the neural renderer draws the garment over the body-only background. "
            "Writes an MP4, an animated GIF or a folder of numbered PNGs, atomically, and "
            "prints the time per frame."
        ),
    )
    p.add_argument("project", help="project folder with joint2coarse/ and renderer/ trained")
    p.add_argument(
        "--motion",
        required=True,
        metavar="M.bvh|NAME|KIND",
        help="a motion file (BVH, glTF/GLB or DeepMimic; any rig, retargeted), a project motion (e.g. dance) or a procedural "
        "kind (walk, twirl, ...)",
    )
    p.add_argument("--frames", type=int, default=None, help="first N frames (procedural: make N)")
    p.add_argument("--seed", type=int, default=0, help="seed of a procedural motion")
    p.add_argument(
        "--camera",
        default="orbit",
        metavar="orbit|front|FILE.json",
        help="orbit: circle the body once over the clip; front: face it; a JSON file: one "
        "camera (core.camera camera_to_dict) or a list (frame t uses camera t, the last one "
        "after the list ends), a dng camera file, or a keyed camera path (the studio's "
        '\'Save path JSON\': {"format": "garment-studio/camera-path", "keys": [{"frame", '
        '"eye", "target", "fov_deg"}, ...]}, interpolated smoothly round the body). '
        "The built-in cameras follow the body.",
    )
    p.add_argument(
        "--size",
        type=int,
        default=None,
        metavar="PX",
        help=f"image width (and height) in pixels (default {DEFAULT_SIZE}; a JSON camera "
        "keeps its own size unless given)",
    )
    p.add_argument("--elevation", type=float, default=10.0, help="built-in cameras, degrees")
    p.add_argument("--azimuth", type=float, default=0.0, help="first azimuth, degrees (0 front)")
    p.add_argument(
        "--out", required=True, metavar="video.mp4|anim.gif|DIR/", help="output file or folder"
    )
    p.add_argument("--fps", type=float, default=None, help="video frame rate (default: motion's)")
    p.add_argument(
        "--side-by-side",
        action="store_true",
        help="put the simulated target (project motions) or the shaded Joint2Coarse proxy "
        "beside each render",
    )
    p.add_argument(
        "--renderer",
        default=None,
        metavar="MODEL.pt",
        help="renderer model (default PROJECT/renderer/renderer.pt), e.g. a fine-tuned one",
    )
    p.add_argument(
        "--backdrop",
        default=None,
        metavar="IMG",
        help="composite the body over this image (for background fine-tuned renderers; "
        "default: backdrop-0.png beside --renderer when there is one)",
    )
    p.add_argument(
        "--lighting",
        default=None,
        metavar="LIGHT",
        help="light the body and the reference with a preset, an environment image or a "
        "lighting.json (default: lighting.json beside --renderer when there is one, else the "
        "data set's studio light)",
    )
    p.add_argument("--device", default="cpu", help="torch device of the renderer (cpu, cuda)")
    p.set_defaults(handler=run)


def cameras_from_file(path) -> list:
    """Cameras of a JSON file: one camera dict, a list of them, or a ``save_cameras`` file;
    or the :class:`core.camera.CameraKey` s of a keyed camera path."""
    path = Path(path)
    if not path.is_file():
        raise InputError("camera file not found", path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"not valid JSON ({exc})", path) from None
    if isinstance(data, dict) and (data.get("format") == CAMERA_PATH_FORMAT or "keys" in data):
        cams = camera_keys_from_dict(data, path)
    elif isinstance(data, dict) and "format" in data:
        cams = load_cameras(path)
    elif isinstance(data, list):
        cams = []
        for i, c in enumerate(data):
            try:
                cams.append(camera_from_dict(c))
            except InputError as exc:
                raise InputError(f"camera {i}: {exc.problem}", path) from None
    else:
        cams = [camera_from_dict(data, path)]
    if not cams:
        raise InputError("no cameras in the file", path)
    return cams


def camera_for_frame(pb, t: int, n: int, args, file_cameras) -> object:
    """The camera of frame t of n."""
    if file_cameras is not None and isinstance(file_cameras[0], CameraKey):
        size = args.size or DEFAULT_SIZE
        return path_cameras(file_cameras, [t], size, size)[0]
    if file_cameras is not None:
        cam = file_cameras[min(t, len(file_cameras) - 1)]
        if args.size is not None and cam.width != args.size:
            h = max(1, round(args.size * cam.height / cam.width))
            cam = resize_camera(cam, args.size, h)
        return cam
    size = args.size or DEFAULT_SIZE
    azimuth = args.azimuth + (360.0 * t / n if args.camera == "orbit" else 0.0)
    return pb.default_camera(t, size, size, azimuth, args.elevation)


def labelled(images: list, labels: list[str]):
    """Images side by side, each with its label in the top-left corner: (H, W', 3) uint8."""
    from PIL import Image, ImageDraw

    strip = Image.fromarray(np.concatenate(images, axis=1))
    draw = ImageDraw.Draw(strip)
    x = 0
    for im, label in zip(images, labels):
        draw.text((x + 3, 2), label, fill=(0, 0, 0))
        x += im.shape[1]
    return np.asarray(strip)


def run(args: argparse.Namespace) -> int:

    import torch
    from tqdm import tqdm

    if args.size is not None and args.size < 8:
        raise InputError(f"--size must be at least 8 pixels, got {args.size}")
    if args.frames is not None and args.frames < 1:
        raise InputError(f"--frames must be >= 1, got {args.frames}")
    file_cameras = None
    if args.camera not in CAMERAS:
        if not args.camera.lower().endswith(".json"):
            raise InputError(f"--camera must be orbit, front or a .json file, got {args.camera!r}")
        file_cameras = cameras_from_file(args.camera)
    torch.set_num_threads(1)  # one thread is the robust choice beside other work (see pipeline)
    lighting = None if args.lighting is None else load_lighting(args.lighting)
    if lighting is None and args.renderer is not None:
        lighting = saved_lighting(args.renderer)
    shading = None if lighting is None else ShadingConfig(lighting=lighting)
    pb = Playback(args.project, device=args.device, renderer_path=args.renderer, shading=shading)
    pb.renderer  # noqa: B018 - a missing or bad model fails now, before any work
    backdrop = args.backdrop
    if backdrop is None and args.renderer is not None:
        beside = Path(args.renderer).parent / "backdrop-0.png"
        backdrop = beside if beside.is_file() else None
    if backdrop is not None:
        pb.set_backdrop(load_image(backdrop))
    motion = load_motion_for(pb.project, args.motion, frames=args.frames, seed=args.seed)
    pb.set_motion(motion)
    n = pb.num_frames
    fps = args.fps or pb.fps
    writer = FrameWriter(args.out, fps)
    times = {"background": [], "raster+network": []}
    start = time.perf_counter()
    label = None
    with writer, tqdm(total=n, desc="render", unit="frame", leave=False) as bar:
        for t in range(n):
            cam = camera_for_frame(pb, t, n, args, file_cameras)
            image = pb.render(t, cam)
            for k in times:
                times[k].append(pb.last_timings[k])
            if args.side_by_side:
                ref, label = pb.reference_image(t, cam)
                image = labelled([image, ref], ["neural render", label])
            writer.append(image)
            bar.set_postfix({"ms": f"{pb.last_timings['total']:.0f}"}, refresh=False)
            bar.update(1)
    wall = time.perf_counter() - start
    bg, net = (float(np.median(times[k])) for k in ("background", "raster+network"))
    h, w = writer.size
    print(
        f"wrote {args.out}: {n} frames, {w}x{h}, {fps:g} fps"
        + (f" (beside: {label})" if label else "")
    )
    print(
        f"per frame (median): Joint2Coarse {pb.joint2coarse_ms:.2f} ms (batch), background {bg:.1f} ms, "
        f"raster+network {net:.1f} ms, render total {pb.joint2coarse_ms + bg + net:.1f} ms "
        f"({1e3 / (pb.joint2coarse_ms + bg + net):.1f} fps); {1e3 * wall / n:.0f} ms/frame "
        "with writing"
    )
    return 0
