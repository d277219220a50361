"""The Joint2Coarse stage's configuration and named presets."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from core.errors import InputError
from training.configs import PlainConfig

#: The Joint2Coarse models :attr:`Joint2CoarseConfig.model` names.
MODELS = ("paper", "ours")
#: The frames :attr:`Joint2CoarseConfig.residual_frame` names.
RESIDUAL_FRAMES = ("hips", "skinned")
#: The frames :attr:`Joint2CoarseConfig.feature_frame` names.
FEATURE_FRAMES = ("heading", "hips", "hips+heading")
#: The losses :attr:`Joint2CoarseConfig.residual_loss` names.
RESIDUAL_LOSSES = ("squared", "distance")
#: Stretch (``len / rest - 1``) a project's Joint2Coarse prediction may keep on an edge
#: (:func:`training.joint2coarse.prediction_stretch_limit`): as it comes the network stretched
#: its edges' 99th percentile to 0.117 on quick's validation motions, the simulation's 0.003;
#: at 0.01 it is 0.013, the error a little lower (docs/decisions.md, "Joint2Coarse's
#: prediction strain-limited").
PREDICTION_STRETCH = 0.01
#: Shortening sweeps of that limit (each moves an edge's excess one edge along the cloth).
PREDICTION_SWEEPS = 30


@dataclass(frozen=True)
class Joint2CoarseConfig(PlainConfig):
    """Joint motion -> coarse proxy: descriptor, network sizes, training schedule.

    The defaults are the paper's (DESIGN, "The method"); ``PRESETS`` names smaller ones.
    """

    kind: ClassVar[str] = "joint2coarse"

    model: str = "paper"
    """Which Joint2Coarse: ``paper`` (the paper's shape autoencoder and motion encoder, the
    fields below) or ``ours`` (:mod:`training.joint2coarse.body_model`: the proxy skinned to the
    body plus a residual network on the joints' history; it uses ``window``, ``stride``,
    ``clamp_z``, ``skin_fade``, the ``residual_*`` fields and ``learning_rate`` (``ridge`` for
    the linear residual), and trains in seconds)."""
    ridge: float = 30.0
    """``ours``: ridge penalty of the residual, per training frame, on z-scored features.
    Chosen on the quick preset's validation motions (mean over them of the mean / p95 vertex
    error, mm; ``dng train joint2coarse P --set ridge=R``, report ``validation_motions``):
    1: 69.1 / 161, 10: 53.5 / 117, 30: 52.7 / 110 (with a spun idle in the library instead of
    ``walk-fast``: 0.1: 82.8 / 211, 1: 71.2 / 170, 10: 55.2 / 122, 30: 53.7 / 112, 100: 55.4 /
    114). Before the validation dance was spun, 1 was best (49.1 / 109 against 54.1 / 110 at
    10); a residual in the heading frame instead of the hips' gave 60.9 against 59.8 mm."""
    residual_widths: tuple[int, ...] = (256, 256)
    """``ours``: hidden widths of the residual network (ReLU layers on the motion features,
    :func:`~training.joint2coarse.body_model.fit_residual_network`); ``()`` gives the linear
    residual fitted in closed form (``ridge``). Chosen on the quick preset's validation motions:
    the mean over them of the mean / p95 vertex error (mm), over seeds 0 and 1, of a fresh quick
    project (``dng demo --out P``, then ``python benchmarks/joint2coarse_validation.py P --set
    model=ours --set residual_widths=[W,W] --seeds 0 1``): linear 65.1 / 134, (128, 128) 48.0 /
    103, (256, 256) 46.3 / 96, (512, 512) 45.9 / 94 (within seed noise, 4x the weights),
    (256, 256, 256) 47.5 / 98; the paper's model on the same splits 55.8 / 124. Those were
    measured with the 6-clip library; with the 19-clip one the quick preset sets (128, 128) and
    6000 ``residual_steps`` (docs/decisions.md gives the figures)."""
    residual_basis: int = 128
    """``ours``: the network predicts the coefficients of this many principal components of the
    training residuals (as ``residual_widths``: 64: 46.8 / 97, 256: 46.7 / 98, the same within
    seed noise)."""
    residual_steps: int = 3000
    """``ours``: training steps of the residual network (20 s on one thread on the quick
    project; 6000: 46.0 / 95, the same within seed noise)."""
    residual_dropout: float = 0.1
    """``ours``: dropout after every hidden ReLU of the residual network (as
    ``residual_widths``: 0: 52.2 / 108, 0.2: 46.9 / 98)."""
    residual_weight_decay: float = 1e-4
    """``ours``: AdamW's decoupled weight decay of the residual network. On the quick
    project's validation motions (the quick preset's model, seeds 0 to 2, ``python
    benchmarks/joint2coarse_validation.py P --seeds 0 1 2 --set residual_weight_decay=W``):
    1e-4 27.9 / 62 mm (mean / p95), 0.01 28.1 / 62, 0.1 28.2 / 62: no better."""
    residual_input_noise: float = 0.0
    """``ours``: standard deviation of Gaussian noise added to the residual network's normalised
    inputs in training (in units of each feature's spread; 0: none), a regulariser for motions
    whose features lie off the training set's. Measured as ``residual_weight_decay``: 0.1 29.4 /
    64, 0.3 32.9 / 72, against 27.9 / 62 without: it hurts."""
    residual_loss: str = "squared"
    """``ours``: what the residual network's training minimises: ``squared`` (the residual's
    squared error, summed over coordinates) or ``distance`` (each vertex's distance to its
    target, the error the figures report, averaged over vertices: each step over
    :data:`~training.joint2coarse.body_model.DISTANCE_VERTICES` of them drawn at random). Where
    the cloth may go one way or another for the same motion, the squared error is lowest at the
    mean of the outcomes, which lies inside all of them (a shorter, smoother skirt); the
    distance is lowest at their median. On the quick preset's
    validation motions (its model, seeds 0 to 2, ``python benchmarks/joint2coarse_validation.py
    P --seeds 0 1 2 --set residual_loss=distance``): 22.8 / 61 mm (mean / p95) against 23.4 /
    62, at 128 vertices a step; at 256 22.9 / 61, over every vertex 22.8 / 61 (the same with
    ``--distance-vertices 256`` and ``--distance-vertices 989``). The quick
    preset sets it. Model files written before this field existed read as ``squared``."""
    residual_members: int = 1
    """``ours``: residual networks trained from seeds ``seed``, ``seed + 1``, ...; the residual
    is their mean (folded into one wider network: the hidden layers side by side, block
    diagonal after the first, each member's last layer onto the shared principal components, so
    a frame costs little more than one member's). Chosen on the quick preset's validation
    motions (its model, seeds 0 to 2; ``python benchmarks/joint2coarse_validation.py P --seeds
    0 1 2 --set residual_members=N``): docs/decisions.md."""
    residual_frame: str = "hips"
    """``ours``: the frame the residual is predicted in: ``hips`` (the hips' rotation, every
    vertex alike) or ``skinned`` (each vertex's own: the blend of its bones' rotations by its
    skinning weights, orthonormalised; the residual is then a displacement of the rest proxy
    before skinning, as a pose-corrective blend shape). On the quick project's validation
    motions (its model, seeds 0 to 2, ``python benchmarks/joint2coarse_validation.py P --seeds 0
    1 2 --set residual_frame=skinned``, P = a quick project with the 35-clip library, features
    in the heading frame): ``skinned`` 23.9 / 60 mm (mean / p95) against 23.4 / 58, worse on
    the capture windows (CMU 01_03 26.8 / 80 against 24.5 / 72): not taken."""
    feature_frame: str = "heading"
    """``ours``: the frame the residual's motion features are taken in
    (:func:`~training.joint2coarse.body_model.motion_features`): ``heading`` (the descriptor's:
    upright, turned with the pelvis's heading), ``hips`` (the whole window turned into the
    current hips' frame, so a pelvis tilted as no training clip tilts it still gives familiar
    features, and gravity's direction in that frame) or ``hips+heading`` (those and the current
    pose in the heading frame too). Model files written before this field existed read as
    ``heading``. The quick preset sets ``hips+heading`` (docs/decisions.md
    gives the figures)."""
    mirror: bool = False
    """Train on each training clip's left-right mirror too (:mod:`training.joint2coarse.augment`:
    the simulation of the mirrored motion, for no simulation; a project's garment that is not
    symmetric trains without, and its report says so), both models; ours then also predicts
    symmetrically, as the mean of its prediction and the reflected prediction for the mirrored
    motion (twice the work a frame).
    The quick preset sets it, chosen on its validation motions (mean over them of the mean /
    p95 vertex error, mm, seeds 0 to 5: 34.0 / 74 without, 28.8 / 64 with; ``python
    benchmarks/joint2coarse_validation.py P --set mirror=true --seeds 0 1 2 3 4 5``)."""
    skin_fade: float = 1.0
    """``ours``: how the skinning fades down the garment: a vertex at relative height h in the
    garment (1 at the top, 0 at the hem) keeps ``h ** skin_fade`` of the body's skinning
    weights and follows the hips rigidly for the rest (0: skinned everywhere). On the quick
    preset's validation motions (as ``ridge``): at ridge 1, 0: 74.0 / 176, 1: 71.2 / 170,
    3: 71.5 / 172; at ridge 30, 1: 53.7 / 112, 3: 53.8 / 113."""
    window: int = 34
    """Frames of motion history the descriptor covers (current frame included). ``ours``
    reads back as far as its longest lag (:mod:`~training.joint2coarse.body_model`'s
    ``TURN_LAGS``: 16 samples, 32 frames at ``stride`` 2), so
    beyond 34 frames the window only sets the shortest motion it accepts (on the quick project's
    validation motions, ``--set window=50`` gave the preset's figures to the digit at seeds 0
    to 2: README, "Chosen again on the converged ground truth")."""
    stride: int = 2
    """Sample every ``stride``-th frame of the window: ``ceil(window / stride)`` samples
    (34 / 2 = 17 samples x 19 joints x 3 = the paper's 969 inputs)."""
    encoder_widths: tuple[int, ...] = (2048, 1024, 512, 256, 128)
    """Hidden widths of the shape encoder (the decoder mirrors them), for a proxy of
    ``width_reference_vertices`` vertices or more."""
    latent_dim: int = 64
    """Size of the shape latent the motion encoder is trained to hit."""
    motion_widths: tuple[int, ...] = (512, 256, 128)
    """Hidden widths of the motion encoder (its output is the ``latent_dim`` latent)."""
    output_basis: int = 256
    """Size of the decoder's linear output basis: its last layer predicts this many coefficients
    of the principal components of the (normalised, output-frame) training shapes, and the basis
    turns them into the ``Vc * 3`` coordinates. The decoder then ends in a ``width x K`` layer
    and a fixed ``K x Vc * 3`` basis instead of a ``width x Vc * 3`` layer: at 2000 vertices and
    K = 256, 2.0 M weights instead of 12 M, which is what makes streaming fast. Used only where
    it makes the layer smaller (:meth:`basis_size`; small proxies keep the full layer). 0 gives
    the paper's full last layer everywhere; model files written before this field existed read
    as 0."""
    tilt_follow: float = 0.5
    """How far the frame each proxy vertex is predicted in follows the root's tilt (pelvis pitch
    and roll), not only its heading: the top of the garment (the waistband) takes this fraction
    of the tilt, falling linearly with height to none at the hem
    (:func:`~training.joint2coarse.descriptor.to_output_frame`). 0 is the paper's root frame
    for every vertex. Measured on the quick data set, CMU 01_01 (its pelvis is pitched 22
    degrees on average, against 3 to 9 in the training clips), J2C seeds 0, 1, 2: ``dng demo
    --out P``, then ``dng train joint2coarse P --set seed=S --set tilt_follow=F`` and ``dng
    eval P --json``:

    ==========  ==================  =============  ==========================
    follow      mean error (mm)     p95 (mm)       our image MSE, its proxy
    ==========  ==================  =============  ==========================
    0           64.5, 64.7, 70.8    134, 128, 149  0.0086, 0.0081, 0.0090
    0.5         52.3, 56.2, 57.4    116, 121, 126  0.0081, 0.0081, 0.0081
    1           54.8, 54.9, 55.0    131, 134, 134  0.0090, 0.0084, 0.0093
    ==========  ==================  =============  ==========================

    At 1 the waistband fits best, but the predicted skirt comes out narrower than the simulated
    one and every method's images get worse; 0.5 keeps most of the gain and gives the best
    images. The twirl has no tilt, so it changes only within seed noise. Model files written
    before this field existed read as 0.

    That table was measured on a test clip. Chosen again on the quick preset's six validation
    motions, on the ground truth with the layers' thickness (mean / p95 mm over them and seeds 0
    to 2, ``python benchmarks/joint2coarse_validation.py P --seeds 0 1 2 --set model=paper --set
    tilt_follow=F``, the library with ten replayed capture windows more than the preset keeps):
    0: 42.6 / 95, 0.5: 42.3 / 96, 1: 40.8 / 92. The quick preset sets 1; the default stays 0.5
    for the presets not measured so."""
    width_reference_vertices: int = 2048
    """Proxy vertex count at which ``encoder_widths`` apply in full. Smaller proxies scale every
    shape-network width by ``n_vertices / width_reference_vertices`` (rounded up), never below
    ``min_width``; larger proxies keep the listed widths."""
    min_width: int = 64
    """Smallest hidden width the small-proxy rule may produce."""
    dropout: float = 0.05
    """Dropout probability after every hidden ReLU (training only)."""
    learning_rate: float = 1e-3
    """RMSprop learning rate of the autoencoder and motion-encoder stages."""
    finetune_learning_rate: float = 1e-4
    """RMSprop learning rate of the end-to-end fine-tune (motion encoder + decoder)."""
    batch_size: int = 32
    """Frames per optimisation step."""
    autoencoder_steps: int = 20000
    """Steps of stage 1: the shape autoencoder on proxy vertices (vertex L2)."""
    motion_steps: int = 20000
    """Steps of stage 2: the motion encoder onto the frozen shape latent (latent L2)."""
    finetune_steps: int = 5000
    """Steps of stage 3: motion encoder + decoder end to end on vertex L2 (0 turns it off)."""
    val_fraction: float = 0.15
    """Fraction of every clip held out for validation: its last frames, as one contiguous block."""
    clamp_z: float = 10.0
    """Normalised inputs (and normalised outputs) are clamped to ``[-clamp_z, clamp_z]``, so
    motions far outside the training range still give bounded proxies."""
    std_floor: float = 1e-3
    """Smallest standard deviation (metres) used to normalise a coordinate; coordinates that
    hardly move in training are not blown up."""
    seed: int = 0
    """Seeds initial weights, shuffling and dropout: the same seed gives the same weights."""
    checkpoint_every: int = 500
    """Write the resumable training checkpoint every this many steps (and at every stage end)."""
    log_every: int = 50
    """Append a row (mean train loss since the last row) to the loss log every this many steps."""
    eval_every: int = 500
    """Compute the validation loss every this many steps (logged in the same row)."""

    def __post_init__(self) -> None:
        positive = (
            "window", "stride", "latent_dim", "width_reference_vertices", "min_width",
            "batch_size", "checkpoint_every", "log_every", "eval_every",
        )  # fmt: skip
        for name in positive:
            v = getattr(self, name)
            if not (isinstance(v, int) and v > 0):
                raise InputError(f"joint2coarse config {name}={v!r} must be a positive integer")
        for name in (
            "autoencoder_steps", "motion_steps", "finetune_steps", "output_basis", "seed",
            "residual_steps",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 0):
                raise InputError(f"joint2coarse config {name}={v!r} must be an integer >= 0")
        for name in ("residual_basis", "residual_members"):
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and v > 0):
                raise InputError(f"joint2coarse config {name}={v!r} must be a positive integer")
        for name in ("encoder_widths", "motion_widths", "residual_widths"):
            v = getattr(self, name)
            if not (isinstance(v, tuple) and all(isinstance(w, int) and w > 0 for w in v)):
                raise InputError(f"joint2coarse config {name}={v!r} must be a tuple of ints > 0")
        if not (isinstance(self.tilt_follow, (int, float)) and 0.0 <= self.tilt_follow <= 1.0):
            raise InputError(
                f"joint2coarse config tilt_follow={self.tilt_follow!r} must be in [0, 1]"
            )
        if self.residual_frame not in RESIDUAL_FRAMES:
            raise InputError(
                f"joint2coarse config residual_frame={self.residual_frame!r}: choose from "
                f"{', '.join(RESIDUAL_FRAMES)}"
            )
        if self.residual_loss not in RESIDUAL_LOSSES:
            raise InputError(
                f"joint2coarse config residual_loss={self.residual_loss!r}: choose from "
                f"{', '.join(RESIDUAL_LOSSES)}"
            )
        if self.feature_frame not in FEATURE_FRAMES:
            raise InputError(
                f"joint2coarse config feature_frame={self.feature_frame!r}: choose from "
                f"{', '.join(FEATURE_FRAMES)}"
            )
        if not isinstance(self.mirror, bool):
            raise InputError(f"joint2coarse config mirror={self.mirror!r} must be true or false")
        if self.model not in MODELS:
            raise InputError(
                f"joint2coarse config model={self.model!r}: choose from {', '.join(MODELS)}"
            )
        for name in ("ridge", "skin_fade", "residual_input_noise", "residual_weight_decay"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"joint2coarse config {name}={v!r} must be a number >= 0")
        for name in ("dropout", "residual_dropout"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 <= v < 1.0):
                raise InputError(f"joint2coarse config {name}={v!r} must be in [0, 1)")
        if not 0.0 <= self.val_fraction < 1.0:
            raise InputError(
                f"joint2coarse config val_fraction={self.val_fraction!r} not in [0, 1)"
            )
        for name in ("learning_rate", "finetune_learning_rate", "clamp_z", "std_floor"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"joint2coarse config {name}={v!r} must be a positive number")

    @property
    def num_samples(self) -> int:
        """Frames sampled from the window: ``ceil(window / stride)``."""
        return -(-self.window // self.stride)

    @property
    def total_steps(self) -> int:
        return self.autoencoder_steps + self.motion_steps + self.finetune_steps

    def shape_widths(self, n_vertices: int) -> tuple[int, ...]:
        """Encoder hidden widths for a proxy of ``n_vertices`` (the small-proxy rule)."""
        scale = min(1.0, n_vertices / self.width_reference_vertices)
        return tuple(max(self.min_width, min(w, math.ceil(w * scale))) for w in self.encoder_widths)

    def basis_size(self, n_vertices: int) -> int:
        """Output basis components for a proxy of ``n_vertices``; 0 means a full last layer.

        The basis is used only where it makes the decoder's output smaller: ``K * (w + Vc * 3)``
        weights against ``w * Vc * 3`` for a last hidden width ``w`` (at 2000 vertices and the
        paper's widths, 2.0 M against 12 M; a 120-vertex proxy keeps its full last layer).
        """
        k, out = self.output_basis, 3 * n_vertices
        widths = self.shape_widths(n_vertices)
        w = widths[0] if widths else self.latent_dim
        return k if 0 < k and k * (w + out) < w * out else 0


#: Named configurations. ``paper``: the published sizes. ``fast``: a quick look on a laptop.
PRESETS: dict[str, Joint2CoarseConfig] = {
    "paper": Joint2CoarseConfig(),
    "fast": Joint2CoarseConfig(autoencoder_steps=3000, motion_steps=3000, finetune_steps=1000),
}
