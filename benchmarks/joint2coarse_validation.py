"""Joint2Coarse on a project's validation motions: the figures every choice is made on.

Usage: ``python benchmarks/joint2coarse_validation.py PROJECT [--set KEY=VALUE ...]
[--seeds 0 1 2] [--without NAME ...] [--train-on NAME ...] [--fit-validation]
[--fit-test NAME ...] [--realisations N [--realisations-of NAME ...]]
[--train-extra KIND:FRAMES[:SEED] ...] [--json] [--test]``

Trains the project's Joint2Coarse (its preset and settings, changed by ``--set`` as ``dng train
joint2coarse`` reads it, e.g. ``--set model=ours --set residual_widths=[]``) on the project's
train split (``sim/NAME-proxy/cache.npz`` of the training motion and ``joint2coarse_extra``),
once per ``--seeds`` (the config's ``seed``), in a temporary folder: nothing is written into the
project. Prints the mean / p95 / max vertex error (mm) against the simulation of every
validation motion (``joint2coarse_validation``), their mean over the motions and, with several
seeds, the mean over seeds, and the training time. ``--test`` adds the test motions: report
them, never choose on them. ``--without`` leaves training motions out (names or shell patterns,
e.g. ``--without '*-spin'``): what each part of the library is worth. ``--realisations N``
trains on N more simulations of every training clip too, each of the proxy moved 10 um
(cached outside the project, as ``dng eval joint2coarse --realisations`` caches them): where
the folds of a motion can go more than one way, more of its outcomes to learn the likely one
from; ``--realisations-of NAME ...`` gives them to those training clips only (names or shell
patterns): which clips' further outcomes pay for their simulation. ``--fit-validation`` trains
on the validation motions too: how closely the model fits motions it has seen, against what it
does on motions it has not (never a choice: a diagnosis); ``--fit-test NAME ...`` the same for
test motions (it implies ``--test``). ``--train-on`` moves some validation
motions into training and scores the others: what training on validation motions too would be
worth to motions it has not seen. ``--train-extra KIND:FRAMES[:SEED] ...`` trains on
procedural clips the project does not hold too (e.g. ``squat:540 kick:300 kneel:300``), each
made as a library clip is (``pipeline.stages.motions.motion_from_spec``) and simulated with the
project's settings (cached outside the project, as the realisations are): what a new kind of
training clip is worth to the validation motions. ``--no-turn-lags`` measures ours
without the turning-rate features over longer lags, ``--every-joint-dynamic`` with every
joint's velocities and accelerations instead of ``DYNAMIC_JOINTS``', ``--long-lags`` with
every dynamic feature over twice the lags too (with ``--set window=66``), and
``--distance-vertices N`` the distance loss over N vertices a step (ablations inside this
process).
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import sys
import tempfile
import time
from dataclasses import asdict, replace
from functools import partial

import numpy as np
import torch

from app.commands import parse_setting
from core.errors import InputError
from core.mesh import load_mesh
from core.motion.procedural import PROCEDURAL_KINDS
from core.project import Project
from core.sim import load_cache
from core.sim.sanity import FLOOR_PERTURBATION_M
from pipeline.config import joint2coarse_config, joint2coarse_splits, project_config
from pipeline.joint2coarse_eval import simulate_cached
from pipeline.library import MotionSpec
from pipeline.stages.joint2coarse import mirror_setting
from pipeline.stages.motions import load_project_motion, motion_from_spec
from training.joint2coarse import (
    Joint2CoarseClip,
    body_model,
    joint2coarse_inputs,
    predict_proxy,
    train_joint2coarse,
    vertex_errors,
)
from training.joint2coarse.body_model import body_rig


def _clip(project: Project, name: str) -> Joint2CoarseClip:
    joints, root_rot = joint2coarse_inputs(load_project_motion(project, name))
    positions = load_cache(project.path(f"sim/{name}-proxy", "cache.npz")).positions
    return Joint2CoarseClip(joints, root_rot, positions, name=name)


def _matching(names: list[str], patterns: list[str]) -> list[str]:
    """The ``names`` that match any of ``patterns`` (names or shell patterns), in their order."""
    return [n for n in names if any(fnmatch.fnmatch(n, p) for p in patterns)]


def _realisation(project: Project, config, name: str, seed: int) -> Joint2CoarseClip:
    """Training clip ``name`` on another simulation of its motion: the proxy moved 10 um by the
    offsets of ``seed`` (cached in the scratch folder, as ``dng eval joint2coarse`` caches)."""
    motion = load_project_motion(project, name)
    log = partial(print, file=sys.stderr, flush=True)
    sim = simulate_cached(project, config, motion, log, None, FLOOR_PERTURBATION_M, seed)[0]
    joints, root_rot = joint2coarse_inputs(motion)
    return Joint2CoarseClip(joints, root_rot, sim.positions, name=f"{name}-moved-{seed}")


def _extra(project: Project, config, text: str) -> Joint2CoarseClip:
    """A procedural training clip the project does not hold, ``KIND:FRAMES[:SEED]``: made as a
    library clip is and simulated with the project's settings (cached in the scratch folder)."""
    parts = text.split(":")
    if len(parts) not in (2, 3) or parts[0] not in PROCEDURAL_KINDS:
        raise InputError(
            f"--train-extra {text}: need KIND:FRAMES[:SEED], KIND one of {', '.join(PROCEDURAL_KINDS)}"
        )
    try:
        frames, seed = int(parts[1]), int(parts[2]) if len(parts) == 3 else 0
    except ValueError:
        raise InputError(f"--train-extra {text}: FRAMES and SEED are whole numbers") from None
    if frames < 2:
        raise InputError(f"--train-extra {text}: need at least 2 frames")
    name = f"extra-{parts[0]}-{seed}"
    motion = motion_from_spec(MotionSpec(name, parts[0], frames, seed=seed), config)
    log = partial(print, file=sys.stderr, flush=True)
    sim = simulate_cached(project, config, motion, log)[0]
    joints, root_rot = joint2coarse_inputs(motion)
    return Joint2CoarseClip(joints, root_rot, sim.positions, name=name)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("project")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--seeds", type=int, nargs="+", default=None, help="default: the config's")
    ap.add_argument("--json", action="store_true", help="print only JSON")
    ap.add_argument("--test", action="store_true", help="also the test motions (report only)")
    ap.add_argument(
        "--fit-validation", action="store_true",
        help="diagnosis: train on the validation motions too (how closely it fits what it saw)",
    )  # fmt: skip
    ap.add_argument(
        "--fit-test", nargs="+", default=[], metavar="NAME",
        help="diagnosis: train on these test motions too (names or shell patterns; implies "
        "--test): how closely the model fits a test motion once it has seen it, against what it "
        "predicts for it unseen (never a choice)",
    )  # fmt: skip
    ap.add_argument(
        "--realisations", type=int, default=0, metavar="N",
        help="train on N more simulations of every training clip too, each of the proxy moved "
        "10 um by offsets of its own (simulated once, cached as dng eval joint2coarse caches): "
        "what more outcomes of the same motions are worth",
    )  # fmt: skip
    ap.add_argument(
        "--realisations-of", nargs="+", default=[], metavar="NAME",
        help="with --realisations: only these training clips' (names or shell patterns)",
    )  # fmt: skip
    ap.add_argument(
        "--train-on", nargs="+", default=[], metavar="NAME",
        help="validation motions to train on too (names or shell patterns), scored no more: "
        "what training on part of the validation split is worth to the rest of it",
    )  # fmt: skip
    ap.add_argument(
        "--train-extra", nargs="+", default=[], metavar="KIND:FRAMES[:SEED]",
        help="procedural clips the project does not hold to train on too (e.g. squat:540), "
        "simulated with the project's settings (cached as the realisations are)",
    )  # fmt: skip
    ap.add_argument(
        "--without", nargs="+", default=[], metavar="NAME",
        help="training motions to leave out (names or shell patterns such as '*-spin')",
    )  # fmt: skip
    ap.add_argument(
        "--no-turn-lags", action="store_true",
        help="ablation: ours without the pelvis's turning rate over longer lags (TURN_LAGS)",
    )  # fmt: skip
    ap.add_argument(
        "--every-joint-dynamic", action="store_true",
        help="ablation: ours with every joint's velocities and accelerations (not DYNAMIC_JOINTS)",
    )  # fmt: skip
    ap.add_argument(
        "--long-lags", action="store_true",
        help="ablation: ours with velocities, accelerations and turning rates over twice the "
        "lags too (24 and 32 samples; give a window that holds them, e.g. --set window=66)",
    )  # fmt: skip
    ap.add_argument(
        "--distance-vertices", type=int, default=None, metavar="N",
        help="with --set residual_loss=distance: vertices a step (body_model.DISTANCE_VERTICES)",
    )  # fmt: skip
    args = ap.parse_args()
    if args.distance_vertices is not None:  # as --no-turn-lags: this process only
        if args.distance_vertices < 1:
            ap.error(f"--distance-vertices {args.distance_vertices} must be at least 1")
        body_model.DISTANCE_VERTICES = args.distance_vertices
    if args.long_lags:  # as --no-turn-lags: this process only
        body_model.VELOCITY_LAGS += (24,)
        body_model.ACCELERATION_LAGS += (12,)
        body_model.TURN_LAGS += (24, 32)
    if args.every_joint_dynamic:  # as --no-turn-lags: this process only
        body_model._DYNAMIC = list(body_model._DESC.values())
    if args.no_turn_lags:  # an ablation of this process only: nothing is saved
        body_model.TURN_LAGS = ()

    ablations = [
        f for f in ("every_joint_dynamic", "no_turn_lags", "long_lags") if getattr(args, f)
    ]
    if args.distance_vertices is not None:
        ablations.append(f"distance_vertices={args.distance_vertices}")
    torch.set_num_threads(1)
    project = Project(args.project)
    config = project_config(project)
    changes = dict(parse_setting(item) for item in args.overrides)
    config = replace(config, joint2coarse_overrides={**config.joint2coarse_overrides, **changes})
    cfg = joint2coarse_config(config)
    if args.long_lags and cfg.num_samples <= max(body_model.TURN_LAGS):
        ap.error(
            f"--long-lags reads {max(body_model.TURN_LAGS)} samples back: the window of "
            f"{cfg.window} frames holds {cfg.num_samples} (give e.g. --set window=66)"
        )
    splits = joint2coarse_splits(config)
    left_out = _matching(splits["train"], args.without)
    if args.without and not left_out:
        ap.error(f"--without matches no training motion (they are: {', '.join(splits['train'])})")
    splits["train"] = [n for n in splits["train"] if n not in left_out]
    if not splits["train"]:
        ap.error("--without leaves no training motion")
    moved = _matching(splits["validation"], args.train_on)
    if args.train_on and not moved:
        ap.error(f"--train-on matches no validation motion ({', '.join(splits['validation'])})")
    if moved and len(moved) == len(splits["validation"]):
        ap.error("--train-on leaves no validation motion to score (see --fit-validation)")
    splits["train"] += moved
    splits["validation"] = [n for n in splits["validation"] if n not in moved]
    fitted = _matching(splits["test"], args.fit_test)
    if args.fit_test and not fitted:
        ap.error(f"--fit-test matches no test motion ({', '.join(splits['test'])})")
    if args.realisations < 0:
        ap.error(f"--realisations {args.realisations} must be at least 0")
    again_of = splits["train"]
    if args.realisations_of:
        if not args.realisations:
            ap.error("--realisations-of needs --realisations N (N at least 1)")
        again_of = _matching(splits["train"], args.realisations_of)
        if not again_of:
            ap.error(f"--realisations-of matches no training motion ({', '.join(splits['train'])})")
    clips = [_clip(project, name) for name in splits["train"] + fitted]
    firsts = {c.name: c.proxy for c in clips}
    again = [
        (name, _realisation(project, config, name, seed))
        for seed in range(args.realisations)
        for name in again_of
    ]
    clips += [clip for _, clip in again]
    try:
        extras = [_extra(project, config, text) for text in args.train_extra]
    except InputError as err:
        ap.error(str(err))
    clips += extras
    # how far each clip's second outcome is from its first: what one simulation leaves open
    apart = [vertex_errors(clip.proxy, firsts[name]).mean_mm for name, clip in again]
    if args.fit_validation:
        clips += [_clip(project, name) for name in splits["validation"]]
    rig = None
    proxy_file = project.path("proxy", "positions.obj")
    if cfg.model == "ours":
        rig = body_rig(config.body, load_mesh(proxy_file)[0].vertices, cfg.skin_fade)
    # as the project's stage trains (a garment that is not symmetric: no mirrors, said)
    cfg, mirror, _ = mirror_setting(cfg, proxy_file, lambda line: print(line, file=sys.stderr))
    scored = {"validation": splits["validation"]}
    if args.test or fitted:
        scored["test"] = splits["test"]
    refs = {
        n: (_clip(project, n), load_cache(project.path(f"sim/{n}-proxy", "cache.npz")).positions)
        for names in scored.values()
        for n in names
    }
    runs = []
    for seed in args.seeds if args.seeds is not None else [cfg.seed]:
        run_cfg = replace(cfg, seed=seed)
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            result = train_joint2coarse(clips, tmp, run_cfg, progress=False, rig=rig, mirror=mirror)
            train_s = time.perf_counter() - start
        run = {"seed": seed, "train_s": train_s}
        for split, names in scored.items():
            errors = {}
            for n in names:
                clip, ref = refs[n]
                pred = predict_proxy(result.net, clip.joints, clip.root_rotations)
                errors[n] = asdict(vertex_errors(pred, ref))
            means = {
                k: float(np.mean([e[k] for e in errors.values()])) for k in ("mean_mm", "p95_mm")
            }
            run[split] = {"motions": errors, "mean_over_motions": means}
        runs.append(run)
    summary = {
        split: {
            k: float(np.mean([r[split]["mean_over_motions"][k] for r in runs]))
            for k in ("mean_mm", "p95_mm")
        }
        for split in scored
    }
    out = {
        "config": cfg.to_dict(), "splits": scored, "train": splits["train"], "left_out": left_out,
        "fit_validation": args.fit_validation, "trained_on_validation": moved,
        "trained_on_test": fitted, "realisations": args.realisations,
        "realisations_of": again_of if args.realisations else [],
        "realisations_from_first_mm": float(np.mean(apart)) if apart else None,
        "train_extra": [c.name for c in extras],
        "ablations": ablations,
        "runs": runs, "mean_over_seeds": summary,
    }  # fmt: skip
    if args.json:
        print(json.dumps(out, indent=1))
        return
    print(
        f"model={cfg.model}, settings changed: {changes or 'none'}"
        + (f", ablations: {', '.join(ablations)}" if ablations else "")
    )
    if args.fit_validation:
        print("trained on the validation motions too: these are fits, not predictions")
    if moved:
        print(f"trained on validation motions {', '.join(moved)} too: scored on the others")
    if fitted:
        print(f"trained on test motions {', '.join(fitted)} too: their figures are fits")
    if args.realisations:
        print(
            f"trained on {args.realisations} more simulation(s) of "
            + (
                "every training clip"
                if len(again_of) == len(splits["train"])
                else f"{len(again_of)} training clips ({', '.join(again_of)})"
            )
            + f" too, {np.mean(apart):.1f} mm mean from the clips' own"
        )
    if extras:
        print(f"trained on procedural clips {', '.join(c.name for c in extras)} too")
    if left_out:
        print(f"left out of training: {', '.join(left_out)} ({len(clips)} motions trained on)")
    for run in runs:
        for split in scored:
            cells = "  ".join(
                f"{n} {e['mean_mm']:.1f}/{e['p95_mm']:.0f}"
                for n, e in run[split]["motions"].items()
            )
            m = run[split]["mean_over_motions"]
            print(
                f"seed {run['seed']} {split:10s} mean/p95 mm {m['mean_mm']:6.1f} / "
                f"{m['p95_mm']:5.0f}   ({cells}; trained in {run['train_s']:.1f} s)"
            )
    for split, m in summary.items():
        print(f"{split} over {len(runs)} seed(s): {m['mean_mm']:.1f} / {m['p95_mm']:.0f} mm")


if __name__ == "__main__":
    main()
