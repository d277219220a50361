"""Write a project's torch bundle (:mod:`training.torchpath.bundle`): runs where the whole studio
is installed (it reads the project with :class:`pipeline.playback.Playback`)."""

from __future__ import annotations

import os

import numpy as np
import torch

from core.errors import InputError
from core.features import FeatureConfig
from core.fileio import atomic_path
from core.skeleton import forward_kinematics, skinning_transforms
from pipeline.playback import Playback, load_motion_for
from pipeline.stages.dataset import dataset_rig
from training.joint2coarse import joint2coarse_inputs
from training.joint2coarse.model import MODEL_FORMAT
from training.renderer.train import load_model
from training.torchpath.bundle import BUNDLE_FORMAT


def clip_arrays(pb: Playback, motion) -> dict:
    """A motion on the mannequin as a bundle clip (see the bundle's docstring)."""
    joints, root_rot = joint2coarse_inputs(motion)
    pos, rot = forward_kinematics(pb.body.skeleton, motion.rotations, motion.root_positions)
    transforms = skinning_transforms(pb.body.skeleton, pos, rot)
    return {
        "joints": torch.from_numpy(np.ascontiguousarray(joints, np.float32)),
        "root_rotations": torch.from_numpy(np.ascontiguousarray(root_rot, np.float32)),
        "root_positions": torch.from_numpy(np.asarray(motion.root_positions, np.float64).copy()),
        "transforms": torch.from_numpy(np.ascontiguousarray(transforms, np.float32)),
        "fps": float(motion.fps),
    }


def export_bundle(
    project: str | os.PathLike,
    out: str | os.PathLike,
    motions: list[str] | None = None,
    *,
    frames: int | None = None,
    joint2coarse: str | os.PathLike | None = None,
) -> dict:
    """Write ``out`` (atomically): :func:`make_bundle` of the project; returns the bundle."""
    bundle = make_bundle(project, motions, frames=frames, joint2coarse=joint2coarse)
    with atomic_path(out) as tmp:
        torch.save(bundle, tmp)
    return bundle


def make_bundle(
    project: str | os.PathLike,
    motions: list[str] | None = None,
    *,
    frames: int | None = None,
    joint2coarse: str | os.PathLike | None = None,
) -> dict:
    """The project's models, proxy, body and the given motions (default: its training motion;
    any of :func:`pipeline.playback.load_motion_for`: BVH files, project motions, procedural
    kinds), the first ``frames`` of each when given. ``joint2coarse``: another Joint2Coarse
    model file than the project's (``paper`` or ``ours``, e.g. ``joint2coarse/compare-ours``)."""
    pb = Playback(project, joint2coarse_path=joint2coarse)
    if not pb.has_renderer():
        raise InputError(
            "no trained renderer: train one first (dng train renderer)", pb.renderer_path
        )
    names = motions or [pb.config.train_motion.name]
    clips = {}
    for name in names:
        motion = load_motion_for(pb.project, name, frames=frames)
        clips[str(name)] = clip_arrays(pb, motion)
    j2c = {
        "format": MODEL_FORMAT,
        "config": pb.joint2coarse.config.to_dict(),
        "n_vertices": pb.joint2coarse.n_vertices,
        "descriptor_dim": pb.joint2coarse.descriptor_dim,
        "state_dict": pb.joint2coarse.state_dict(),
    }
    config, net, _ = load_model(pb.renderer_path)
    rig = dataset_rig(pb.config, np.stack(pb.garment_box()))
    fc = FeatureConfig()
    bundle = {
        "format": BUNDLE_FORMAT,
        "joint2coarse": j2c,
        "renderer": {"config": config.to_dict(), "generator": net.state_dict()},
        "proxy": {
            "faces": torch.from_numpy(np.asarray(pb.proxy_faces, np.int64).copy()),
            "uvs": torch.from_numpy(np.asarray(pb.proxy_uvs, np.float32).copy()),
            "seam_map": torch.from_numpy(pb.seam_map.copy()),
            # the strain limit Joint2Coarse's predictions keep (Playback's ``stretch``)
            "stretch": {
                "edges": torch.from_numpy(np.asarray(pb.stretch.edges, np.int64).copy()),
                "lengths": torch.from_numpy(np.asarray(pb.stretch.lengths, np.float64).copy()),
                "limit": float(pb.stretch.limit),
                "sweeps": int(pb.stretch.sweeps),
            },
        },
        "body": {
            "vertices": torch.from_numpy(np.asarray(pb.body.vertices, np.float32).copy()),
            "weights": torch.from_numpy(np.asarray(pb.body.weights, np.float32).copy()),
            "faces": torch.from_numpy(np.asarray(pb.body_faces, np.int64).copy()),
        },
        "rig": {
            "fov_y_deg": float(rig.fov_y_deg),
            "target_y": float(rig.target[1]),
            "radius": float(rig.radius_range[0]),
        },
        "features": {"sigma": float(fc.sigma), "frame_offsets": list(fc.frame_offsets)},
        "clips": clips,
    }
    return bundle
