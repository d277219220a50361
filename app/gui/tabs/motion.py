"""The Motion tab's controller: open a project (its window settings, garment and trained
networks), pick a motion (a project motion, a procedural kind or a BVH file) and predict its
proxy on the ``playback`` worker, pick the body to play on, fine-tune to a body shape, a
background image or a light (a job on the Pipeline tab's runner). A relit model plays under its
light, beside the reference rendered under the same light."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from app.gui.model import Cancelled, format_seconds, load_settings, unique_edges
from app.gui.part import Part
from core.compositing import load_image
from core.errors import InputError
from core.lighting import PRESETS, load_lighting
from core.mesh import load_mesh
from core.project import Project
from pipeline.finetune import (
    BACKDROP_FILE,
    RELIGHT_STEPS,
    finetune_background_images,
    finetune_body_shape,
    finetune_lighting,
    saved_lighting,
)
from pipeline.playback import Playback, load_motion_for

#: Procedural kinds offered in the motion list (``core.motion.procedural.PROCEDURAL_KINDS``;
#: written out so the window opens without importing the motion code).
PROCEDURAL = (
    "dance", "twirl", "walk", "circle-walk", "idle", "jump", "broad-jump", "run", "squat", "kick",
    "kneel",
)  # fmt: skip
#: The light picker's last item: it opens a file dialog for an environment image.
ENVIRONMENT_ITEM = "environment image..."
#: The name of the relighting job (on the Pipeline tab's runner).
RELIGHT_JOB = "fine-tune light"


class MotionTab(Part):
    """Project, motion and body choice; ``studio`` is the :class:`app.gui.controller.Studio`
    it belongs to. What is loaded plays in :attr:`app.gui.controller.Studio.player`."""

    def __init__(self, studio):
        super().__init__(studio)
        self.motion_items: list[str] = []
        self.body_items: list[str] = []
        self.playback_root: Path | None = None
        self.renderer_path: Path | None = None
        #: The light "Fine-tune to this light" uses: a preset's name or an environment image.
        self.light_spec = next(iter(PRESETS))
        self.environments: list[str] = []  # environment images picked so far
        self.relighting = False  # a relighting job runs

    def apply_settings(self) -> None:
        """Put the settings into the tab's widgets."""
        s, v = self.studio.settings, self.view
        v.motion_frames.int_value = s.motion_frames
        for name, slider in v.body_sliders.items():
            if name in s.body:
                slider.double_value = float(s.body[name])

    # ------------------------------------------------------------------ project

    def open_project(self, path: str | os.PathLike) -> None:
        """Open a project folder: restore its window settings, load its garment, proxy and
        trained networks (Playback), and its saved motion and camera."""
        studio = self.studio
        root = Path(path)
        if not (root / "project.json").is_file():
            studio.show_error(InputError("not a garment project (no project.json)", root))
            return
        try:
            studio.settings = load_settings(root)
            config = Project(root).settings().get("pipeline", {})
        except InputError as exc:
            studio.show_error(exc)
            return
        studio.project = root
        self.view.project_label.text = str(root)
        studio.apply_settings()
        self.fill_motion_list()
        self.fill_body_list()
        target = root / "garment" / "target.obj"
        if target.is_file():
            if not studio.settings.camera and "proxy_verts" in config:
                self.set(
                    proxy_verts=int(config["proxy_verts"]),
                    texture_size=int(config.get("proxy_texture", studio.settings.texture_size)),
                )
                studio.apply_settings()
            studio.garment_tab.load_garment(str(target))
        self.open_playback(root)

    def fill_motion_list(self) -> None:
        combo = self.view.motion_combo
        combo.clear_items()
        names = []
        if self.studio.project is not None:
            names = sorted(p.stem for p in (self.studio.project / "motions").glob("*.bvh"))
        self.motion_items = [*names, *[k for k in PROCEDURAL if k not in names]]
        for name in self.motion_items:
            combo.add_item(name)

    def fill_body_list(self) -> None:
        combo = self.view.body_combo
        combo.clear_items()
        self.body_items = ["project body"]
        project = self.studio.project
        if project is not None:
            found = project / "finetune"
            self.body_items += sorted(
                p.name for p in found.glob("body-*") if (p / "renderer" / "renderer.pt").is_file()
            )
            # Relit renderers play on the project's body, under their light.
            self.body_items += sorted(
                p.name for p in found.glob("light-*") if (p / "renderer.pt").is_file()
            )
        for name in self.body_items:
            combo.add_item(name)

    def open_playback(
        self,
        root: Path,
        renderer_path: Path | None = None,
        backdrop=None,
        motion=None,
        lighting=None,
    ) -> None:
        """Load ``root``'s trained networks (a project or a fine-tuned sub-project; another
        renderer file, a backdrop image, the light of the body and the reference: a
        :class:`core.lighting.Lighting`) on the playback worker, then its motion."""
        studio, player = self.studio, self.studio.player
        self.playback_root = root
        self.renderer_path = renderer_path
        self.view.status.text = f"loading {root.name} (Joint2Coarse, body) ..."
        motion = motion or studio.settings.motion

        def job():
            import torch  # heavy: imported on the worker, so the window opens at once

            torch.set_num_threads(1)
            device = "cuda" if torch.cuda.is_available() else "cpu"
            pb = Playback(root, renderer_path=renderer_path, device=device)
            if backdrop is not None:
                pb.set_backdrop(backdrop)
            if lighting is not None:
                pb.shading = replace(pb.shading, lighting=lighting)
            player.playback = pb
            return pb.has_renderer(), device == "cuda"

        def done(out) -> None:
            has_renderer, player.gpu = out
            player.live_disabled_reason = "" if has_renderer else "no trained renderer yet"
            self.view.status.text = f"opened {root}" + (
                "" if has_renderer else " (no trained renderer: live render off)"
            )
            self.load_motion(motion, restore=True)

        studio.play_worker.submit(job, done, studio.show_error, key="open")

    # ------------------------------------------------------------------ motion

    def set_motion_frames(self, n: int) -> None:
        self.set(motion_frames=int(n))

    def load_motion(self, name_or_path: str, frames: int | None = None, restore=False) -> None:
        """Load a project motion, a procedural kind or a BVH file and predict its proxy."""
        studio, player = self.studio, self.studio.player
        if self.playback_root is None:
            studio.show_error(InputError("open a trained project first to play motions"))
            return
        name = str(name_or_path)
        kind_frames = frames or studio.settings.motion_frames
        self.set(motion=name)
        self.view.status.text = f"loading motion {Path(name).name} ..."

        def job():
            pb = player.playback
            is_kind = name in PROCEDURAL and not pb.project.path("motions", f"{name}.bvh").is_file()
            motion = load_motion_for(pb.project, name, frames=kind_frames if is_kind else frames)
            pb.set_motion(motion)
            n = pb.num_frames
            body = np.stack([pb.body_vertices(t) for t in range(n)])
            proxy = np.stack([pb.proxy_vertices(t) for t in range(n)])
            sim = pb.simulated_proxy()
            if sim is not None and len(sim) < n:
                sim = None
            faces = None
            if sim is not None:
                faces = load_mesh(pb.project.path("proxy", "positions.obj"))[0].faces
            return {
                "n": n,
                "fps": pb.fps,
                "body": body,
                "body_faces": pb.body_faces,
                "proxy": proxy,
                "proxy_faces": pb.proxy_faces,
                "proxy_uvs": pb.proxy_uvs,
                "sim": sim,
                "sim_edges": None if faces is None else unique_edges(faces),
                "name": motion.name,
                "j2c_ms": pb.joint2coarse_ms,
            }

        def done(r) -> None:
            v = self.view
            sim = "simulation cache: yes" if r["sim"] is not None else "no simulation cache"
            v.motion_label.text = (
                f"{r['name']}: {r['n']} frames at {r['fps']:g} fps, Joint2Coarse "
                f"{r['j2c_ms']:.1f} ms/frame; {sim}"
            )
            v.show_sim.enabled = r["sim"] is not None
            if name in self.motion_items:
                v.motion_combo.selected_index = self.motion_items.index(name)
            player.set_motion(r, restore=restore)
            v.status.text = f"motion {r['name']} ready"

        studio.play_worker.submit(job, done, studio.show_error, key="motion")

    # ------------------------------------------------------------------ body shapes

    def set_body_param(self, name: str, value: float) -> None:
        self.set(body={**self.settings.body, name: float(value)})

    def select_body(self, item: str) -> None:
        """Play on the project's body or a fine-tuned body sub-project's, or a relit renderer."""
        project = self.studio.project
        if project is None:
            return
        if item.startswith("light-"):
            self.play_relit(project / "finetune" / item / "renderer.pt")
            return
        root = project if item == "project body" else project / "finetune" / item
        self.open_playback(root, motion=self.studio.settings.motion)

    def play_relit(self, model: Path) -> None:
        """Play a relit renderer (``PROJECT/finetune/light-NAME/renderer.pt``) on the project's
        body, under the light and over the backdrop saved beside it."""
        backdrop = model.parent / BACKDROP_FILE
        self.open_playback(
            self.studio.project,
            renderer_path=model,
            backdrop=load_image(backdrop) if backdrop.is_file() else None,
            lighting=saved_lighting(model),
            motion=self.studio.settings.motion,
        )

    def finetune_body(self) -> None:
        studio = self.studio
        if studio.project is None:
            studio.show_error(InputError("open a trained project first"))
            return
        try:
            shape = studio.settings.body_shape()
        except InputError as exc:
            studio.show_error(exc)
            return
        body = studio.settings.body
        name = "-".join(f"{k}{v:g}" for k, v in sorted(body.items())) or "default"
        root = studio.project

        def run(project, config, log, progress):
            return finetune_body_shape(root, shape, name, log=log, progress=False)

        studio.pipeline_tab.start_job(
            f"fine-tune body {name}", [("fine-tune body", run)], refresh=True
        )

    def finetune_background(self, image_path: str) -> None:
        studio = self.studio
        if studio.project is None:
            studio.show_error(InputError("open a trained project first"))
            return
        root, path = studio.project, Path(image_path)

        def run(project, config, log, progress):
            result = finetune_background_images(root, [path], path.stem, log=log, progress=False)
            return result, load_image(path)

        def after(out) -> None:
            result, image = out
            self.view.finetune_label.text = f"background model: {result.model_path}"
            self.open_playback(root, renderer_path=result.model_path, backdrop=image)

        studio.pipeline_tab.start_job(
            "fine-tune background", [("fine-tune background", run)], after=after
        )

    # ------------------------------------------------------------------ light

    @property
    def light_specs(self) -> list[str | None]:
        """What each item of the light picker stands for: a preset, an environment image
        picked before, and None for :data:`ENVIRONMENT_ITEM` (a file dialog)."""
        return [*PRESETS, *self.environments, None]

    @property
    def light_items(self) -> list[str]:
        """The light picker's items (:attr:`light_specs` as shown)."""
        return [*PRESETS, *(Path(p).name for p in self.environments), ENVIRONMENT_ITEM]

    def fill_light_list(self) -> None:
        """Put :attr:`light_items` into the picker, the chosen light selected."""
        combo = self.view.light_combo
        combo.clear_items()
        for item in self.light_items:
            combo.add_item(item)
        combo.selected_index = self.light_specs.index(self.light_spec)

    def set_light(self, spec: str | os.PathLike) -> None:
        """Choose the light to fine-tune to: a preset's name (:data:`core.lighting.PRESETS`)
        or an environment image (equirectangular .hdr, .exr, .png, .jpg), read on the plots
        worker first (a bad one is an error and the choice stays as it was)."""
        studio, spec = self.studio, str(spec)

        def done(lighting) -> None:
            if spec not in PRESETS and spec not in self.environments:
                self.environments.append(spec)
            self.light_spec = spec
            self.fill_light_list()
            self.view.finetune_label.text = f"light: {lighting.name}"

        def failed(exc: BaseException) -> None:
            self.fill_light_list()
            studio.show_error(exc)

        studio.misc_worker.submit(lambda: load_lighting(spec), done, failed, key="light")

    def finetune_light(self, steps: int = RELIGHT_STEPS) -> None:
        """Fine-tune the project's renderer to the chosen light
        (:func:`pipeline.finetune.finetune_lighting`, into ``PROJECT/finetune/light-NAME/``),
        step by step on the label; Cancel stops it at the next step (a restart resumes). Then
        play the relit model under its light, beside the reference rendered under it."""
        studio = self.studio
        if studio.project is None:
            studio.show_error(InputError("open a trained project first"))
            return
        if studio.pipeline_tab.job_running:
            studio.show_error(InputError("a job is already running: cancel it first"))
            return
        root, spec, label = studio.project, self.light_spec, self.view.finetune_label
        name = Path(spec).name
        label.text = f"relight to {name}: starting"
        self.relighting = True

        def shown_step(i: int) -> None:
            left = studio.pipeline_tab.job_eta.seconds_left()
            label.text = f"relight to {name}: step {i} of {steps}" + (
                "" if left is None else f", about {format_seconds(left)} left"
            )

        def run(project, config, log, progress):
            def step(i: int, _losses) -> None:
                progress(i, steps)  # a cancelled job raises Cancelled here: the run stops
                studio.post(lambda: shown_step(i))

            result = finetune_lighting(
                root, spec, steps=steps, callback=step, log=log, progress=False
            )
            backdrop = result.model_path.parent / BACKDROP_FILE
            image = load_image(backdrop) if backdrop.is_file() else None
            return result, saved_lighting(result.model_path), image

        def after(out) -> None:
            result, lighting, image = out
            self.relighting = False
            label.text = f"relit model ({lighting.name}): {result.model_path}"
            player = studio.player
            player.pause()
            if player.mode == "play" and player.num_frames:  # keep the frame and the camera
                self.set(camera=player.current_pose().as_dict(), frame=int(player.frame))
            self.set(view_mode="compare")  # the relit render beside the reference
            self.fill_body_list()  # the relit renderer can be picked again later
            self.view.body_combo.selected_index = self.body_items.index(result.out_dir.name)
            self.open_playback(
                root, renderer_path=result.model_path, backdrop=image, lighting=lighting
            )

        def failed(exc: BaseException) -> None:
            self.relighting = False
            stopped = "cancelled" if isinstance(exc, Cancelled) else "failed"
            label.text = f"relight to {name}: {stopped} (a restart resumes)"

        studio.pipeline_tab.start_job(
            RELIGHT_JOB, [(RELIGHT_JOB, run)], after=after, on_error=failed
        )

    def cancel_finetune(self) -> None:
        """Stop the relighting at its next step."""
        if self.relighting:
            self.studio.pipeline_tab.cancel()
            self.view.finetune_label.text = "relight: cancelling ..."
