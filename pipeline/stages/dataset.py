"""Stages ``dataset`` and ``testset``: the renderer's training samples (frames t-1, t, t+1 from
random cameras) and each test motion's ground truth from unseen cameras."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np

from core.body.mannequin import make_body
from core.body.skinning import pose_body
from core.camera import CameraRigConfig, camera_to_dict, random_cameras
from core.fileio import write_json
from core.lighting import load_lighting
from core.mesh import Mesh, load_mesh
from core.project import Project, fingerprint
from core.shading import ShadingConfig, render_views, write_png
from core.sim import load_cache
from pipeline.config import Log, PipelineConfig, quiet
from pipeline.stages.motions import load_project_motion
from training.dataset import sample_name

#: Version of ``samples.json``: 2 names the ground truth's hash (a project rendered before it
#: renders again, so the stages trained on a stale ground truth rerun too).
INDEX_VERSION = 2
#: Random camera streams (``random_cameras(seed=(config.seed, STREAM, t))``) of the test sets
#: and of the renderers' validation set; the training set's is ``(config.seed, t)``.
TEST_CAMERAS, VALIDATION_CAMERAS = 1, 2

# ---------------------------------------------------------------------------------- data set


def project_shading(config: PipelineConfig, threads: int | None = None) -> ShadingConfig:
    """How the project's ground truth is rendered: its light (:attr:`PipelineConfig.lighting`),
    ray casts on ``threads`` (default: ``config.raster_threads``)."""
    threads = config.raster_threads if threads is None else threads
    return ShadingConfig(lighting=load_lighting(config.lighting), threads=threads)


def lighting_params(config: PipelineConfig) -> dict:
    """What a rendering stage's parameters say of the light: nothing for the studio's (so a
    project made before lights could be chosen keeps its stages), else the light itself."""
    if config.lighting == "studio":
        return {}
    return {"lighting": load_lighting(config.lighting).to_dict()}


def dataset_rig(config: PipelineConfig, garment_vertices: np.ndarray):
    """Cameras on a circle that frame the garment (it fills most of the image)."""
    lo, hi = garment_vertices.min(axis=0), garment_vertices.max(axis=0)
    centre = (lo + hi) / 2
    half = 0.5 * float(np.linalg.norm(hi - lo)) * 1.15  # room for the swing
    fov = 40.0
    dist = half / np.tan(np.radians(fov / 2))
    return CameraRigConfig(
        width=config.image_size,
        height=config.image_size,
        fov_y_deg=fov,
        target=(0.0, float(centre[1]), 0.0),
        radius_range=(dist, dist * 1.15),
        elevation_deg_range=(-5.0, 25.0),
        target_jitter=0.03,
    )


def sample_frames(num_frames: int, stride: int) -> list[int]:
    """Centres t of samples (t-1, t, t+1): every ``stride`` frames, away from the ends."""
    return list(range(1, num_frames - 1, max(1, stride)))


def stage_dataset(project: Project, config: PipelineConfig, log: Log = quiet) -> Path:
    """Ground-truth renders of the simulated target on the body, and body-only backgrounds.

    For every sample centre t (:func:`sample_frames`) and each of ``views_per_frame`` cameras
    (``random_cameras(seed=(seed, t))``, following the body's root at t), renders frames t-1,
    t, t+1 from that camera. Writes per sample three PNG strips (H, 3W): ``..._image.png``,
    ``..._background.png``, ``..._mask.png``; and ``samples.json`` with the cameras. Feature
    maps are not stored: :class:`training.dataset.GarmentDataset` rasterizes them on the fly.
    """
    train = config.train_motion.name
    target_cache = project.path(f"sim/{train}-target", "cache.npz")
    motion_file = project.path("motions", f"{train}.bvh")
    params = {
        "index": INDEX_VERSION,
        "views": config.views_per_frame,
        "stride": config.frame_stride,
        "size": config.image_size,
        "seed": config.seed,
        "body": asdict(config.body),
        **lighting_params(config),
    }

    def work(out: Path) -> list[str]:
        samples = render_samples(
            project, config, train, out, seed=(config.seed,), views=config.views_per_frame,
            stride=config.frame_stride, desc="ground truth",
        )  # fmt: skip
        log(f"  {len(samples)} samples of 3 frames at {config.image_size} px")
        return ["samples.json", *_sample_files(samples)]

    project.run_stage("dataset", params, [target_cache, motion_file], work)
    return project.stage_dir("dataset")


def render_samples(
    project: Project,
    config: PipelineConfig,
    motion_name: str,
    out: Path,
    *,
    seed: tuple[int, ...],
    views: int,
    stride: int,
    desc: str,
) -> list[dict]:
    """Render the samples of one clip into ``out``: PNG strips and ``samples.json``.

    For every centre t (:func:`sample_frames`) and each of ``views`` cameras
    (``random_cameras(seed=(*seed, t))`` on :func:`dataset_rig`, following the body's root at
    t), renders the target on the body and the body alone at frames t-1, t, t+1. Returns the
    sample records written to ``samples.json``, which also names the target cache's content
    hash (``ground_truth``): the stages trained or scored on these images take ``samples.json``
    as their input, so a new ground truth reruns them even where the cameras stay the same.
    """
    from tqdm import tqdm

    cache_file = project.path(f"sim/{motion_name}-target", "cache.npz")
    cache = load_cache(cache_file)
    motion = load_project_motion(project, motion_name)
    rest, _ = load_mesh(project.path("garment", "target.obj"))
    body = make_body(config.body)
    body_frames = pose_body(body, motion)
    rig = dataset_rig(config, rest.vertices)
    root = motion.root_positions
    centres = sample_frames(cache.num_frames, stride)
    cams = {}
    for t in centres:
        shift = np.array([root[t, 0], 0.0, root[t, 2]])
        for k, cam in enumerate(random_cameras(views, (*seed, t), rig)):
            e = cam.extrinsic.astype(np.float64).copy()
            e[:3, 3] -= e[:3, :3] @ shift  # follow the body: the camera moves with the root
            cams[(t, k)] = type(cam)(cam.K, e.astype(cam.extrinsic.dtype), cam.width, cam.height)
    # Render frame by frame: each frame is seen by the cameras of samples t-1, t, t+1.
    strips: dict[tuple[int, int], list] = {key: [None] * 3 for key in cams}
    frames = sorted({t + d for t in centres for d in (-1, 0, 1)})
    shading = project_shading(config)
    for f in tqdm(frames, desc=desc, unit="frame", leave=False):
        wanted = [(t, k, f - t + 1) for (t, k) in cams if abs(f - t) <= 1]
        garment = Mesh(cache.positions[f], cache.faces)
        body_mesh = Mesh(body_frames[f], body.faces)
        views_f = render_views(garment, body_mesh, [cams[(t, k)] for t, k, _ in wanted], shading)
        for (t, k, slot), gt in zip(wanted, views_f):
            strips[(t, k)][slot] = gt
            if all(s is not None for s in strips[(t, k)]):
                _write_sample(out, t, k, strips.pop((t, k)), write_png)
    samples = [{"frame": t, "view": k, "camera": camera_to_dict(c)} for (t, k), c in cams.items()]
    write_json(
        out / "samples.json",
        {"motion": motion_name, "fps": cache.fps, "num_frames": cache.num_frames,
         "ground_truth": fingerprint({}, [cache_file]), "samples": samples},
    )  # fmt: skip
    return samples


def _sample_files(samples: list[dict]) -> list[str]:
    return [
        f"samples/{sample_name(s['frame'], s['view'])}_{kind}.png"
        for s in samples
        for kind in ("image", "background", "mask")
    ]


def stage_testset(
    project: Project,
    config: PipelineConfig,
    motion_name: str,
    log: Log = quiet,
    *,
    validation: bool = False,
) -> Path:
    """Ground truth of an unseen motion from unseen cameras: ``testset/MOTION/``.

    Same layout as the training set (:func:`stage_dataset`), with cameras from another random
    stream (``seed=(config.seed, 1, t)``), ``config.test_views`` per centre frame, every
    ``config.test_stride`` frames. The renderers' validation motion (``validation``) has a
    stream of its own (``seed=(config.seed, 2, t)``), so it shares no camera with a test set.
    Needs the motion's target (``sim/MOTION-target``).
    """
    stream = VALIDATION_CAMERAS if validation else TEST_CAMERAS
    target_cache = project.path(f"sim/{motion_name}-target", "cache.npz")
    stage = f"testset/{motion_name}"
    params = {
        "index": INDEX_VERSION,
        "views": config.test_views,
        "stride": config.test_stride,
        "size": config.image_size,
        "seed": config.seed,
        "body": asdict(config.body),
        **({"cameras": stream} if validation else {}),
        **lighting_params(config),
    }

    def work(out: Path) -> list[str]:
        samples = render_samples(
            project, config, motion_name, out, seed=(config.seed, stream), views=config.test_views,
            stride=config.test_stride, desc=f"ground truth {motion_name}",
        )  # fmt: skip
        what = "validation samples from cameras of its own" if validation else "test samples"
        log(f"  {motion_name}: {len(samples)} {what} (unseen cameras)")
        return ["samples.json", *_sample_files(samples)]

    project.run_stage(
        stage, params, [target_cache, project.path("motions", f"{motion_name}.bvh")], work
    )
    return project.stage_dir(stage)


def _write_sample(out: Path, t: int, k: int, gts: list, write_png) -> None:
    name = sample_name(t, k)
    write_png(out / "samples" / f"{name}_image.png", np.concatenate([g.image for g in gts], 1))
    write_png(
        out / "samples" / f"{name}_background.png", np.concatenate([g.background for g in gts], 1)
    )
    mask = np.concatenate([np.round(g.coverage * 255).astype(np.uint8) for g in gts], 1)
    write_png(out / "samples" / f"{name}_mask.png", mask)
