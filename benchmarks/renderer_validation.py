"""A renderer or a baseline on a project's validation motion: what its settings are chosen on.

Usage: ``python benchmarks/renderer_validation.py PROJECT --method ours|pix2pix|dnr|dnr-gan
[--set KEY=VALUE ...] [--seeds 0 1] [--source sim|joint2coarse] [--steps N] [--device cpu|cuda]
[--workers W] [--keep DIR] [--json]``

Trains the method as the project would (its preset and settings; ``--set`` changes one field of
the method's configuration, as ``dng train renderer`` / ``dng train baselines`` read it, e.g.
``--set lr_g=2e-4 --set lr_decay_from=0.5``) on the project's data set (its training motion's
images over the proxy ``--source`` names: the simulated one, or Joint2Coarse's prediction of it;
default the project's ``renderer_source``), once per ``--seeds``, in a temporary folder: the
project's models are left as they are. ``--steps`` changes the budget (default the project's
``renderer_steps``; a baseline trains as many steps as ours, on our schedule, so every method
gets the longer budget alike); ``--device`` trains on a GPU, with ``--workers`` loader processes
(the batches, hence the weights, do not depend on them); scoring runs on the CPU. Then scores it
on the renderers' validation motion (protocol V, ``renderer_validation``: its own cameras) on
Joint2Coarse's proxy and on the simulated one (``--keep DIR`` keeps each seed's model file as
``DIR/METHOD-seed-N.pt``, to render or look at), and prints the garment region's MSE, GMSD,
mean gradient-similarity deficit, detail ratio and SSIM, the full frame's MSE and the flicker
(means over the samples), per seed and over the seeds.

``--extra-motion NAME`` (repeatable) trains on more than the training motion: beside the data
set, the samples of NAME, one of Joint2Coarse's training clips (never a validation or test
motion), rendered as the data set's are (its cameras' stream, views and frame stride) over the
proxy the method trains on (the clip's simulation, or Joint2Coarse's prediction of it, as the
training motion's is made). Its target and images are made in the project first when missing
(``sim/NAME-target/``, ``renderer-extra/NAME/``); every method gets the same samples and
steps.

The validation motion's target and images are made in the project first when they are missing
(as ``dng eval`` makes them; a project made before the split gets ``--motion NAME``, one of its
Joint2Coarse validation motions). The test motions are never scored here: choose on these
figures, then report the test split once with ``dng eval``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from app.commands import parse_setting
from core.errors import InputError
from core.fileio import atomic_path
from core.project import Project
from pipeline.config import (
    baseline_config,
    joint2coarse_splits,
    project_config,
    renderer_config,
    renderer_validation_motion,
)
from pipeline.stages.dataset import render_samples, stage_testset
from pipeline.stages.joint2coarse import joint2coarse_prediction
from pipeline.stages.simulate import stage_simulate
from training.baselines import KINDS, load_for_evaluation, train_baseline
from training.dataset import GarmentDataset
from training.evaluate import EvalConfig, evaluate_motion
from training.renderer.train import train_renderer

METRICS = (
    "mse_masked", "gmsd_masked", "gms_masked", "detail_masked", "ssim_masked", "mse", "flicker",
)  # fmt: skip
SOURCES = {"joint2coarse": "Joint2Coarse's proxy", "sim": "simulated proxy"}


def extra_samples(project: Project, config, name: str, log) -> GarmentDataset:
    """The training samples of ``name``, one of the project's Joint2Coarse training clips,
    made in the project when missing: its target (``stage_simulate``) and its samples rendered
    as the data set's (:func:`pipeline.stages.dataset.render_samples`: the training cameras'
    stream, ``views_per_frame``, ``frame_stride``) into ``renderer-extra/NAME/``; over the
    proxy ``config.renderer_source`` names (Joint2Coarse's prediction of the clip is made as the
    training motion's, strain-limited)."""
    if name not in joint2coarse_splits(config)["train"]:
        raise InputError(
            f"--extra-motion {name!r} is not one of Joint2Coarse's training clips (a renderer "
            "never trains on a validation or test motion)"
        )
    stage_simulate(project, config, name, "target", log)
    folder = Path("renderer-extra") / name
    out = project.root / folder
    if not (out / "samples.json").is_file():
        tmp = out.with_name(f".{name}.partial")
        shutil.rmtree(tmp, ignore_errors=True)
        (tmp / "samples").mkdir(parents=True)
        render_samples(
            project, config, name, tmp, seed=(config.seed,), views=config.views_per_frame,
            stride=config.frame_stride, desc=f"ground truth {name}",
        )  # fmt: skip
        shutil.rmtree(out, ignore_errors=True)
        tmp.rename(out)
    positions = None
    if config.renderer_source == "joint2coarse":
        positions = joint2coarse_prediction(project, name)
    return GarmentDataset(
        project.root, source=config.renderer_source, folder=folder, proxy_positions=positions
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("project")
    ap.add_argument("--method", required=True, choices=["ours", *KINDS])
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--seeds", type=int, nargs="+", default=None, help="default: the project's")
    ap.add_argument("--motion", help="the validation motion, for a project made before the split")
    ap.add_argument(
        "--source", choices=list(SOURCES), help="the proxy it trains on (default: the project's)"
    )
    ap.add_argument("--steps", type=int, help="training steps (default: the project's)")
    ap.add_argument("--device", default="cpu", help="cpu or cuda[:i] (training; scored on the CPU)")
    ap.add_argument("--workers", type=int, default=0, help="data loader processes")
    ap.add_argument("--keep", metavar="DIR", help="keep each seed's model file in DIR")
    ap.add_argument(
        "--extra-motion", action="append", default=[], metavar="NAME",
        help="also train on this Joint2Coarse training clip's samples (repeatable)",
    )  # fmt: skip
    ap.add_argument("--json", action="store_true", help="print only JSON")
    args = ap.parse_args()
    if args.steps is not None and args.steps < 1:
        ap.error(f"--steps must be a positive integer, got {args.steps}")
    if args.workers < 0:
        ap.error(f"--workers must be >= 0, got {args.workers}")
    try:
        device = torch.device(args.device)
    except RuntimeError:
        ap.error(f"--device {args.device!r}: not a torch device (cpu, cuda, cuda:1, ...)")
    if device.type == "cuda" and not torch.cuda.is_available():
        ap.error(f"--device {args.device}: no CUDA GPU on this machine")

    torch.set_num_threads(1)
    project = Project(args.project)
    try:
        config = project_config(project)
        if args.motion:
            config = replace(config, renderer_validation=args.motion)
        if args.source:
            config = replace(config, renderer_source=args.source)
        if args.steps is not None:
            config = replace(config, renderer_steps=args.steps)
        validation = renderer_validation_motion(config)
    except InputError as exc:
        ap.error(str(exc))
    if validation is None:
        ap.error("the project has no renderer validation motion: give --motion NAME")
    log = (lambda _: None) if args.json else print
    stage_simulate(project, config, validation.name, "target", log)
    stage_testset(project, config, validation.name, log, validation=True)

    changes = dict(parse_setting(item) for item in args.overrides)
    if args.method == "ours":
        config = replace(config, renderer_overrides={**config.renderer_overrides, **changes})
    else:
        config = replace(config, baseline_overrides={**config.baseline_overrides, **changes})
    data = GarmentDataset(project.root, source=config.renderer_source)
    try:
        extra = [extra_samples(project, config, name, log) for name in args.extra_motion]
    except InputError as exc:
        ap.exit(2, f"renderer_validation: {exc}\n")
    if extra:
        data = torch.utils.data.ConcatDataset([data, *extra])
    scored = {
        src: GarmentDataset(project.root, source=src, split=validation.name) for src in SOURCES
    }
    runs = []
    for seed in args.seeds if args.seeds is not None else [config.seed]:
        seeded = replace(config, seed=seed)
        # the trainers say what they leave out on stdout: with --json it carries the JSON alone
        quiet = contextlib.redirect_stdout(sys.stderr) if args.json else contextlib.nullcontext()
        with tempfile.TemporaryDirectory() as tmp, quiet:
            start = time.perf_counter()
            if args.method == "ours":
                cfg = renderer_config(seeded)
                result = train_renderer(
                    data, tmp, cfg, progress=False, device=args.device, workers=args.workers
                )
            else:
                cfg = baseline_config(seeded, args.method)
                result = train_baseline(
                    args.method, data, tmp, cfg, progress=False, device=args.device,
                    workers=args.workers,
                )  # fmt: skip
            train_s = time.perf_counter() - start
            model = load_for_evaluation(result.model_path)
            if args.keep:
                keep = Path(args.keep)
                keep.mkdir(parents=True, exist_ok=True)
                with atomic_path(keep / f"{args.method}-seed-{seed}.pt") as tmp_model:
                    shutil.copyfile(result.model_path, tmp_model)
        results, _ = evaluate_motion(
            {src: (model, d) for src, d in scored.items()}, EvalConfig(sheet_samples=0)
        )
        figures = {
            src: {m: r.metrics.summary()[m]["mean"] for m in METRICS} for src, r in results.items()
        }
        runs.append({"seed": seed, "train_s": train_s, "figures": figures})
    mean = {
        src: {m: float(np.mean([r["figures"][src][m] for r in runs])) for m in METRICS}
        for src in SOURCES
    }
    out = {
        "method": args.method, "changes": changes, "extra_motions": args.extra_motion,
        "samples": len(data), "source": config.renderer_source,
        "motion": validation.name, "device": args.device,
        "config": cfg.to_dict(), "runs": runs, "mean_over_seeds": mean,
    }  # fmt: skip
    if args.json:
        print(json.dumps(out, indent=1))
        return
    print(
        f"{args.method} on {validation.name} (validation), trained over the proxy "
        f"'{config.renderer_source}', settings changed: {changes or 'none'}; "
        f"{len(data)} training samples"
        + (f" (with {', '.join(args.extra_motion)})" if args.extra_motion else "")
    )
    for run in runs + [{"seed": "all", "figures": mean}]:
        for src, f in run["figures"].items():
            trained = f", trained in {run['train_s']:.0f} s" if "train_s" in run else ""
            print(
                f"seed {run['seed']}  {SOURCES[src]:21s} MSE garment {f['mse_masked']:.4f}  "
                f"GMSD garment {f['gmsd_masked']:.3f}  GMS deficit garment "
                f"{f['gms_masked']:.3f}  detail garment {f['detail_masked']:.2f}  "
                f"SSIM garment {f['ssim_masked']:.4f}  MSE {f['mse']:.4f}  "
                f"flicker {f['flicker']:.4f}{trained}"
            )


if __name__ == "__main__":
    main()
