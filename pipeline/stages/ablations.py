"""Stage ``ablations``: renderer variants trained beside ours in sub-projects
(``ablations/NAME/``): no motion features, fewer views, a template instead of the derived proxy."""

from __future__ import annotations

import os
from dataclasses import replace

from core.errors import InputError
from core.project import Project
from pipeline.config import (
    Log,
    PipelineConfig,
    available_extra_motions,
    available_test_motions,
    available_validation_motions,
    quiet,
)
from pipeline.stages.dataset import stage_dataset
from pipeline.stages.joint2coarse import stage_joint2coarse
from pipeline.stages.proxy import stage_proxy
from pipeline.stages.renderer import stage_renderer
from pipeline.stages.simulate import stage_simulate

#: Ablations (``PipelineConfig.ablations``): ``no-motion`` (the renderer without motion
#: features), ``no-temporal`` (SPADE conditioned on zeros instead of frame t-1's latent, a
#: discriminator that sees single frames), ``views-N`` (a training set with N cameras per frame
#: instead of ``views_per_frame``), ``template-NAME`` (a coarse template fitted to the target
#: instead of the derived proxy; NAME from ``dng garment list``).
ABLATION_KINDS = ("no-motion", "no-temporal", "views-", "template-")

#: The ablations that retrain only the renderer, on the project's data set, with these changes.
RENDERER_ABLATIONS = {"no-motion": {"use_motion": False}, "no-temporal": {"use_temporal": False}}


def check_ablation(name: str) -> None:
    ok = name in RENDERER_ABLATIONS
    if name.startswith("views-"):
        ok = name[6:].isdigit() and int(name[6:]) > 0
    if name.startswith("template-"):
        ok = len(name) > 9
    if not ok:
        raise InputError(
            f"unknown ablation {name!r}: use no-motion, no-temporal, views-N or template-NAME"
        )


def ablation_project(project: Project, name: str) -> Project:
    """The folder of an ablation that needs its own stages (``ablations/NAME``)."""
    return Project(project.root / "ablations" / name)


def _link(sub: Project, project: Project, names: list[str]) -> None:
    """Share the parent's finished stage folders with a sub-project (symbolic links)."""
    sub.root.mkdir(parents=True, exist_ok=True)
    for name in names:
        link = sub.root / name
        if link.is_symlink() or link.exists():
            continue
        os.symlink(os.path.relpath(project.root / name, sub.root), link)


def stage_ablation(
    project: Project, config: PipelineConfig, name: str, log: Log = quiet, progress: bool = True
) -> dict:
    """Train one ablation of the renderer (see :data:`ABLATION_KINDS`); returns its report.

    ``no-motion`` and ``no-temporal`` (:data:`RENDERER_ABLATIONS`) train into
    ``ablations/NAME/`` from the project's data set. The others
    are sub-projects under ``ablations/NAME/`` that share the parent's finished folders by
    symbolic links and run only the stages that differ: ``views-N`` its own training set and
    renderer; ``template-NAME`` its own proxy (the template fitted to the target), proxy
    simulations, Joint2Coarse and renderer, on the parent's ground-truth images (the same
    target motion, so the scores compare).
    """
    check_ablation(name)
    if name in RENDERER_ABLATIONS:
        return stage_renderer(
            project, config, log, progress, stage=f"ablations/{name}",
            overrides=RENDERER_ABLATIONS[name],
        )  # fmt: skip
    sub = ablation_project(project, name)
    if name.startswith("views-"):
        views = int(name[6:])
        _link(sub, project, ["motions", "garment", "proxy", "sim", "joint2coarse"])
        sub_config = replace(config, views_per_frame=views)
        sub.save_settings({"ablation": name, "pipeline": sub_config.as_params()})
        stage_dataset(sub, sub_config, log)
        return stage_renderer(sub, sub_config, log, progress)
    template = name[len("template-") :]
    _link(sub, project, ["motions", "garment", "dataset", "testset"])
    sub_config = replace(config, proxy_template=template)
    sub.save_settings({"ablation": name, "pipeline": sub_config.as_params()})
    stage_proxy(sub, sub_config, log)
    library = (*available_extra_motions(config), *available_validation_motions(config))
    for m in (config.train_motion, *library, *available_test_motions(config)):
        stage_simulate(sub, sub_config, m.name, "proxy", log)
    stage_joint2coarse(sub, sub_config, log, progress)
    return stage_renderer(sub, sub_config, log, progress)


def ablation_label(name: str, config: PipelineConfig) -> str:
    """The ablation's row name in the comparison table."""
    if name == "no-motion":
        return "ours, no motion features"
    if name == "no-temporal":
        return "ours, no temporal conditioning"
    if name.startswith("views-"):
        return f"ours, {name[6:]} views per frame (not {config.views_per_frame})"
    return f"ours, {name[len('template-') :]} template as proxy"
