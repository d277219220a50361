"""What a project runs, set against the paper: the table of deviations, and what each method of
the comparison got (capacity, schedule, losses, compositing).

Both are computed from the project's resolved configurations (:func:`~pipeline.config.
renderer_config`, :func:`~pipeline.config.baseline_config`, :func:`~pipeline.config.
joint2coarse_config`) and the code's fixed choices, so the report cannot drift from what ran; the
README's copy of the quick preset's tables is checked against them by the tests
(``tests/test_deviations.py``). The paper's numbers are DESIGN.md's ("The method").
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from core.sim.config import CHEBYSHEV_RHO, SimConfig
from pipeline.config import (
    PipelineConfig,
    available_extra_motions,
    baseline_config,
    joint2coarse_config,
    renderer_config,
)

#: The paper's settings this module compares against (DESIGN.md, "The method").
PAPER_TRAIN_FRAMES = 850
PAPER_VIEWS = 10
PAPER_IMAGE_SIZE = 512
PAPER_TEXTURE = ((512, 256, 128, 64), 16)
PAPER_LATENT = (16, 16, 512)  # at 512 px
PAPER_LOSS = {"w_l1": 10.0, "w_perceptual": 10.0, "w_fm": 5.0, "w_gan": 0.5}
PAPER_LR = {"lr_g": 1e-4, "lr_d": 3e-4}
#: Adam's eps: the paper names none, so the libraries' default.
PAPER_ADAM_EPS = 1e-8


@dataclass(frozen=True)
class Deviation:
    """One way the project's run differs from the paper's method."""

    part: str
    """What it concerns: data, ground truth, proxy, Joint2Coarse, renderer, training."""
    paper: str
    """What the paper does."""
    here: str
    """What this project does."""
    why: str
    """The reason, with where it was measured when it was."""


@dataclass(frozen=True)
class MethodBudget:
    """What one method of the image comparison trains with."""

    method: str
    parameters: int
    """Trainable parameters of what renders (network and neural texture; no discriminator)."""
    texture: str
    """Neural texture, levels x channels (``-``: none)."""
    steps: int
    batch: int
    learning_rate: str
    """The generator's Adam rate and its schedule."""
    losses: str
    background: str
    """How the body around the garment gets into the image."""


def _texture(sizes, channels, lr_scale: float = 1.0) -> str:
    levels = f"{len(sizes)} levels ({', '.join(str(s) for s in sizes)} texels) x {channels} ch"
    return levels if lr_scale == 1.0 else f"{levels}, learning at {lr_scale:g}x the rate"


def _schedule(lr: float, decay_from: float) -> str:
    if decay_from >= 1.0:
        return f"{lr:g}, constant"
    return f"{lr:g}, falling linearly to 0 from {decay_from:.0%} of the steps"


def _losses(cfg, gan_weight: str = "w_gan") -> str:
    parts = [f"L1 {cfg.w_l1:g}"]
    if cfg.w_pyramid:
        parts.append(f"Laplacian pyramid {cfg.w_pyramid:g}")
    if cfg.w_detail:
        parts.append(f"detail energy {cfg.w_detail:g}")
    if cfg.w_perceptual:
        parts.append(
            f"perceptual {cfg.w_perceptual:g}" + ("" if cfg.vgg_path else " (off: no VGG19 file)")
        )
    if cfg.w_fm:
        parts.append(f"feature matching {cfg.w_fm:g}")
    if getattr(cfg, gan_weight):
        parts.append(f"GAN {getattr(cfg, gan_weight):g}")
    return ", ".join(parts)


def _meta(build):
    """A model built on torch's ``meta`` device: shapes only, no memory, no time (the paper
    preset's four networks would take about 1 GB on the CPU)."""
    import torch

    with torch.device("meta"):
        return build()


def _latent(cfg) -> tuple[int, int, int]:
    from training.renderer.model import RenderNet

    side = cfg.image_size // 2**cfg.n_down
    return side, side, _meta(lambda: RenderNet(cfg)).spade.conv1.in_channels


def deviations(config: PipelineConfig) -> list[Deviation]:
    """Every way ``config``'s run differs from the paper, in pipeline order."""
    from training.joint2coarse.config import PREDICTION_STRETCH, PREDICTION_SWEEPS

    r = renderer_config(config)
    j = joint2coarse_config(config)
    rows: list[Deviation] = []

    def add(part, paper, here, why):
        rows.append(Deviation(part, paper, here, why))

    train = config.train_motion
    if train.frames != PAPER_TRAIN_FRAMES:
        add(
            "data",
            f"one {PAPER_TRAIN_FRAMES}-frame dance",
            f"one {train.frames}-frame {train.kind}, a sample centred every {config.frame_stride} "
            "frames",
            "CPU budget: simulation, renders and training scale with the frames",
        )
    if config.views_per_frame != PAPER_VIEWS:
        add(
            "data",
            f"{PAPER_VIEWS} random cameras per frame",
            f"{config.views_per_frame} random cameras per frame",
            "CPU budget (the fewer-views ablation measures what it costs)",
        )
    if r.image_size != PAPER_IMAGE_SIZE:
        add(
            "data",
            f"{PAPER_IMAGE_SIZE} px images",
            f"{r.image_size} px",
            "CPU budget: a step costs about the pixel count",
        )
    steps = f"{config.sim_substeps} x {config.sim_iterations} substeps x iterations a frame"
    if config.sim_solver == "implicit":
        solver = (
            f"ours, implicit BDF2 steps by Newton's method, {config.sim_substeps} a frame, each "
            f"until its update is under {config.sim_implicit_tol * 1000:g} mm "
            + ("root mean square" if config.sim_implicit_norm == "rms" else "at every vertex")
            + "; its bending toward its rest shape"
        )
    else:
        solver = f"newton, Style3D, {steps}, Chebyshev-accelerated, rho {CHEBYSHEV_RHO}"
    if config.target_mode in ("embed", "tiers"):
        tiers = config.target_mode == "tiers"
        add(
            "ground truth",
            "the detailed garment simulated (Marvelous Designer)",
            "the proxy simulated ("
            + solver
            + (
                ", kept off the body by the depth of the target's layers beneath it, which also "
                f"make it bend {SimConfig().layer_bending:g} times as stiffly as the fabric and "
                "buckle in compression"
                if config.layer_thickness
                else ""
            )
            + "); the detailed target embedded in it"
            + (
                ", its hanging pieces (the frill tiers) simulated as cloth of their own on it "
                "(the same implicit solver, seams kinematic, one-sided contact with the "
                "layer beneath, no contact between tiers); its layers keep their offsets"
                if tiers
                else ": its details keep their offsets, no secondary motion of their own"
            )
            + (
                "; its inner layers pushed out of the body's capsules where they would sink in"
                if config.target_contact
                else ""
            ),
            "simulating stacked layers millimetres apart takes minutes per clip on 2 cores; "
            "Marvelous Designer is not available",
        )
    else:
        add(
            "ground truth",
            "the detailed garment simulated (Marvelous Designer)",
            f"simulated with newton (Style3D, {steps}; the proxy Chebyshev-accelerated, rho "
            f"{CHEBYSHEV_RHO}, the layers not: they touch)",
            "Marvelous Designer is not available",
        )
    if config.proxy_template:
        add(
            "proxy",
            "a coarse garment made for the target",
            f"the built-in template `{config.proxy_template}` fitted to the target",
            "the template ablation",
        )
    else:
        add(
            "proxy",
            "a coarse garment made for the target",
            f"derived automatically: layers collapsed, decimated to about {config.proxy_verts} "
            "vertices, xatlas UV atlas",
            "the studio's point: any detailed garment in, no hand work",
        )
    extra = available_extra_motions(config)
    if extra:
        frames = train.frames + sum(m.frames for m in extra)
        add(
            "Joint2Coarse",
            "trained on the one training motion",
            f"trained on a library of {1 + len(extra)} clips ({frames} frames), "
            f"chosen on validation clips ({len(config.joint2coarse_validation)})",
            "one dance does not generalise to unseen motions",
        )
    if j.mirror:
        symmetric = "; ours predicts the mean of its prediction and the mirror's, reflected"
        add(
            "Joint2Coarse",
            "trained on the simulated clips as they are",
            "each clip's left-right mirror added (the mirrored motion's simulation, for none)"
            + (symmetric if j.model == "ours" else ""),
            "chosen on the validation clips",
        )
    if j.model == "ours":
        add(
            "Joint2Coarse",
            "shape autoencoder + motion encoder",
            "ours: the proxy skinned to the body plus a residual on the joints' history"
            + (
                ", trained on each vertex's distance (not its squared error)"
                if j.residual_loss == "distance"
                else ""
            ),
            "chosen on the validation clips",
        )
    else:
        if j.tilt_follow:
            add(
                "Joint2Coarse",
                "vertices predicted in the root's heading frame",
                f"the waistband follows {j.tilt_follow:g} of the pelvis's tilt, none at the hem",
                "measured in `tilt_follow`'s docstring (chosen before the validation split)",
            )
        if j.output_basis and config.proxy_verts * 3 > j.output_basis:
            add(
                "Joint2Coarse",
                "decoder's last layer to every coordinate",
                f"to {j.output_basis} principal components of the training shapes",
                "6x fewer weights at 2000 vertices: what makes streaming fast",
            )
        if config.proxy_verts < j.width_reference_vertices:
            add(
                "Joint2Coarse",
                "shape network 2048-1024-512-256-128-64",
                f"widths scaled by vertices / {j.width_reference_vertices} (at least "
                f"{j.min_width}) for smaller proxies",
                "smaller proxies get proportionally smaller networks; not measured against full widths",
            )
    add(
        "Joint2Coarse",
        "prediction used as it comes",
        f"its edges shortened to at most {PREDICTION_STRETCH:.0%} stretch against the proxy's "
        f"rest shape (a strain limit, {PREDICTION_SWEEPS} sweeps) wherever it is used; vertices "
        "inside the body pushed out of the simulation's capsules where asked (`dng predict "
        "proxy --push-out`)",
        "the network stretches the proxy's edges many times more than the cloth does "
        '(docs/decisions.md, "Joint2Coarse\'s prediction strain-limited"); the report gives '
        "stretch and penetration against the simulation's",
    )
    sizes, channels = PAPER_TEXTURE
    if (tuple(r.texture_sizes), r.texture_channels) != (sizes, channels):
        add(
            "renderer",
            f"neural texture {_texture(sizes, channels)}",
            _texture(r.texture_sizes, r.texture_channels),
            "the texture's sampling backward dominates a CPU step",
        )
    latent = _latent(r)
    if latent != PAPER_LATENT:
        add(
            "renderer",
            f"latent {'x'.join(map(str, PAPER_LATENT))} at {PAPER_IMAGE_SIZE} px",
            f"{'x'.join(map(str, latent))} at {r.image_size} px (first layer {r.base_width} "
            f"channels, discriminator {r.disc_width})",
            "CPU budget",
        )
    if r.skip_connections:
        add(
            "renderer",
            "decoder from the latent alone",
            "U-Net skips from frame t's encoder at every scale; they bypass the SPADE block, "
            "so the temporal conditioning acts at the bottleneck only",
            "sharper folds within a few thousand steps",
        )
    if r.texture_readout:
        add(
            "renderer",
            "the texture reaches the image through the network alone",
            "also through a 1 x 1 conv from frame t's texture sample to the last layer's RGB "
            "and alpha logits",
            "without it the frill tiers came through too slowly for a few hundred steps: the "
            "garment's detail on the validation motion was 0.49 of the ground truth's, 0.55 at "
            "twice the steps, 0.74 with a readout of the RGB alone (docs/decisions.md, "
            '"texture_readout")',
        )
    if r.blend_output:
        add(
            "renderer",
            "the image is the network's output",
            "blended with the real background by a predicted alpha (the body off the garment "
            "is exact; the baselines must learn it)",
            "the body off the garment is exact, not a learned copy (the garment-region "
            "figures leave it out)",
        )
    if r.blend_output and r.texture_readout and r.alpha_prior:
        add(
            "renderer",
            "(no blend)",
            f"the blend's alpha logit raised by {r.alpha_prior:g} on the proxy's coverage: "
            "the garment starts opaque where the proxy is, and the network learns where to "
            "carve it",
            "learned from nothing in a few hundred steps, the alpha let the backdrop through "
            "the garment, where most of our garment-region error was; chosen on the validation "
            'motion (docs/decisions.md, "alpha_prior")',
        )
    add(
        "renderer",
        "SPADE block's shortcut SPADE(I(Z))",
        "the identity",
        "fewer parameters; not measured against the paper's",
    )
    add(
        "renderer",
        "SPADE normalises with batch statistics",
        "each latent cell over its channels (positional normalisation)",
        "batch-1 streaming and crops give the same image as training batches",
    )
    if r.w_perceptual and not r.vgg_path:
        add(
            "training",
            "perceptual (VGG19) loss",
            "off: no VGG19 weights file (`--set vgg_path=FILE` turns it on)",
            "no weights can be downloaded here",
        )
    if r.w_pyramid or r.w_detail:
        add(
            "training",
            "no loss on the image's bands of detail",
            ", ".join(
                f"{name} {w:g}"
                for name, w in (("Laplacian pyramid", r.w_pyramid), ("detail energy", r.w_detail))
                if w
            )
            + " beside L1 (`pyramid_l1`, `detail_energy_l1` in training/losses.py)",
            "they stand in for the perceptual loss and the GAN, which sharpen the paper's "
            "renders but have no weights here or do not pay at 600 steps; chosen on the "
            'validation motion (docs/decisions.md, "texture_readout")',
        )
    weights = {k: getattr(r, k) for k in PAPER_LOSS}
    if weights != PAPER_LOSS:
        add(
            "training",
            _losses_of(PAPER_LOSS),
            _losses_of(weights),
            "chosen on the validation motion: at the quick preset's steps the adversarial "
            "terms cost garment-region MSE and SSIM (the quick preset's comment in "
            "pipeline/config.py)",
        )
    if (r.lr_g, r.lr_d) != (PAPER_LR["lr_g"], PAPER_LR["lr_d"]) or r.lr_decay_from < 1.0:
        add(
            "training",
            f"Adam {_schedule(PAPER_LR['lr_g'], 1.0)} (D {PAPER_LR['lr_d']:g})",
            f"{_schedule(r.lr_g, r.lr_decay_from)} (D {r.lr_d:g})",
            "a few hundred steps: measured in `lr_decay_from`'s docstring",
        )
    if r.adam_eps != PAPER_ADAM_EPS:
        add(
            "training",
            f"Adam's eps not stated (the libraries' default, {PAPER_ADAM_EPS:g})",
            f"{r.adam_eps:g}, for every method",
            "a neural texel's gradient is about 1e-10: at 1e-8 the texture hardly learns "
            "(`adam_eps`'s docstring)",
        )
    if r.texture_lr_scale != 1.0:
        add(
            "training",
            "one learning rate for the network and its neural texture",
            f"the texture's texels at {r.texture_lr_scale:g}x the network's rate, for ours and DNR",
            "with Adam a texel moves about the rate a step: a few hundred steps at one rate "
            "left the texture near its initial noise (`texture_lr_scale`'s docstring)",
        )
    if config.renderer_source == "joint2coarse":
        add(
            "training",
            "the renderer trains on the training motion's simulated coarse garment",
            "every renderer and baseline trains on Joint2Coarse's prediction of it (the proxy "
            "they are shown at test time)",
            "chosen on the validation motion: lower garment-region MSE for every method, on "
            "Joint2Coarse's proxy and on the simulated one (the quick preset's comment in "
            "pipeline/config.py)",
        )
    if config.renderer_validation:
        add(
            "evaluation",
            "the training motion from unseen cameras (Table 1)",
            "that (protocol P), unseen motions (U), and a validation motion with cameras of its "
            f"own (V, `{config.renderer_validation}`) where every renderer and baseline setting "
            "is chosen",
            "settings chosen on the figures they report would flatter them",
        )
    if "no-motion" in config.ablations:
        add(
            "ablation",
            "without motion features: the neural texture's sample alone",
            "the texture's sample and the proxy's coverage mask (one channel, as DNR's input)",
            "on the texture alone the blend's mask never left the background in 600 steps "
            "(`use_motion`'s docstring): the ablation would measure the missing coverage",
        )
    return rows


def _losses_of(weights: dict) -> str:
    return (
        f"L1 {weights['w_l1']:g}, perceptual {weights['w_perceptual']:g}, "
        f"feature matching {weights['w_fm']:g}, GAN {weights['w_gan']:g}"
    )


def method_budgets(config: PipelineConfig) -> list[MethodBudget]:
    """What ours and each baseline of ``config`` train with (parameters counted on a model of the
    project's configuration built on the ``meta`` device)."""
    from training.baselines import build_model
    from training.renderer.model import RenderNet

    def count(build) -> int:
        return sum(p.numel() for p in _meta(build).parameters() if p.requires_grad)

    r = renderer_config(config)
    rows = [
        MethodBudget(
            "ours",
            count(lambda: RenderNet(r)),
            _texture(r.texture_sizes, r.texture_channels, r.texture_lr_scale),
            r.steps,
            r.batch_size,
            _schedule(r.lr_g, r.lr_decay_from),
            _losses(r),
            "real background pasted by a predicted alpha"
            if r.blend_output
            else "learned from the background image",
        )
    ]
    for kind in config.baselines:
        b = baseline_config(config, kind)
        sizes = getattr(b, "texture_sizes", None)
        rows.append(
            MethodBudget(
                kind,
                count(lambda b=b: build_model(b)),
                _texture(sizes, b.texture_channels, b.texture_lr_scale) if sizes else "-",
                b.steps,
                b.batch_size,
                _schedule(b.lr_g, b.lr_decay_from),
                _losses(b),
                "learned from the background image",
            )
        )
    return rows


def deviations_markdown(rows: list[Deviation]) -> str:
    """:func:`deviations`' rows as a Markdown table."""
    lines = ["| part | the paper | here | why |", "| --- | --- | --- | --- |"]
    lines += [f"| {d.part} | {d.paper} | {d.here} | {d.why} |" for d in rows]
    return "\n".join(lines)


def methods_markdown(rows: list[MethodBudget]) -> str:
    """:func:`method_budgets`' rows as a Markdown table."""
    lines = [
        "| method | parameters | neural texture | steps x batch | learning rate (G) | losses | "
        "background |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    lines += [
        f"| {m.method} | {m.parameters / 1e6:.2f} M | {m.texture} | {m.steps} x {m.batch} | "
        f"{m.learning_rate} | {m.losses} | {m.background} |"
        for m in rows
    ]
    return "\n".join(lines)


def as_json(config: PipelineConfig) -> dict:
    """Both tables for ``report.json`` (``deviations``, ``methods``: lists of the records'
    fields)."""
    return {
        "deviations": [asdict(d) for d in deviations(config)],
        "methods": [asdict(m) for m in method_budgets(config)],
    }


def from_json(data: dict) -> tuple[list[Deviation], list[MethodBudget]]:
    """Inverse of :func:`as_json`."""
    return (
        [Deviation(**d) for d in data["deviations"]],
        [MethodBudget(**m) for m in data["methods"]],
    )
