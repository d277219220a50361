"""The studio window (the view): widgets and the 3D scene, nothing else.

Every method here runs on the main thread. The controllers (:mod:`app.gui.controller`'s
``Studio`` and its parts: :class:`app.gui.player.Player` for the main area, the timeline and the
live render, :mod:`app.gui.tabs` for the tabs) call the ``show_*`` / ``set_*`` methods; each
widget's action calls the part it belongs to. Layout::

    +--------------------------------------+---------------------------+
    |                                      | live: neural | reference  |
    |          3D view (SceneWidget)       | frame time, fps           |
    |                                      +---------------------------+
    |                                      | tabs: Garment | Motion |  |
    +--------------------------------------+   Pipeline | Export      |
    | > play  [=======timeline=======] 12  |                           |
    +--------------------------------------+---------------------------+
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import open3d.visualization.gui as gui
import open3d.visualization.rendering as rendering

from app.gui.backend import selected_backend
from app.gui.model import (
    DETAIL_SCALE_RANGE,
    PLAY_SPEEDS,
    PROXY_VERTS_RANGE,
    RENDER_SIZES,
    TEXTURE_SIZES,
    VIEW_MODES,
    checker_texture,
)

#: Width of the right-hand panel, in font heights.
PANEL_EM = 30
#: NEAR_FAR_NOTE: a hand-set projection (near 0.05 m, far 100 m) made frames take tens of
#: seconds under Mesa's software Vulkan (lavapipe); Filament queued them and the window froze at
#: its next ImGui buffer resize. Cameras are therefore set through ``setup_camera``.
#: Colours (RGBA) of the scene's parts.
COLOURS = {
    "target": (0.78, 0.74, 0.70, 1.0),
    "target_wire": (0.25, 0.25, 0.25, 1.0),
    "proxy_wire": (0.95, 0.45, 0.05, 1.0),
    "body": (0.80, 0.66, 0.58, 1.0),
    "sim_wire": (0.85, 0.10, 0.10, 1.0),
    "j2c": (0.30, 0.55, 0.85, 1.0),
}


def _texture(arr: np.ndarray) -> o3d.geometry.Image:
    """(H, W, 3+) uint8 -> an Open3D image (a material's texture)."""
    return o3d.geometry.Image(np.ascontiguousarray(np.asarray(arr, np.uint8)[..., :3]))


def _image(arr: np.ndarray) -> o3d.geometry.Image:
    """(H, W, 3+) uint8 -> an Open3D image for an ``ImageWidget``. On Filament's OpenGL
    backend Open3D 0.20's ``ImageWidget`` shows its image upside down (not on Vulkan; the 3D
    view and materials' textures are upright on both): the rows are flipped there."""
    rgb = np.asarray(arr, np.uint8)
    return _texture(rgb[::-1] if selected_backend() == "opengl" else rgb)


def _label_row(text: str, widget, em: float) -> gui.Horiz:
    row = gui.Horiz(0.25 * em)
    row.add_child(gui.Label(text))
    row.add_child(widget)
    return row


class StudioWindow:
    """Widgets of the studio; ``studio`` (:class:`app.gui.controller.Studio`) and its parts
    receive the user's actions."""

    def __init__(self, studio, width: int = 1500, height: int = 940):
        self.studio = studio
        player = studio.player
        app = gui.Application.instance
        self.window = app.create_window("Garment studio", width, height)
        w = self.window
        em = w.theme.font_size
        self.em = em
        self._checker = _texture(checker_texture(256))
        self._geometry: set[str] = set()

        # 3D view
        self.scene = gui.SceneWidget()
        self.scene.scene = rendering.Open3DScene(w.renderer)
        self.scene.scene.set_background((1.0, 1.0, 1.0, 1.0))
        self.scene.scene.show_axes(False)
        # Software rendering (Mesa lavapipe) is what the studio must survive: no tone-mapping,
        # bloom or anti-aliasing passes (they cost more than the meshes and have stalled
        # Filament's render thread for minutes).
        view = self.scene.scene.view
        view.set_post_processing(False)
        # Filament's defaults render every fragment several times: a redraw plus a read-back
        # of this view took 1.8-2.2 s on lavapipe, 0.63 s with one sample, no ambient
        # occlusion and no shadow maps (docs/gui.md).
        view.set_sample_count(1)
        view.set_antialiasing(False, False)
        view.set_ambient_occlusion(False, False)
        view.set_shadowing(False, rendering.View.ShadowType.PCF)
        self.scene.scene.set_lighting(
            rendering.Open3DScene.LightingProfile.NO_SHADOWS, (0.3, -0.8, -0.5)
        )
        # Scene caching: a window redraw re-renders the 3D view only after :meth:`scene_changed`,
        # so a redraw for a label or an image costs no 3D frame.
        self.scene.enable_scene_caching(True)
        #: The 3D view changed since the last :meth:`redraw` (the studio paces such redraws).
        self.scene_dirty = True
        w.add_child(self.scene)

        # the neural viewport: the same place as the 3D view (one of them is shown); the
        # image is upscaled to the widget, the last one stays until the next replaces it
        self.neural = gui.ImageWidget(_image(np.full((128, 128, 3), 255, np.uint8)))
        self.neural.set_on_mouse(self._on_neural_mouse)
        self.neural.visible = False
        w.add_child(self.neural)
        self.neural_stats = gui.Label("neural view: open a trained project")
        self.neural_stats.visible = False
        w.add_child(self.neural_stats)
        self.view_mode = "scene"
        self.main_size = (width - int(PANEL_EM * self.em), height)
        self._drag_at: tuple[float, float] | None = None

        # timeline under the 3D view
        self.timeline = gui.Horiz(0.5 * em, gui.Margins(0.5 * em, 0.25 * em, 0.5 * em, 0.25 * em))
        self.play_button = gui.Button("Play")
        self.play_button.horizontal_padding_em = 0.8
        self.play_button.set_on_clicked(player.toggle_play)
        self.frame_slider = gui.Slider(gui.Slider.INT)
        self.frame_slider.set_limits(0, 1)
        self.frame_slider.set_on_value_changed(lambda v: player.seek(int(v)))
        self.frame_label = gui.Label("frame 0 / 0   0.00 s")
        self.mode_combo = gui.Combobox()
        for label, _mode in VIEW_MODES:
            self.mode_combo.add_item(label)
        self.mode_combo.set_on_selection_changed(
            lambda _t, i: player.set_view_mode(VIEW_MODES[i][1])
        )
        self.mode_combo.selected_index = [m for _l, m in VIEW_MODES].index("scene")
        self.speed_combo = gui.Combobox()
        for sp in PLAY_SPEEDS:
            self.speed_combo.add_item(f"{sp:g}x")
        self.speed_combo.selected_index = PLAY_SPEEDS.index(1.0)
        self.speed_combo.set_on_selection_changed(
            lambda _t, i: player.set_play_speed(PLAY_SPEEDS[i])
        )
        self.loop_check = gui.Checkbox("loop")
        self.loop_check.checked = True
        self.loop_check.set_on_checked(player.set_loop)
        self.reset_button = gui.Button("Reset view")
        self.reset_button.horizontal_padding_em = 0.4
        self.reset_button.set_on_clicked(player.reset_view)
        self.timeline.add_child(self.mode_combo)
        self.timeline.add_child(self.play_button)
        self.timeline.add_child(self.frame_slider)
        self.timeline.add_child(self.frame_label)
        self.timeline.add_child(self.speed_combo)
        self.timeline.add_child(self.loop_check)
        self.timeline.add_child(self.reset_button)
        w.add_child(self.timeline)

        # right panel
        self.panel = gui.Vert(0.4 * em, gui.Margins(0.5 * em, 0.5 * em, 0.5 * em, 0.5 * em))
        live_title = gui.Horiz(0.5 * em)
        live_title.add_child(gui.Label("Live neural render"))
        self.live_check = gui.Checkbox("on")
        self.live_check.set_on_checked(player.set_live_render)
        live_title.add_child(self.live_check)
        self.gt_check = gui.Checkbox("reference")
        self.gt_check.set_on_checked(player.set_show_ground_truth)
        live_title.add_child(self.gt_check)
        self.size_combo = gui.Combobox()
        for s in RENDER_SIZES:
            self.size_combo.add_item(f"{s} px")
        self.size_combo.set_on_selection_changed(
            lambda _t, i: player.set_render_size(RENDER_SIZES[i])
        )
        live_title.add_child(self.size_combo)
        self.panel.add_child(live_title)
        self.live_image = gui.ImageWidget(_image(np.full((128, 260, 3), 235, np.uint8)))
        self.panel.add_child(self.live_image)
        self.live_label = gui.Label("neural | reference: open a trained project")
        self.panel.add_child(self.live_label)

        self.tabs = gui.TabControl()
        self.tabs.add_tab("Garment", self._garment_tab(em))
        self.tabs.add_tab("Motion", self._motion_tab(em))
        self.tabs.add_tab("Pipeline", self._pipeline_tab(em))
        self.tabs.add_tab("Export", self._export_tab(em))
        self.panel.add_child(self.tabs)
        self.status = gui.Label("ready")
        self.panel.add_child(self.status)
        w.add_child(self.panel)

        w.set_on_layout(self._on_layout)
        w.set_on_key(self._on_key)
        w.set_on_close(studio.on_close)

    # -- tabs ------------------------------------------------------------------------------

    def _garment_tab(self, em: float):
        c, player = self.studio.garment_tab, self.studio.player
        tab = gui.Vert(0.35 * em, gui.Margins(0.3 * em, 0.3 * em, 0.3 * em, 0.3 * em))
        row = gui.Horiz(0.3 * em)
        self.garment_combo = gui.Combobox()
        for name in c.builtin_garments():
            self.garment_combo.add_item(name)
        self.garment_combo.set_on_selection_changed(lambda t, _i: c.load_garment(t))
        row.add_child(self.garment_combo)
        open_button = gui.Button("Open mesh...")
        open_button.set_on_clicked(self._open_mesh_dialog)
        row.add_child(open_button)
        tab.add_child(row)
        self.garment_label = gui.Label("no garment")
        tab.add_child(self.garment_label)

        row = gui.Horiz(0.3 * em)
        self.show_target = gui.Checkbox("shaded")
        self.show_target.set_on_checked(lambda v: player.set_visibility(show_target=v))
        self.show_wire = gui.Checkbox("wireframe")
        self.show_wire.set_on_checked(lambda v: player.set_visibility(show_wireframe=v))
        self.show_proxy = gui.Checkbox("proxy")
        self.show_proxy.set_on_checked(lambda v: player.set_visibility(show_proxy=v))
        self.show_body = gui.Checkbox("body")
        self.show_body.set_on_checked(lambda v: player.set_visibility(show_body=v))
        for wdg in (self.show_target, self.show_wire, self.show_proxy, self.show_body):
            row.add_child(wdg)
        tab.add_child(row)

        tab.add_child(gui.Label("Proxy"))
        self.verts_slider = gui.Slider(gui.Slider.INT)
        self.verts_slider.set_limits(*PROXY_VERTS_RANGE)
        self.verts_slider.set_on_value_changed(lambda v: c.derive_proxy(target_verts=int(v)))
        tab.add_child(_label_row("target vertices", self.verts_slider, em))
        self.detail_slider = gui.Slider(gui.Slider.DOUBLE)
        self.detail_slider.set_limits(*DETAIL_SCALE_RANGE)
        self.detail_slider.set_on_value_changed(lambda v: c.derive_proxy(detail_scale=float(v)))
        tab.add_child(_label_row("detail scale (m)", self.detail_slider, em))
        self.texture_combo = gui.Combobox()
        for s in TEXTURE_SIZES:
            self.texture_combo.add_item(str(s))
        self.texture_combo.set_on_selection_changed(
            lambda _t, i: c.derive_proxy(texture_size=TEXTURE_SIZES[i])
        )
        tab.add_child(_label_row("texture size", self.texture_combo, em))
        row = gui.Horiz(0.5 * em)
        self.atlas_image = gui.ImageWidget(_image(np.full((160, 160, 3), 40, np.uint8)))
        row.add_child(self.atlas_image)
        self.report_label = gui.Label("\n".join(["derive a proxy to see its report"] + [""] * 8))
        row.add_child(self.report_label)
        row.add_stretch()
        tab.add_child(row)
        use = gui.Button("Use this proxy for the project")
        use.set_on_clicked(c.apply_proxy_to_project)
        tab.add_child(use)
        return tab

    def _motion_tab(self, em: float):
        c, player = self.studio.motion_tab, self.studio.player
        tab = gui.Vert(0.35 * em, gui.Margins(0.3 * em, 0.3 * em, 0.3 * em, 0.3 * em))
        row = gui.Horiz(0.3 * em)
        open_project = gui.Button("Open project...")
        open_project.set_on_clicked(self._open_project_dialog)
        row.add_child(open_project)
        self.project_label = gui.Label("no project")
        row.add_child(self.project_label)
        tab.add_child(row)
        row = gui.Horiz(0.3 * em)
        self.motion_combo = gui.Combobox()
        self.motion_combo.set_on_selection_changed(lambda t, _i: c.load_motion(t))
        row.add_child(self.motion_combo)
        bvh = gui.Button("BVH...")
        bvh.set_on_clicked(self._open_bvh_dialog)
        row.add_child(bvh)
        tab.add_child(row)
        self.motion_frames = gui.Slider(gui.Slider.INT)
        self.motion_frames.set_limits(10, 600)
        self.motion_frames.set_on_value_changed(lambda v: c.set_motion_frames(int(v)))
        tab.add_child(_label_row("procedural frames", self.motion_frames, em))
        self.motion_label = gui.Label("no motion")
        tab.add_child(self.motion_label)
        self.show_sim = gui.Checkbox("simulated proxy (red wireframe) beside Joint2Coarse")
        self.show_sim.set_on_checked(lambda v: player.set_visibility(show_sim=v))
        tab.add_child(self.show_sim)

        tab.add_child(gui.Label("Body"))
        row = gui.Horiz(0.3 * em)
        self.body_combo = gui.Combobox()
        self.body_combo.set_on_selection_changed(lambda t, _i: c.select_body(t))
        row.add_child(self.body_combo)
        tab.add_child(_label_row("play on", row, em))
        self.body_sliders = {}
        for name, lo, hi in (("height", 1.4, 2.0), ("hip", 0.8, 1.3), ("build", -1.0, 1.0)):
            s = gui.Slider(gui.Slider.DOUBLE)
            s.set_limits(lo, hi)
            s.set_on_value_changed(lambda v, n=name: c.set_body_param(n, float(v)))
            self.body_sliders[name] = s
            tab.add_child(_label_row(name, s, em))
        ft = gui.Button("Fine-tune renderer to this body")
        ft.set_on_clicked(c.finetune_body)
        tab.add_child(ft)
        bg = gui.Button("Fine-tune to a background image...")
        bg.set_on_clicked(self._open_background_dialog)
        tab.add_child(bg)
        row = gui.Horiz(0.3 * em)
        self.light_combo = gui.Combobox()
        for item in c.light_items:
            self.light_combo.add_item(item)
        self.light_combo.set_on_selection_changed(lambda _t, i: self._pick_light(i))
        row.add_child(self.light_combo)
        relight = gui.Button("Fine-tune to this light")
        relight.horizontal_padding_em = 0.4
        relight.set_on_clicked(c.finetune_light)
        row.add_child(relight)
        cancel = gui.Button("Cancel")
        cancel.horizontal_padding_em = 0.4
        cancel.set_on_clicked(c.cancel_finetune)
        row.add_child(cancel)
        tab.add_child(_label_row("light", row, em))
        self.finetune_label = gui.Label("")
        tab.add_child(self.finetune_label)
        return tab

    def _pipeline_tab(self, em: float):
        c = self.studio.pipeline_tab
        tab = gui.Vert(0.35 * em, gui.Margins(0.3 * em, 0.3 * em, 0.3 * em, 0.3 * em))
        row = gui.Horiz(0.3 * em)
        for label, which in (
            ("Simulate", "simulate"),
            ("Build data", "dataset"),
            ("Joint2Coarse", "joint2coarse"),
            ("Renderer", "renderer"),
            ("All", "all"),
        ):
            b = gui.Button(label)
            b.horizontal_padding_em = 0.4
            b.set_on_clicked(lambda w=which: c.run_pipeline(w))
            row.add_child(b)
        tab.add_child(row)
        row = gui.Horiz(0.3 * em)
        self.progress = gui.ProgressBar()
        row.add_child(self.progress)
        cancel = gui.Button("Cancel")
        cancel.set_on_clicked(c.cancel)
        row.add_child(cancel)
        tab.add_child(row)
        self.job_label = gui.Label("idle")
        tab.add_child(self.job_label)
        self.log_label = gui.Label("")
        tab.add_child(self.log_label)
        row = gui.Horiz(0.3 * em)
        self.loss_image = gui.ImageWidget(_image(np.full((120, 200, 3), 245, np.uint8)))
        self.preview_image = gui.ImageWidget(_image(np.full((120, 200, 3), 245, np.uint8)))
        row.add_child(self.loss_image)
        row.add_child(self.preview_image)
        tab.add_child(row)
        return tab

    def _export_tab(self, em: float):
        c = self.studio.export_tab
        tab = gui.Vert(0.35 * em, gui.Margins(0.3 * em, 0.3 * em, 0.3 * em, 0.3 * em))
        row = gui.Horiz(0.3 * em)
        add = gui.Button("Add view to path")
        add.set_on_clicked(c.add_path_key)
        clear = gui.Button("Clear path")
        clear.set_on_clicked(c.clear_path)
        row.add_child(add)
        row.add_child(clear)
        tab.add_child(row)
        self.path_label = gui.Label("camera path: orbit (no key views)")
        tab.add_child(self.path_label)
        row = gui.Horiz(0.3 * em)
        save_path = gui.Button("Save path JSON...")
        save_path.set_on_clicked(
            lambda: self._save_dialog("camera path", ".json", c.save_camera_path)
        )
        self.export_reference = gui.Checkbox("reference beside")
        self.export_reference.set_on_checked(c.set_export_reference)
        row.add_child(save_path)
        row.add_child(self.export_reference)
        tab.add_child(row)
        self.export_frames = gui.Slider(gui.Slider.INT)
        self.export_frames.set_limits(2, 240)
        self.export_frames.set_on_value_changed(lambda v: c.set_export_frames(int(v)))
        tab.add_child(_label_row("frames", self.export_frames, em))
        row = gui.Horiz(0.3 * em)
        mp4 = gui.Button("Export MP4...")
        mp4.set_on_clicked(lambda: self._save_dialog("MP4", ".mp4", c.export_video))
        gif = gui.Button("GIF...")
        gif.set_on_clicked(lambda: self._save_dialog("GIF", ".gif", c.export_gif))
        obj = gui.Button("Export proxy OBJ...")
        obj.set_on_clicked(lambda: self._save_dialog("OBJ", ".obj", c.export_proxy))
        save = gui.Button("Save settings")
        save.set_on_clicked(self.studio.save_settings)
        row.add_child(mp4)
        row.add_child(gif)
        row.add_child(obj)
        row.add_child(save)
        tab.add_child(row)
        row = gui.Horiz(0.3 * em)
        self.export_progress = gui.ProgressBar()
        row.add_child(self.export_progress)
        stop = gui.Button("Cancel export")
        stop.set_on_clicked(c.cancel_export)
        row.add_child(stop)
        tab.add_child(row)
        self.export_label = gui.Label("")
        tab.add_child(self.export_label)
        tab.add_child(
            gui.Label(
                "keys: space play/pause, left/right step a frame,\nhome first frame, "
                "r reset the view; "
                "drag the neural view: orbit,\nright/shift drag pan, ctrl drag/wheel zoom"
            )
        )
        return tab

    # -- layout and keys ---------------------------------------------------------------------

    def _on_layout(self, ctx) -> None:
        r = self.window.content_rect
        panel_w = int(PANEL_EM * self.em)
        bar_h = int(2.2 * self.em)
        left_w = r.width - panel_w
        main = gui.Rect(r.x, r.y, left_w, r.height - bar_h)
        self.main_size = (main.width, main.height)
        # While the neural image fills the main area the 3D view shrinks to one pixel under
        # it. Hiding the SceneWidget, or drawing the image over a full-size one, froze software
        # Vulkan (Filament waiting in SyncThreads, llvmpipe spinning) within seconds.
        neural = self.view_mode != "scene"
        self.scene.frame = gui.Rect(r.x, r.y, 1, 1) if neural else main
        self.neural.frame = main
        self.neural_stats.frame = gui.Rect(
            r.x + 4, r.y + 4, min(left_w - 8, int(34 * self.em)), int(1.6 * self.em)
        )
        self.timeline.frame = gui.Rect(r.x, r.y + r.height - bar_h, left_w, bar_h)
        self.panel.frame = gui.Rect(r.x + left_w, r.y, panel_w, r.height)

    def show_view_mode(self, mode: str) -> None:
        """Show the 3D view (``scene``) or the neural image (``neural``, ``compare``) in the
        main area; the hidden one is not drawn."""
        if mode == self.view_mode:
            return  # no relayout: every one is a chance for the software-Vulkan freeze
        self.view_mode = mode
        neural = mode != "scene"
        self.neural.visible = neural
        self.neural_stats.visible = neural
        modes = [m for _label, m in VIEW_MODES]
        if mode in modes:
            self.mode_combo.selected_index = modes.index(mode)
        self.window.set_needs_layout()
        self.window.post_redraw()

    def _on_neural_mouse(self, event) -> object:
        """Drags on the neural image move the camera that renders it: left orbits, right or
        shift+left pans, ctrl+left or the wheel zooms (as in the 3D view)."""
        t = gui.MouseEvent.Type
        if event.type == t.BUTTON_DOWN:
            self._drag_at = (event.x, event.y)
        elif event.type == t.DRAG and self._drag_at is not None:
            dx, dy = event.x - self._drag_at[0], event.y - self._drag_at[1]
            self._drag_at = (event.x, event.y)
            if event.is_modifier_down(gui.KeyModifier.CTRL):
                self.studio.player.neural_zoom(dy / 100.0)
            elif event.is_button_down(gui.MouseButton.RIGHT) or event.is_modifier_down(
                gui.KeyModifier.SHIFT
            ):
                self.studio.player.neural_drag(dx, dy, pan=True)
            else:
                self.studio.player.neural_drag(dx, dy)
        elif event.type == t.BUTTON_UP:
            self._drag_at = None
        elif event.type == t.WHEEL:
            self.studio.player.neural_zoom(event.wheel_dy)
        else:
            return gui.Widget.EventCallbackResult.IGNORED
        return gui.Widget.EventCallbackResult.CONSUMED

    def _on_key(self, event) -> bool:
        """Window-level keys (before the focused widget): True consumes the key."""
        if event.type != gui.KeyEvent.Type.DOWN:
            return False
        actions = {
            gui.KeyName.SPACE: self.studio.player.toggle_play,
            gui.KeyName.RIGHT: lambda: self.studio.player.step(1),
            gui.KeyName.LEFT: lambda: self.studio.player.step(-1),
            gui.KeyName.HOME: lambda: self.studio.player.seek(0),
            gui.KeyName.R: self.studio.player.reset_view,
        }
        action = actions.get(event.key)
        if action is None:
            return False
        action()
        return True

    # -- dialogs -----------------------------------------------------------------------------

    def _file_dialog(self, mode, title: str, filters, on_done, on_cancel=None) -> None:
        dlg = gui.FileDialog(mode, title, self.window.theme)
        for ext, label in filters:
            dlg.add_filter(ext, label)

        def cancelled() -> None:
            self.window.close_dialog()
            if on_cancel is not None:
                on_cancel()

        dlg.set_on_cancel(cancelled)

        def done(path: str) -> None:
            self.window.close_dialog()
            on_done(path)

        dlg.set_on_done(done)
        self.window.show_dialog(dlg)

    def _open_mesh_dialog(self) -> None:
        self._file_dialog(
            gui.FileDialog.OPEN,
            "Open a detailed garment",
            [(".obj .ply .glb .gltf .off .stl", "meshes"), ("", "all files")],
            self.studio.garment_tab.load_garment,
        )

    def _open_bvh_dialog(self) -> None:
        self._file_dialog(
            gui.FileDialog.OPEN,
            "Open a motion",
            [(".bvh .glb .gltf .txt .json", "motion (BVH, glTF, DeepMimic)")],
            self.studio.motion_tab.load_motion,
        )

    def _open_project_dialog(self) -> None:
        self._file_dialog(
            gui.FileDialog.OPEN_DIR,
            "Open a project folder",
            [],
            self.studio.motion_tab.open_project,
        )

    def _open_background_dialog(self) -> None:
        self._file_dialog(
            gui.FileDialog.OPEN,
            "Background image",
            [(".png .jpg .jpeg", "images")],
            self.studio.motion_tab.finetune_background,
        )

    def _pick_light(self, index: int) -> None:
        """The light picker: a preset or an environment image picked before, or the last
        item, a file dialog for a new environment image (cancelled: the choice stays)."""
        c = self.studio.motion_tab
        spec = c.light_specs[index]
        if spec is not None:
            c.set_light(spec)
            return
        self._file_dialog(
            gui.FileDialog.OPEN,
            "Environment image (equirectangular)",
            [(".hdr .exr .png .jpg .jpeg", "environment images"), ("", "all files")],
            c.set_light,
            on_cancel=c.fill_light_list,
        )

    def _save_dialog(self, what: str, ext: str, on_done) -> None:
        self._file_dialog(gui.FileDialog.SAVE, f"Export {what}", [(ext, what)], on_done)

    def show_error(self, title: str, message: str) -> None:
        """A modal dialog naming the problem; the window stays usable after OK."""
        em = self.em
        dlg = gui.Dialog(title)
        box = gui.Vert(0.5 * em, gui.Margins(em, em, em, em))
        box.add_child(gui.Label(message))
        ok = gui.Button("OK")
        ok.set_on_clicked(self.window.close_dialog)
        row = gui.Horiz()
        row.add_stretch()
        row.add_child(ok)
        box.add_child(row)
        dlg.add_child(box)
        self.window.show_dialog(dlg)

    def close_dialog(self) -> None:
        self.window.close_dialog()

    # -- scene -------------------------------------------------------------------------------

    def set_mesh(
        self,
        name: str,
        vertices: np.ndarray,
        faces: np.ndarray,
        colour=None,
        uvs: np.ndarray | None = None,
        visible: bool = True,
    ) -> None:
        """Add or replace a shaded triangle mesh; ``uvs`` (V, 2) textures it with the checker."""
        mesh = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(np.asarray(vertices, np.float64)),
            o3d.utility.Vector3iVector(np.asarray(faces, np.int32)),
        )
        mesh.compute_vertex_normals()
        mat = rendering.MaterialRecord()
        mat.shader = "defaultLit"
        if uvs is not None:
            uv = np.asarray(uvs, np.float64)[np.asarray(faces, np.int64)].reshape(-1, 2)
            uv[:, 1] = 1.0 - uv[:, 1]  # OBJ v up -> image rows down
            mesh.triangle_uvs = o3d.utility.Vector2dVector(uv)
            mesh.triangle_material_ids = o3d.utility.IntVector(np.zeros(len(faces), np.int32))
            mat.albedo_img = self._checker
            mat.base_color = (1.0, 1.0, 1.0, 1.0)
        else:
            mat.base_color = colour or (0.8, 0.8, 0.8, 1.0)
        self._replace(name, mesh, mat, visible)

    def set_lines(
        self, name: str, vertices: np.ndarray, edges: np.ndarray, colour, visible: bool = True
    ) -> None:
        """Add or replace a wireframe: one-pixel lines in ``colour`` (RGBA)."""
        lines = o3d.geometry.LineSet(
            o3d.utility.Vector3dVector(np.asarray(vertices, np.float64)),
            o3d.utility.Vector2iVector(np.asarray(edges, np.int32)),
        )
        lines.paint_uniform_color(np.asarray(colour[:3], np.float64))
        # Plain one-pixel lines, not Open3D's wide-line shader ("unlitLine"): a LineSet in
        # that shader replaced every play frame stalled lavapipe for 5-230 s within seconds of
        # playing (a bisection of the playback scene; docs/gui.md).
        mat = rendering.MaterialRecord()
        mat.shader = "defaultUnlit"
        self._replace(name, lines, mat, visible)

    def _replace(self, name: str, geometry, material, visible: bool) -> None:
        scene = self.scene.scene
        if name in self._geometry:
            scene.remove_geometry(name)
        scene.add_geometry(name, geometry, material)
        scene.show_geometry(name, visible)
        self._geometry.add(name)
        self.scene_changed()

    def remove(self, name: str) -> None:
        if name in self._geometry:
            self.scene.scene.remove_geometry(name)
            self._geometry.discard(name)
            self.scene_changed()

    def show(self, name: str, visible: bool) -> None:
        if name in self._geometry:
            self.scene.scene.show_geometry(name, visible)
            self.scene_changed()

    def scene_changed(self) -> None:
        """The 3D view's content or camera changed: its next window redraw renders it anew
        (scene caching keeps the last 3D frame otherwise)."""
        self.scene.force_redraw()
        self.scene_dirty = True

    def has(self, name: str) -> bool:
        return name in self._geometry

    def frame_camera(self, lo: np.ndarray, hi: np.ndarray, fov: float = 40.0) -> None:
        box = o3d.geometry.AxisAlignedBoundingBox(np.asarray(lo, float), np.asarray(hi, float))
        self.scene.setup_camera(fov, box, box.get_center())
        self.scene_changed()

    def look_at(self, eye, target, up, fov: float) -> None:
        # The projection comes from setup_camera (Open3D's own near/far for a box around the
        # target and the eye), never from a hand-made set_projection: see NEAR_FAR_NOTE.
        eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
        r = max(float(np.linalg.norm(eye - target)), 0.5)
        box = o3d.geometry.AxisAlignedBoundingBox(target - r, target + r)
        self.scene.setup_camera(float(fov), box, target.astype(np.float32))
        self.scene.look_at(target.astype(np.float32), eye.astype(np.float32), up)
        self.scene.center_of_rotation = target.astype(np.float32)
        self.scene_changed()

    def gl_matrices(self) -> tuple[np.ndarray, np.ndarray, float]:
        """The 3D view camera's (view, projection, vertical fov)."""
        cam = self.scene.scene.camera
        return (
            np.asarray(cam.get_view_matrix(), np.float64),
            np.asarray(cam.get_projection_matrix(), np.float64),
            float(cam.get_field_of_view()),
        )

    # -- widgets -----------------------------------------------------------------------------

    def set_image(self, widget: gui.ImageWidget, arr: np.ndarray) -> None:
        widget.update_image(_image(arr))

    def set_frame(self, t: int, n: int, fps: float = 30.0) -> None:
        self.frame_slider.set_limits(0, max(n - 1, 1))
        self.frame_slider.int_value = int(t)
        self.frame_label.text = f"frame {t} / {max(n - 1, 0)}   {t / max(fps, 1e-6):.2f} s"

    def set_playing(self, playing: bool) -> None:
        self.play_button.text = "Pause" if playing else "Play"

    def redraw(self) -> None:
        """Ask Open3D to draw the window at its next tick (the 3D view too if it changed)."""
        self.scene_dirty = False
        self.window.post_redraw()
