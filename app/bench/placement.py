"""``dng bench placement``: how much of each method's advantage survives Joint2Coarse's error.

On a trained project (``dng demo``), every test motion's proxy is moved from the simulated one
towards Joint2Coarse's prediction, vertex by vertex: ``sim + s * (pred - sim)`` for each scale
s in ``--scales`` (0: the simulated proxy, the renderers alone; 1: Joint2Coarse's, what
``dng eval`` scores as ``ours``). The proxy's mean vertex error is s times Joint2Coarse's. Every
method that ``dng eval`` renders on Joint2Coarse's proxy from the project's own data (ours, the
baselines, the ``no-motion``, ``no-temporal`` and ``views-N`` ablations) renders each of these
proxies from the test motions' unseen cameras, scored as ``dng eval`` scores (the test motions
pooled). One more row, ``autoencoder`` (``--no-autoencoder`` skips it): the proxy
Joint2Coarse's decoder gives for the simulated shapes themselves (its shape autoencoder,
:func:`training.joint2coarse.reconstruct_proxy`), close to what a perfect motion encoder
would reach with the shapes the network learnt.

What it measures: how accurate Joint2Coarse has to be for a renderer's advantage to hold at
test time. A misplaced proxy puts every method's garment in the same wrong place; that error
adds to each method's own, so the ratios between methods move towards 1 as it grows.

Writes ``OUT/placement.json`` (after every row, so a run stopped late keeps what it measured)
and ``OUT/placement.png`` (each method's MSE, and ours over each other method's, against the
proxy's mean error).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from app.bench import add_output_arguments, project_test_sets
from core.errors import InputError
from core.fileio import atomic_path, write_json
from core.project import Project
from core.sim import load_cache
from pipeline.config import project_config
from pipeline.stages.evaluate import eval_methods
from pipeline.stages.motions import load_project_motion
from training.dataset import GarmentDataset, proxy_source_file

HELP = "image error of every method as Joint2Coarse's proxy error shrinks to simulation's"

#: Default scales of Joint2Coarse's error (0: the simulated proxy; 1: Joint2Coarse's own).
DEFAULT_SCALES = (0.0, 0.1, 0.25, 0.5, 1.0)
#: The paper's MSE of ours over Deferred Neural Rendering (Table 1: 0.116 / 0.204).
PAPER_RATIO = 0.116 / 0.204


def add_arguments(parser: argparse.ArgumentParser) -> None:

    add_output_arguments(parser)
    parser.add_argument("--project", required=True, help="a trained project folder (dng demo)")
    parser.add_argument(
        "--scales", type=float, nargs="+", default=list(DEFAULT_SCALES), metavar="S",
        help="fractions of Joint2Coarse's error to render at, each >= 0 (default: %(default)s)",
    )  # fmt: skip
    parser.add_argument(
        "--motions", nargs="+", default=None, metavar="NAME",
        help="test motions (default: every one with a test set)",
    )  # fmt: skip
    parser.add_argument(
        "--methods", nargs="+", default=None, metavar="NAME",
        help="methods to render, as dng eval names them (default: ours, the baselines and the "
        "project's no-motion, no-temporal and views-N ablations)",
    )  # fmt: skip
    parser.add_argument(
        "--no-autoencoder", action="store_true",
        help="skip the row of the shapes Joint2Coarse's decoder reaches from the simulation",
    )  # fmt: skip
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default: 1)")


# ------------------------------------------------------------------------- pure parts


def blend_positions(sim: np.ndarray, pred: np.ndarray, scale: float) -> np.ndarray:
    """The proxy ``scale`` of the way from the simulated one to the prediction, per vertex.

    Parameters
    ----------
    sim, pred : (T, V, 3) float, the same shape
    scale : float >= 0 (0: ``sim``; 1: ``pred``; above 1 moves further than the prediction)

    Returns
    -------
    (T, V, 3) float32 ``sim + scale * (pred - sim)``, computed in float64.
    """
    sim, pred = np.asarray(sim, np.float64), np.asarray(pred, np.float64)
    if sim.shape != pred.shape or sim.ndim != 3 or sim.shape[-1] != 3:
        raise InputError(f"proxies must be the same (T, V, 3), got {sim.shape} and {pred.shape}")
    if not (math.isfinite(scale) and scale >= 0):
        raise InputError(f"scale {scale!r} must be a finite number >= 0")
    return (sim + scale * (pred - sim)).astype(np.float32)


def check_scales(scales) -> list[float]:
    """Sorted distinct scales; InputError for a negative or non-finite one."""
    for s in scales:
        if not (math.isfinite(s) and s >= 0):
            raise InputError(f"--scales {s!r}: each must be a finite number >= 0")
    return sorted({float(s) for s in scales})


def ratios(mse: dict[str, float]) -> dict[str, float]:
    """Ours' MSE over every other method's: ``{"ours/dnr": ..., ...}`` (methods with MSE 0
    are left out)."""
    ours = mse.get("ours")
    if ours is None:
        return {}
    return {f"ours/{name}": ours / v for name, v in mse.items() if name != "ours" and v > 0}


# ------------------------------------------------------------------------- the project


def project_methods(project, config, names: list[str] | None) -> dict[str, Path]:
    """name -> model file of the methods ``dng eval`` renders on Joint2Coarse's proxy from the
    project's own data (the template ablation renders another project's proxy: left out)."""
    found = {
        name: path
        for name, (path, source, root) in eval_methods(project, config).items()
        if source == "joint2coarse" and Path(root) == Path(project.root)
    }
    if names is not None:
        unknown = [n for n in names if n not in found]
        if unknown:
            raise InputError(
                f"unknown method(s) {', '.join(unknown)}; this project has {', '.join(found)}",
                project.root,
            )
        found = {n: found[n] for n in names}
    for name, path in found.items():
        if not Path(path).is_file():
            raise InputError(f"no trained model for {name}: run dng demo first", path)
    return found


def project_motions(root: Path, config, names: list[str] | None) -> list[str]:
    """Test motions with a test set, a Joint2Coarse prediction and a simulated proxy."""
    order = project_test_sets(root, config)
    if names is not None:
        missing = [n for n in names if n not in order]
        if missing:
            raise InputError(
                f"no test set for {', '.join(missing)}; have {', '.join(sorted(order))}",
                root / "testset",
            )
        order = list(dict.fromkeys(names))
    for name in order:
        for source, what in (
            ("joint2coarse", "Joint2Coarse prediction"),
            ("sim", "simulated proxy"),
        ):
            path = proxy_source_file(root, source, name)
            if not path.is_file():
                raise InputError(f"no {what} of {name}", path)
    return order


def _proxies(project, motions: list[str], autoencoder: bool) -> dict[str, dict]:
    """motion -> {"sim": (T, V, 3), "pred": ..., and "autoencoder": ... when asked}."""
    from training.joint2coarse import joint2coarse_inputs, load_model, reconstruct_proxy

    net = load_model(project.path("joint2coarse", "joint2coarse.pt")) if autoencoder else None
    if net is not None and not hasattr(net, "shape_encoder"):  # ours: the paper's model beside it
        paper = project.path("joint2coarse", "compare-paper/joint2coarse.pt")
        if not paper.is_file():
            raise InputError(
                "the project's Joint2Coarse (model=ours) has no shape autoencoder and no paper "
                "model beside it: pass --no-autoencoder",
                paper,
            )
        net = load_model(paper)
    out = {}
    for name in motions:
        sim = load_cache(project.path(f"sim/{name}-proxy", "cache.npz")).positions
        pred_file = project.path("joint2coarse", f"pred-{name}.npz")
        pred = np.load(pred_file)["positions"]
        if pred.shape != sim.shape:
            raise InputError(
                f"prediction of shape {pred.shape} does not fit the simulated proxy {sim.shape}",
                pred_file,
            )
        out[name] = {"sim": sim, "pred": pred}
        if net is not None:
            joints, root_rot = joint2coarse_inputs(load_project_motion(project, name))
            out[name]["autoencoder"] = reconstruct_proxy(net, sim, joints, root_rot)
    return out


def score(project, models: dict, motions: list[str], positions: dict[str, np.ndarray]) -> dict:
    """Render and score every model on every motion with the given proxies.

    positions : motion -> (T, V, 3) proxy. Returns ``{"methods": name -> pooled summary,
    "motions": motion -> name -> MSE mean}``.
    """
    from training.evaluate import EvalConfig, evaluate_motion
    from training.metrics import FrameMetrics

    totals = {name: FrameMetrics() for name in models}
    per_motion = {}
    for name in motions:
        data = GarmentDataset(
            project.root, source="joint2coarse", split=name, proxy_positions=positions[name]
        )
        results, _ = evaluate_motion(
            {m: (model, data) for m, model in models.items()}, EvalConfig(sheet_samples=0)
        )
        per_motion[name] = {m: r.metrics.summary()["mse"]["mean"] for m, r in results.items()}
        for m, r in results.items():
            for metric, values in r.metrics.values.items():
                totals[m].add(metric, values)
    return {"methods": {m: t.summary() for m, t in totals.items()}, "motions": per_motion}


# ------------------------------------------------------------------------- the bench


def run(args: argparse.Namespace) -> int:
    import torch

    from training.baselines import load_for_evaluation
    from training.joint2coarse import vertex_errors

    root = Path(args.project)
    if not root.is_dir():
        raise InputError("project folder not found", root)
    if args.threads < 1:
        raise InputError("--threads must be >= 1")
    scales = check_scales(args.scales)
    project = Project(root)
    config = project_config(project)
    motions = project_motions(root, config, args.motions)
    paths = project_methods(project, config, args.methods)
    autoencoder = not args.no_autoencoder
    if autoencoder and not project.path("joint2coarse", "joint2coarse.pt").is_file():
        raise InputError(
            "no trained Joint2Coarse for the autoencoder row (or pass --no-autoencoder)",
            project.path("joint2coarse", "joint2coarse.pt"),
        )
    torch.set_num_threads(args.threads)
    say = (lambda *a, **k: None) if args.json else (lambda *a, **k: print(*a, **k, flush=True))
    out = Path(args.out)
    proxies = _proxies(project, motions, autoencoder)
    models = {name: load_for_evaluation(path) for name, path in paths.items()}
    j2c_mm = {m: vertex_errors(p["pred"], p["sim"]).mean_mm for m, p in proxies.items()}
    frames = {m: len(p["sim"]) for m, p in proxies.items()}
    load_before = os.getloadavg()
    rows: list[dict] = []
    table = {
        "bench": "placement",
        "complete": False,
        "project": str(root),
        "test_motions": motions,
        "methods": list(models),
        "joint2coarse_error_mm": j2c_mm,
        "paper_ratio_ours_to_dnr": PAPER_RATIO,
        "threads": args.threads,
        "note": "proxy = sim + scale * (Joint2Coarse - sim) per vertex; error_mm: the proxy's "
        "mean vertex distance to the simulated one; metrics as dng eval (pixel values in [0, 1], "
        "unseen cameras, test motions pooled); 'autoencoder': the shape autoencoder's "
        "reconstruction of the simulated proxy",
        "load_average_before": list(load_before),
        "rows": rows,
    }

    def save() -> None:
        table["load_average_after"] = list(os.getloadavg())
        write_json(out / "placement.json", table)

    say(
        f"project {root}: {', '.join(motions)}; Joint2Coarse's mean error "
        + ", ".join(f"{m} {e:.1f} mm" for m, e in j2c_mm.items())
        + f"; {len(models)} methods; load average {load_before[0]:.2f} on {os.cpu_count()} CPUs"
    )
    say(_header(list(models)))
    points = [(f"scale {s:g}", s) for s in scales] + (
        [("autoencoder", None)] if autoencoder else []
    )
    for label, s in points:
        start = time.perf_counter()
        if s is None:
            positions = {m: p["autoencoder"] for m, p in proxies.items()}
        else:
            positions = {m: blend_positions(p["sim"], p["pred"], s) for m, p in proxies.items()}
        errors = {m: vertex_errors(positions[m], proxies[m]["sim"]).mean_mm for m in motions}
        scored = score(project, models, motions, positions)
        summaries = scored["methods"]
        mse = {name: summary["mse"]["mean"] for name, summary in summaries.items()}
        row = {
            "label": label,
            "scale": s,
            "error_mm": errors,
            "error_mm_pooled": sum(errors[m] * frames[m] for m in motions) / sum(frames.values()),
            "mse": mse,
            "ssim": {name: summary["ssim"]["mean"] for name, summary in summaries.items()},
            "psnr": {name: summary["psnr"]["mean"] for name, summary in summaries.items()},
            "ratios": ratios(mse),
            "motions": scored["motions"],
            "metrics": summaries,
            "seconds": time.perf_counter() - start,
        }
        rows.append(row)
        save()
        say(_format_row(row, list(models)))
    table["complete"] = True
    save()
    plot(rows, out / "placement.png", title=f"{root.name}: {', '.join(motions)}")
    if args.json:
        print(json.dumps(table, indent=2, default=str))
    else:
        after = table["load_average_after"]
        print(f"load average after: {after[0]:.2f} / {after[1]:.2f} / {after[2]:.2f}")
        print(f"wrote {out / 'placement.json'} and {out / 'placement.png'}")
    return 0


def _header(methods: list[str]) -> str:
    cells = [f"{'proxy':<12}", f"{'error mm':>8}"]
    cells += [f"{m + ' MSE':>{max(10, len(m) + 4)}}" for m in methods]
    if "ours" in methods:
        cells += [f"{'ours/' + m:>{max(9, len(m) + 5)}}" for m in methods if m != "ours"]
    return " ".join(cells)


def _format_row(row: dict, methods: list[str]) -> str:
    cells = [f"{row['label']:<12}", f"{row['error_mm_pooled']:>8.1f}"]
    cells += [f"{row['mse'][m]:>{max(10, len(m) + 4)}.5f}" for m in methods]
    if "ours" in methods:
        cells += [
            f"{row['ratios'].get('ours/' + m, float('nan')):>{max(9, len(m) + 5)}.3f}"
            for m in methods
            if m != "ours"
        ]
    return " ".join(cells)


def plot(rows: list[dict], path, title: str = "") -> None:
    """Left: each method's MSE against the proxy's mean error (the scales as lines, the
    autoencoder as crosses). Right: ours over each other method, with the paper's ratio."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2), dpi=100)
    line = [r for r in rows if r["scale"] is not None]
    extra = [r for r in rows if r["scale"] is None]
    methods = list(rows[0]["mse"]) if rows else []
    for i, name in enumerate(methods):
        color = f"C{i}"
        left.plot([r["error_mm_pooled"] for r in line], [r["mse"][name] for r in line], "o-",
                  color=color, label=name)  # fmt: skip
        left.plot([r["error_mm_pooled"] for r in extra], [r["mse"][name] for r in extra], "x",
                  color=color, ms=9)  # fmt: skip
        if name == "ours":
            continue
        key = f"ours/{name}"
        right.plot([r["error_mm_pooled"] for r in line], [r["ratios"].get(key) for r in line],
                   "o-", color=color, label=key)  # fmt: skip
        right.plot([r["error_mm_pooled"] for r in extra], [r["ratios"].get(key) for r in extra],
                   "x", color=color, ms=9)  # fmt: skip
    right.axhline(PAPER_RATIO, color="k", ls="--", lw=1, label=f"paper ours/DNR {PAPER_RATIO:.2f}")
    right.axhline(1.0, color="grey", lw=0.8)
    for ax in (left, right):
        ax.set_xlabel("proxy's mean vertex error against simulation (mm)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    left.set_ylabel("MSE (pixel values in [0, 1])")
    right.set_ylabel("MSE of ours / MSE of method")
    left.set_title(f"image error vs proxy error ({title}); x: autoencoder", fontsize=9)
    right.set_title("ours relative to each method", fontsize=9)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp)
    plt.close(fig)
