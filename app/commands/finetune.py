"""``dng finetune PROJECT --body-shape k=v ... | --background IMG ... | --lighting LIGHT``: adapt a
trained renderer."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from core.body.shape import BodyShape
from core.errors import InputError
from core.lighting import PRESETS
from core.project import Project
from pipeline import finetune
from pipeline.config import project_config
from pipeline.finetune import RELIGHT_EXAMPLES, RELIGHT_STEPS


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "finetune",
        help="fine-tune a project's renderer to a new body shape, background or light",
        description=(
            "Body shape: a sub-project PROJECT/finetune/body-NAME/ with the same garment and "
            "proxy, the proxy simulated on the new body, a new data set and Joint2Coarse; "
            "every renderer weight is fine-tuned (25% of the training steps by default). "
            "Background: the data set recomposited over the images; only the last decoder "
            "layers, the refinement blocks and the discriminator train; the model goes to "
            "PROJECT/finetune/background-NAME/. Light: two samples of the data set rendered "
            "again under the light (over --background when given), and only the last two "
            "decoder layers and the discriminator train on them (100 steps by default); the "
            "model goes to PROJECT/finetune/light-NAME/. Play the result with dng render "
            "(--renderer for a background or light model)."
        ),
    )
    p.add_argument("project", help="project folder with a trained renderer/renderer.pt")
    what = p.add_mutually_exclusive_group()
    what.add_argument(
        "--body-shape",
        nargs="+",
        metavar="K=V",
        help="the new body, e.g. height=1.8 build=0.4 (core.body.shape.BodyShape fields; "
        "unnamed ones keep the project's values)",
    )
    what.add_argument(
        "--lighting",
        metavar="LIGHT",
        help=f"a light preset ({', '.join(PRESETS)}), an equirectangular environment image "
        "(.hdr, .exr, .png, .jpg) or a lighting.json",
    )
    p.add_argument(
        "--background",
        nargs="+",
        metavar="IMG",
        help="backdrop image(s): PNG, JPEG, ... (alone: a background fine-tune; with "
        "--lighting: the one backdrop of the relit examples)",
    )
    p.add_argument(
        "--examples",
        nargs="+",
        default=[str(RELIGHT_EXAMPLES)],
        metavar="N|SAMPLE=IMG",
        help=f"--lighting: how many data-set samples to render under the light (default "
        f"{RELIGHT_EXAMPLES}), or your own renders under it, SAMPLE=IMG each: the garment on the "
        "body at data-set sample SAMPLE's frame t from its camera (dataset/samples.json)",
    )
    p.add_argument("--steps", type=int, default=None, help="fine-tuning steps (default: see above)")
    p.add_argument(
        "--name",
        default=None,
        help="name of the result folder (default: the light's name with --lighting, else default)",
    )
    p.add_argument(
        "--renderer", default=None, metavar="MODEL.pt", help="start from this model instead"
    )
    p.add_argument(
        "--no-joint2coarse",
        action="store_true",
        help="body shape: do not train Joint2Coarse on the new body (the sub-project then has "
        "no proxy predictor of its own)",
    )
    p.add_argument("--device", default="cpu", help="torch device (cpu, cuda)")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:

    import torch

    if not (args.body_shape or args.background or args.lighting):
        raise InputError("say what to fine-tune to: --body-shape, --background or --lighting")
    if args.body_shape and args.background:
        raise InputError("--body-shape and --background are two fine-tunes: run them one at a time")
    if args.steps is not None and args.steps < 1:
        raise InputError(f"--steps must be >= 1, got {args.steps}")
    torch.set_num_threads(1)  # one thread is the robust choice beside other work (see pipeline)

    def log(message: str) -> None:
        print(message, file=sys.stderr, flush=True)

    if args.lighting is not None:
        if args.background is not None and len(args.background) != 1:
            raise InputError(f"--lighting takes one --background image, got {len(args.background)}")
        result = finetune.finetune_lighting(
            args.project,
            args.lighting,
            args.name,
            background=None if args.background is None else args.background[0],
            examples=_examples(args.examples),
            steps=RELIGHT_STEPS if args.steps is None else args.steps,
            renderer_path=args.renderer,
            device=args.device,
            log=log,
        )
    elif args.background:
        result = finetune.finetune_background_images(
            args.project,
            args.background,
            args.name or "default",
            steps=args.steps,
            renderer_path=args.renderer,
            device=args.device,
            log=log,
        )
    elif args.body_shape:
        if not Path(args.project).is_dir():
            raise InputError("project folder not found", args.project)
        base = project_config(Project(args.project)).body
        shape = BodyShape.parse(args.body_shape, base)
        result = finetune.finetune_body_shape(
            args.project,
            shape,
            args.name or "default",
            steps=args.steps,
            renderer_path=args.renderer,
            joint2coarse=not args.no_joint2coarse,
            device=args.device,
            log=log,
        )
    print(f"wrote {result.model_path} ({result.steps} steps)")
    if result.loss_start is None:
        print("loss: no step ran (resumed a finished run)")
    else:
        print(
            f"loss: generator {result.loss_start:.4g} -> {result.loss_end:.4g}, "
            f"L1 {result.l1_start:.4g} -> {result.l1_end:.4g} (first -> last step)"
        )
    if args.background or args.lighting:
        print(f"play it: dng render {args.project} --renderer {result.model_path} --motion ...")
    else:
        print(f"play it: dng render {result.out_dir} --motion ...")
    return 0


def _examples(items: list[str]) -> int | list[str]:
    """``--examples``: a count alone, or ``SAMPLE=IMG`` items."""
    if len(items) == 1 and items[0].lstrip("-").isdigit():
        return int(items[0])
    return items
