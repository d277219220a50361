"""How far per-vertex motion features, interpolated across each triangle, are from the exact
per-pixel ones.

The renderer's motion features are ``exp(-|x - joint|^2 / sigma)``. The studio evaluates them
at the proxy's vertices and interpolates with the rasterizer's barycentrics
(:func:`core.features.motion_feature_map`); the exact map evaluates them at each pixel's own
surface point. The Gaussian is not linear in ``x``, so the two differ inside every triangle,
most where a triangle is large next to a joint. This prints that difference on a simulated
proxy, over the garment's pixels, for several frames and views::

    python benchmarks/feature_interpolation.py PROJECT [--motion dance] [--size 256]

PROJECT is a project folder made by ``dng demo`` (it reads ``sim/MOTION-proxy/cache.npz`` and
``motions/MOTION.bvh``). Figures: mean, p99 and max absolute error over garment pixels and
channels (features lie in [0, 1]), and the same relative to the pixel's largest channel.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from core.camera import make_camera
from core.errors import InputError
from core.features import DEFAULT_FRAME_OFFSETS, interpolate, joint_window, vertex_motion_features
from core.motion.load import load_motion
from core.raster import MeshScene
from core.sim.cache import load_cache


def surface_points(fragments, faces: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """World position of each garment pixel's hit point: (N, 3), N = pixels with a hit."""
    hit = fragments.face_id >= 0
    corners = vertices[faces[fragments.face_id[hit]]]  # (N, 3, 3)
    return np.einsum("nk,nkc->nc", fragments.barycentrics[hit].astype(np.float64), corners)


def compare_frame(
    vertices: np.ndarray, faces: np.ndarray, window: np.ndarray, camera, sigma: float
) -> dict[str, np.ndarray]:
    """Absolute errors of interpolated features against exact ones on one view.

    Returns ``abs`` (N, C) and ``rel`` (N, C) (error over the pixel's largest exact channel).
    """
    fragments = MeshScene(vertices, faces).rasterize(camera)
    hit = fragments.face_id >= 0
    per_vertex = vertex_motion_features(vertices, window, sigma)
    interpolated = interpolate(fragments, faces, per_vertex)[hit]
    exact = vertex_motion_features(surface_points(fragments, faces, vertices), window, sigma)
    err = np.abs(interpolated.astype(np.float64) - exact)
    peak = np.maximum(exact.max(axis=1, keepdims=True), 1e-6)
    return {"abs": err, "rel": err / peak}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("project")
    parser.add_argument("--motion", default="dance")
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--frames", type=int, default=8, help="frames spread over the clip")
    parser.add_argument("--views", type=int, default=4, help="cameras round the body")
    parser.add_argument("--sigma", type=float, default=0.1)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    root = Path(args.project)
    cache_path = root / "sim" / f"{args.motion}-proxy" / "cache.npz"
    motion_path = root / "motions" / f"{args.motion}.bvh"
    try:
        cache = load_cache(cache_path)
        joints = load_motion(motion_path).joint_positions()
    except (InputError, OSError) as exc:
        print(f"feature_interpolation: error: {exc}", file=sys.stderr)
        return 2
    frames = np.linspace(
        max(DEFAULT_FRAME_OFFSETS), min(len(joints), len(cache.positions)) - 1, args.frames
    ).astype(int)
    errs, rels, pixels = [], [], 0
    start = time.perf_counter()
    for t in frames:
        v = cache.positions[t].astype(np.float64)
        centre = v.mean(axis=0)
        window = joint_window(joints, int(t))
        for k in range(args.views):
            a = 2 * np.pi * k / args.views
            eye = centre + 2.5 * np.array([np.sin(a), 0.15, np.cos(a)])
            cam = make_camera(eye, centre, width=args.size, height=args.size)
            r = compare_frame(v, cache.faces, window, cam, args.sigma)
            errs.append(r["abs"].ravel())
            rels.append(r["rel"].ravel())
            pixels += len(r["abs"])
    e, q = np.concatenate(errs), np.concatenate(rels)
    out = {
        "project": str(root),
        "motion": args.motion,
        "size": args.size,
        "frames": [int(t) for t in frames],
        "views": args.views,
        "garment_pixels": pixels,
        "vertices": int(cache.positions.shape[1]),
        "faces": int(len(cache.faces)),
        "abs_mean": float(e.mean()),
        "abs_p99": float(np.percentile(e, 99)),
        "abs_max": float(e.max()),
        "rel_mean": float(q.mean()),
        "rel_p99": float(np.percentile(q, 99)),
        "seconds": time.perf_counter() - start,
    }
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        print(
            f"{args.motion}: {out['vertices']} vertices, {pixels} garment pixels "
            f"({len(frames)} frames x {args.views} views at {args.size} px), sigma {args.sigma}"
        )
        print(
            f"  |interpolated - exact|: mean {out['abs_mean']:.2e}  p99 {out['abs_p99']:.2e}  "
            f"max {out['abs_max']:.2e}  (features in [0, 1])"
        )
        print(
            f"  relative to the pixel's largest channel: mean {out['rel_mean']:.2e}  "
            f"p99 {out['rel_p99']:.2e}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
