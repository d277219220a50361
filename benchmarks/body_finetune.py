"""Fine-tuning the renderer to a new body shape against training it from scratch (the paper's
section (iii): fine-tuning takes 20 to 30% of the iterations of training from scratch).

Usage: ``python benchmarks/body_finetune.py PROJECT --shape NAME k=v [k=v ...] [--fractions
0.1 0.25 0.5] [--json]``

``dng finetune PROJECT --body-shape k=v ... --name NAME --no-joint2coarse`` makes the body's
sub-project (``PROJECT/finetune/body-NAME/``: the training motion's proxy and target simulated
on the new body, its data set) and fine-tunes every renderer weight from the project's model.
Here the fine-tune runs once for each budget, a fraction of the project's renderer steps, each
with its own learning-rate schedule (:func:`training.renderer.train.finetune_body`), and a
renderer of the project's configuration trains from scratch on the same data for all the
steps. All train and are scored on the simulated proxy (the renderers alone). Each is scored,
garment-region MSE, on the training motion from unseen cameras on the new body
(``testset/MOTION`` of the sub-project), beside the project's model as it is ("before"). The
fraction reached is the smallest budget whose MSE is no worse than from scratch's.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict
from pathlib import Path

from core.body.shape import BodyShape
from core.errors import InputError
from core.project import Project
from pipeline.config import project_config, renderer_config
from pipeline.finetune import finetune_body_shape
from pipeline.stages.dataset import stage_testset
from training.dataset import GarmentDataset


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("project")
    ap.add_argument("--shape", nargs="+", required=True, metavar="NAME K=V")
    ap.add_argument("--fractions", type=float, nargs="+", default=[0.1, 0.25, 0.5])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    import torch

    torch.set_num_threads(1)
    name, pairs = args.shape[0], args.shape[1:]
    try:
        row = measure(Path(args.project), name, pairs, sorted(args.fractions))
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    command = (
        f"python benchmarks/body_finetune.py PROJECT --shape {name} {' '.join(pairs)} "
        f"--fractions {' '.join(map(str, sorted(args.fractions)))}"
    )
    if args.json:
        print(json.dumps({"command": command, **row}))
        return 0
    print(command)
    print("| renderer | steps | garment-region MSE | seconds |")
    print("| --- | --- | --- | --- |")
    for r in row["rows"]:
        secs = "" if r["seconds"] is None else f"{r['seconds']:.0f}"
        print(f"| {r['name']} | {r['steps']} | {r['mse']:.4f} | {secs} |")
    reached = row["fraction_reached"]
    print("fraction reached:", "not within the budgets" if reached is None else reached)
    return 0


def score(model_path: Path, data) -> float:
    from training.baselines import load_for_evaluation
    from training.evaluate import EvalConfig, evaluate_motion

    results, _ = evaluate_motion({"m": (load_for_evaluation(model_path), data)}, EvalConfig())
    return results["m"].metrics.summary()["mse_masked"]["mean"]


def measure(root: Path, name: str, pairs: list[str], fractions: list[float]) -> dict:
    from training.renderer.train import finetune_body, train_renderer

    config = project_config(Project(root))
    shape = BodyShape.parse(pairs, config.body)
    cfg = renderer_config(config)
    parent = root / "renderer" / "renderer.pt"
    budgets = [max(1, math.ceil(f * cfg.steps)) for f in fractions]
    start = time.perf_counter()
    first = finetune_body_shape(
        root, shape, name, steps=budgets[0], joint2coarse=False, progress=False
    )
    setup = time.perf_counter() - start
    sub = Project(first.out_dir)
    sub_config = project_config(sub)
    motion = sub_config.train_motion.name
    stage_testset(sub, sub_config, motion)
    train = GarmentDataset(sub.root, source="sim")
    test = GarmentDataset(sub.root, source="sim", split=motion)
    rows = [{"name": "before (the project's)", "steps": 0, "seconds": None, "path": parent}]
    rows.append({"name": "fine-tuned", "steps": budgets[0], "seconds": None,
                 "path": first.model_path})  # fmt: skip
    bench = sub.root / "bench"
    for steps in budgets[1:]:
        t0 = time.perf_counter()
        res = finetune_body(parent, train, bench / f"finetune-{steps}", steps=steps,
                            progress=False)  # fmt: skip
        rows.append({"name": "fine-tuned", "steps": steps,
                     "seconds": time.perf_counter() - t0, "path": res.model_path})  # fmt: skip
    t0 = time.perf_counter()
    scratch = train_renderer(train, bench / "scratch", cfg, progress=False)
    rows.append({"name": "from scratch", "steps": cfg.steps,
                 "seconds": time.perf_counter() - t0, "path": scratch.model_path})  # fmt: skip
    for r in rows:
        r["mse"] = score(r.pop("path"), test)
    best = rows[-1]["mse"]
    reached = next((r["steps"] / cfg.steps for r in rows[1:-1] if r["mse"] <= best), None)
    return {
        "shape": {"name": name, **asdict(shape)},
        "setup_seconds": setup,
        "rows": rows,
        "fraction_reached": reached,
    }


if __name__ == "__main__":
    raise SystemExit(main())
