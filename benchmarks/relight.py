"""Relighting a trained renderer from two example renders (the paper's section (iv)), measured.

Usage: ``python benchmarks/relight.py PROJECT [--lights low-sun overcast] [--split
validation|test] [--steps 100] [--out DIR] [--json]``

For each light (a preset of :data:`core.lighting.PRESETS`, an environment image or a lighting
JSON), the held-out samples of the split (the renderers' validation motion, or every test
motion, from their unseen cameras) are rendered again under that light
(:class:`pipeline.finetune.LitDataset`). Three renderers are scored on them, garment-region MSE
and SSIM as the report computes them, and the distance of the garment's mean colour to the
ground truth's (mean over frames of the norm of the RGB difference, in [0, 1] units):

- **before**: the project's renderer as it is;
- **after**: fine-tuned to the light by :func:`pipeline.finetune.finetune_lighting` (two
  samples of the data set rendered under the light; the last two decoder layers train);
- **from scratch**: a renderer of the project's configuration trained from scratch, for the
  project's steps, on the whole data set rendered under the light (the ceiling).

The gap closed is (before - after) / (before - from scratch) of the garment-region MSE.
Seconds are wall-clock on this machine, one torch thread. ``OUT/relight-LIGHT.png`` shows the
ground truth, before, after and from scratch on three held-out samples.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from core.errors import InputError
from core.lighting import load_lighting
from core.project import Project
from core.shading import contact_sheet, write_png
from pipeline.config import available_test_motions, project_config, renderer_config
from pipeline.finetune import LitDataset, finetune_lighting, lighting_backdrop
from training.dataset import GarmentDataset

#: Held-out samples shown in the picture.
SHOWN = 3


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("project")
    ap.add_argument("--lights", nargs="+", default=["low-sun", "overcast"])
    ap.add_argument("--split", choices=("validation", "test"), default="validation")
    ap.add_argument("--steps", type=int, default=100, help="fine-tuning steps")
    ap.add_argument(
        "--scratch-steps", type=int, default=None, help="from scratch (default: the project's)"
    )
    ap.add_argument("--out", default=None, help="folder of the from-scratch runs and pictures")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    import torch

    torch.set_num_threads(1)
    try:
        rows = [
            measure(Path(args.project), light, args.split, args.steps, args.scratch_steps, args.out)
            for light in args.lights
        ]
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    command = (
        f"python benchmarks/relight.py PROJECT --lights {' '.join(args.lights)} "
        f"--split {args.split} --steps {args.steps}"
        + ("" if args.scratch_steps is None else f" --scratch-steps {args.scratch_steps}")
    )
    if args.json:
        print(json.dumps({"command": command, "rows": [flat(r) for r in rows]}))
        return 0
    print(f"{command}: garment-region MSE / SSIM / mean-colour distance on the {args.split} split")
    print("| light | before | after (two examples) | from scratch | gap closed | seconds |")
    print("| --- | --- | --- | --- | --- | --- |")
    for r in rows:
        cells = [
            f"{r[m]['mse']:.4f} / {r[m]['ssim']:.3f} / {r[m]['colour']:.3f}"
            for m in ("before", "after", "scratch")
        ]
        secs = f"{r['after']['seconds']:.0f} / {r['scratch']['seconds']:.0f}"
        print(f"| {r['light']} | {' | '.join(cells)} | {r['gap_closed']:.2f} | {secs} |")
    return 0


def flat(row: dict) -> dict:
    """A row as one level of figures (the results page's benchmark tables)."""
    out = {"light": row["light"], "held_out": ", ".join(row["held_out"])}
    for model in ("before", "after", "scratch"):
        for key, value in row[model].items():
            if value is not None:
                out[f"{model}_{key}"] = value
    out["gap_closed"] = row["gap_closed"]
    return out


def held_out(root: Path, split: str) -> list[str]:
    config = project_config(Project(root))
    if split == "validation":
        if config.renderer_validation is None:
            raise InputError("the project has no renderer validation motion", root)
        return [config.renderer_validation]
    return [m.name for m in available_test_motions(config)]


def score(model, data) -> dict:
    """Garment-region MSE and SSIM (means over frames t and t+1) and the mean-colour distance
    of frame t's garment region, and the first renders of frame t."""
    import torch

    from training.evaluate import EvalConfig, evaluate_motion, garment_region

    results, _ = evaluate_motion({"m": (model, data)}, EvalConfig(sheet_samples=SHOWN))
    summary = results["m"].metrics.summary()
    distances = []
    frames = torch.cat(results["m"].frames_t)
    for i in range(len(data)):
        s = data[i]
        region = garment_region({k: v[None] for k, v in s.items()})[0, 0].numpy() > 0
        if region.any():
            ours = frames[i].numpy()[:, region].mean(1)
            real = s["target"][1].numpy()[:, region].mean(1)
            distances.append(float(np.linalg.norm(ours - real)))
    return {
        "mse": summary["mse_masked"]["mean"],
        "ssim": summary["ssim_masked"]["mean"],
        "colour": float(np.mean(distances)),
        "tiles": results["m"].tiles,
    }


def measure(
    root: Path, light: str, split: str, steps: int, scratch_steps: int | None, out: str | None
) -> dict:
    from training.baselines import load_for_evaluation
    from training.renderer.train import train_renderer

    config = project_config(Project(root))
    lit = load_lighting(light)
    out_dir = Path(out) if out else root / "finetune" / "bench-relight"
    tests = []
    base0 = GarmentDataset(root, source=config.renderer_source)
    backdrop = lighting_backdrop(light, lit, None, base0.samples[0][2])
    for motion in held_out(root, split):
        base = GarmentDataset(root, source="joint2coarse", split=motion)
        tests.append(LitDataset(base, lit, backdrop))
    models = {}
    models["before"] = (root / "renderer" / "renderer.pt", None)
    start = time.perf_counter()
    tuned = finetune_lighting(root, light, f"bench-{Path(lit.name).stem}", steps=steps,
                              progress=False)  # fmt: skip
    models["after"] = (tuned.model_path, time.perf_counter() - start)
    start = time.perf_counter()
    full = LitDataset(base0, lit, backdrop)
    cfg = renderer_config(config)
    scratch = train_renderer(
        full, out_dir / f"scratch-{Path(lit.name).stem}", cfg, steps=scratch_steps, progress=False
    )
    models["scratch"] = (scratch.model_path, time.perf_counter() - start)
    row: dict = {"light": lit.name, "held_out": held_out(root, split)}
    tiles: list[np.ndarray] = []
    for name, (path, seconds) in models.items():
        model = load_for_evaluation(path)
        parts = [score(model, d) for d in tests]
        n = [len(d) for d in tests]
        row[name] = {
            k: float(np.average([p[k] for p in parts], weights=n))
            for k in ("mse", "ssim", "colour")
        }
        row[name]["seconds"] = seconds
        tiles.append(parts[0]["tiles"])
    gt = [
        (tests[0].frames(i)["target"][1].transpose(1, 2, 0) * 255 + 0.5).astype(np.uint8)
        for i in range(SHOWN)
    ]
    gap = row["before"]["mse"] - row["scratch"]["mse"]
    row["gap_closed"] = (row["before"]["mse"] - row["after"]["mse"]) / gap if gap else float("nan")
    sheet = contact_sheet(
        gt + [t for ts in tiles for t in ts],
        [f"{lit.name}: ground truth"] * SHOWN
        + [label for label in ("before", "after", "from scratch") for _ in range(SHOWN)],
        columns=SHOWN,
    )
    out_dir.mkdir(parents=True, exist_ok=True)
    write_png(out_dir / f"relight-{Path(lit.name).stem}.png", sheet)
    return row


if __name__ == "__main__":
    raise SystemExit(main())
