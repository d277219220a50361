"""Where in the garment region each method's error lies: a diagnosis of the renderers' MSE.

Usage: ``python benchmarks/renderer_regions.py PROJECT [--motion NAME] [--source
joint2coarse|sim] [--model NAME=FILE ...] [--measure mse|gms|blur] [--json]``

Scores the project's renderer and baselines (and any other model file given with ``--model``,
such as one kept by ``benchmarks/renderer_validation.py --keep``) on one evaluated motion
(default: the renderers' validation motion, protocol V) and splits each method's squared error
over the garment region (the ground truth's garment or the proxy's coverage, as the report's
garment-region figures take it) by what the pixel holds:

- ``garment on the proxy, body behind``: the ground truth shows the garment, the proxy covers
  the pixel, and the body-only image shows the body there;
- ``garment on the proxy, backdrop behind``: the same with the plain backdrop behind;
- ``garment off the proxy``: the garment where the proxy does not reach (a flare);
- ``proxy only, body shows``: the proxy covers the pixel, the ground truth shows the body (a
  gap between tiers, or the body in front);
- ``proxy only, backdrop shows``: the proxy covers it, the ground truth shows the backdrop.

Each figure is the category's summed squared error (mean over RGB) over the number of
garment-region pixels, so a method's figures add up to its pixel-pooled garment-region MSE
(the report's is the mean over samples of each sample's MSE, close to it). The backdrop is told
from the body by the body-only image's difference from its corner pixel.

``--measure gms`` splits the gradient magnitude similarity instead (GMS, the per-pixel map the
report's GMSD is the standard deviation of, :func:`training.metrics.gmsd`): each method's
deficit ``1 - GMS`` over the garment region's inner pixels, by whether the ground truth has an
edge there (its gradient magnitude over :data:`EDGE_GRADIENT`) and whether the proxy covers the
pixel, each summed over the region's pixel count (so they add up to the mean deficit), beside
the GMSD. A low GMSD is a deficit spread evenly, not a small one: a method can miss fewer edges
and still have the larger GMSD, if what it misses it misses all at once.

``--measure blur`` scores each method's renders as they are and blurred (a Gaussian of each
:data:`BLUR_SIGMAS`, in pixels), and the ground truth itself blurred alike and moved a pixel to
the right, by the report's garment-region GMSD, mean gradient-similarity deficit, detail ratio
and MSE: what each measure says of a blur it is meant to see.

``--measure dynamics`` asks how much of the garment's image is the detailed target's motion of
its own. It renders the same target embedded in the same simulated proxy (every piece carried
by the proxy, as ``target_mode="embed"`` makes it: what the ground truth would show if the
tiers had no dynamics of their own) from each sample's camera at frame t, exactly as the ground
truth is rendered, and scores that image against the ground truth by the report's
garment-region measures: its MSE is how much the tiers' own motion changes the image. Beside
it, each method's garment-region MSE against the ground truth and against that embedded image:
a method nearer the embedded image than the ground truth draws the tiers where the proxy
carries them, and misses their motion of their own. ``--sheet FILE`` also writes a PNG of
:data:`SHEET_SAMPLES` samples spread over the motion: the ground truth, the embedded image and
each method's render, a row each.
"""

from __future__ import annotations

import argparse
import json

import torch

from core.errors import InputError
from core.project import Project
from core.shading import write_png
from pipeline.config import project_config, renderer_validation_motion
from training.baselines import load_for_evaluation
from training.dataset import GarmentDataset
from training.evaluate import garment_region
from training.metrics import (
    detail_ratio,
    gaussian_window,
    gms_deficit,
    gmsd,
    gradient_magnitude,
    gradient_similarity,
    luminance,
    mse,
)

CATEGORIES = (
    "garment on the proxy, body behind",
    "garment on the proxy, backdrop behind",
    "garment off the proxy",
    "proxy only, body shows",
    "proxy only, backdrop shows",
)
#: Summed |RGB difference| from the corner pixel above which the body-only image shows the body.
BODY_THRESHOLD = 0.05
#: The :func:`split_gms` classes: the ground truth's edges and flat parts, on the
#: proxy and off it.
GMS_CATEGORIES = ("edge, on the proxy", "flat, on the proxy", "edge, off the proxy",
                  "flat, off the proxy")  # fmt: skip
#: Gaussian blurs (sigma, pixels) of ``--measure blur``.
BLUR_SIGMAS = (0.7, 1.0, 1.5)
#: The measures of ``--measure blur``: the report's garment-region figures.
BLUR_MEASURES = {"gmsd": gmsd, "gms deficit": gms_deficit, "detail": detail_ratio, "mse": mse}
#: Samples (spread evenly over the motion) in ``--measure dynamics --sheet``'s picture.
SHEET_SAMPLES = 4
#: Gradient magnitude (Prewitt, of the luma in [0, 1]) above which a ground-truth pixel is an edge:
#: a step of 0.15 in luma across the 3 px filter (a tier's shaded rim against the red).
EDGE_GRADIENT = 0.05


def categories(batch: dict) -> list[torch.Tensor]:
    """The :data:`CATEGORIES` masks (B, H, W) bool of frame t of a collated batch."""
    garment = batch["target_mask"][:, 1, 0] > 0.5
    proxy = batch["proxy_mask"][:, 1, 0] > 0
    bg = batch["background"][:, 1]
    body = (bg - bg[:, :, :1, :1]).abs().sum(1) > BODY_THRESHOLD
    return [
        garment & proxy & body,
        garment & proxy & ~body,
        garment & ~proxy,
        ~garment & proxy & body,
        ~garment & proxy & ~body,
    ]


def renders(models: dict, data, batch_size: int = 4):
    """Each collated batch of ``data`` with every method's render of its frame t: yields
    (batch, {name: (B, 3, H, W) float in [0, 1]})."""
    for start in range(0, len(data), batch_size):
        items = [data[i] for i in range(start, min(start + batch_size, len(data)))]
        batch = torch.utils.data.default_collate(items)
        with torch.no_grad():
            yield batch, {n: m.render(batch).float().clamp(0, 1) for n, m in models.items()}


def _sums(values: torch.Tensor, masks: list[torch.Tensor]) -> torch.Tensor:
    """(B, H, W) values summed over each (B, H, W) bool mask -> (len(masks),) float64."""
    return torch.tensor([float(values[m].sum()) for m in masks], dtype=torch.float64)


def _split(names: tuple[str, ...], count: torch.Tensor, sums: dict, pixels: float) -> dict:
    """The split's record: each category's share of ``pixels`` and each method's sums over
    them, with their total."""
    if pixels == 0:
        raise InputError("no garment-region pixel in the motion's samples")
    methods = {}
    for name, s in sums.items():
        row = {c: float(v / pixels) for c, v in zip(names, s, strict=True)}
        row["total"] = float(s.sum() / pixels)
        methods[name] = row
    share = {c: float(v / pixels) for c, v in zip(names, count, strict=True)}
    return {"pixels": int(pixels), "share": share, "methods": methods}


def split_error(models: dict, data, batch_size: int = 4) -> dict:
    """{"pixels": garment-region pixel count, "share": {category: share of them},
    "methods": {name: {category: summed squared error / pixels, "total": their sum}}}."""
    sse = {name: torch.zeros(len(CATEGORIES), dtype=torch.float64) for name in models}
    count = torch.zeros(len(CATEGORIES), dtype=torch.float64)
    region = 0.0
    for batch, outs in renders(models, data, batch_size):
        masks = categories(batch)
        region += float((garment_region(batch)[:, 0] > 0).sum())
        count += _sums(torch.ones_like(masks[0], dtype=torch.float64), masks)
        for name, out in outs.items():
            sse[name] += _sums(((out - batch["target"][:, 1]) ** 2).mean(1), masks)
    return _split(CATEGORIES, count, sse, region)


def split_gms(models: dict, data, batch_size: int = 4) -> dict:
    """{"pixels": the garment region's inner pixel count, "share": {GMS category: share of
    them}, "methods": {name: {category: summed 1 - GMS / pixels, "total": their sum (the mean
    deficit), "gmsd": the mean over samples of each one's GMSD, as the report's}}}."""
    deficit = {name: torch.zeros(len(GMS_CATEGORIES), dtype=torch.float64) for name in models}
    scores = {name: [] for name in models}
    count = torch.zeros(len(GMS_CATEGORIES), dtype=torch.float64)
    for batch, outs in renders(models, data, batch_size):
        target = batch["target"][:, 1]
        region = garment_region(batch)
        inner = region[:, 0, 1:-1, 1:-1] > 0
        proxy = batch["proxy_mask"][:, 1, 0, 1:-1, 1:-1] > 0
        g_target = gradient_magnitude(luminance(target))[:, 0]
        edge = g_target > EDGE_GRADIENT
        masks = [inner & edge & proxy, inner & ~edge & proxy, inner & edge & ~proxy,
                 inner & ~edge & ~proxy]  # fmt: skip
        count += _sums(torch.ones_like(g_target, dtype=torch.float64), masks)
        for name, out in outs.items():
            gms = gradient_similarity(gradient_magnitude(luminance(out))[:, 0], g_target)
            deficit[name] += _sums(1 - gms, masks)
            scores[name].append(gmsd(out, target, region))
    out = _split(GMS_CATEGORIES, count, deficit, float(count.sum()))
    for name, row in out["methods"].items():
        frames = torch.cat(scores[name])
        row["gmsd"] = float(frames[~frames.isnan()].mean())
    return out


def blurred(images: torch.Tensor, sigma: float) -> torch.Tensor:
    """(N, 3, H, W) images under a separable Gaussian of ``sigma`` pixels (3 sigma each side,
    the edges replicated)."""
    radius = max(1, round(3 * sigma))
    w = gaussian_window(2 * radius + 1, sigma).to(images.dtype)
    x = torch.nn.functional.pad(images, (radius,) * 4, mode="replicate")
    x = torch.nn.functional.conv2d(x, w.view(1, 1, 1, -1).repeat(3, 1, 1, 1), groups=3)
    return torch.nn.functional.conv2d(x, w.view(1, 1, -1, 1).repeat(3, 1, 1, 1), groups=3)


def blur_scores(models: dict, data, sigmas=BLUR_SIGMAS, batch_size: int = 4) -> dict:
    """{"rows": {row: {measure: mean over samples}}}: each method as it renders and blurred by
    each sigma, then the ground truth blurred alike and a pixel to the right
    (:data:`BLUR_MEASURES`, on the garment region as the report takes it)."""
    values: dict[str, dict[str, list]] = {}
    for batch, outs in renders(models, data, batch_size):
        target = batch["target"][:, 1]
        region = garment_region(batch)
        images = {}
        for name, out in outs.items():
            images[name] = out
            images.update({f"{name}, blurred {s:g} px": blurred(out, s) for s in sigmas})
        images.update({f"ground truth, blurred {s:g} px": blurred(target, s) for s in sigmas})
        images["ground truth, a pixel to the right"] = torch.roll(target, 1, dims=3)
        for row, image in images.items():
            for measure, fn in BLUR_MEASURES.items():
                v = fn(image, target, region)
                values.setdefault(row, {}).setdefault(measure, []).append(v)
    rows = {}
    for row, per in values.items():
        rows[row] = {}
        for measure, chunks in per.items():
            v = torch.cat(chunks)
            rows[row][measure] = float(v[~v.isnan()].mean())
    if not rows:
        raise InputError("no sample in the motion's test set")
    return {"rows": rows}


def embedded_images(project: Project, config, data) -> torch.Tensor:
    """Frame t of each of ``data``'s samples with the detailed target embedded in the simulated
    proxy (:func:`pipeline.stages.simulate.embedded_target`), rendered with the project's light
    from the sample's camera: (N, 3, H, W) float in [0, 1], 8-bit as the ground truth's PNGs."""
    from core.body.mannequin import make_body
    from core.body.skinning import pose_body
    from core.mesh import Mesh, load_mesh
    from core.shading import render_views
    from pipeline.stages.dataset import project_shading
    from pipeline.stages.motions import load_project_motion
    from pipeline.stages.simulate import embedded_target

    motion = data.split
    positions, _, _ = embedded_target(project, config, motion)
    faces = load_mesh(project.path("garment", "target.obj"))[0].faces
    body = make_body(config.body)
    body_frames = pose_body(body, load_project_motion(project, motion))
    shading = project_shading(config)
    by_frame: dict[int, list[int]] = {}
    for i, (t, _, _) in enumerate(data.samples):
        by_frame.setdefault(t, []).append(i)
    out: list = [None] * len(data.samples)
    for t, idx in by_frame.items():
        views = render_views(
            Mesh(positions[t], faces), Mesh(body_frames[t], body.faces),
            [data.samples[i][2] for i in idx], shading,
        )  # fmt: skip
        for i, gt in zip(idx, views, strict=True):
            out[i] = torch.from_numpy(gt.image.astype("float32") / 255).permute(2, 0, 1)
    return torch.stack(out)


def dynamics_scores(models: dict, data, embedded: torch.Tensor, batch_size: int = 4) -> dict:
    """{"embedded": {measure: mean}, "methods": {name: {"mse": ..., "mse_to_embedded": ...}}}:
    the embedded images ``embedded`` (N, 3, H, W), one per sample of ``data``, scored against
    the ground truth by :data:`BLUR_MEASURES`, and each method's garment-region MSE against the
    ground truth and against the embedded image; means over the samples, on the report's
    garment region."""
    if len(embedded) != len(data):
        raise InputError(f"{len(embedded)} embedded images for {len(data)} samples")
    values: dict[str, list] = {}
    methods: dict[str, dict[str, list]] = {}
    start = 0
    for batch, outs in renders(models, data, batch_size):
        target = batch["target"][:, 1]
        region = garment_region(batch)
        still = embedded[start : start + len(target)]
        start += len(target)
        for measure, fn in BLUR_MEASURES.items():
            values.setdefault(measure, []).append(fn(still, target, region))
        for name, out in outs.items():
            row = methods.setdefault(name, {"mse": [], "mse_to_embedded": []})
            row["mse"].append(mse(out, target, region))
            row["mse_to_embedded"].append(mse(out, still, region))
    if not values:
        raise InputError("no sample in the motion's test set")
    return {
        "embedded": {m: _mean(c) for m, c in values.items()},
        "methods": {n: {k: _mean(c) for k, c in row.items()} for n, row in methods.items()},
    }


def dynamics_sheet(models: dict, data, embedded: torch.Tensor, samples: int = SHEET_SAMPLES):
    """(H', W', 3) uint8: ``samples`` of ``data`` spread evenly over it, a column each; a row
    for the ground truth, one for the embedded images ``embedded`` (N, 3, H, W) and one per
    method (:func:`core.shading.contact_sheet`)."""
    import numpy as np

    from core.shading import contact_sheet

    picks = sorted({round(i * (len(data) - 1) / max(samples - 1, 1)) for i in range(samples)})
    batch = torch.utils.data.default_collate([data[i] for i in picks])
    with torch.no_grad():
        rows = {"ground truth": batch["target"][:, 1], "embedded": embedded[picks]}
        rows.update({n: m.render(batch).float().clamp(0, 1) for n, m in models.items()})

    def tile(image: torch.Tensor) -> np.ndarray:
        return (image.permute(1, 2, 0).numpy() * 255 + 0.5).astype(np.uint8)

    tiles = [tile(image) for images in rows.values() for image in images]
    labels = [name for name in rows for _ in picks]
    return contact_sheet(tiles, labels, columns=len(picks))


def _mean(chunks: list[torch.Tensor]) -> float:
    """The mean of per-sample values, NaNs (a sample without a garment region) left out."""
    v = torch.cat(chunks)
    return float(v[~v.isnan()].mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("project")
    ap.add_argument("--motion", help="an evaluated motion (default: the validation motion)")
    ap.add_argument("--source", choices=["joint2coarse", "sim"], default="joint2coarse")
    ap.add_argument("--model", action="append", default=[], metavar="NAME=FILE")
    ap.add_argument(
        "--measure", choices=["mse", "gms", "blur", "dynamics"], default="mse",
        help="split the squared error (mse) or the gradient similarity's deficit (gms), "
        "score the renders blurred (blur), or against the target embedded (dynamics)",
    )  # fmt: skip
    ap.add_argument("--json", action="store_true", help="print only JSON")
    ap.add_argument(
        "--sheet", metavar="FILE", help="with --measure dynamics: write the samples' picture"
    )
    args = ap.parse_args()
    if args.sheet and args.measure != "dynamics":
        ap.error("--sheet goes with --measure dynamics")
    torch.set_num_threads(1)
    project = Project(args.project)
    try:
        config = project_config(project)
        motion = args.motion
        if motion is None:
            spec = renderer_validation_motion(config)
            if spec is None:
                ap.error("the project has no renderer validation motion: give --motion NAME")
            motion = spec.name
        files = {"ours": project.path("renderer", "renderer.pt")}
        for kind in config.baselines:
            files[kind] = project.path(f"baselines/{kind}", f"{kind}.pt")
        for item in args.model:
            name, sep, path = item.partition("=")
            if not sep or not name or not path:
                ap.error(f"--model {item!r}: give NAME=FILE")
            files[name] = path
        models = {name: load_for_evaluation(path) for name, path in files.items()}
        data = GarmentDataset(project.root, source=args.source, split=motion)
        if args.measure == "dynamics":
            still = embedded_images(project, config, data)
            scores = dynamics_scores(models, data, still)
            if args.sheet:
                write_png(args.sheet, dynamics_sheet(models, data, still))
        else:
            split = {"mse": split_error, "gms": split_gms, "blur": blur_scores}[args.measure]
            scores = split(models, data)
        out = {"motion": motion, "source": args.source, "measure": args.measure, **scores}
    except InputError as exc:
        ap.exit(2, f"renderer_regions: {exc}\n")
    if args.json:
        print(json.dumps(out, indent=1))
        return
    if args.measure == "dynamics":
        e = out["embedded"]
        print(f"{motion}, {args.source} proxy: garment region, means over the samples")
        print(
            "the target embedded, against the ground truth: "
            + ", ".join(f"{m} {e[m]:.4f}" for m in BLUR_MEASURES)
        )
        print(f"{'method':24s} {'MSE':>10s} {'MSE against the embedded image':>32s}")
        for name, row in out["methods"].items():
            print(f"{name:24s} {row['mse']:10.4f} {row['mse_to_embedded']:32.4f}")
        return
    if args.measure == "blur":
        print(f"{motion}, {args.source} proxy: garment region, means over the samples")
        print(f"{'render':40s} " + " ".join(f"{m:>12s}" for m in BLUR_MEASURES))
        for row, f in out["rows"].items():
            print(f"{row:40s} " + " ".join(f"{f[m]:12.4f}" for m in BLUR_MEASURES))
        return
    names = list(out["methods"])
    what = "1 - GMS" if args.measure == "gms" else "squared error"
    print(f"{motion}, {args.source} proxy: {out['pixels']} garment-region pixels; {what}")
    print(f"{'where':40s} {'share':>6s} " + " ".join(f"{n[:12]:>12s}" for n in names))
    rows = (*GMS_CATEGORIES, "total", "gmsd") if args.measure == "gms" else (*CATEGORIES, "total")
    for c in rows:
        share = f"{out['share'][c]:6.3f}" if c in out["share"] else " " * 6
        row = " ".join(f"{out['methods'][n][c]:12.5f}" for n in names)
        print(f"{c:40s} {share} {row}")


if __name__ == "__main__":
    main()
