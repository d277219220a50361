"""The report's headline ratio, ours over DNR, at other training seeds: its spread.

Usage: ``python benchmarks/renderer_seeds.py PROJECT [--seeds 1] [--json]``

Trains our renderer and DNR as the project does (its preset, settings and data set, over its
``renderer_source`` proxy), once per ``--seeds``, in a temporary folder (the project's models
are left as they are), and scores both on the project's test sets of protocol U (the unseen
motions) and P (the training motion), from their unseen cameras, on Joint2Coarse's proxy, as
``dng eval`` does. Prints each seed's garment-region MSE of both and the ratio ours / DNR per
protocol (U: the mean over its motions of each method's MSE, as the report pools it), beside
the project's own seed from ``eval/report.json``, and the ratios' spread over the seeds. This
reports the test split; it chooses nothing. ``--json``: ``rows`` (seed, protocol, both MSEs,
the ratio) for ``dng report PROJECT --results docs/results.md --bench renderer-seeds=FILE``,
and the ``spread`` per protocol.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tempfile
import time
from dataclasses import replace

import numpy as np
import torch

from core.errors import InputError
from core.project import Project
from pipeline.config import available_test_motions, baseline_config, project_config, renderer_config
from training.baselines import load_for_evaluation, train_baseline
from training.dataset import GarmentDataset
from training.evaluate import EvalConfig, evaluate_motion
from training.renderer.train import train_renderer

METHODS = ("ours", "dnr")


def ratios(values: dict, protocols: dict) -> dict:
    """Ours / DNR per protocol from ``values`` {method: {motion: per-frame garment-region MSE}}
    and ``protocols`` {name: [motions]}: each method's mean over the protocol's frames (pooled
    over its motions, as the report pools them), divided."""
    out = {}
    for name, motions in protocols.items():
        means = {
            m: float(np.mean(np.concatenate([values[m][k] for k in motions]))) for m in METHODS
        }
        out[name] = {
            **{f"{m}_mse": v for m, v in means.items()},
            "ratio": means["ours"] / means["dnr"],
        }
    return out


def _own_seed(project: Project) -> dict | None:
    """The project's own models' figures from ``eval/report.json`` (None when it has none)."""
    path = project.path("eval", "report.json")
    if not path.is_file():
        return None
    report = json.loads(path.read_text(encoding="utf-8"))
    try:
        return {
            name: {
                **{f"{m}_mse": part["methods"][m]["mse_masked"]["mean"] for m in METHODS},
                "ratio": part["mse_masked_ratio_ours_to_dnr"],
            }
            for name, part in (("U", report), ("P", report["protocol_p"]))
        }
    except KeyError:
        return None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("project")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(1)
    log = (lambda m: print(m, file=sys.stderr, flush=True)) if args.json else print
    try:
        project = Project(args.project)
        config = project_config(project)
        tests = [m.name for m in available_test_motions(config)]
        protocols = {"U": tests, "P": [config.train_motion.name]}
        for motion in [*tests, config.train_motion.name]:
            if not project.path(f"testset/{motion}", "samples.json").is_file():
                raise InputError(
                    f"no test set of {motion}: run dng demo or dng eval first", project.root
                )
        data = GarmentDataset(project.root, source=config.renderer_source)
        scored = {
            motion: GarmentDataset(project.root, source="joint2coarse", split=motion)
            for motion in [*tests, config.train_motion.name]
        }
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    runs = []
    for seed in args.seeds:
        seeded = replace(config, seed=seed)
        models, seconds = {}, {}
        quiet = contextlib.redirect_stdout(sys.stderr) if args.json else contextlib.nullcontext()
        with tempfile.TemporaryDirectory() as tmp, quiet:
            for method in METHODS:
                start = time.perf_counter()
                if method == "ours":
                    result = train_renderer(
                        data, f"{tmp}/ours", renderer_config(seeded), progress=False
                    )
                else:
                    cfg = baseline_config(seeded, method)
                    result = train_baseline(method, data, f"{tmp}/{method}", cfg, progress=False)
                seconds[method] = time.perf_counter() - start
                models[method] = load_for_evaluation(result.model_path)
                log(f"seed {seed}: {method} trained in {seconds[method]:.0f} s")
        values = {m: {} for m in METHODS}
        for motion, dataset in scored.items():
            results, _ = evaluate_motion(
                {m: (models[m], dataset) for m in METHODS}, EvalConfig(sheet_samples=0)
            )
            for m in METHODS:
                v = np.asarray(results[m].metrics.values["mse_masked"], np.float64)
                values[m][motion] = v[np.isfinite(v)]
        runs.append({"seed": seed, "train_s": seconds, "ratios": ratios(values, protocols)})
        for name, r in runs[-1]["ratios"].items():
            log(
                f"seed {seed}, {name}: ours {r['ours_mse']:.4f}, DNR {r['dnr_mse']:.4f}, ours / DNR {r['ratio']:.3f}"
            )
    own = _own_seed(project)
    every = ([{"seed": config.seed, "ratios": own}] if own else []) + runs
    spread = {
        name: {
            "seeds": [r["seed"] for r in every],
            "ratios": [r["ratios"][name]["ratio"] for r in every],
            "mean": float(np.mean([r["ratios"][name]["ratio"] for r in every])),
            "range": float(np.ptp([r["ratios"][name]["ratio"] for r in every])),
        }
        for name in protocols
    }
    rows = [{"seed": r["seed"], "protocol": p, **r["ratios"][p]} for r in every for p in protocols]
    if args.json:
        command = "python benchmarks/renderer_seeds.py PROJECT --seeds " + " ".join(
            str(seed) for seed in args.seeds
        )
        out = {"command": command, "rows": rows, "protocols": protocols, "project_seed": own}
        out["runs"] = runs
        print(json.dumps({**out, "spread": spread}))
    else:
        for name, s in spread.items():
            shown = ", ".join(f"seed {k} {v:.3f}" for k, v in zip(s["seeds"], s["ratios"]))
            print(f"{name}: ours / DNR, garment-region MSE on Joint2Coarse's proxy: {shown}; "
                  f"mean {s['mean']:.3f}, range {s['range']:.3f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
