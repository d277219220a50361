"""A project's settings: :class:`PipelineConfig`, the presets (``smoke``, ``quick``, ``paper``;
their motions are in :mod:`pipeline.library`), and the one place where each stage's configuration
is resolved (:func:`sim_config`, :func:`joint2coarse_config`, :func:`renderer_config`, ...)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from core.body.shape import BodyShape
from core.errors import InputError
from core.project import Project
from core.sim import SimConfig
from pipeline.library import CMU_CLIP, LIBRARY_TRAIN, LIBRARY_VALIDATION, MotionSpec

TARGET_MODES = ("embed", "tiers", "simulate")  #: ``PipelineConfig.target_mode``'s values


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
    renderer_validation: str | None = None
    """The renderers' validation motion (protocol V, one of ``joint2coarse_validation``'s, from
    cameras of its own): their every setting is chosen on it. None: no validation split."""
    proxy_verts: int = 1000
    """Target vertex count of the derived proxy."""
    proxy_texture: int = 512
    """Texture size the proxy's UV atlas is packed for."""
    fabric: str = "cotton"
    """Fabric preset of the simulation (``core.sim.config``)."""
    sim_substeps: int = 8
    """Simulation substeps per frame at 30 fps ..."""
    sim_iterations: int = 16
    """... and solver iterations per substep (``core.sim.config.QUALITY``: 8 x 16 is ``medium``);
    with ``sim_solver="implicit"``, the most Newton iterations a step runs."""
    sim_solver: str = "style3d"
    """The proxy's cloth solver (``core.sim.config.SOLVERS``): newton's ``style3d``, or ours,
    ``implicit`` (a single surface: ``target_mode="simulate"`` needs ``style3d``)."""
    sim_implicit_tol: float = 1.0e-4
    """``sim_solver="implicit"``: the Newton update a step stops under, metres ..."""
    sim_implicit_norm: str = "max"
    """... measured by its largest vertex (``max``) or its root mean square (``rms``)."""
    simulate_target: bool = True
    """Make the detailed target's motion too (needed for ground-truth images)."""
    target_mode: str = "embed"
    """How the detailed target moves (``TARGET_MODES``): ``simulate`` (cloth), ``embed`` or ``tiers``."""
    layer_thickness: bool = True
    """Keep the simulated proxy off the body by the depth of the target's layers beneath it
    (``core.sim.thickness``), as the layered garment is (docs/decisions.md, "layer_thickness")."""
    target_contact: bool = True
    """Keep the embedded target's inner layers out of the hips (docs/decisions.md, "target_contact")."""
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
    """Renderer fields changed from the preset, e.g. ``{"w_gan": 0.0}`` (``--set w_gan=0``); DNR
    with our loss (``dnr-gan``) takes the same loss weights, the other baselines keep theirs."""
    renderer_source: str = "sim"
    """The proxy the renderers train on: ``sim`` (the training motion's simulated proxy, the
    paper) or ``joint2coarse`` (Joint2Coarse's prediction of it, which test time always uses)."""
    baselines: tuple[str, ...] = ("pix2pix", "dnr", "dnr-gan")
    """Baselines trained on the same data set, as many steps as ours (``training.baselines``)."""
    baseline_overrides: dict = field(default_factory=dict)
    """Fields changed from every baseline's preset, e.g. ``{"lr_decay_from": 0.5}`` (``--set``)."""
    ablations: tuple[str, ...] = ()
    """Renderer ablations scored beside ours (:data:`ABLATION_KINDS`), each one more training."""
    proxy_template: str | None = None
    """A built-in coarse template fitted to the target instead of a derived proxy (an ablation)."""
    inception_path: str = ""
    """InceptionV3 weights (torchvision layout) for FID; empty: FID is reported unavailable."""
    lpips_path: str = ""
    """``lpips`` AlexNet weights (``training.lpips``) for tLP; empty: tLP is reported unavailable."""
    joint2coarse_extra: tuple[MotionSpec, ...] = ()
    """More training motions for Joint2Coarse only, named apart from the test motions."""
    joint2coarse_validation: tuple[MotionSpec, ...] = ()
    """Joint2Coarse's validation motions, never trained on: every Joint2Coarse choice is made on
    them, the test motions are only reported (docs/decisions.md, "joint2coarse_validation")."""
    joint2coarse_compare: tuple[str, ...] = ()
    """Other Joint2Coarse models (``training.joint2coarse.config.MODELS``) trained on the same
    splits and reported beside the project's own (``compare``), which is skipped here."""
    joint2coarse_preset: str = "fast"
    """Joint2Coarse preset name (``training.joint2coarse.PRESETS``) ..."""
    joint2coarse_steps: tuple[int, int, int] | None = None
    """... with (autoencoder, motion, finetune) step counts overridden when given ..."""
    joint2coarse_overrides: dict = field(default_factory=dict)
    """... and any other fields changed from the preset, e.g. ``{"dropout": 0.2}`` (``--set``)."""
    seed: int = 0
    """Seed of everything random in training."""
    loader_workers: int = 0
    """DataLoader processes loading the renderers' batches ahead (``training.loader``; the weights
    are the same for any count): 0 on a small CPU machine, a few on a GPU one (``--workers 4``)."""
    torch_threads: int = 1
    """CPU threads torch uses for training and inference: one, since more spin against anything
    running beside them on a small machine (docs/decisions.md, "torch_threads")."""
    lighting: str = "studio"
    """The ground truth's light: a preset (``core.lighting.PRESETS``), an image or a JSON."""
    raster_threads: int = 1
    """Threads of the stages' ray casts (``core.raster.RasterConfig.threads``, 0: every core),
    one as two stages run side by side; same images (docs/decisions.md, "raster_threads")."""

    def __post_init__(self) -> None:
        if self.target_mode not in TARGET_MODES:
            raise InputError(f"target_mode must be one of {TARGET_MODES}, not {self.target_mode!r}")
        for name, least in (("loader_workers", 0), ("torch_threads", 1), ("raster_threads", 0)):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= least):
                raise InputError(f"{name} must be an integer >= {least}, got {value!r}")
        simulated = self.simulate_target and self.target_mode == "simulate"
        if self.sim_solver == "implicit" and simulated:
            raise InputError(
                "target_mode='simulate' simulates the target's layers, which the implicit "
                "solver cannot (a single surface): use sim_solver='style3d' with it"
            )

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


#: The paper preset's test motions: a kind it never trains on besides the twirl (a walk).
_PAPER_TESTS: tuple[MotionSpec, ...] = (
    MotionSpec("twirl", "twirl", 300, seed=1),
    MotionSpec("walk", "walk", 300, seed=2),
    MotionSpec("cmu-01_01", "file", 300, path=str(CMU_CLIP), start_s=2.0),
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
        renderer_source="joint2coarse",  # as quick's
        joint2coarse_extra=(MotionSpec("circle-walk", "circle-walk", 30, seed=2),),
        joint2coarse_validation=(MotionSpec("val-walk", "walk", 36, seed=4, speed=1.3),),
        renderer_validation="val-walk",
        joint2coarse_compare=("paper", "ours"),
        joint2coarse_steps=(300, 300, 100),
    ),
    # The default: minutes on 2 cores, results that look like the garment. Its choices were made
    # on the validation motions; each one's figures are in docs/decisions.md under its key.
    "quick": PipelineConfig(
        # Converged cloth at about Style3D medium's cost ("sim_solver"); 0.3 mm, as 1 mm let the
        # layered proxy overstretch on the high jump ("sim_implicit_tol").
        sim_solver="implicit",
        sim_substeps=2,
        sim_iterations=16,
        sim_implicit_tol=3.0e-4,
        sim_implicit_norm="rms",
        target_mode="tiers",  # detail that moves on its own ("target_mode = tiers")
        renderer_steps=600,  # the training L1 is flat from there ("renderer_steps")
        # L1 alone ("renderer_overrides"): without a GAN, "DNR with our loss" is DNR, so the
        # baselines leave it out. Every renderer trains on the predicted proxy ("renderer_source").
        renderer_overrides={"w_fm": 0.0, "w_gan": 0.0},
        renderer_source="joint2coarse",
        baselines=("pix2pix", "dnr"),
        joint2coarse_extra=(
            MotionSpec("walk", "walk", 300, seed=3),
            MotionSpec("circle-walk", "circle-walk", 300, seed=4),
            MotionSpec("jump", "jump", 150, seed=5),
            *LIBRARY_TRAIN,
        ),
        joint2coarse_validation=LIBRARY_VALIDATION,
        # The renderers' validation split: real capture, like the test clip a user brings.
        renderer_validation="val-cmu-01_03",
        # Ours drives the project, the paper's beside it (compare); figures: docs/decisions.md.
        joint2coarse_overrides={
            "model": "ours",  # ahead of the paper's on the validation motions
            "residual_widths": [128, 128],  # narrower and longer than the defaults
            "residual_steps": 6000,
            "residual_members": 3,  # better at each seed than one; five no better
            "mirror": True,  # each clip's left-right mirror too, a symmetric prediction
            "skin_fade": 0.0,  # the body's skinning all the way down the skirt
            "tilt_follow": 1.0,  # for the paper's model, beside ours
            "feature_frame": "hips+heading",  # motion features in the current hips' frame
            "residual_loss": "distance",  # trained on each vertex's distance, the error reported
        },
        joint2coarse_compare=("paper", "ours"),
    ),
    # The paper's sizes, for a GPU machine.
    "paper": PipelineConfig(
        train_motion=MotionSpec("dance", "dance", 850, seed=0),
        test_motions=_PAPER_TESTS,
        proxy_verts=2000,
        sim_substeps=16,
        sim_iterations=32,
        target_mode="simulate",
        views_per_frame=10,
        frame_stride=1,
        image_size=512,
        renderer_preset="paper",
        ablations=("no-motion", "no-temporal", "views-5", "template-long-skirt"),
        joint2coarse_preset="paper",
        # Choices are made on validation here too, less this preset's procedural test kinds (a
        # walk), which no choice sees.
        joint2coarse_validation=tuple(
            m
            for m in LIBRARY_VALIDATION
            if m.kind not in {t.kind for t in _PAPER_TESTS if t.kind != "file"}
        ),
        renderer_validation="val-cmu-01_03",
    ),
}


def preset(name: str) -> PipelineConfig:
    if name not in PRESETS:
        raise InputError(f"unknown preset {name!r}; choose from {', '.join(PRESETS)}")
    return PRESETS[name]


Log = Callable[[str], None]


def quiet(_: str) -> None:
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


def renderer_validation_motion(config: PipelineConfig) -> MotionSpec | None:
    """The renderers' validation motion (:attr:`PipelineConfig.renderer_validation`), None when
    there is none or its file is not on this machine; InputError when it names no motion of
    ``joint2coarse_validation``."""
    name = config.renderer_validation
    if name is None:
        return None
    spec = {m.name: m for m in config.joint2coarse_validation}.get(name)
    if spec is None:
        raise InputError(
            f"renderer_validation {name!r} is not one of the validation motions "
            f"({', '.join(m.name for m in config.joint2coarse_validation) or 'none'})"
        )
    return spec if on_this_machine((spec,)) else None


def joint2coarse_splits(config: PipelineConfig) -> dict[str, list[str]]:
    """Names of Joint2Coarse's train, validation and test motions (those on this machine)."""
    return {
        "train": [config.train_motion.name, *(m.name for m in available_extra_motions(config))],
        "validation": [m.name for m in available_validation_motions(config)],
        "test": [m.name for m in available_test_motions(config)],
    }


def sim_config(config: PipelineConfig):
    """The simulation settings of a project (fabric, substeps): every proxy simulation of the
    project, and ``dng eval joint2coarse``'s, runs with these."""
    return SimConfig(
        fabric=config.fabric, substeps=config.sim_substeps, iterations=config.sim_iterations,
        solver=config.sim_solver, implicit_tol=config.sim_implicit_tol,
        implicit_norm=config.sim_implicit_norm,
    )  # fmt: skip


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


def baseline_config(config: PipelineConfig, kind: str):
    """A baseline's configuration: the preset matching the renderer's, with as many steps as
    ours and our optimiser schedule (``lr_g``, ``lr_decay_from``, ``adam_eps``,
    ``texture_lr_scale``), better on validation than each baseline's own (docs/decisions.md,
    "baseline_config")."""
    from training.baselines import PRESETS as BASELINE_PRESETS

    if kind not in BASELINE_PRESETS:
        raise InputError(f"unknown baseline {kind!r}; choose from {sorted(BASELINE_PRESETS)}")
    names = BASELINE_PRESETS[kind]
    name = config.renderer_preset if config.renderer_preset in names else "cpu"
    ours = renderer_config(config)
    cfg = names[name].replace(
        image_size=config.image_size, seed=config.seed, steps=ours.steps, lr_g=ours.lr_g,
        lr_decay_from=ours.lr_decay_from, adam_eps=ours.adam_eps,
        texture_lr_scale=ours.texture_lr_scale,
    )  # fmt: skip
    if kind == "dnr-gan":  # "DNR with our loss": the weights ours trains with, overrides included
        loss = ("w_l1", "w_perceptual", "w_fm", "w_gan")
        cfg = cfg.replace(**{k: getattr(ours, k) for k in loss})
    if config.baseline_overrides:
        cfg = type(cfg).from_dict({**cfg.to_dict(), **config.baseline_overrides})
    return cfg
