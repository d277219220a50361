"""Stage ``motions``: every motion of the project as a BVH on the mannequin (``motions/``)."""

from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path

from core.errors import InputError
from core.motion.bvh import write_bvh
from core.motion.mapping import canonical_positions
from core.motion.procedural import make_motion
from core.motion.retarget import retarget
from core.project import Project
from pipeline.config import (
    Log,
    MotionSpec,
    PipelineConfig,
    available_extra_motions,
    available_test_motions,
    available_validation_motions,
    quiet,
)


def stage_motions(project: Project, config: PipelineConfig, log: Log = quiet) -> list[str]:
    """Write every motion of the project as a BVH on the mannequin: ``motions/NAME.bvh``."""
    specs = (
        config.train_motion,
        *available_extra_motions(config),
        *available_validation_motions(config),
        *available_test_motions(config),
    )
    params = {"specs": [asdict(s) for s in specs], "fps": config.fps, "body": asdict(config.body)}
    inputs = [s.path for s in specs if s.kind == "file"]

    def work(out: Path) -> list[str]:
        names = []
        for spec in specs:
            motion = motion_from_spec(spec, config)
            write_bvh(out / f"{spec.name}.bvh", motion)
            names.append(f"{spec.name}.bvh")
            log(f"  {spec.name}: {motion.num_frames} frames at {motion.fps:g} fps")
        return names

    project.run_stage("motions", params, inputs, work)
    return [s.name for s in specs]


def motion_from_spec(spec: MotionSpec, config: PipelineConfig):
    from core.motion.load import load_motion, resample
    from core.motion.variation import source_frames, vary_motion

    frames = source_frames(spec.frames, spec.speed)  # before playing it faster or slower
    if spec.kind != "file":
        motion = make_motion(spec.kind, frames, config.fps, spec.seed, config.body)
    else:
        source = resample(load_motion(spec.path), config.fps)
        first = int(round(spec.start_s * config.fps))
        if first + frames > source.num_frames:
            raise InputError(
                f"{frames} frames from {spec.start_s} s wanted, the clip has {source.num_frames}",
                spec.path,
            )
        positions = canonical_positions(source)[first : first + frames]
        motion = retarget(positions, config.fps, config.body, name=spec.name)
    change = (spec.speed, spec.amplitude, spec.heading_deg, spec.turn_deg_s)
    if change == (1.0, 1.0, 0.0, 0.0):
        return motion
    varied = vary_motion(motion, *change)
    return replace(
        varied,
        rotations=varied.rotations[: spec.frames],
        root_positions=varied.root_positions[: spec.frames],
    )


def load_project_motion(project: Project, name: str):
    """A motion written by :func:`stage_motions` (a Motion on the mannequin's joints)."""
    from core.motion.load import load_motion

    return load_motion(project.path("motions", f"{name}.bvh"))
