"""Fine-tuning a project's trained renderer to a new body shape, a new background or a new light.

- **Body shape** (:func:`finetune_body_shape`): a sub-project ``PROJECT/finetune/body-NAME/``
  with the parent's pipeline settings but the new :class:`core.body.shape.BodyShape`, and the
  parent's garment and proxy copied unchanged (so the UV atlas, hence the neural texture, stays
  valid). The pipeline's own stages make the training motion on the new body, simulate the
  proxy, drive the target, render the data set and train Joint2Coarse there (so the sub-project
  plays like any project); then every renderer weight is fine-tuned from the parent's model
  (:func:`training.renderer.train.finetune_body`, 25% of the steps by default) into
  ``body-NAME/renderer/renderer.pt``.
- **Background** (:func:`finetune_background_images`): the project's data set with every
  sample's background and ground truth recomposited over the given images
  (:class:`BackdropDataset`); only the last decoder layers, the refinement blocks and the
  discriminator train (:func:`training.renderer.train.finetune_background`). Output:
  ``PROJECT/finetune/background-NAME/renderer.pt`` with the images beside it
  (``backdrop-K.png``) for playback.
- **Light** (:func:`finetune_lighting`, the paper's section (iv)): two samples of the data set
  rendered again under the new light (:mod:`core.lighting`) over the new backdrop
  (:class:`LitDataset`); the last two decoder layers and the discriminator train on them for
  about 100 steps (:func:`training.renderer.train.finetune_relight`). Output:
  ``PROJECT/finetune/light-NAME/renderer.pt`` with ``lighting.json`` (what the studio and
  ``dng render`` light the body and the reference with), ``backdrop-0.png`` and
  ``examples.png`` beside it.

How pixels are separated from the empty studio background: the data set's images are rendered
(:mod:`core.shading`) over one known clear colour (``ShadingConfig.background``), averaged in
linear RGB over ``k x k`` ray samples per pixel. Rasterizing the same surfaces from the same
camera at the same ``k x k`` samples gives each pixel's exact surface coverage ``c``
(:func:`surface_coverage`): the body alone for backgrounds, body + detailed garment for ground
truth. Since ``pixel = mean(surface samples) + (1 - c) * clear`` in linear RGB, replacing the
clear colour by a new backdrop is ``pixel + (1 - c) * (backdrop - clear)`` (:func:`recomposite`):
exact up to 8-bit rounding, with antialiased edges kept, no colour keying.
"""

from __future__ import annotations

import copy
import json
import os
import shutil
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from core.body.mannequin import make_body
from core.body.skinning import pose_body
from core.compositing import fit_image, load_image, recomposite, surface_coverage
from core.errors import InputError
from core.fileio import atomic_path, write_json
from core.lighting import Lighting, environment_view, load_lighting, read_environment
from core.mesh import Mesh
from core.project import Project
from core.shading import ShadingConfig, contact_sheet, render_views, write_png
from core.sim import load_cache
from pipeline.config import (
    Log,
    available_extra_motions,
    available_validation_motions,
    project_config,
    quiet,
)
from pipeline.playback import RENDERER_MODEL
from pipeline.stages.dataset import stage_dataset
from pipeline.stages.joint2coarse import stage_joint2coarse
from pipeline.stages.motions import stage_motions
from pipeline.stages.simulate import stage_simulate
from training.dataset import GarmentDataset

#: Sub-folder of a project that holds fine-tuned models.
FINETUNE_DIR = "finetune"
#: Parent folders copied into a body sub-project unchanged (the UV atlas must not change).
COPIED_STAGES = ("garment", "proxy")

# ------------------------------------------------------------------------------ background


class BackdropDataset:
    """A project's data set with each sample recomposited over a backdrop image.

    Sample ``i`` uses ``images[i % len(images)]`` (scaled to cover the image, centre-cropped).
    Its ``background`` (body only) and ``target`` (garment + body) frames are recomposited
    (:func:`recomposite`) with coverage from rasterizing the posed body, and the body with the
    simulated detailed target, from the sample's camera; everything else is the base sample.

    Parameters
    ----------
    base : training.dataset.GarmentDataset
    images : sequence of (H, W, 3) uint8
    shading : core.shading.ShadingConfig the data set was rendered with (the default)
    """

    def __init__(self, base, images: Sequence[np.ndarray], shading=None):
        if not images:
            raise InputError("background fine-tuning needs at least one image")
        self.base = base
        self.shading = ShadingConfig() if shading is None else shading
        self.body, self.body_frames, self.target = _scene(base)
        self.images = [np.asarray(im, np.uint8) for im in images]
        self._fitted: dict[tuple[int, int, int], np.ndarray] = {}

    def __len__(self) -> int:
        return len(self.base)

    def with_motion_per_vertex(self) -> BackdropDataset:
        """The same samples over the base's per-vertex motion features (what a trainer on a
        GPU loads: ``training.loader.for_device``)."""
        other = copy.copy(self)
        other.base = self.base.with_motion_per_vertex()
        return other

    def backdrop(self, i: int, width: int, height: int) -> np.ndarray:
        k = i % len(self.images)
        if (k, width, height) not in self._fitted:
            self._fitted[(k, width, height)] = fit_image(self.images[k], width, height)
        return self._fitted[(k, width, height)]

    def __getitem__(self, i: int) -> dict:
        import torch

        sample = dict(self.base[i])
        t, _, camera = self.base.samples[i]
        back = self.backdrop(i, camera.width, camera.height)
        k, clear = self.shading.supersample, self.shading.background
        images, backgrounds = [], []
        for j, f in enumerate((t - 1, t, t + 1)):
            image, background = (
                (sample[key][j].numpy().transpose(1, 2, 0) * 255 + 0.5).astype(np.uint8)
                for key in ("target", "background")
            )
            image, background = over_backdrop(
                image, background, self.target.positions[f], self.target.faces,
                self.body_frames[f], self.body.faces, camera, k, clear, back,
            )  # fmt: skip
            images.append(image.transpose(2, 0, 1).astype(np.float32) / 255)
            backgrounds.append(background.transpose(2, 0, 1).astype(np.float32) / 255)
        sample["target"] = torch.from_numpy(np.ascontiguousarray(np.stack(images)))
        sample["background"] = torch.from_numpy(np.ascontiguousarray(np.stack(backgrounds)))
        return sample


def over_backdrop(
    image, background, garment, garment_faces, body, body_faces, camera, k, clear, back
) -> tuple[np.ndarray, np.ndarray]:
    """One frame's render (garment on body) and body-alone render, each (H, W, 3) uint8 over
    the clear colour ``clear``, put over the backdrop ``back`` (H, W, 3) uint8 instead: the
    coverage of each from rasterizing its surfaces at the render's ``k x k`` samples
    (:func:`core.compositing.recomposite`). garment (Vg, 3), body (Vb, 3) float vertices."""
    verts = np.concatenate([garment, body]).astype(np.float32)
    faces = np.concatenate([garment_faces, body_faces + len(garment)])
    image = recomposite(image, surface_coverage(verts, faces, camera, k), clear, back)
    background = recomposite(background, surface_coverage(body, body_faces, camera, k), clear, back)
    return image, background


def _scene(base):
    """The body (a :class:`core.mesh.Mesh`-like record), its posed vertices (T, V, 3) and the
    detailed target's cache of the motion a data set (or test set) ``base`` shows."""
    from core.motion.load import load_motion  # scipy: not on the torch-only path's machine

    root = Path(base.root)
    index = json.loads((Path(base.folder) / "samples.json").read_text())
    motion_name = index["motion"]
    config = project_config(Project(root))
    body = make_body(config.body)
    body_frames = pose_body(body, load_motion(root / "motions" / f"{motion_name}.bvh"))
    target = root / "sim" / f"{motion_name}-target" / "cache.npz"
    if not target.is_file():
        raise InputError("no detailed target cache (the data set's ground truth)", target)
    return body, body_frames, load_cache(target)


class LitDataset:
    """Samples of a data set (or a test set) rendered again under another light.

    Sample ``i`` is the base's sample ``indices[i]``: the same proxy inputs, with its
    ``target`` (garment on body), ``background`` (body alone) and ``target_mask`` frames
    t-1, t, t+1 rendered by :func:`core.shading.render_views` under ``lighting`` and
    recomposited over ``backdrop`` (fitted to the image; None keeps the clear colour). Renders
    are made once, on first use.

    Parameters
    ----------
    base : training.dataset.GarmentDataset
    lighting : core.lighting.Lighting
    backdrop : (H, W, 3) uint8 or None
    indices : base samples to take (default: all of them)
    threads : ray-casting threads (0: every core)
    targets : base sample -> (H, W, 3) uint8, a render of frame t made elsewhere (a user's
        tool, under the same light) that replaces the garment on the body at frame t
    """

    def __init__(
        self, base, lighting: Lighting, backdrop=None, indices=None, threads: int = 0, targets=None
    ):
        self.base = base
        self.indices = list(range(len(base))) if indices is None else [int(i) for i in indices]
        if not self.indices:
            raise InputError("a relit data set needs at least one sample")
        for i in self.indices:
            if not 0 <= i < len(base):
                raise InputError(f"sample {i} is not in the data set ({len(base)} samples)")
        self.shading = ShadingConfig(lighting=lighting, threads=threads)
        self.backdrop = None if backdrop is None else np.asarray(backdrop, np.uint8)
        self.body, self.body_frames, self.target = _scene(base)
        self.samples = [base.samples[i] for i in self.indices]
        self.targets = {} if targets is None else dict(targets)
        self._renders: dict[int, dict] = {}

    def __len__(self) -> int:
        return len(self.indices)

    def with_motion_per_vertex(self) -> LitDataset:
        """The same samples over the base's per-vertex motion features (a GPU trainer's)."""
        other = copy.copy(self)
        other.base = self.base.with_motion_per_vertex()
        return other

    def frames(self, i: int) -> dict[str, np.ndarray]:
        """Sample i's renders: ``target`` and ``background`` (3, 3, H, W) float32 in [0, 1],
        ``target_mask`` (3, 1, H, W) float32 (garment coverage)."""
        if i in self._renders:
            return self._renders[i]
        t, _, camera = self.samples[i]
        k, clear = self.shading.supersample, self.shading.background
        body_faces = self.body.faces
        back = None
        if self.backdrop is not None:
            back = fit_image(self.backdrop, camera.width, camera.height)
        out = {"target": [], "background": [], "target_mask": []}
        for f in (t - 1, t, t + 1):
            body, garment = self.body_frames[f], self.target.positions[f]
            gt = render_views(
                Mesh(garment, self.target.faces), Mesh(body, body_faces), [camera], self.shading
            )[0]
            image, background = gt.image, gt.background
            if back is not None:
                image, background = over_backdrop(
                    image, background, garment, self.target.faces, body, body_faces,
                    camera, k, clear, back,
                )  # fmt: skip
            out["target"].append(image.transpose(2, 0, 1).astype(np.float32) / 255)
            out["background"].append(background.transpose(2, 0, 1).astype(np.float32) / 255)
            out["target_mask"].append(gt.coverage[None].astype(np.float32))
        given = self.targets.get(self.indices[i])
        if given is not None:
            out["target"][1] = np.asarray(given).transpose(2, 0, 1).astype(np.float32) / 255
        self._renders[i] = {key: np.stack(v) for key, v in out.items()}
        return self._renders[i]

    def __getitem__(self, i: int) -> dict:
        import torch

        sample = dict(self.base[self.indices[i]])
        for key, value in self.frames(i).items():
            sample[key] = torch.from_numpy(np.ascontiguousarray(value))
        return sample


@dataclass(frozen=True)
class FinetuneResult:
    """What a fine-tuning run wrote and how the loss moved.

    Attributes
    ----------
    model_path : Path of the fine-tuned renderer.pt
    out_dir : Path of its folder (a sub-project for a body shape)
    steps : int
    loss_start, loss_end : generator loss of the first and the last step (None if skipped)
    l1_start, l1_end : L1 part of it
    """

    model_path: Path
    out_dir: Path
    steps: int
    loss_start: float | None
    loss_end: float | None
    l1_start: float | None
    l1_end: float | None


class _LossTrace:
    def __init__(self):
        self.first: dict | None = None
        self.last: dict | None = None

    def __call__(self, step: int, losses: dict | None) -> None:
        if losses is None:
            return
        if self.first is None:
            self.first = losses
        self.last = losses


def _result(train_result, out_dir: Path, trace: _LossTrace) -> FinetuneResult:
    get = lambda d, k: None if d is None else float(d[k])  # noqa: E731
    return FinetuneResult(
        model_path=Path(train_result.model_path),
        out_dir=out_dir,
        steps=train_result.steps,
        loss_start=get(trace.first, "loss_g"),
        loss_end=get(trace.last, "loss_g"),
        l1_start=get(trace.first, "l1"),
        l1_end=get(trace.last, "l1"),
    )


def check_name(name: str) -> str:
    """A fine-tune name must be a plain folder name."""
    if not name or any(c in name for c in "/\\") or name in (".", "..") or name.startswith("."):
        raise InputError(f"bad fine-tune name {name!r}: use letters, digits, - and _")
    return name


def parent_renderer(project_root: str | os.PathLike, renderer_path=None) -> Path:
    """The trained renderer to start from (InputError naming it when missing)."""
    path = Path(renderer_path) if renderer_path else Path(project_root).joinpath(*RENDERER_MODEL)
    if not path.is_file():
        raise InputError("no trained renderer to fine-tune: train one first", path)
    return path


def finetune_background_images(
    project_root: str | os.PathLike,
    image_paths: Sequence[str | os.PathLike],
    name: str = "default",
    *,
    steps: int | None = None,
    renderer_path: str | os.PathLike | None = None,
    device: str = "cpu",
    progress: bool = True,
    log: Log = quiet,
) -> FinetuneResult:
    """Fine-tune the project's renderer to the backdrop images (see the module docstring).

    Writes ``PROJECT/finetune/background-NAME/``: ``renderer.pt``, its checkpoint and loss
    log, ``backdrop-K.png`` (the images as given, for playback) and ``finetune.json``.
    ``steps`` defaults to the model's ``background_finetune_steps``.
    """
    from training.renderer.train import finetune_background

    root = Path(project_root)
    if not root.is_dir():
        raise InputError("project folder not found", root)
    images = [load_image(p) for p in image_paths]  # bad files fail before any work
    if not images:
        raise InputError("give at least one background image")
    model = parent_renderer(root, renderer_path)
    out = root / FINETUNE_DIR / f"background-{check_name(name)}"
    data = BackdropDataset(GarmentDataset(root), images)
    log(f"background fine-tuning from {model}: {len(data)} samples over {len(images)} image(s)")
    trace = _LossTrace()
    result = finetune_background(
        model, data, out, steps=steps, device=device, progress=progress, callback=trace
    )
    for k, im in enumerate(images):
        write_png(out / f"backdrop-{k}.png", im)
    write_json(
        out / "finetune.json",
        {
            "mode": "background",
            "parent_model": str(model),
            "images": [str(p) for p in image_paths],
            "steps": result.steps,
        },
    )
    return _result(result, out, trace)


#: Steps of a relighting fine-tune: the paper's "about 100 iterations".
RELIGHT_STEPS = 100
#: Example renders a relighting fine-tune learns from: the paper's two.
RELIGHT_EXAMPLES = 2
#: Beside a relit model: the light its body and reference are rendered under, and the backdrop.
LIGHTING_FILE, BACKDROP_FILE = "lighting.json", "backdrop-0.png"


def example_samples(n_samples: int, examples: int) -> list[int]:
    """Indices of ``examples`` samples spread evenly over a data set of ``n_samples``."""
    if examples < 1:
        raise InputError(f"give at least one example, got {examples}")
    if examples > n_samples:
        raise InputError(f"{examples} examples asked of a data set of {n_samples} samples")
    return [int((k + 0.5) * n_samples / examples) for k in range(examples)]


def read_examples(items: Sequence[str], n_samples: int, size: int) -> dict[int, np.ndarray]:
    """A user's example renders, ``SAMPLE=IMAGE`` each: the garment on the body at data-set
    sample SAMPLE's frame t from its camera (``dataset/samples.json``), ``size`` pixels
    square. InputError naming the item or the file when it is not one."""
    out: dict[int, np.ndarray] = {}
    if not items:
        raise InputError("give at least one example")
    for item in items:
        index, sep, path = str(item).partition("=")
        if not sep or not index.strip().isdigit() or not path:
            raise InputError(
                f"an example is SAMPLE=IMAGE (a data-set sample's index), got {item!r}"
            )
        i = int(index)
        if i >= n_samples:
            raise InputError(f"example {item!r}: the data set has samples 0 to {n_samples - 1}")
        image = load_image(path)
        if image.shape[:2] != (size, size):
            h, w = image.shape[:2]
            raise InputError(
                f"the example is {w} x {h}; the project's images are {size} x {size}", path
            )
        out[i] = image
    return out


def lighting_backdrop(spec, lighting: Lighting, background, camera) -> np.ndarray | None:
    """The backdrop of a relit view: the ``background`` image when given; else, for an
    environment image, what the camera sees of it (:func:`core.lighting.environment_view`);
    else None (the clear studio colour; a lighting JSON keeps no image to show)."""
    if background is not None:
        return load_image(background)
    image = Path(str(spec))
    if lighting.environment and image.is_file() and image.suffix.lower() != ".json":
        return environment_view(read_environment(image), camera)
    return None


def saved_lighting(model_path: str | os.PathLike) -> Lighting | None:
    """The light a relit model was fine-tuned to (``lighting.json`` beside it), or None."""
    path = Path(model_path).parent / LIGHTING_FILE
    return load_lighting(path) if path.is_file() else None


def finetune_lighting(
    project_root: str | os.PathLike,
    lighting: str | os.PathLike,
    name: str | None = None,
    *,
    background: str | os.PathLike | None = None,
    examples: int | Sequence[str] = RELIGHT_EXAMPLES,
    steps: int = RELIGHT_STEPS,
    renderer_path: str | os.PathLike | None = None,
    device: str = "cpu",
    progress: bool = True,
    callback=None,
    log: Log = quiet,
) -> FinetuneResult:
    """Fine-tune the project's renderer to a new light from a few example renders.

    Parameters
    ----------
    project_root : a project with a trained renderer and its data set
    lighting : a light preset's name, an environment image or a lighting JSON
        (:func:`core.lighting.load_lighting`)
    name : the result's folder is ``PROJECT/finetune/light-NAME/`` (default: the light's name)
    background : a backdrop image (default: an environment image's own view, or none)
    examples : how many data-set samples to render under the light (:func:`example_samples`),
        or a user's own renders under it, ``SAMPLE=IMAGE`` each (:func:`read_examples`): the
        body alone is then rendered under ``lighting`` here, as the renderer's input
    steps : fine-tuning steps
    callback : called after each step with (step, losses) (raising stops the run)

    Writes ``renderer.pt``, its checkpoint and loss log, ``lighting.json``, ``backdrop-0.png``
    (when there is a backdrop), ``examples.png`` (the example frames) and ``finetune.json``.
    """
    from training.renderer.train import finetune_relight

    root = Path(project_root)
    if not root.is_dir():
        raise InputError("project folder not found", root)
    if steps < 1:
        raise InputError(f"steps must be >= 1, got {steps}")
    lit = load_lighting(lighting)  # a bad light or image fails before any work
    model = parent_renderer(root, renderer_path)
    base = GarmentDataset(root, source=project_config(Project(root)).renderer_source)
    given = None
    if isinstance(examples, int):
        indices = example_samples(len(base), examples)
    else:
        given = read_examples(examples, len(base), base.samples[0][2].width)
        indices = sorted(given)
    backdrop = lighting_backdrop(lighting, lit, background, base.samples[0][2])
    out = root / FINETUNE_DIR / f"light-{check_name(name or Path(lit.name).stem)}"
    data = LitDataset(base, lit, backdrop, indices, targets=given)
    log(f"relighting {model} to {lit.name}: {len(indices)} example renders, {steps} steps")
    trace = _LossTrace()

    def step(i: int, losses) -> None:
        trace(i, losses)
        if callback is not None:
            callback(i, losses)

    # The light and the backdrop first: a model beside them is never played in another light.
    write_json(out / LIGHTING_FILE, lit.to_dict())
    if backdrop is not None:
        write_png(out / BACKDROP_FILE, backdrop)
    result = finetune_relight(
        model, data, out, steps=steps, device=device, progress=progress, callback=step
    )
    frames = [data.frames(i)["target"][1] for i in range(len(data))]
    tiles = [(f.transpose(1, 2, 0) * 255 + 0.5).astype(np.uint8) for f in frames]
    write_png(out / "examples.png", contact_sheet(tiles, [f"example {i}" for i in indices]))
    write_json(
        out / "finetune.json",
        {
            "mode": "lighting",
            "parent_model": str(model),
            "lighting": str(lighting),
            "background": None if background is None else str(background),
            "examples": indices,
            "example_images": None if given is None else [str(e) for e in examples],
            "steps": result.steps,
        },
    )
    return _result(result, out, trace)


def finetune_body_shape(
    project_root: str | os.PathLike,
    shape,
    name: str = "default",
    *,
    steps: int | None = None,
    renderer_path: str | os.PathLike | None = None,
    joint2coarse: bool = True,
    device: str = "cpu",
    progress: bool = True,
    log: Log = quiet,
) -> FinetuneResult:
    """Fine-tune the project's renderer to a new body shape (see the module docstring).

    Parameters
    ----------
    project_root : the parent project (trained renderer in ``renderer/renderer.pt``)
    shape : core.body.shape.BodyShape
    name : the sub-project is ``PROJECT/finetune/body-NAME/``
    steps : renderer fine-tuning steps (default: 25% of the model's ``steps``)
    joint2coarse : also train Joint2Coarse on the new body (the sub-project then plays)

    Stages already done in the sub-project with the same inputs are reused.
    """
    from training.renderer.train import finetune_body

    root = Path(project_root)
    if not root.is_dir():
        raise InputError("project folder not found", root)
    parent = Project(root)
    config = project_config(parent)
    model = parent_renderer(root, renderer_path)
    for stage in COPIED_STAGES:
        if not parent.stage_dir(stage).is_dir():
            raise InputError(f"the project has no {stage}/ to reuse", parent.stage_dir(stage))
    sub_root = root / FINETUNE_DIR / f"body-{check_name(name)}"
    sub = Project(sub_root)
    sub_root.mkdir(parents=True, exist_ok=True)
    # The training motion only: test motions would cost simulations the fine-tune does not use.
    sub_config = replace(config, body=shape, test_motions=(), renderer_validation=None)
    settings = {k: v for k, v in parent.settings().items() if k != "pipeline"}
    sub.save_settings(
        {**settings, "pipeline": sub_config.as_params(), "finetune_of": str(root.resolve())}
    )
    for stage in COPIED_STAGES:
        _copy_tree(parent.stage_dir(stage), sub.stage_dir(stage))
    train = sub_config.train_motion.name
    log(f"body-shape sub-project {sub_root}: {asdict(shape)}")
    stage_motions(sub, sub_config, log)
    stage_simulate(sub, sub_config, train, "proxy", log)
    if sub_config.simulate_target:
        stage_simulate(sub, sub_config, train, "target", log)
    stage_dataset(sub, sub_config, log)
    if joint2coarse:
        # Joint2Coarse trains on its whole library and is chosen on its validation clips: their
        # proxies, on the new body, too
        for m in (*available_extra_motions(sub_config), *available_validation_motions(sub_config)):
            stage_simulate(sub, sub_config, m.name, "proxy", log)
        stage_joint2coarse(sub, sub_config, log, progress=progress)
    log(f"renderer fine-tuning from {model}")
    trace = _LossTrace()
    result = finetune_body(
        model,
        GarmentDataset(sub_root),
        sub_root / "renderer",
        steps=steps,
        device=device,
        progress=progress,
        callback=trace,
    )
    write_json(
        sub_root / "renderer" / "finetune.json",
        {"mode": "body", "parent_model": str(model), "body": asdict(shape), "steps": result.steps},
    )
    return _result(result, sub_root, trace)


def _copy_tree(src: Path, dst: Path) -> None:
    """Copy a stage folder file by file, each atomically; identical files are left alone."""
    for f in sorted(src.rglob("*")):
        if not f.is_file() or ".tmp" in f.name:
            continue
        target = dst / f.relative_to(src)
        if target.is_file() and target.read_bytes() == f.read_bytes():
            continue
        with atomic_path(target) as tmp:
            shutil.copyfile(f, tmp)
