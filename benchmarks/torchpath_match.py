"""How far the torch-only render path's images are from today's path (``dng render``).

Plays a trained project twice, frame by frame as a viewer streams it: through
:class:`pipeline.playback.Playback` (Embree rasterizer, numpy features) and through
:class:`training.torchpath.TorchPlayer` on a bundle of the same project (everything in torch),
with the project's Joint2Coarse or another model file (``--joint2coarse``, e.g. ours, trained
beside the paper's as ``joint2coarse/compare-ours/joint2coarse.pt``)::

    python benchmarks/torchpath_match.py PROJECT [--joint2coarse FILE] [--frames 8] \
        [--sizes 128 256 512] [--azimuth 30] [--device cpu]

Figures per size, over every pixel and channel of the streamed frames (uint8 levels): mean
absolute difference, share of values more than 2 levels apart, largest difference; and the
largest distance between the two paths' proxies (m). The two rasterizers break ties on
triangle edges differently, which moves single pixels; nothing else differs.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from core.errors import InputError
from pipeline.playback import Playback, load_motion_for
from pipeline.torch_export import export_bundle
from training.torchpath import TorchPlayer


def measure(
    project: str,
    joint2coarse: str | None,
    frames: int,
    sizes: list[int],
    azimuth: float,
    device: str,
) -> dict:
    """The figures of the module docstring, per size: a dict ready for JSON."""
    pb = Playback(project, joint2coarse_path=joint2coarse)
    motion = pb.config.train_motion.name
    pb.set_motion(load_motion_for(pb.project, motion, frames=frames))
    frames = min(frames, pb.num_frames)
    with tempfile.TemporaryDirectory() as tmp:
        bundle = Path(tmp) / "bundle.pt"
        export_bundle(project, bundle, frames=frames, joint2coarse=joint2coarse)
        player = TorchPlayer(bundle, device)
    player.set_clip(motion)
    proxy = player.proxy(range(frames)).cpu().numpy()
    proxy_m = max(float(np.abs(proxy[t] - pb.proxy_vertices(t)).max()) for t in range(frames))
    rows = []
    for size in sizes:
        diffs = []
        for t in range(frames):
            cam = pb.default_camera(t, size, size, azimuth_deg=azimuth)
            ref = pb.render(t, cam).astype(np.int16)
            out = player.render(t, cam).cpu().numpy().astype(np.int16)
            diffs.append(np.abs(out - ref))
        d = np.stack(diffs)
        rows.append(
            {
                "size": size,
                "frames": frames,
                "mean_levels": float(d.mean()),
                "share_over_2_levels": float((d > 2).mean()),
                "max_levels": int(d.max()),
            }
        )
    return {
        "project": str(project),
        "joint2coarse": player.joint2coarse.config.model,
        "motion": motion,
        "device": str(player.device),
        "proxy_max_m": proxy_m,
        "rows": rows,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("project")
    parser.add_argument("--joint2coarse", default=None, help="another Joint2Coarse model file")
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--sizes", type=int, nargs="+", default=[128, 256, 512])
    parser.add_argument("--azimuth", type=float, default=30.0)
    parser.add_argument("--device", default="cpu", help="the torch path's device")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    try:
        result = measure(
            args.project, args.joint2coarse, args.frames, args.sizes, args.azimuth, args.device
        )
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(
        f"{result['project']}: Joint2Coarse {result['joint2coarse']}, motion {result['motion']}, "
        f"torch path on {result['device']}; proxies differ by {result['proxy_max_m']:.2g} m at most"
    )
    print(f"{'size':>5} {'frames':>6} {'mean levels':>11} {'> 2 levels':>10} {'max':>4}")
    for r in result["rows"]:
        print(
            f"{r['size']:>5} {r['frames']:>6} {r['mean_levels']:>11.5f} "
            f"{100 * r['share_over_2_levels']:>9.4f}% {r['max_levels']:>4}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
