"""The garment project's stages, from a detailed garment to Joint2Coarse, over one folder.

Each stage is a function of a :class:`core.project.Project` and a :class:`PipelineConfig`; it
writes its outputs into its own folder of the project with the parameters that made them and
is skipped when neither its parameters nor its input files changed. ``dng demo``, the other
CLI commands and the GUI all call these functions.

Stages and their folders::

    motions/    NAME.bvh for the training motion and every test motion (on the mannequin)
    garment/    target.obj, the detailed garment
    proxy/      proxy.obj (with UVs), positions.obj (seam-free), seams.npz, report.json
    sim/NAME-proxy/, sim/NAME-target/    cache.npz + report.json per simulated clip
    dataset/    samples.json (frame, camera per sample), samples/*.png strips of frames
                t-1, t, t+1: ground truth, body-only background, garment mask
    joint2coarse/    the trained model, its loss log, pred-MOTION.npz for the training and
                     every test motion, report.json
    renderer/   renderer.pt (the neural renderer), renderer_loss.csv, loss.png, previews/,
                report.json
    testset/NAME/    ground truth of each test motion from unseen cameras (dataset layout)
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from core.body.shape import BodyShape
from core.errors import InputError
from core.fileio import write_json, write_npz
from core.project import Project

#: Real motion capture used as an unseen test motion when Debian's assimp-testmodels is there.
CMU_CLIP = Path("/usr/share/assimp/models/BVH/01_01.bvh")


@dataclass(frozen=True)
class MotionSpec:
    """One motion of the project: procedural (``kind`` from PROCEDURAL_KINDS) or a BVH file."""

    name: str
    """File stem under ``motions/`` and the name in reports."""
    kind: str
    """A procedural kind (dance, twirl, walk, ...) or ``file`` for ``path``."""
    frames: int
    """Frames to keep (at the project's fps)."""
    seed: int = 0
    """Seed of a procedural motion."""
    path: str | None = None
    """The BVH file when ``kind == "file"`` (any rig; it is retargeted onto the mannequin)."""
    start_s: float = 0.0
    """Seconds to skip at the start of a file (motion capture often starts in a T-pose)."""
    speed: float = 1.0
    """Played this many times faster (``core.motion.variation.vary_motion``) ..."""
    amplitude: float = 1.0
    """... with its joint rotation angles scaled by this ..."""
    heading_deg: float = 0.0
    """... turned by this many degrees about the vertical ..."""
    turn_deg_s: float = 0.0
    """... and turning at this many degrees per second (a spin): a training-library variation."""


@dataclass(frozen=True)
class PipelineConfig:
    """Everything that decides a project's outputs. Presets: :data:`PRESETS`."""

    garment: str = "multilayer-skirt"
    """A built-in garment name (``dng garment list``) or the path of a mesh file."""
    garment_resolution_mm: float | None = None
    """Resolution of a built-in garment (its default when None)."""
    body: BodyShape = field(default_factory=BodyShape)
    """The mannequin's shape."""
    fps: float = 30.0
    """Frame rate of every motion and cache."""
    train_motion: MotionSpec = MotionSpec("dance", "dance", 300, seed=0)
    """The training motion (the paper: 850 frames of dance)."""
    test_motions: tuple[MotionSpec, ...] = (
        MotionSpec("twirl", "twirl", 150, seed=1),
        MotionSpec("cmu-01_01", "file", 150, path=str(CMU_CLIP), start_s=2.0),
    )
    """Unseen motions for evaluation; a file that is not on this machine is skipped."""
    proxy_verts: int = 1000
    """Target vertex count of the derived proxy."""
    proxy_texture: int = 512
    """Texture size the proxy's UV atlas is packed for."""
    fabric: str = "cotton"
    """Fabric preset of the simulation (``core.sim.config``)."""
    sim_substeps: int = 8
    """Simulation substeps per frame at 30 fps ..."""
    sim_iterations: int = 16
    """... and solver iterations per substep: 8 x 16 is ``core.sim.config.QUALITY``
    ``medium``, about the old 2 x 16's cost since each linear solve is one launch (``final``,
    16 x 32, is the trustworthy one: a twirl flares; about 4x the cost). See ``dng bench sim``."""
    simulate_target: bool = True
    """Make the detailed target's motion too (needed for ground-truth images)."""
    target_mode: str = "embed"
    """How the detailed target moves: ``simulate`` it as cloth on the body (the paper's ground
    truth; minutes per clip on CPU, and stacked layers millimetres apart need small steps), or
    ``embed`` it in the simulated proxy (``core.sim.embed``: the target follows the proxy's
    dynamics exactly, its details keep their offsets, no secondary motion of their own)."""
    views_per_frame: int = 5
    """Cameras per training frame (the paper: 10); each gives one sample of frames t-1, t, t+1."""
    frame_stride: int = 2
    """Every this many frames of the training motion is the centre of samples."""
    image_size: int = 128
    """Training image width and height in pixels (the paper: 512)."""
    test_views: int = 2
    """Unseen cameras per evaluated frame of each test motion (``testset/``)."""
    test_stride: int = 5
    """Every this many frames of a test motion is the centre of an evaluation sample."""
    renderer_preset: str = "cpu"
    """Neural renderer preset (``training.renderer.PRESETS``: tiny, cpu, paper) ..."""
    renderer_steps: int | None = None
    """... with its step count overridden when given (baselines train as many steps)."""
    renderer_overrides: dict = field(default_factory=dict)
    """Renderer configuration fields changed from the preset, e.g. ``{"w_gan": 0.0}``
    (``dng train renderer --set w_gan=0``). DNR with our loss (``dnr-gan``) takes the same
    loss weights; the other baselines keep theirs."""
    renderer_source: str = "sim"
    """The proxy the renderer trains on: ``sim`` (simulated, the paper) or ``joint2coarse``
    (predicted, so it learns to hide Joint2Coarse's errors). Test time always uses
    Joint2Coarse's prediction."""
    baselines: tuple[str, ...] = ("pix2pix", "dnr", "dnr-gan")
    """Baselines trained on the same data set for the comparison (``training.baselines.KINDS``);
    each trains ``renderer_steps`` steps, like ours."""
    baseline_overrides: dict = field(default_factory=dict)
    """Baseline configuration fields changed from their presets, for every baseline, e.g.
    ``{"lr_decay_from": 0.5}`` (``dng train baselines --set lr_decay_from=0.5``)."""
    ablations: tuple[str, ...] = ()
    """Renderer ablations trained and scored beside ours (:data:`ABLATION_KINDS`):
    ``no-motion``, ``views-N``, ``template-NAME``. Each costs about one renderer training."""
    proxy_template: str | None = None
    """A built-in coarse template (``dng garment list``) fitted to the target instead of a
    derived proxy (the ``template-NAME`` ablation sets it)."""
    inception_path: str = ""
    """InceptionV3 weights (torchvision layout) for FID; empty: FID is reported unavailable."""
    joint2coarse_extra: tuple[MotionSpec, ...] = ()
    """More training motions for Joint2Coarse only (their proxies are simulated; the renderer
    still trains on ``train_motion``'s data set). Names must differ from the test motions."""
    joint2coarse_validation: tuple[MotionSpec, ...] = ()
    """Joint2Coarse's validation motions: simulated, never trained on. Every Joint2Coarse choice
    (model, sizes, ``ridge``, ``skin_fade``, which motions train) is made on their figures; the
    test motions are only reported. The three splits: train (``train_motion`` and
    ``joint2coarse_extra``), validation (these), test (``test_motions``)."""
    joint2coarse_compare: tuple[str, ...] = ()
    """Other Joint2Coarse models (``training.joint2coarse.config.MODELS``: ``paper``, ``ours``)
    trained on the same splits beside the project's own and reported next to it (``compare``
    in the report); the project's own model (``--set model=...``) is skipped here."""
    joint2coarse_preset: str = "fast"
    """Joint2Coarse preset name (``training.joint2coarse.PRESETS``) ..."""
    joint2coarse_steps: tuple[int, int, int] | None = None
    """... with (autoencoder, motion, finetune) step counts overridden when given ..."""
    joint2coarse_overrides: dict = field(default_factory=dict)
    """... and any other fields changed from the preset, e.g. ``{"dropout": 0.2}``
    (``dng train joint2coarse --set dropout=0.2``)."""
    seed: int = 0
    """Seed of everything random in training."""
    torch_threads: int = 1
    """CPU threads torch uses for training and inference. One is the robust choice on a small
    machine: when anything else runs beside it, more threads spin against each other (measured
    here: 1.1 s per Joint2Coarse step with 2 threads beside other work, against milliseconds)."""

    def as_params(self) -> dict:
        return asdict(self)

    @classmethod
    def from_params(cls, data: dict, path=None) -> PipelineConfig:
        """Inverse of :meth:`as_params` (what ``project.json`` stores); InputError if malformed."""
        try:
            data = dict(data)
            data["body"] = BodyShape(**data.get("body", {}))
            data["train_motion"] = MotionSpec(**data["train_motion"])
            data["test_motions"] = tuple(MotionSpec(**m) for m in data.get("test_motions", ()))
            for key in ("joint2coarse_extra", "joint2coarse_validation"):
                data[key] = tuple(MotionSpec(**m) for m in data.get(key, ()))
            for key in ("baselines", "ablations", "joint2coarse_compare"):
                if key in data:
                    data[key] = tuple(data[key])
            if data.get("joint2coarse_steps") is not None:
                data["joint2coarse_steps"] = tuple(data["joint2coarse_steps"])
            return cls(**data)
        except (KeyError, TypeError) as exc:
            raise InputError(f"malformed pipeline settings ({exc})", path) from None


def project_config(project: Project) -> PipelineConfig:
    """The pipeline settings saved in a project (``dng demo`` writes them)."""
    settings = project.settings()
    if "pipeline" not in settings:
        raise InputError(
            "not a garment project (no pipeline settings): create one with dng demo",
            project.root / "project.json",
        )
    return PipelineConfig.from_params(settings["pipeline"], project.root / "project.json")


#: Real capture beside CMU 01_01 in Debian's assimp-testmodels: a walk-and-turn and a boxer.
CMU_0103_CLIP = CMU_CLIP.with_name("01_03.bvh")
BOXING_CLIP = CMU_CLIP.with_name("Boxing_Toes.bvh")
#: Joint2Coarse's training library beyond the quick preset's four clips: the procedural kinds
#: varied in seed, speed, amplitude and heading (never the twirl: a test kind), and windows of
#: real capture (never CMU 01_01: a test clip). 850 frames in 6 clips: a simulated proxy clip
#: costs about 7.6 s (lead-in, set-up) plus 57 ms a frame on 2 cores (the quick preset's
#: circle-walk, 300 frames, 24.8 s; twirl, 150 frames, 16.2 s), about 1.6 min in all. Chosen
#: on the validation motions: an idle spun at 300 degrees a second (``turn_deg_s``) in place of
#: ``walk-fast`` gave 53.7 / 112 mm (mean / p95, ours) against 52.7 / 110, both 53.6 / 111.
LIBRARY_TRAIN: tuple[MotionSpec, ...] = (
    MotionSpec("dance-varied", "dance", 150, seed=6, speed=1.3, amplitude=1.2, heading_deg=90.0),
    MotionSpec("walk-fast", "walk", 100, seed=8, speed=1.6, heading_deg=-45.0),
    *(
        MotionSpec(f"cmu-01_03-{s:02.0f}", "file", 150, path=str(CMU_0103_CLIP), start_s=s)
        for s in (3.0, 18.0)
    ),
    *(
        MotionSpec(f"boxing-{s:02.0f}", "file", 150, path=str(BOXING_CLIP), start_s=s)
        for s in (2.0, 17.0)
    ),
)
#: Joint2Coarse's validation motions, what every choice is made on: 300 frames, about 0.7 min.
LIBRARY_VALIDATION: tuple[MotionSpec, ...] = (
    MotionSpec(
        "val-dance-spin",
        "dance",
        100,
        seed=20,
        speed=0.85,
        amplitude=1.15,
        heading_deg=-60.0,
        turn_deg_s=-240.0,
    ),
    MotionSpec("val-cmu-01_03", "file", 100, path=str(CMU_0103_CLIP), start_s=33.0),
    MotionSpec("val-boxing", "file", 100, path=str(BOXING_CLIP), start_s=10.0),
)

PRESETS: dict[str, PipelineConfig] = {
    # The tests run this: every stage end to end in well under three minutes on 2 cores.
    "smoke": PipelineConfig(
        garment_resolution_mm=25.0,
        train_motion=MotionSpec("dance", "dance", 40, seed=0),
        test_motions=(
            MotionSpec("twirl", "twirl", 20, seed=1),
            MotionSpec("cmu-01_01", "file", 20, path=str(CMU_CLIP), start_s=2.0),
        ),
        proxy_verts=300,
        proxy_texture=256,
        sim_substeps=1,
        views_per_frame=2,
        frame_stride=6,
        image_size=64,
        test_views=1,
        test_stride=6,
        renderer_preset="tiny",
        renderer_steps=30,
        joint2coarse_extra=(MotionSpec("circle-walk", "circle-walk", 30, seed=2),),
        joint2coarse_validation=(MotionSpec("val-walk", "walk", 36, seed=4, speed=1.3),),
        joint2coarse_compare=("paper", "ours"),
        joint2coarse_steps=(300, 300, 100),
    ),
    # The default: minutes on 2 cores, results that look like the garment.
    # Renderer: 600 steps. Measured on this project at a constant rate, the training L1 of the
    # cpu preset is flat from there (0.0109 at 500, 0.0103 at 700, 0.0105 at 1000), and the
    # baselines train as long. The cpu preset now decays its rates over the second half.
    # Joint2Coarse also trains on a walk, a circle walk and a jump: measured on this preset,
    # unseen-motion error fell from 142 to 121 mm (twirl) and 148 to 68 mm (CMU 01_01).
    # The adversarial terms weigh a fifth of the paper's (FM 1, GAN 0.1; its L1 10): with no VGG
    # weights here the perceptual half of the reconstruction loss is off, and at 600 steps the
    # full weights cost pixel error. Measured at constant rates on this preset's data set,
    # simulated proxy, MSE twirl / CMU: 0.0023 / 0.0034 at FM 5, GAN 0.5; 0.0019 / 0.0027 at
    # FM 1, GAN 0.1; 0.0017 / 0.0025 with L1 alone (dng train renderer PROJECT --set w_fm=1
    # --set w_gan=0.1, dng eval).
    "quick": PipelineConfig(
        renderer_steps=600,
        renderer_overrides={"w_fm": 1.0, "w_gan": 0.1},
        joint2coarse_extra=(
            MotionSpec("walk", "walk", 300, seed=3),
            MotionSpec("circle-walk", "circle-walk", 300, seed=4),
            MotionSpec("jump", "jump", 150, seed=5),
            *LIBRARY_TRAIN,
        ),
        joint2coarse_validation=LIBRARY_VALIDATION,
        # The paper's autoencoder drives the project, ours beside it on the same splits (report:
        # compare), chosen by validation on a fresh project (dng demo --out /tmp/q14): on the
        # validation motions the paper's averaged 55.4 / 120 mm (mean / p95), ours 66.1 / 136.
        # (A scratch project whose clips were simulated by several code versions had given
        # ours 52.7 / 110 against 64.4 / 176; the fresh project is the one that counts.)
        joint2coarse_compare=("paper", "ours"),
    ),
    # The paper's sizes, for a GPU machine.
    "paper": PipelineConfig(
        train_motion=MotionSpec("dance", "dance", 850, seed=0),
        test_motions=(
            MotionSpec("twirl", "twirl", 300, seed=1),
            MotionSpec("walk", "walk", 300, seed=2),
            MotionSpec("cmu-01_01", "file", 300, path=str(CMU_CLIP), start_s=2.0),
        ),
        proxy_verts=2000,
        sim_substeps=16,
        sim_iterations=32,
        target_mode="simulate",
        views_per_frame=10,
        frame_stride=1,
        image_size=512,
        renderer_preset="paper",
        ablations=("no-motion", "views-5", "template-long-skirt"),
        joint2coarse_preset="paper",
    ),
}


def preset(name: str) -> PipelineConfig:
    if name not in PRESETS:
        raise InputError(f"unknown preset {name!r}; choose from {', '.join(PRESETS)}")
    return PRESETS[name]


Log = Callable[[str], None]


def _quiet(_: str) -> None:
    pass


# ---------------------------------------------------------------------------------- stages


def available_test_motions(config: PipelineConfig) -> tuple[MotionSpec, ...]:
    """The test motions whose files exist on this machine."""
    return tuple(m for m in config.test_motions if m.kind != "file" or Path(m.path).is_file())


def on_this_machine(specs: tuple[MotionSpec, ...]) -> tuple[MotionSpec, ...]:
    """The motions whose files exist on this machine (procedural ones always do)."""
    return tuple(m for m in specs if m.kind != "file" or Path(m.path).is_file())


def available_extra_motions(config: PipelineConfig) -> tuple[MotionSpec, ...]:
    """Joint2Coarse's extra training motions whose files exist on this machine."""
    return on_this_machine(config.joint2coarse_extra)


def available_validation_motions(config: PipelineConfig) -> tuple[MotionSpec, ...]:
    """Joint2Coarse's validation motions whose files exist on this machine."""
    return on_this_machine(config.joint2coarse_validation)


def joint2coarse_splits(config: PipelineConfig) -> dict[str, list[str]]:
    """Names of Joint2Coarse's train, validation and test motions (those on this machine)."""
    return {
        "train": [config.train_motion.name, *(m.name for m in available_extra_motions(config))],
        "validation": [m.name for m in available_validation_motions(config)],
        "test": [m.name for m in available_test_motions(config)],
    }


def stage_motions(project: Project, config: PipelineConfig, log: Log = _quiet) -> list[str]:
    """Write every motion of the project as a BVH on the mannequin: ``motions/NAME.bvh``."""
    from core.motion.bvh import write_bvh

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
            motion = _make_motion(spec, config)
            write_bvh(out / f"{spec.name}.bvh", motion)
            names.append(f"{spec.name}.bvh")
            log(f"  {spec.name}: {motion.num_frames} frames at {motion.fps:g} fps")
        return names

    project.run_stage("motions", params, inputs, work)
    return [s.name for s in specs]


def _make_motion(spec: MotionSpec, config: PipelineConfig):
    from core.motion.load import load_motion, resample
    from core.motion.mapping import canonical_positions
    from core.motion.procedural import make_motion
    from core.motion.retarget import retarget
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


def stage_garment(project: Project, config: PipelineConfig, log: Log = _quiet) -> Path:
    """The detailed target garment: ``garment/target.obj``."""
    from core.mesh import load_mesh, save_mesh

    builtin = not Path(config.garment).suffix
    params = {
        "garment": config.garment,
        "resolution_mm": config.garment_resolution_mm,
        "body": asdict(config.body),
    }

    def work(out: Path) -> list[str]:
        if builtin:
            from templates.garments import make_garment

            mesh = make_garment(
                config.garment, config.garment_resolution_mm, config.body, config.seed
            )
        else:
            mesh, _ = load_mesh(config.garment)
        save_mesh(out / "target.obj", mesh)
        log(f"  {config.garment}: {mesh.num_vertices} vertices, {mesh.num_faces} faces")
        return ["target.obj"]

    project.run_stage("garment", params, [] if builtin else [config.garment], work)
    return project.path("garment", "target.obj")


def stage_proxy(project: Project, config: PipelineConfig, log: Log = _quiet) -> dict:
    """The coarse proxy of the target: UV'd ``proxy.obj``, seam-free ``positions.obj``."""
    from core.mesh import load_mesh, save_mesh
    from core.proxy import ProxyConfig, derive_proxy

    target = project.path("garment", "target.obj")
    cfg = ProxyConfig(target_verts=config.proxy_verts, texture_size=config.proxy_texture)
    params: dict = {"proxy": asdict(cfg)}
    if config.proxy_template:
        params["template"] = config.proxy_template

    def work(out: Path) -> list[str]:
        mesh, _ = load_mesh(target)
        template = None
        if config.proxy_template:
            from templates.garments import make_garment

            template = make_garment(config.proxy_template, shape=config.body)
        result = derive_proxy(mesh, cfg, path=target, template=template)
        save_mesh(out / "proxy.obj", result.proxy)
        save_mesh(out / "positions.obj", result.positions)
        write_npz(out / "seams.npz", seam_map=result.seam_map)
        write_json(out / "report.json", result.report)
        log(
            f"  proxy: {result.positions.num_vertices} vertices "
            f"({result.proxy.num_vertices} with UV seams)"
        )
        return ["proxy.obj", "positions.obj", "seams.npz", "report.json"]

    project.run_stage("proxy", params, [target], work)
    import json

    return json.loads(project.path("proxy", "report.json").read_text())


def stage_simulate(
    project: Project,
    config: PipelineConfig,
    motion_name: str,
    which: str,
    log: Log = _quiet,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Simulate the proxy (``which="proxy"``) or the target under a motion of the project.

    The target is simulated, or embedded in the proxy's simulation of the same motion, as
    ``config.target_mode`` says. Writes ``sim/MOTION-WHICH/cache.npz`` and ``report.json``;
    returns the cache's path.
    """
    from core.mesh import load_mesh
    from core.sim import save_cache
    from core.sim.simulate import simulate

    if which not in ("proxy", "target"):
        raise InputError(f"which must be 'proxy' or 'target', got {which!r}")
    if config.target_mode not in ("simulate", "embed"):
        raise InputError(f"target_mode must be 'simulate' or 'embed', got {config.target_mode!r}")
    if which == "target" and config.target_mode == "embed":
        return _embed_target(project, config, motion_name, log)
    garment = (
        project.path("proxy", "positions.obj")
        if which == "proxy"
        else project.path("garment", "target.obj")
    )
    motion_file = project.path("motions", f"{motion_name}.bvh")
    sim_cfg = sim_config(config)
    params = {"sim": asdict(sim_cfg), "body": asdict(config.body), "which": which}
    stage = f"sim/{motion_name}-{which}"

    def work(out: Path) -> list[str]:
        mesh, _ = load_mesh(garment)
        motion = load_project_motion(project, motion_name)
        cache, report = simulate(
            mesh, motion, config.body, sim_cfg, path=garment, progress=progress
        )
        save_cache(out / "cache.npz", cache)
        write_json(out / "report.json", asdict(report))
        log(
            f"  {motion_name}/{which}: {cache.num_frames} frames x {cache.num_vertices} vertices, "
            f"{report.ms_per_frame:.0f} ms/frame, penetration {report.penetration_mean_mm:.2f} mm"
        )
        return ["cache.npz", "report.json"]

    project.run_stage(stage, params, [garment, motion_file], work)
    return project.path(stage, "cache.npz")


def sim_config(config: PipelineConfig):
    """The simulation settings of a project (fabric, substeps): every proxy simulation of the
    project, and ``dng eval joint2coarse``'s, runs with these."""
    from core.sim import SimConfig

    return SimConfig(
        fabric=config.fabric, substeps=config.sim_substeps, iterations=config.sim_iterations
    )


def _embed_target(project: Project, config: PipelineConfig, motion_name: str, log: Log) -> Path:
    """The target driven by the proxy's simulation (``target_mode="embed"``), measured like a
    simulation: edge stretch and compression against the rest garment, tears, penetration into
    the body colliders; ``sheet.png`` shows the proxy and the target on the body."""
    from core.body.shape import mannequin_skeleton
    from core.mesh import load_mesh
    from core.sim import SimCache, load_cache, save_cache
    from core.sim.colliders import body_capsules, pose_capsules
    from core.sim.embed import FRAME_SMOOTHING_M, SMOOTHING_M, drive, embed, strain_stats
    from core.sim.simulate import penetration_depths
    from core.skeleton import forward_kinematics, skinning_transforms

    target_file = project.path("garment", "target.obj")
    proxy_file = project.path("proxy", "positions.obj")
    proxy_cache = project.path(f"sim/{motion_name}-proxy", "cache.npz")
    stage = f"sim/{motion_name}-target"
    params = {
        "mode": "embed",
        "method": "smoothed-binding-deformation",
        "smoothing_m": SMOOTHING_M,
        "frame_smoothing_m": FRAME_SMOOTHING_M,
        "body": asdict(config.body),
    }

    def work(out: Path) -> list[str]:
        target, _ = load_mesh(target_file)
        proxy, _ = load_mesh(proxy_file)
        cache = load_cache(proxy_cache)
        start = time.perf_counter()
        embedding = embed(target.vertices, proxy.vertices, proxy.faces, target_faces=target.faces)
        positions = drive(embedding, cache.positions)
        seconds = time.perf_counter() - start
        strain = strain_stats(positions, target.vertices, target.faces)
        motion = load_project_motion(project, motion_name)
        skeleton = mannequin_skeleton(config.body)
        pos, rot = forward_kinematics(skeleton, motion.rotations, motion.root_positions)
        capsules = body_capsules(skeleton, config.body)
        ends = pose_capsules(capsules, skinning_transforms(skeleton, pos, rot))
        depth = penetration_depths(positions, ends, capsules.radii)
        params_out = {**cache.params, "target_mode": "embed", "proxy_cache": str(proxy_cache)}
        save_cache(out / "cache.npz", SimCache(positions, target.faces, cache.fps, params_out))
        rows = [("proxy", cache.positions, cache.faces), ("target", positions, target.faces)]
        _garment_sheet(out / "sheet.png", rows, config.body, motion)
        report = {
            "mode": "embed",
            "frames": int(len(positions)),
            "vertices": int(target.num_vertices),
            "ms_per_frame": 1e3 * seconds / len(positions),
            "strain_max": strain.stretch_max,
            "strain_p99": strain.stretch_p99,
            "compression_max": strain.compression_max,
            "compression_p99": strain.compression_p99,
            "torn_edges": strain.torn_edges,
            "penetration_mean_mm": float(depth.mean() * 1e3),
            "penetration_max_mm": float(depth.max() * 1e3),
            "penetrating_fraction": float((depth > 0).mean()),
            "finite": bool(np.isfinite(positions).all()),
            "sheet": "sheet.png",
        }
        write_json(out / "report.json", report)
        log(
            f"  {motion_name}/target (embedded in the proxy): {report['frames']} frames x "
            f"{report['vertices']} vertices, {report['ms_per_frame']:.1f} ms/frame, stretch max "
            f"{strain.stretch_max:.3f} p99 {strain.stretch_p99:.3f}, "
            f"penetration {report['penetration_mean_mm']:.2f} mm"
        )
        return ["cache.npz", "report.json", "sheet.png"]

    project.run_stage(stage, params, [target_file, proxy_file, proxy_cache], work)
    return project.path(stage, "cache.npz")


def _garment_sheet(path: Path, rows, shape, motion, frames: int = 5) -> None:
    """A contact sheet: one row per garment ``rows`` [(label, positions (T, V, 3), faces
    (F, 3))] on the posed mannequin, at ``frames`` frames spread over the clip (front view)."""
    from core.body.mannequin import make_body
    from core.body.skinning import pose_body
    from core.camera import make_camera
    from core.mesh import Mesh
    from core.shading import contact_sheet, render_views, write_png

    body = make_body(shape)
    picked = np.linspace(0, len(rows[0][1]) - 1, frames).round().astype(int)
    posed = pose_body(body, motion)
    tiles, labels = [], []
    for label, positions, faces in rows:
        for f in picked:
            centre = motion.root_positions[f].astype(np.float64)
            eye = centre + np.array([0.0, 0.1, 2.6])
            cam = make_camera(eye, centre + np.array([0.0, -0.2, 0.0]), width=192, height=192)
            garment = Mesh(np.asarray(positions[f], np.float32), np.asarray(faces, np.int64))
            (view,) = render_views(garment, Mesh(posed[f], body.faces), [cam])
            tiles.append(view.image)
            labels.append(f"{label} f{f}")
    write_png(path, contact_sheet(tiles, labels, columns=len(picked)))


def joint2coarse_config(config: PipelineConfig):
    from training.joint2coarse import PRESETS as J2C_PRESETS

    if config.joint2coarse_preset not in J2C_PRESETS:
        raise InputError(
            f"unknown joint2coarse preset {config.joint2coarse_preset!r}; "
            f"choose from {', '.join(J2C_PRESETS)}"
        )
    cfg = replace(J2C_PRESETS[config.joint2coarse_preset], seed=config.seed)
    if config.joint2coarse_steps is not None:
        a, m, f = config.joint2coarse_steps
        cfg = replace(cfg, autoencoder_steps=a, motion_steps=m, finetune_steps=f)
    if config.joint2coarse_overrides:
        cfg = type(cfg).from_dict({**cfg.to_dict(), **config.joint2coarse_overrides})
    return cfg


def stage_joint2coarse(
    project: Project, config: PipelineConfig, log: Log = _quiet, progress: bool = True
) -> dict:
    """Train Joint2Coarse on its training split's proxy simulations; evaluate on the validation
    and test motions.

    Writes the model and loss log (``training.joint2coarse``), ``pred-MOTION.npz`` for the
    training motion and every validation and test motion, and ``report.json`` with the splits,
    per-vertex errors against simulation (mean and 95th percentile in mm) per validation and
    test motion, body penetration of the predictions and of the simulation, and inference time
    per frame.
    """
    import torch

    from core.mesh import load_mesh
    from core.sim import load_cache
    from training.joint2coarse import (
        Joint2CoarseClip,
        joint2coarse_inputs,
        predict_proxy,
        train_joint2coarse,
    )
    from training.joint2coarse.body_model import body_rig

    torch.set_num_threads(config.torch_threads)
    cfg = joint2coarse_config(config)
    splits = joint2coarse_splits(config)
    train, extra = splits["train"][0], splits["train"][1:]
    vals, tests = splits["validation"], splits["test"]
    names = [train, *extra, *vals, *tests]
    if len(set(names)) != len(names):
        raise InputError(f"Joint2Coarse's train, validation and test motions {names} must differ")
    caches = {n: project.path(f"sim/{n}-proxy", "cache.npz") for n in names}
    motions = [project.path("motions", f"{n}.bvh") for n in names]
    proxy_file = project.path("proxy", "positions.obj")
    params = {"joint2coarse": cfg.to_dict(), "train": train, "tests": tests}
    if config.joint2coarse_compare:
        params["compare"] = list(config.joint2coarse_compare)
    if extra:
        params["extra"] = extra
    if vals:
        params["validation"] = vals
    inputs = [*caches.values(), *motions]
    if cfg.model == "ours":
        inputs.append(proxy_file)

    def work(out: Path) -> list[str]:
        clips = []
        for name in (train, *extra):
            joints, root_rot = joint2coarse_inputs(load_project_motion(project, name))
            positions = load_cache(caches[name]).positions
            clips.append(Joint2CoarseClip(joints, root_rot, positions, name=name))
        joints, root_rot = clips[0].joints, clips[0].root_rotations
        rig = None
        if cfg.model == "ours":
            rig = body_rig(config.body, load_mesh(proxy_file)[0].vertices, cfg.skin_fade)
        result = train_joint2coarse(clips, out, cfg, progress=progress, rig=rig)
        report = {
            "config": cfg.to_dict(),
            "model": cfg.model,
            "splits": splits,
            "train_motion": train,
            "extra_train_motions": extra,
            "validation_error_mm": {k: asdict(v) for k, v in result.stage_errors.items()},
            "validation_mean_shape_baseline_mm": asdict(result.baseline)
            if result.baseline
            else None,
            "validation_motions": {},
            "motions": {},
            "compare": {},
        }
        outputs = [result.model_path.name, result.log_path.name]
        # The training motion's prediction: the proxy the renderer sees at test time.
        write_npz(out / f"pred-{train}.npz", positions=predict_proxy(result.net, joints, root_rot))
        outputs.append(f"pred-{train}.npz")
        for split, key in ((vals, "validation_motions"), (tests, "motions")):
            for name in split:
                report[key][name] = _evaluate_joint2coarse(
                    project, config, result.net, name, load_cache(caches[name]), out,
                    picture=key == "motions",
                )  # fmt: skip
                outputs.append(f"pred-{name}.npz")
                if key == "motions":
                    outputs.append(f"compare-{name}.png")
                e = report[key][name]["error_mm"]
                log(
                    f"  {name}: mean {e['mean_mm']:.1f} mm, p95 {e['p95_mm']:.1f} mm "
                    f"({'validation' if key != 'motions' else 'test'} motion)"
                )
        for other in config.joint2coarse_compare:
            if other == cfg.model:
                continue
            log(f"  the {other} model beside it, trained on the same splits")
            other_cfg = replace(cfg, model=other)
            other_rig = rig
            if other == "ours" and rig is None:
                rest = load_mesh(proxy_file)[0].vertices
                other_rig = body_rig(config.body, rest, other_cfg.skin_fade)
            folder = out / f"compare-{other}"
            trained = train_joint2coarse(clips, folder, other_cfg, progress=progress, rig=other_rig)
            report["compare"][other] = _compare_errors(project, trained.net, caches, vals, tests)
            outputs.append(f"compare-{other}/{trained.model_path.name}")
        write_json(out / "report.json", report)
        return [*outputs, "report.json"]

    if "ours" in config.joint2coarse_compare and proxy_file not in inputs:
        inputs.append(proxy_file)
    resumable = ["joint2coarse_train.pt"]
    resumable += [f"compare-{m}/joint2coarse_train.pt" for m in config.joint2coarse_compare]
    project.run_stage("joint2coarse", params, inputs, work, resumable=resumable)
    import json

    return json.loads(project.path("joint2coarse", "report.json").read_text())


def _compare_errors(project: Project, net, caches: dict, vals: list, tests: list) -> dict:
    """A comparison model's vertex errors (mm) on the validation and test motions."""
    from core.sim import load_cache
    from training.joint2coarse import joint2coarse_inputs, predict_proxy, vertex_errors

    out: dict[str, dict] = {"validation_motions": {}, "motions": {}}
    for split, key in ((vals, "validation_motions"), (tests, "motions")):
        for name in split:
            joints, root_rot = joint2coarse_inputs(load_project_motion(project, name))
            pred = predict_proxy(net, joints, root_rot)
            error = vertex_errors(pred, load_cache(caches[name]).positions)
            out[key][name] = {"error_mm": asdict(error)}
    return out


def _evaluate_joint2coarse(
    project, config, net, name, reference, out: Path, picture: bool = True
) -> dict:
    """Predict a test motion; compare with its simulation, with and without the push-out
    against the body (the capsules the simulation collides with); time the inference; write a
    side-by-side picture. Penetration is reported for the prediction and the simulation alike."""
    from core.body.mannequin import make_body
    from core.mesh import load_mesh
    from training.joint2coarse import (
        Joint2CoarseStream,
        joint2coarse_inputs,
        predict_proxy,
        reconstruct_proxy,
        vertex_errors,
    )
    from training.joint2coarse.collision import penetration_summary, simulation_colliders

    motion = load_project_motion(project, name)
    joints, root_rot = joint2coarse_inputs(motion)
    start = time.perf_counter()
    pred = predict_proxy(net, joints, root_rot)
    ms = 1e3 * (time.perf_counter() - start) / len(pred)
    stream = Joint2CoarseStream(net)  # one frame at a time, as the GUI plays a motion
    frame_ms = []
    for t in range(len(joints)):
        start = time.perf_counter()
        stream.push(joints[t], root_rot[t])
        frame_ms.append(1e3 * (time.perf_counter() - start))
    body = make_body(config.body)
    top = float(load_mesh(project.path("proxy", "positions.obj"))[0].vertices[:, 1].max())
    capsules, radii = simulation_colliders(
        config.body, motion, top, sim_config(config).arm_colliders
    )
    pushed = predict_proxy(net, joints, root_rot, capsules=capsules, radii=radii)
    write_npz(out / f"pred-{name}.npz", positions=pred)

    def measured(positions: np.ndarray) -> dict:
        pen = penetration_summary(positions, capsules, radii)
        return {
            "error_mm": asdict(vertex_errors(positions, reference.positions)),
            "penetration_mm": {
                "mean": pen["mean_mm"],
                "max": pen["max_mm"],
                "fraction": pen["inside_percent"] / 100.0,
            },
        }

    if picture:
        _side_by_side(out / f"compare-{name}.png", reference, pred, body, motion)
    extra = {}
    if hasattr(net, "shape_encoder"):  # the paper's model
        # What the decoder reaches from the shapes themselves, encoded (no motion involved).
        rebuilt = reconstruct_proxy(net, reference.positions, joints, root_rot)
        extra["autoencoder_error_mm"] = asdict(vertex_errors(rebuilt, reference.positions))
    return {
        "frames": int(len(pred)),
        **measured(pred),
        "with_push_out": measured(pushed),
        "simulation_penetration_mm": measured(reference.positions)["penetration_mm"],
        **extra,
        "batch_ms_per_frame": ms,
        "streaming_ms_per_frame": {
            "median": float(np.median(frame_ms)),
            "p95": float(np.percentile(frame_ms, 95)),
        },
    }


def _side_by_side(path: Path, reference, predicted: np.ndarray, body, motion) -> None:
    """Simulated proxy above, Joint2Coarse's prediction below, at five frames of the clip."""
    from core.body.skinning import pose_body
    from core.camera import make_camera
    from core.mesh import Mesh
    from core.shading import contact_sheet, render_views, write_png

    frames = np.linspace(0, len(predicted) - 1, 5).round().astype(int)
    posed = pose_body(body, motion)
    tiles, labels = [], []
    for label, cache in (("simulation", reference.positions), ("Joint2Coarse", predicted)):
        for f in frames:
            centre = motion.root_positions[f].astype(np.float64)
            eye = centre + np.array([0.0, 0.1, 2.6])
            cam = make_camera(eye, centre + np.array([0.0, -0.2, 0.0]), width=192, height=192)
            garment = Mesh(np.asarray(cache[f], np.float32), reference.faces)
            (gt,) = render_views(garment, Mesh(posed[f], body.faces), [cam])
            tiles.append(gt.image)
            labels.append(f"{label} f{f}")
    write_png(path, contact_sheet(tiles, labels, columns=len(frames)))


# ---------------------------------------------------------------------------------- renderer


def renderer_config(config: PipelineConfig):
    """The project's neural-renderer configuration: the preset at the project's image size."""
    from training.renderer.config import preset as renderer_preset

    cfg = renderer_preset(config.renderer_preset).replace(
        image_size=config.image_size, seed=config.seed
    )
    if config.renderer_steps is not None:
        cfg = cfg.replace(steps=config.renderer_steps)
    if config.renderer_overrides:
        cfg = type(cfg).from_dict({**cfg.to_dict(), **config.renderer_overrides})
    return cfg


def _proxy_source_file(project: Project, source: str, motion_name: str) -> Path:
    if source == "sim":
        return project.path(f"sim/{motion_name}-proxy", "cache.npz")
    if source == "joint2coarse":
        return project.path("joint2coarse", f"pred-{motion_name}.npz")
    raise InputError(f"renderer_source must be 'sim' or 'joint2coarse', got {source!r}")


def stage_renderer(
    project: Project,
    config: PipelineConfig,
    log: Log = _quiet,
    progress: bool = True,
    *,
    stage: str = "renderer",
    overrides: dict | None = None,
) -> dict:
    """Train the neural renderer on the project's data set: ``renderer/``.

    Writes ``renderer.pt`` (load with :func:`training.renderer.train.load_model`), the CSV loss
    log, ``loss.png`` (loss curves), ``previews/step_N.png`` (prediction | ground truth) and
    ``report.json`` (steps, seconds per step, first and last logged losses). A run killed half
    way resumes from its checkpoint. ``stage`` and ``overrides`` (RendererConfig fields) train a
    variant into another folder (the ablations).
    """
    import torch

    from training.dataset import GarmentDataset
    from training.renderer.train import train_renderer

    cfg = renderer_config(config).replace(**(overrides or {}))
    train = config.train_motion.name
    source_file = _proxy_source_file(project, config.renderer_source, train)
    index = project.path("dataset", "samples.json")
    params = {"renderer": cfg.to_dict(), "source": config.renderer_source}

    def work(out: Path) -> list[str]:
        torch.set_num_threads(config.torch_threads)
        data = GarmentDataset(project.root, source=config.renderer_source)
        start = time.perf_counter()
        result = train_renderer(data, out, cfg, progress=progress)
        seconds = time.perf_counter() - start
        rows = read_loss_log(result.log_path)
        plot_losses(rows, out / "loss.png", f"neural renderer ({config.renderer_preset}, {stage})")
        report = {
            "config": cfg.to_dict(),
            "source": config.renderer_source,
            "samples": len(data),
            "steps": result.steps,
            "resumed_at_step": result.resumed_at_step,
            "skipped_steps": result.skipped_steps,
            "perceptual": result.perceptual,
            "seconds": seconds,
            "seconds_per_step": seconds / max(result.steps - result.resumed_at_step, 1),
            "first": rows[0] if rows else None,
            "last": rows[-1] if rows else None,
        }
        write_json(out / "report.json", report)
        if rows:
            log(
                f"  {result.steps} steps, L1 {rows[0]['l1']:.4f} -> {rows[-1]['l1']:.4f}, "
                f"{report['seconds_per_step']:.2f} s/step"
            )
        previews = sorted(p.relative_to(out).as_posix() for p in (out / "previews").glob("*.png"))
        return [result.model_path.name, result.log_path.name, "loss.png", "report.json", *previews]

    project.run_stage(
        stage,
        params,
        [index, source_file, project.path("proxy", "proxy.obj")],
        work,
        resumable=["renderer_train.pt"],
    )
    import json

    return json.loads(project.path(stage, "report.json").read_text())


def read_loss_log(path: Path) -> list[dict]:
    """Rows of a CSV loss log as dicts of floats (``off`` and empty cells dropped)."""
    import csv

    rows = []
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            parsed = {}
            for k, v in row.items():
                try:
                    parsed[k] = float(v)
                except (TypeError, ValueError):
                    continue
            rows.append(parsed)
    return rows


def plot_losses(rows: list[dict], path: Path, title: str) -> None:
    """Loss curves (every logged column but bookkeeping) against step, as a PNG, atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from core.fileio import atomic_path

    skip = {"step", "epoch", "skipped", "seconds"}
    fig, ax = plt.subplots(figsize=(6, 3.5), dpi=100)
    if rows:
        steps = [r["step"] for r in rows]
        for key in rows[0]:
            if key in skip:
                continue
            ax.plot(steps, [r.get(key, np.nan) for r in rows], label=key)
        ax.set_yscale("symlog", linthresh=1e-2)
        ax.legend(fontsize=7, ncol=3)
    ax.set_xlabel("step")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def baseline_config(config: PipelineConfig, kind: str):
    """A baseline's configuration: the preset matching the renderer's, as many steps as ours."""
    from training.baselines import PRESETS as BASELINE_PRESETS

    if kind not in BASELINE_PRESETS:
        raise InputError(f"unknown baseline {kind!r}; choose from {sorted(BASELINE_PRESETS)}")
    names = BASELINE_PRESETS[kind]
    name = config.renderer_preset if config.renderer_preset in names else "cpu"
    ours = renderer_config(config)
    cfg = names[name].replace(image_size=config.image_size, seed=config.seed, steps=ours.steps)
    if kind == "dnr-gan":  # "DNR with our loss": the weights ours trains with, overrides included
        loss = ("w_l1", "w_perceptual", "w_fm", "w_gan")
        cfg = cfg.replace(**{k: getattr(ours, k) for k in loss})
    if config.baseline_overrides:
        cfg = type(cfg).from_dict({**cfg.to_dict(), **config.baseline_overrides})
    return cfg


def stage_baseline(
    project: Project, config: PipelineConfig, kind: str, log: Log = _quiet, progress: bool = True
) -> dict:
    """Train one baseline on the renderer's data set: ``baselines/KIND/`` (model, loss log,
    ``loss.png``, ``report.json``)."""
    import torch

    from training.baselines import train_baseline
    from training.dataset import GarmentDataset

    cfg = baseline_config(config, kind)
    source_file = _proxy_source_file(project, config.renderer_source, config.train_motion.name)
    stage = f"baselines/{kind}"
    params = {"kind": kind, "baseline": cfg.to_dict(), "source": config.renderer_source}

    def work(out: Path) -> list[str]:
        torch.set_num_threads(config.torch_threads)
        data = GarmentDataset(project.root, source=config.renderer_source)
        start = time.perf_counter()
        result = train_baseline(kind, data, out, cfg, progress=progress)
        seconds = time.perf_counter() - start
        rows = read_loss_log(result.log_path)
        plot_losses(rows, out / "loss.png", f"baseline {kind}")
        report = {
            "kind": kind,
            "config": cfg.to_dict(),
            "steps": result.steps,
            "skipped_steps": result.skipped_steps,
            "seconds": seconds,
            "seconds_per_step": seconds / max(result.steps - result.resumed_at_step, 1),
            "first": rows[0] if rows else None,
            "last": rows[-1] if rows else None,
        }
        write_json(out / "report.json", report)
        log(f"  {kind}: {result.steps} steps, {report['seconds_per_step']:.2f} s/step")
        return [result.model_path.name, result.log_path.name, "loss.png", "report.json"]

    inputs = [project.path("dataset", "samples.json"), source_file]
    project.run_stage(stage, params, inputs, work, resumable=[f"{kind}_train.pt"])
    import json

    return json.loads(project.path(stage, "report.json").read_text())


def stage_baselines(
    project: Project, config: PipelineConfig, log: Log = _quiet, progress: bool = True
) -> dict:
    """Every baseline of ``config.baselines`` (:func:`stage_baseline`), one after another."""
    return {kind: stage_baseline(project, config, kind, log, progress) for kind in config.baselines}


#: Ablations (``PipelineConfig.ablations``): ``no-motion`` (the renderer without motion
#: features), ``views-N`` (a training set with N cameras per frame instead of
#: ``views_per_frame``), ``template-NAME`` (a coarse template fitted to the target instead of the
#: derived proxy; NAME from ``dng garment list``).
ABLATION_KINDS = ("no-motion", "views-", "template-")


def check_ablation(name: str) -> None:
    ok = name == "no-motion"
    if name.startswith("views-"):
        ok = name[6:].isdigit() and int(name[6:]) > 0
    if name.startswith("template-"):
        ok = len(name) > 9
    if not ok:
        raise InputError(f"unknown ablation {name!r}: use no-motion, views-N or template-NAME")


def ablation_project(project: Project, name: str) -> Project:
    """The folder of an ablation that needs its own stages (``ablations/NAME``)."""
    return Project(project.root / "ablations" / name)


def _link(sub: Project, project: Project, names: list[str]) -> None:
    """Share the parent's finished stage folders with a sub-project (symbolic links)."""
    import os

    sub.root.mkdir(parents=True, exist_ok=True)
    for name in names:
        link = sub.root / name
        if link.is_symlink() or link.exists():
            continue
        os.symlink(os.path.relpath(project.root / name, sub.root), link)


def stage_ablation(
    project: Project, config: PipelineConfig, name: str, log: Log = _quiet, progress: bool = True
) -> dict:
    """Train one ablation of the renderer (see :data:`ABLATION_KINDS`); returns its report.

    ``no-motion`` trains into ``ablations/no-motion/`` from the project's data set. The others
    are sub-projects under ``ablations/NAME/`` that share the parent's finished folders by
    symbolic links and run only the stages that differ: ``views-N`` its own training set and
    renderer; ``template-NAME`` its own proxy (the template fitted to the target), proxy
    simulations, Joint2Coarse and renderer, on the parent's ground-truth images (the same
    target motion, so the scores compare).
    """
    check_ablation(name)
    if name == "no-motion":
        return stage_renderer(
            project, config, log, progress, stage="ablations/no-motion",
            overrides={"use_motion": False},
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
    for m in (config.train_motion, *available_test_motions(config)):
        stage_simulate(sub, sub_config, m.name, "proxy", log)
    stage_joint2coarse(sub, sub_config, log, progress)
    return stage_renderer(sub, sub_config, log, progress)


def ablation_label(name: str, config: PipelineConfig) -> str:
    """The ablation's row name in the comparison table."""
    if name == "no-motion":
        return "ours, no motion features"
    if name.startswith("views-"):
        return f"ours, {name[6:]} views per frame (not {config.views_per_frame})"
    return f"ours, {name[len('template-') :]} template as proxy"


def eval_methods(project: Project, config: PipelineConfig) -> dict[str, tuple[Path, str, Path]]:
    """The methods ``stage_eval`` scores: name -> (model file, proxy source at test time,
    project folder whose proxy and test sets it renders).

    ``ours`` renders Joint2Coarse's proxy (no simulation at test time, the method's claim);
    ``ours (simulated proxy)`` renders the simulated proxy of the same motion, which separates
    the renderer's error from Joint2Coarse's. Baselines render both proxies too; ablations
    render Joint2Coarse's.
    """
    root = project.root
    methods = {
        "ours": (project.path("renderer", "renderer.pt"), "joint2coarse", root),
        "ours (simulated proxy)": (project.path("renderer", "renderer.pt"), "sim", root),
    }
    for kind in config.baselines:
        methods[kind] = (project.path(f"baselines/{kind}", f"{kind}.pt"), "joint2coarse", root)
    for kind in config.baselines:  # the renderers alone, on the right geometry
        model = project.path(f"baselines/{kind}", f"{kind}.pt")
        methods[f"{kind} (simulated proxy)"] = (model, "sim", root)
    for name in config.ablations:
        check_ablation(name)
        if name == "no-motion":
            model, data = project.path("ablations/no-motion", "renderer.pt"), root
        elif name.startswith("views-"):
            model, data = ablation_project(project, name).path("renderer", "renderer.pt"), root
        else:
            sub = ablation_project(project, name)
            model, data = sub.path("renderer", "renderer.pt"), sub.root
        methods[ablation_label(name, config)] = (model, "joint2coarse", data)
    return methods


def stage_eval(project: Project, config: PipelineConfig, log: Log = _quiet) -> dict:
    """Score every method on every test motion from unseen cameras: ``eval/report.json`` and
    ``eval/compare-MOTION.png`` (ground truth and each method on the same frames)."""
    import torch

    from core.shading import contact_sheet, write_png
    from training.baselines import load_for_evaluation
    from training.dataset import GarmentDataset
    from training.evaluate import EvalConfig, evaluate_motion, fid_scores
    from training.metrics import FrameMetrics

    tests = [m.name for m in available_test_motions(config)]
    methods = eval_methods(project, config)
    eval_cfg = EvalConfig(inception_path=config.inception_path)
    inputs = [path for path, _, _ in methods.values()]
    for name in tests:
        for root in {r for _, _, r in methods.values()}:
            data = Project(root)
            inputs += [
                data.path(f"testset/{name}", "samples.json"),
                data.path("joint2coarse", f"pred-{name}.npz"),
                data.path(f"sim/{name}-proxy", "cache.npz"),
            ]
    params = {
        "eval": eval_cfg.to_dict(),
        "methods": {k: [v[1], str(v[2])] for k, v in methods.items()},
    }

    def work(out: Path) -> list[str]:
        torch.set_num_threads(config.torch_threads)
        models = {name: load_for_evaluation(path) for name, (path, _, _) in methods.items()}
        totals = {name: FrameMetrics() for name in methods}
        report: dict = {"methods": {}, "motions": {}, "test_motions": tests}
        outputs = []
        for motion in tests:
            data = {
                (root, src): GarmentDataset(root, source=src, split=motion)
                for _, src, root in methods.values()
            }
            log(
                f"  evaluating {motion}: {len(data[(project.root, 'joint2coarse')])} samples x "
                f"{len(methods)} methods"
            )
            results, gt_tiles = evaluate_motion(
                {
                    name: (models[name], data[(root, src)])
                    for name, (_, src, root) in methods.items()
                },
                eval_cfg,
            )
            report["motions"][motion] = {
                name: {
                    "samples": len(data[(methods[name][2], methods[name][1])]),
                    **r.metrics.summary(),
                }
                for name, r in results.items()
            }
            for name, r in results.items():
                for metric, values in r.metrics.values.items():
                    totals[name].add(metric, values)
            tiles, labels = [], []
            for row_name, row in (
                ("ground truth", gt_tiles),
                *((n, r.tiles) for n, r in results.items()),
            ):
                tiles += row
                labels += [row_name] * len(row)
            write_png(
                out / f"compare-{motion}.png", contact_sheet(tiles, labels, columns=len(gt_tiles))
            )
            outputs.append(f"compare-{motion}.png")
            for name, r in results.items():
                report["motions"][motion][name].update(fid_scores(r, eval_cfg))
        for name in methods:
            report["methods"][name] = totals[name].summary()
        for suffix in ("", " (simulated proxy)"):
            ours, dnr = report["methods"][f"ours{suffix}"], report["methods"].get(f"dnr{suffix}")
            if dnr and dnr["mse"]["mean"]:
                key = "mse_ratio_ours_to_dnr" + ("_simulated_proxy" if suffix else "")
                report[key] = ours["mse"]["mean"] / dnr["mse"]["mean"]
        write_json(out / "report.json", report)
        return [*outputs, "report.json"]

    project.run_stage("eval", params, inputs, work)
    import json

    return json.loads(project.path("eval", "report.json").read_text())


def stage_videos(project: Project, config: PipelineConfig, log: Log = _quiet) -> dict:
    """Side-by-side videos of every test motion: simulated ground truth | neural render of
    Joint2Coarse's proxy, from a camera circling the body once over the clip (unseen views).
    Writes ``videos/MOTION.gif`` and ``report.json`` (ms per frame of the neural path)."""
    import torch

    from core.shading import contact_sheet
    from training.playback import FrameWriter, Playback, load_motion_for

    tests = [m.name for m in available_test_motions(config)]
    inputs = [
        project.path("renderer", "renderer.pt"),
        project.path("joint2coarse", "joint2coarse.pt"),
    ]
    inputs += [project.path(f"sim/{n}-target", "cache.npz") for n in tests]
    params = {"tests": tests, "size": config.image_size}

    def work(out: Path) -> list[str]:
        torch.set_num_threads(config.torch_threads)
        pb = Playback(project.root)
        report = {}
        for name in tests:
            pb.set_motion(load_motion_for(project, name))  # a project motion: has its truth
            n = pb.num_frames
            timings = []
            with FrameWriter(out / f"{name}.gif", config.fps) as writer:
                for t in range(n):
                    cam = pb.default_camera(t, config.image_size, config.image_size, 360.0 * t / n)
                    neural = pb.render(t, cam)
                    timings.append(pb.last_timings)
                    truth, label = pb.reference_image(t, cam)
                    scale = max(1, -(-192 // config.image_size))  # tiles big enough for labels
                    tiles = [
                        np.kron(x, np.ones((scale, scale, 1), np.uint8)) for x in (truth, neural)
                    ]
                    writer.append(contact_sheet(tiles, [label, "neural render"], columns=2))
            med = {k: float(np.median([x[k] for x in timings])) for k in timings[0]}
            report[name] = {"frames": n, "median_ms": med}
            log(f"  videos/{name}.gif: {n} frames, neural path {med['total']:.0f} ms/frame median")
        write_json(out / "report.json", report)
        return [*(f"{n}.gif" for n in tests), "report.json"]

    project.run_stage("videos", params, inputs, work)
    import json

    return json.loads(project.path("videos", "report.json").read_text())


# ---------------------------------------------------------------------------------- data set


def dataset_rig(config: PipelineConfig, garment_vertices: np.ndarray):
    """Cameras on a circle that frame the garment (it fills most of the image)."""
    from core.camera import CameraRigConfig

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


def stage_dataset(project: Project, config: PipelineConfig, log: Log = _quiet) -> Path:
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
        "views": config.views_per_frame,
        "stride": config.frame_stride,
        "size": config.image_size,
        "seed": config.seed,
        "body": asdict(config.body),
    }

    def work(out: Path) -> list[str]:
        samples = _render_samples(
            project, config, train, out, seed=(config.seed,), views=config.views_per_frame,
            stride=config.frame_stride, desc="ground truth",
        )  # fmt: skip
        log(f"  {len(samples)} samples of 3 frames at {config.image_size} px")
        return ["samples.json", *_sample_files(samples)]

    project.run_stage("dataset", params, [target_cache, motion_file], work)
    return project.stage_dir("dataset")


def _render_samples(
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
    sample records written to ``samples.json``.
    """
    from tqdm import tqdm

    from core.body.mannequin import make_body
    from core.body.skinning import pose_body
    from core.camera import camera_to_dict, random_cameras
    from core.mesh import Mesh, load_mesh
    from core.shading import render_views, write_png
    from core.sim import load_cache

    cache = load_cache(project.path(f"sim/{motion_name}-target", "cache.npz"))
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
    for f in tqdm(frames, desc=desc, unit="frame", leave=False):
        wanted = [(t, k, f - t + 1) for (t, k) in cams if abs(f - t) <= 1]
        garment = Mesh(cache.positions[f], cache.faces)
        body_mesh = Mesh(body_frames[f], body.faces)
        views_f = render_views(garment, body_mesh, [cams[(t, k)] for t, k, _ in wanted])
        for (t, k, slot), gt in zip(wanted, views_f):
            strips[(t, k)][slot] = gt
            if all(s is not None for s in strips[(t, k)]):
                _write_sample(out, t, k, strips.pop((t, k)), write_png)
    samples = [{"frame": t, "view": k, "camera": camera_to_dict(c)} for (t, k), c in cams.items()]
    write_json(
        out / "samples.json",
        {"motion": motion_name, "fps": cache.fps, "num_frames": cache.num_frames,
         "samples": samples},
    )  # fmt: skip
    return samples


def _sample_files(samples: list[dict]) -> list[str]:
    return [
        f"samples/{sample_name(s['frame'], s['view'])}_{kind}.png"
        for s in samples
        for kind in ("image", "background", "mask")
    ]


def stage_testset(
    project: Project, config: PipelineConfig, motion_name: str, log: Log = _quiet
) -> Path:
    """Ground truth of an unseen motion from unseen cameras: ``testset/MOTION/``.

    Same layout as the training set (:func:`stage_dataset`), with cameras from another random
    stream (``seed=(config.seed, 1, t)``), ``config.test_views`` per centre frame, every
    ``config.test_stride`` frames. Needs the motion's target (``sim/MOTION-target``).
    """
    target_cache = project.path(f"sim/{motion_name}-target", "cache.npz")
    stage = f"testset/{motion_name}"
    params = {
        "views": config.test_views,
        "stride": config.test_stride,
        "size": config.image_size,
        "seed": config.seed,
        "body": asdict(config.body),
    }

    def work(out: Path) -> list[str]:
        samples = _render_samples(
            project, config, motion_name, out, seed=(config.seed, 1), views=config.test_views,
            stride=config.test_stride, desc=f"ground truth {motion_name}",
        )  # fmt: skip
        log(f"  {motion_name}: {len(samples)} test samples from unseen cameras")
        return ["samples.json", *_sample_files(samples)]

    project.run_stage(
        stage, params, [target_cache, project.path("motions", f"{motion_name}.bvh")], work
    )
    return project.stage_dir(stage)


def sample_name(t: int, k: int) -> str:
    return f"t{t:05d}_v{k:02d}"


def _write_sample(out: Path, t: int, k: int, gts: list, write_png) -> None:
    name = sample_name(t, k)
    write_png(out / "samples" / f"{name}_image.png", np.concatenate([g.image for g in gts], 1))
    write_png(
        out / "samples" / f"{name}_background.png", np.concatenate([g.background for g in gts], 1)
    )
    mask = np.concatenate([np.round(g.coverage * 255).astype(np.uint8) for g in gts], 1)
    write_png(out / "samples" / f"{name}_mask.png", mask)
