"""The Garment tab's controller: a built-in garment or a mesh file, its proxy (derived on the
``proxy`` worker; slider changes coalesce and re-run only what they affect) and "Use this proxy
for the project"."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

from app.gui.model import (
    TEXTURE_SIZES,
    atlas_image,
    cached_builtin_garment,
    process_age,
    proxy_plan,
    proxy_summary,
    reatlas,
    unique_edges,
)
from app.gui.part import Part
from app.gui.window import COLOURS
from core.body.mannequin import make_body
from core.errors import InputError
from core.mesh import load_mesh
from core.project import Project
from core.proxy import ProxyConfig, derive_proxy
from pipeline.config import project_config
from templates.garments import make_garment

#: The built-in garments offered in the tab's list.
BUILTIN_GARMENTS = ("multilayer-skirt", "double-skirt", "tango-skirt", "pleated-skirt", "dress")


class GarmentTab(Part):
    """Garment loading and proxy derivation; ``studio`` is the
    :class:`app.gui.controller.Studio` it belongs to. Garment state is written on the main
    thread from worker results, but ``_proxy_cache`` (the proxy worker's own)."""

    def __init__(self, studio):
        super().__init__(studio)
        self.garment = None  # core.mesh.Mesh
        self.garment_name = ""
        self._garment_id = 0
        self._proxy_cache = None  # (garment id, ProxyConfig, ProxyResult): proxy worker only
        self.proxy_result = None
        self.proxy_plan_ran = ""
        self.body_shown_s: float | None = None  # when the mannequin first showed (process age)
        self.garment_from_cache: bool | None = None
        self.garment_shown_s: float | None = None  # when the first garment showed
        self.loading: tuple[str, float] | None = None  # (what, since): status shows progress

    @staticmethod
    def builtin_garments() -> list[str]:
        return list(BUILTIN_GARMENTS)

    def apply_settings(self) -> None:
        """Put the settings into the tab's widgets."""
        s, v = self.studio.settings, self.view
        v.verts_slider.int_value = s.proxy_verts
        v.detail_slider.double_value = s.detail_scale
        v.texture_combo.selected_index = TEXTURE_SIZES.index(s.texture_size)
        names = self.builtin_garments()
        if s.garment in names:
            v.garment_combo.selected_index = names.index(s.garment)

    def show_mannequin(self) -> None:
        """Show the rest body at once (before any garment is ready), framed by the camera."""
        shape = self.studio.settings.body_shape()

        def job():
            b = make_body(shape)
            return b.vertices, b.faces

        def done(out) -> None:
            bv, bf = out
            if self.garment is None:
                self.view.set_mesh("rest_body", bv, bf, COLOURS["body"])
                self.view.frame_camera(bv.min(0) - 0.1, bv.max(0) + 0.1)
                self.studio.player.apply_visibility()
            self.body_shown_s = process_age()

        self.studio.proxy_worker.submit(job, done, self.studio.show_error, key="mannequin")

    def load_garment(self, name_or_path: str, resolution_mm: float | None = None) -> None:
        """Load a built-in garment by name or a mesh file, show it and derive its proxy."""
        studio = self.studio
        name = str(name_or_path)
        res = resolution_mm or studio.settings.garment_resolution_mm
        self.set(garment=name, garment_resolution_mm=res)
        body = studio.settings.body_shape()
        builtin = not Path(name).suffix
        what = f"generating {name} (first time; cached after)" if builtin else f"loading {name}"
        self.loading = (what, time.perf_counter())
        self.view.status.text = f"{what} ..."

        def job():
            from_cache = None
            if not builtin:
                mesh, _ = load_mesh(name)
            else:
                try:
                    mesh, from_cache = cached_builtin_garment(name, res, body, make_garment)
                except (KeyError, ValueError) as exc:
                    raise InputError(f"garment {name!r}: {exc}") from None
            b = make_body(body)
            return mesh, (b.vertices, b.faces), from_cache

        def failed(exc: BaseException) -> None:
            self.loading = None
            studio.show_error(exc)

        studio.proxy_worker.submit(job, self._garment_loaded, failed, key="garment")

    def _garment_loaded(self, result) -> None:
        mesh, (bv, bf), self.garment_from_cache = result
        self.loading = None
        self.garment_shown_s = self.garment_shown_s or process_age()
        self.garment = mesh
        self._garment_id += 1
        self.garment_name = self.studio.settings.garment
        v = self.view
        v.garment_label.text = (
            f"{Path(self.garment_name).name}: {mesh.num_vertices} vertices, {mesh.num_faces} faces"
        )
        self.studio.player.enter_mode("garment")
        v.set_mesh("target", mesh.vertices, mesh.faces, COLOURS["target"])
        v.set_lines("target_wire", mesh.vertices, unique_edges(mesh.faces), COLOURS["target_wire"])
        v.set_mesh("rest_body", bv, bf, COLOURS["body"])
        self.studio.player.apply_visibility()
        self.frame_view()
        v.status.text = f"loaded {Path(self.garment_name).name}"
        self.derive_proxy()

    def frame_view(self) -> None:
        """Frame the loaded garment (or, before one is loaded, nothing changes)."""
        if self.garment is not None:
            lo, hi = self.garment.vertices.min(0), self.garment.vertices.max(0)
            self.view.frame_camera(lo - 0.1, hi + 0.1)

    def proxy_config(self) -> ProxyConfig:
        s = self.studio.settings
        return ProxyConfig(
            target_verts=int(s.proxy_verts),
            detail_scale=float(s.detail_scale),
            texture_size=int(s.texture_size),
        )

    def derive_proxy(self, target_verts=None, detail_scale=None, texture_size=None) -> None:
        """Derive (or update) the proxy of the loaded garment in the proxy worker. Only what a
        change affects re-runs: the texture size alone redoes the atlas, not the surface."""
        studio = self.studio
        changes = {}
        if target_verts is not None:
            changes["proxy_verts"] = int(target_verts)
        if detail_scale is not None:
            changes["detail_scale"] = float(detail_scale)
        if texture_size is not None:
            changes["texture_size"] = int(texture_size)
        self.set(**changes)
        v = self.view
        v.verts_slider.int_value = studio.settings.proxy_verts
        v.detail_slider.double_value = studio.settings.detail_scale
        if studio.settings.texture_size in TEXTURE_SIZES:
            v.texture_combo.selected_index = TEXTURE_SIZES.index(studio.settings.texture_size)
        if self.garment is None:
            return
        try:
            cfg = self.proxy_config()
        except InputError as exc:
            studio.show_error(exc)
            return
        mesh, gid = self.garment, self._garment_id
        path = self.garment_name if Path(self.garment_name).suffix else None
        v.status.text = "deriving the proxy ..."

        def job():
            prev = self._proxy_cache
            plan = "full" if prev is None or prev[0] != gid else proxy_plan(prev[1], cfg)
            if plan == "none":
                result = prev[2]
            elif plan == "atlas":
                result = reatlas(prev[2], cfg.texture_size, cfg.padding)
            else:
                result = derive_proxy(mesh, cfg, path=path)
            self._proxy_cache = (gid, cfg, result)
            image = atlas_image(result.proxy.uvs, result.proxy.faces, 160)
            return plan, result, image

        studio.proxy_worker.submit(job, self._proxy_done, studio.show_error, key="proxy")

    def _proxy_done(self, out) -> None:
        plan, result, image = out
        self.proxy_result = result
        self.proxy_plan_ran = plan
        v = self.view
        pos = result.positions
        v.set_lines("proxy_wire", pos.vertices, unique_edges(pos.faces), COLOURS["proxy_wire"])
        v.set_image(v.atlas_image, image)
        rows = proxy_summary(result.report)
        ran = {"full": "whole derivation", "atlas": "UV atlas only", "none": "nothing"}[plan]
        v.report_label.text = "\n".join(f"{k}: {val}" for k, val in rows) + f"\nre-ran: {ran}"
        v.window.set_needs_layout()
        self.studio.player.apply_visibility()
        v.status.text = f"proxy: {result.proxy.num_vertices} vertices ({ran})"

    def apply_proxy_to_project(self) -> None:
        """Write the garment and proxy settings into the project's pipeline settings and run
        the garment and proxy stages (downstream stages then see their inputs changed)."""
        studio = self.studio
        if studio.project is None:
            studio.show_error(InputError("open a project first (Motion tab)"))
            return
        project = Project(studio.project)
        s = studio.settings
        config = replace(
            project_config(project),
            garment=s.garment,
            garment_resolution_mm=None if Path(s.garment).suffix else s.garment_resolution_mm,
            proxy_verts=s.proxy_verts,
            proxy_texture=s.texture_size,
        )
        data = project.settings()
        data["pipeline"] = config.as_params()
        project.save_settings(data)
        studio.pipeline_tab.run_pipeline("setup")
