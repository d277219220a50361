"""The results page (``docs/results.md``): a project's report, pooled into a page a reader scans.

``dng report PROJECT --results docs/results.md`` writes it from ``PROJECT/report.json`` (and
any benchmark JSON given), so no figure on the page can drift from what ran. The page names
the preset, the ground truth, the machine, the date and the commit it came from.
"""

from __future__ import annotations

import json
from pathlib import Path

from core.errors import InputError
from core.fileio import atomic_path
from pipeline.demo import (
    joint2coarse_physics_markdown,
    joint2coarse_splits_markdown,
    metrics_table,
    ratio_sentence,
)
from pipeline.deviations import deviations_markdown, from_json, methods_markdown

#: The page's sections, in order: ``(anchor, heading)``. The README links to these anchors; a
#: test checks the generator writes every one.
SECTIONS = (
    ("headline", "Headline"),
    ("where-these-figures-come-from", "Where these figures come from"),
    ("joint2coarse", "Joint2Coarse"),
    ("neural-renderer", "Neural renderer"),
    ("simulation", "Simulation"),
    ("speed", "Speed"),
    ("run-time", "Run time"),
    ("what-each-method-got", "What each method got"),
    ("deviations-from-the-paper", "Deviations from the paper"),
)

#: The methods of the headline, as the report names them.
HEADLINE_METHODS = ("ours", "dnr", "pix2pix")

#: The paper's Table 1 ratio of our MSE over DNR's (0.116 / 0.204), against its simulated target.
PAPER_OURS_TO_DNR = 0.57


#: How the detailed target of a project's ground truth moves (``target_mode``): a word for the
#: headline, and the sentence that says what it means.
GROUND_TRUTHS = {
    "simulate": ("simulated", "the detailed target is a cloth simulation of its own"),
    "tiers": (
        "embedded, tiers simulated",
        "the detailed target is carried by the simulated proxy, and its frill tiers are "
        "simulated as cloth on it (a motion of their own; the layers keep their offsets)",
    ),
    "embed": (
        "embedded",
        "the detailed target is carried by the simulated proxy (its details keep their offsets "
        "and have no motion of their own)",
    ),
}


def ground_truth(report: dict) -> tuple[str, str]:
    """``(word, sentence)``: how the project's detailed target moves (:data:`GROUND_TRUTHS`)."""
    mode = report.get("config", {}).get("target_mode", "embed")
    return GROUND_TRUTHS.get(mode, GROUND_TRUTHS["embed"])


def _mean(summary: dict | None) -> float | None:
    return None if not summary else summary.get("mean")


def _cell(value: float | None, fmt: str) -> str:
    return "n/a" if value is None else format(value, fmt)


def headline_rows(report: dict) -> list[tuple[str, str]]:
    """The few figures the README repeats: ``(what, figure)`` rows, test split only."""
    rows: list[tuple[str, str]] = []
    j = report.get("joint2coarse") or {}
    tests = list(j.get("motions", {}))
    if tests:
        models = {j.get("model", "paper"): j, **j.get("compare", {})}
        cells = []
        for name, r in models.items():
            errs = [r["motions"][m]["error_mm"] for m in tests]
            mean = sum(e["mean_mm"] for e in errs) / len(errs)
            p95 = sum(e["p95_mm"] for e in errs) / len(errs)
            label = "ours" if name == "ours" else "the paper's model"
            cells.append(f"{mean:.1f} / {p95:.0f} ({label})")
        rows.append(
            (
                "Joint2Coarse: proxy vertex error on the unseen motions, mean / p95 (mm)",
                "; ".join(cells),
            )
        )
    ev = report.get("evaluation") or {}
    methods = ev.get("methods", {})
    shown = [m for m in HEADLINE_METHODS if m in methods]
    if shown:
        names = " / ".join(
            "DNR" if m == "dnr" else "Pix2Pix" if m == "pix2pix" else m for m in shown
        )
        for key, what, fmt in (
            ("mse_masked", "garment-region MSE", ".4f"),
            ("gmsd_masked", "garment-region GMSD (edges; 0 = the ground truth's)", ".3f"),
            (
                "gms_masked",
                "garment-region gradient-similarity deficit, mean (edges missed; 0 = none)",
                ".3f",
            ),
            ("detail_masked", "garment-region detail ratio (1 = as much fine detail)", ".2f"),
            ("ssim_masked", "garment-region SSIM", ".3f"),
            ("flicker_masked", "garment-region flicker", ".4f"),
            ("tof_masked", "garment-region tOF (optical flow's difference, px)", ".3f"),
        ):
            if not any(methods[m].get(key) for m in shown):
                continue  # a report made before the metric existed
            values = [_cell(_mean(methods[m].get(key)), fmt) for m in shown]
            rows.append(
                (f"Neural render on the unseen motions, {what}: {names}", " / ".join(values))
            )
        full, region = ev.get("mse_ratio_ours_to_dnr"), ev.get("mse_masked_ratio_ours_to_dnr")
        if full is not None and region is not None:
            rows.append(
                (
                    "Ours / DNR, MSE on the unseen motions: full frame; garment region (the "
                    f"paper: {PAPER_OURS_TO_DNR}, full frame, simulated target)",
                    f"{full:.2f}; {region:.2f}",
                )
            )
    videos = report.get("videos") or {}
    if videos:
        totals = sorted(v["median_ms"]["total"] for v in videos.values())
        size = (report.get("renderer") or {}).get("config", {}).get("image_size")
        rows.append(
            (
                "Live neural render, motion to image, ms per frame (median"
                + (f", {size} px" if size else "")
                + ", CPU)",
                " / ".join(f"{t:.0f}" for t in totals),
            )
        )
    if report.get("total_seconds"):
        minutes = f"{report['total_seconds'] / 60:.1f}"
        if (report.get("provenance") or {}).get("from_empty") is False:
            minutes += " (a rerun: it reused the stages an earlier run had made)"
        rows.append(("The run on this machine, minutes", minutes))
    return rows


def headline_markdown(report: dict) -> list[str]:
    """The headline table (the README's results table is a copy of these lines)."""
    lines = ["| result | figure |", "| --- | --- |"]
    lines += [f"| {what} | {figure} |" for what, figure in headline_rows(report)]
    return lines


def _provenance_markdown(report: dict) -> list[str]:
    made = report.get("provenance") or {}
    machine = made.get("machine") or {}
    commit = made.get("commit")
    if machine:
        where = (
            f"{machine.get('cores')} cores of {machine.get('cpu')}, {machine.get('system')}, "
            f"Python {machine.get('python')}, PyTorch {machine.get('torch')}"
            + (", CUDA" if machine.get("cuda") else ", no GPU")
        )
    else:
        where = "not recorded (a report made before provenance was kept)"
    return [
        f"- Preset: `{report.get('preset', 'custom')}`; made by `dng demo --preset "
        f"{report.get('preset', 'custom')} --out PROJECT`, then `dng report PROJECT --results "
        "docs/results.md`.",
        "- Ground truth: {}: {}.".format(*ground_truth(report)),
        f"- Commit: {f'`{commit}`' if commit else 'not recorded'}"
        + {
            True: ", from an empty project folder.",
            False: ", a rerun over an earlier run's "
            "stages (each stage keeps the parameters and inputs that made it).",
        }.get(made.get("from_empty"), "."),
        f"- Date: {made.get('date', 'not recorded')}.",
        f"- Machine: {where}.",
        "- Splits: settings are chosen on the validation motion (protocol V); the unseen test "
        "motions (U) and the training motion from unseen cameras (P) are only reported.",
    ]


def _joint2coarse_markdown(report: dict) -> list[str]:
    j = report.get("joint2coarse")
    if not j:
        return ["Not trained in this project."]
    lines = [
        f"Vertex error of the predicted proxy against the project's simulation (mm). Model "
        f"`{j.get('model', 'paper')}`, trained on {1 + len(j.get('extra_train_motions', []))} "
        "clips; the other column is the paper's model trained beside it.",
        "",
    ]
    lines += joint2coarse_splits_markdown(j)
    if j.get("motions"):
        held = j.get("stretch_limit")
        prediction = (
            f"the prediction (its edges shortened to at most {held['limit']:.0%} stretch, "
            f"{held['sweeps']} sweeps)"
            if held
            else "the prediction as it comes"
        )
        lines += [
            "",
            "Physics beside the distance, on the unseen motions: how deep and how often the "
            "proxy is inside the body's capsules, and its edges' stretch against the proxy's "
            f"rest shape (p99 and max over every edge and frame), for {prediction}, that "
            "pushed out of the body, and the simulation; and the hem's radius (its mean "
            "distance from the axis through the waist, per frame), the prediction's against the "
            "simulation's.",
            "",
            *joint2coarse_physics_markdown(j),
        ]
    return lines


def _renderer_markdown(report: dict) -> list[str]:
    ev = report.get("evaluation")
    if not ev:
        return ["Not evaluated in this project."]
    lines = [
        "Every method from cameras the training never saw, rendering Joint2Coarse's proxy (no "
        "simulation at test time); rows marked *simulated proxy* render the simulation's (the "
        "renderers alone). Mean ± std over frames; garment-region figures first. Flicker is "
        "mean |(R[t+1] - R[t]) - (I[t+1] - I[t])|.",
    ]
    blocks = []
    if ev.get("validation"):
        v = ev["validation"]
        blocks.append(
            (f"V, the validation motion `{v['motion']}` (settings chosen here)", v["methods"])
        )
    blocks.append(
        ("U, the unseen motions " + ", ".join(f"`{m}`" for m in ev["test_motions"]), ev["methods"])
    )
    if ev.get("protocol_p"):
        p = ev["protocol_p"]
        blocks.append(
            (f"P, the training motion `{p['motion']}` (the paper's protocol)", p["methods"])
        )
    for title, methods in blocks:
        lines += ["", f"**{title}**", "", *metrics_table(methods)]
        ratio = ratio_sentence(methods)
        if ratio:
            lines += ["", ratio]
    motions = [*([ev["validation"]["motion"]] if ev.get("validation") else []), *ev["motions"]]
    lines += [
        "",
        "The same frames from every method under the ground truth: "
        + ", ".join(f"`PROJECT/eval/{m}/compare.png`" for m in motions)
        + ".",
    ]
    return lines


def _simulation_markdown(report: dict) -> list[str]:
    sims = report.get("simulation") or {}
    proxies = {k: v for k, v in sims.items() if k.endswith("-proxy")}
    if not proxies:
        return ["No simulation in this project."]
    ms = sorted(s["ms_per_frame"] for s in proxies.values())
    frames = sum(s["frames"] for s in proxies.values())
    worst_strain = max(proxies.items(), key=lambda kv: kv[1]["strain_max"])
    worst_pen = max(proxies.items(), key=lambda kv: kv[1]["penetration_max_mm"])
    finite = sum(1 for s in proxies.values() if s.get("finite"))
    solver = report.get("config", {}).get("sim_solver", "?")
    return [
        f"The proxy simulated on {len(proxies)} clips ({frames} frames) with the `{solver}` "
        f"solver: {finite} of {len(proxies)} finite; ms per frame median "
        f"{ms[len(ms) // 2]:.0f} (range {ms[0]:.0f} to {ms[-1]:.0f}); largest edge strain "
        f"{worst_strain[1]['strain_max']:.3f} (`{worst_strain[0]}`); deepest penetration "
        f"{worst_pen[1]['penetration_max_mm']:.1f} mm (`{worst_pen[0]}`). Per clip: the "
        "project's `report.md`.",
    ]


def _speed_markdown(report: dict) -> list[str]:
    videos = report.get("videos") or {}
    if not videos:
        return ["No videos in this project."]
    lines = [
        "The neural path per frame as `dng render` runs it (median ms):",
        "",
        "| motion | frames | Joint2Coarse | body background | raster + network | total |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for name, v in videos.items():
        m = v["median_ms"]
        lines.append(
            f"| {name} | {v['frames']} | {m['joint2coarse']:.2f} | {m['background']:.0f} | "
            f"{m['raster+network']:.0f} | {m['total']:.0f} |"
        )
    return lines


#: The groups of ``stage_seconds`` the run-time table sums, by the start of a stage's name.
_STAGE_GROUPS = (
    ("motions, garment, proxy, embedding", ("motions", "garment", "proxy", "embedding")),
    ("simulations (overlapping, two at a time)", ("simulate",)),
    ("ground-truth images", ("dataset", "test set", "validation set")),
    ("Joint2Coarse", ("joint2coarse",)),
    ("renderer and baselines", ("neural renderer", "baselines", "ablation")),
    ("evaluation and videos", ("evaluation", "videos")),
)


def _run_time_markdown(report: dict) -> list[str]:
    stages = report.get("stage_seconds") or {}
    lines = ["| stages | seconds (summed; stages in two processes overlap) |", "| --- | --- |"]
    for label, starts in _STAGE_GROUPS:
        total = sum(v for k, v in stages.items() if k.startswith(starts))
        lines.append(f"| {label} | {total:.0f} |")
    if report.get("total_seconds"):
        lines.append(f"| **the run, start to end** | **{report['total_seconds']:.0f}** |")
    return lines


def _bench_markdown(name: str, data) -> list[str]:
    """A benchmark's JSON as a table: a list of flat records (or ``{"rows": [...]}``), else its
    top-level figures; the command that made it first, where the JSON names it (``command``)."""
    rows = data.get("rows") if isinstance(data, dict) else data
    lines = ["", f"### {name}", ""]
    if isinstance(data, dict) and data.get("command"):
        lines += [f"Made by `{data['command']}`.", ""]
    if isinstance(rows, list) and rows and all(isinstance(r, dict) for r in rows):
        keys = [k for k in rows[0] if not isinstance(rows[0][k], (dict, list))]
        lines += ["| " + " | ".join(keys) + " |", "|" + " --- |" * len(keys)]
        for r in rows:
            cells = [
                f"{r.get(k):.4g}" if isinstance(r.get(k), float) else str(r.get(k)) for k in keys
            ]
            lines.append("| " + " | ".join(cells) + " |")
        return lines
    if isinstance(data, dict):
        lines += [
            f"- {k}: {f'{v:.4g}' if isinstance(v, float) else v}"
            for k, v in data.items()
            if not isinstance(v, (dict, list))
        ]
        return lines
    return [*lines, "(no figures this page can show)"]


#: Where the results page's picture goes, relative to the page's folder.
PICTURE = "img/results-compare.png"


def picture_motion(report: dict) -> str | None:
    """The motion whose comparison picture the results page shows: the first unseen one."""
    tests = (report.get("evaluation") or {}).get("test_motions") or []
    return tests[0] if tests else None


def write_picture(project: Path, page_dir: Path, report: dict) -> str | None:
    """Copy the first unseen motion's ``eval/MOTION/compare.png`` beside the results page, as a
    256-colour PNG (a third of the size); return its path relative to ``page_dir`` (None: no
    such picture in the project)."""
    from PIL import Image

    motion = picture_motion(report)
    source = project / "eval" / str(motion) / "compare.png"
    if motion is None or not source.is_file():
        return None
    target = page_dir / PICTURE
    target.parent.mkdir(parents=True, exist_ok=True)
    with Image.open(source) as im:
        small = im.convert("RGB").quantize(256, method=Image.Quantize.MEDIANCUT)
    with atomic_path(target) as tmp:
        small.save(tmp, format="PNG", optimize=True)
    return PICTURE


def results_markdown(
    report: dict, benches: dict[str, object] | None = None, *, picture: str | None = None
) -> str:
    """The results page from a project's ``report.json`` (a dict) and benchmark JSON by name;
    ``picture``: the comparison picture's path relative to the page (:func:`write_picture`)."""
    shown = (
        [
            "",
            f"![ground truth and every method on the unseen motion {picture_motion(report)}]"
            f"({picture})",
            "",
            f"The unseen motion `{picture_motion(report)}` from cameras the training never saw: "
            "the ground truth on top, then each method on the same frames.",
        ]
        if picture
        else []
    )
    body = {
        "headline": [
            f"The `{report.get('preset', 'custom')}` preset's figures on the **test split**, "
            f"against an **{ground_truth(report)[0]}** ground truth (below). Lower is "
            "better for errors, MSE, GMSD and flicker; higher for SSIM; 1 is best for the "
            "detail ratio.",
            "",
            *headline_markdown(report),
            *shown,
        ],
        "where-these-figures-come-from": _provenance_markdown(report),
        "joint2coarse": _joint2coarse_markdown(report),
        "neural-renderer": _renderer_markdown(report),
        "simulation": _simulation_markdown(report),
        "speed": _speed_markdown(report),
        "run-time": _run_time_markdown(report),
        "what-each-method-got": (
            [
                "Trainable parameters of what renders (no discriminator), the training budget and "
                "losses of each method of the comparison.",
                "",
                methods_markdown(from_json(report["against_the_paper"])[1]),
            ]
            if "against_the_paper" in report
            else ["Not recorded in this report."]
        ),
        "deviations-from-the-paper": (
            [deviations_markdown(from_json(report["against_the_paper"])[0])]
            if "against_the_paper" in report
            else ["Not recorded in this report."]
        ),
    }
    lines = [
        "# Results",
        "",
        "Generated by `dng report PROJECT --results docs/results.md` from a project's "
        "`report.json`; do not edit by hand. How each setting was chosen: "
        "[decisions.md](decisions.md).",
    ]
    for anchor, heading in SECTIONS:
        lines += ["", f"## {heading}", "", *body[anchor]]
    if benches:
        lines += ["", "## Benchmarks"]
        for name, data in benches.items():
            lines += _bench_markdown(name, data)
    return "\n".join(lines) + "\n"


def with_headline(page: str, report: dict, path: str | Path = "README.md") -> str:
    """``page`` (a README) with its copy of the headline table replaced by ``report``'s: the
    table that starts with the headline's header row. An :class:`InputError` if it has none."""
    lines = page.split("\n")
    header = headline_markdown({})[0]
    if header not in lines:
        raise InputError(f"{path}: no results table to update (a line {header!r})")
    start = lines.index(header)
    end = start
    while end < len(lines) and lines[end].startswith("|"):
        end += 1
    return "\n".join([*lines[:start], *headline_markdown(report), *lines[end:]])


def load_report(project: str | Path) -> dict:
    """``PROJECT/report.json`` as a dict; an :class:`InputError` naming the file otherwise."""
    path = Path(project) / "report.json"
    if not path.is_file():
        raise InputError(f"{path}: no report (run `dng demo --out {project}` first)")
    try:
        report = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not a readable report: {exc}") from None
    if not isinstance(report, dict) or "preset" not in report:
        raise InputError(f"{path}: not a demo report (no 'preset')")
    return report
