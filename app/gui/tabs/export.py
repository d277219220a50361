"""The Export tab's controller: a camera path keyed on frames (saved with the project and as
JSON for ``dng render --camera``), MP4 / GIF export of neural renders along it on the
``playback`` worker (``pipeline.playback.FrameWriter``: atomic, cancellable), the proxy as
OBJ."""

from __future__ import annotations

from pathlib import Path

from app.gui.model import Cancelled, Eta, format_seconds, side_by_side
from app.gui.part import Part
from app.gui.workers import CancelToken
from core.camera import camera_path_to_dict, path_cameras
from core.errors import InputError
from core.fileio import write_json
from core.mesh import save_mesh
from pipeline.playback import FrameWriter


class ExportTab(Part):
    """Camera path and exports; ``studio`` is the :class:`app.gui.controller.Studio` it
    belongs to (the frame and camera come from its player)."""

    def __init__(self, studio):
        super().__init__(studio)
        self.export_token: CancelToken | None = None

    def apply_settings(self) -> None:
        """Put the settings into the tab's widgets."""
        s, v = self.studio.settings, self.view
        v.export_frames.int_value = s.export_frames
        v.export_reference.checked = s.export_reference
        self.update_path_label()

    # ------------------------------------------------------------------ the camera path

    def add_path_key(self) -> None:
        """Key the 3D view's camera at the current frame (a key already there is replaced)."""
        player = self.studio.player
        key = {**player.current_pose().as_dict(), "frame": int(player.frame)}
        keys = [k for k in self.studio.settings.camera_path if k.get("frame") != key["frame"]]
        self.set(camera_path=sorted([*keys, key], key=lambda k: k.get("frame", 0)))
        self.update_path_label()

    def clear_path(self) -> None:
        self.set(camera_path=[])
        self.update_path_label()

    def update_path_label(self) -> None:
        keys = self.studio.settings.path_keys()
        frames = ", ".join(f"{k.frame:g}" for k in keys)
        self.view.path_label.text = (
            f"camera path: {len(keys)} key(s) at frame(s) {frames}"
            if keys
            else "camera path: orbit (no key views)"
        )

    def set_export_frames(self, n: int) -> None:
        self.set(export_frames=int(n))

    def set_export_reference(self, on: bool) -> None:
        self.set(export_reference=bool(on))

    def save_camera_path(self, path: str) -> Path:
        """Write the keyed camera path as JSON (what ``dng render --camera PATH.json`` reads)."""
        keys = self.studio.settings.path_keys()
        if not keys:
            raise InputError("the camera path is empty: add a key view first")
        out = Path(path)
        write_json(out, camera_path_to_dict(keys))
        self.view.export_label.text = f"wrote {out}"
        return out

    # ------------------------------------------------------------------ exports

    def export_video(self, path: str, size: int | None = None) -> None:
        """Neural renders from the current frame on (``export_frames`` frames) along the keyed
        camera path (an orbit when there are no keys), the reference beside them when
        ``export_reference`` is set, written as MP4 or GIF (by the suffix) atomically. The
        export label shows progress and time left; :meth:`cancel_export` stops it and leaves
        no file."""
        studio, player, v = self.studio, self.studio.player, self.view
        if not player.num_frames:
            studio.show_error(InputError("load a motion of a trained project first"))
            return
        s = studio.settings
        n = s.export_frames
        size = size or max(s.render_size, 128)
        keys = s.path_keys()
        start, fps = player.frame, s.export_fps
        beside = s.export_reference
        out = Path(path)
        if out.suffix.lower() not in (".gif", ".mp4"):
            out = out.with_suffix(".mp4")
        frames = [(start + i) % player.num_frames for i in range(n)]
        cams = path_cameras(keys, frames, size, size) if keys else None
        token, eta = CancelToken(), Eta(1)
        self.export_token = token
        v.export_label.text = f"exporting {n} frames to {out.name} ..."

        def progress(done: int) -> None:
            eta.update(done, n)
            left = format_seconds(eta.seconds_left())
            v.export_label.text = (
                f"exporting {out.name}: {done}/{n} frames, {eta.progress:.0%}, about {left} left"
            )
            v.export_progress.value = eta.progress

        def job():
            pb = player.playback
            with FrameWriter(out, fps) as writer:
                for i, t in enumerate(frames):
                    token.check()
                    cam = (
                        cams[i]
                        if cams is not None
                        else pb.default_camera(t, size, size, azimuth_deg=360.0 * i / n)
                    )
                    image = pb.render(t, cam)
                    if beside:
                        image = side_by_side([image, pb.reference_image(t, cam)[0]])
                    writer.append(image)
                    studio.post(lambda d=i + 1: progress(d))
            return out

        def done(p) -> None:
            self.export_token = None
            v.export_progress.value = 1.0
            v.export_label.text = f"wrote {p}"

        def failed(exc: BaseException) -> None:
            self.export_token = None
            if isinstance(exc, Cancelled):
                v.export_label.text = f"export cancelled: {out.name} not written"
                return
            studio.show_error(exc)

        studio.play_worker.submit(job, done, failed)

    def export_gif(self, path: str, size: int | None = None) -> None:
        """The "GIF..." button: :meth:`export_video` as an animated GIF."""
        self.export_video(str(Path(path).with_suffix(".gif")), size)

    def cancel_export(self) -> None:
        """Stop a running video export before its next frame (no file is written)."""
        if self.export_token is not None:
            self.export_token.cancel()

    def export_proxy(self, path: str) -> None:
        """Write the derived proxy (with its UVs) as OBJ."""
        result = self.studio.garment_tab.proxy_result
        if result is None:
            self.studio.show_error(InputError("derive a proxy first (Garment tab)"))
            return
        out = Path(path)
        if out.suffix.lower() != ".obj":
            out = out.with_suffix(".obj")
        save_mesh(out, result.proxy)
        self.view.export_label.text = f"wrote {out}"
