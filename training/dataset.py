"""The neural renderer's training data: samples of frames (t-1, t, t+1) for one camera view.

Images come from the project's ``dataset`` stage (PNG strips); the proxy's UV map and
motion-feature map are rasterized on the fly from the proxy cache, so the disk holds images
only, never gigabytes of float maps. The proxy comes from simulation (``source="sim"``) or from
Joint2Coarse predictions (``source="joint2coarse"``), the switch the paper's test time needs.
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.camera import camera_from_dict
from core.errors import InputError
from core.features import FeatureConfig, interpolate, joint_window, vertex_motion_features
from core.mesh import load_mesh
from core.raster import RasterConfig, rasterize
from core.shading import colorize_scalar, colorize_uv, contact_sheet, headlight_shading, write_png

#: Keys and shapes of one sample (channels first; a DataLoader adds a leading batch axis).
SAMPLE_KEYS = {
    "uv": "(3, 2, H, W) float32: proxy UV per pixel, 0 off the proxy",
    "motion": "(3, 95, H, W) float32: motion features (19 joints x 5 frames), 0 off the proxy",
    "proxy_mask": "(3, 1, H, W) float32: 1 where the proxy covers the pixel",
    "target": "(3, 3, H, W) float32: ground truth (garment + body) in [0, 1]",
    "background": "(3, 3, H, W) float32: the same view, body only, in [0, 1]",
    "target_mask": "(3, 1, H, W) float32: garment coverage in the ground truth",
    "proxy_shading": "(3, 1, H, W) float32: the proxy shaded grey from the camera, 0 off it "
    "(the Pix2Pix baseline's input; the neural renderer does not read it)",
}
#: What replaces ``motion`` in a data set made with ``motion_per_vertex=True``
#: (:data:`training.renderer.data.VERTEX_MOTION_KEYS`).
VERTEX_MOTION_SAMPLE_KEYS = {
    "motion_corners": "(3, 3, H, W) int32: vertex ids of the covering face's corners, 0 off it",
    "motion_weights": "(3, 3, H, W) float32: their barycentric weights, 0 off the proxy",
    "vertex_motion": "(3, V, 95) float32: motion features per proxy vertex",
}


def sample_name(t: int, k: int) -> str:
    """File stem of the sample centred on frame ``t`` seen by camera ``k``."""
    return f"t{t:05d}_v{k:02d}"


def proxy_source_file(project_root: str | Path, source: str, motion_name: str) -> Path:
    """The cache of a motion's proxy that ``source`` names: ``sim`` (its simulation,
    ``sim/NAME-proxy/cache.npz``) or ``joint2coarse`` (Joint2Coarse's prediction of it,
    ``joint2coarse/pred-NAME.npz``)."""
    root = Path(project_root)
    if source == "sim":
        return root / "sim" / f"{motion_name}-proxy" / "cache.npz"
    if source == "joint2coarse":
        return root / "joint2coarse" / f"pred-{motion_name}.npz"
    raise InputError(f"source must be 'sim' or 'joint2coarse', got {source!r}")


@dataclass(frozen=True)
class ProxyFrames:
    """The proxy as the rasterizer needs it, for every frame of a clip.

    positions : (T, Vs, 3) float32, seam-free vertices (what simulation and Joint2Coarse give)
    seam_map : (Vp,) int64, UV vertex -> seam-free vertex
    faces : (F, 3) int64 over the UV vertices
    uvs : (Vp, 2) float32
    """

    positions: np.ndarray
    seam_map: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray

    def vertices(self, t: int) -> np.ndarray:
        """UV-split vertices at frame t: (Vp, 3) float32."""
        return self.positions[t][self.seam_map]


def load_proxy_frames(project_root: str | Path, positions: np.ndarray) -> ProxyFrames:
    """The project's proxy topology and UVs around a (T, Vs, 3) positions cache."""
    root = Path(project_root)
    proxy, _ = load_mesh(root / "proxy" / "proxy.obj")
    seams = np.load(root / "proxy" / "seams.npz")["seam_map"]
    if proxy.uvs is None:
        raise InputError("proxy has no UVs", root / "proxy" / "proxy.obj")
    if positions.ndim != 3 or positions.shape[1] <= seams.max():
        raise InputError(
            f"proxy cache of shape {positions.shape} does not fit the proxy "
            f"({seams.max() + 1} seam-free vertices)",
            root,
        )
    return ProxyFrames(positions.astype(np.float32), seams, proxy.faces, proxy.uvs)


class GarmentDataset:
    """A torch-style map dataset over the samples of a project's ``dataset`` stage.

    Parameters
    ----------
    project_root : the project folder (after ``stage_dataset``)
    source : ``"sim"`` (simulated proxy) or ``"joint2coarse"`` (predicted proxy)
    features : the motion-feature settings (sigma, frame offsets)
    split : None for the training set (``dataset/``), or a test motion's name for its
        evaluation set from unseen cameras (``testset/NAME/``, made by ``stage_testset``)
    folder : None, or another folder of samples in the same layout, relative to the project
        (what ``benchmarks/renderer_validation.py --extra-motion`` trains on beside
        ``dataset/``); it takes the place of ``split``
    proxy_positions : None, or (T, Vs, 3) float seam-free proxy vertices for every frame of the
        motion, rendered instead of the ``source``'s cache (which then only names them): what
        ``dng bench placement`` uses to render proxies between the simulated one and
        Joint2Coarse's
    motion_per_vertex : samples carry the motion features per vertex with the rasterization
        (:data:`VERTEX_MOTION_SAMPLE_KEYS`) instead of the (3, 95, H, W) map, for the trainer
        to interpolate on its device (:func:`training.renderer.data.motion_maps`); what a
        trainer on a GPU asks for (:meth:`with_motion_per_vertex`)
    threads : the proxy's ray casts' threads (:attr:`core.raster.RasterConfig.threads`; 0: every
        core); the samples are the same whatever the number
    """

    def __init__(
        self,
        project_root: str | Path,
        source: str = "sim",
        features: FeatureConfig | None = None,
        split: str | None = None,
        proxy_positions: np.ndarray | None = None,
        motion_per_vertex: bool = False,
        threads: int = 0,
        folder: str | Path | None = None,
    ):
        from core.motion.load import load_motion
        from training.joint2coarse import joint2coarse_inputs

        self.root = Path(project_root)
        self.folder = self.root / "dataset" if split is None else self.root / "testset" / split
        if folder is not None:
            self.folder = self.root / folder
        index_path = self.folder / "samples.json"
        if not index_path.is_file():
            stage = "dataset" if split is None else "testset"
            raise InputError(f"no data set here: run the {stage} stage first", index_path)
        index = json.loads(index_path.read_text())
        motion_name = index["motion"]
        source_file = proxy_source_file(self.root, source, motion_name)
        if proxy_positions is not None:
            cache = index_path  # what messages about the positions' frame count name
            positions = np.asarray(proxy_positions)
            if positions.ndim != 3 or positions.shape[-1] != 3 or not len(positions):
                raise InputError(
                    f"proxy positions must be (frames, vertices, 3), got {positions.shape}", cache
                )
            if not np.isfinite(positions).all():
                raise InputError("proxy positions hold NaN or infinite values", cache)
        else:
            cache = source_file
            if not cache.is_file():
                what = "simulated proxy cache" if source == "sim" else "Joint2Coarse prediction"
                raise InputError(f"no {what} of {motion_name}", cache)
            positions = np.load(cache)["positions"]
        self.source = source
        self.split = split
        self.motion_per_vertex = motion_per_vertex
        self.raster = RasterConfig(threads=threads)
        self.proxy = load_proxy_frames(self.root, positions)
        self._seamless_faces = self.proxy.seam_map[self.proxy.faces]
        motion = load_motion(self.root / "motions" / f"{motion_name}.bvh")
        joints, _ = joint2coarse_inputs(motion)
        self.joints = joints[:, 1:]  # the 19 canonical joints (Hips dropped)
        if len(self.joints) != len(positions):
            raise InputError(
                f"motion has {len(self.joints)} frames, proxy cache {len(positions)}", cache
            )
        self.features = FeatureConfig() if features is None else features
        self.samples = [
            (s["frame"], s["view"], camera_from_dict(s["camera"], index_path))
            for s in index["samples"]
        ]

    def __len__(self) -> int:
        return len(self.samples)

    def with_motion_per_vertex(self) -> GarmentDataset:
        """The same samples with their motion features per vertex (see the class docstring)."""
        other = copy.copy(self)
        other.motion_per_vertex = True
        return other

    def proxy_maps(self, t: int, camera, motion_per_vertex: bool = False) -> dict[str, np.ndarray]:
        """UV map (2, H, W), motion features (95, H, W), proxy mask (1, H, W) and grey
        headlight shading (1, H, W) at frame t; with ``motion_per_vertex`` the motion
        features' per-vertex form (:data:`VERTEX_MOTION_SAMPLE_KEYS`, one frame) instead."""
        v = self.proxy.vertices(t)
        frags = rasterize(v, self.proxy.faces, camera, self.raster)
        window = joint_window(self.joints, t, self.features.frame_offsets)
        feats = vertex_motion_features(v, window, self.features.sigma)
        if motion_per_vertex:
            covered = frags.face_id >= 0
            corners = self.proxy.faces[np.where(covered, frags.face_id, 0)]  # (H, W, 3)
            motion = {
                "motion_corners": corners.astype(np.int32).transpose(2, 0, 1),
                "motion_weights": (frags.barycentrics * covered[..., None])
                .astype(np.float32)
                .transpose(2, 0, 1),
                "vertex_motion": feats.astype(np.float32),
            }
        else:
            motion = {"motion": interpolate(frags, self.proxy.faces, feats).transpose(2, 0, 1)}
        return {
            "uv": interpolate(frags, self.proxy.faces, self.proxy.uvs).transpose(2, 0, 1),
            **motion,
            "proxy_mask": frags.mask[None].astype(np.float32),
            # Seam-free faces (same order): smooth normals across the UV seams.
            "proxy_shading": headlight_shading(
                frags, self.proxy.positions[t], self._seamless_faces, camera
            )[None],
        }

    def __getitem__(self, i: int) -> dict:
        import torch
        from PIL import Image

        t, k, camera = self.samples[i]
        frames = [self.proxy_maps(f, camera, self.motion_per_vertex) for f in (t - 1, t, t + 1)]
        out = {key: np.stack([fr[key] for fr in frames]) for key in frames[0]}
        w = camera.width
        base = self.folder / "samples" / sample_name(t, k)
        for key, suffix in (("target", "image"), ("background", "background")):
            strip = np.asarray(Image.open(f"{base}_{suffix}.png").convert("RGB"), np.float32) / 255
            out[key] = np.stack(
                [strip[:, j * w : (j + 1) * w].transpose(2, 0, 1) for j in range(3)]
            )
        mask = np.asarray(Image.open(f"{base}_mask.png"), np.float32) / 255
        out["target_mask"] = np.stack([mask[None, :, j * w : (j + 1) * w] for j in range(3)])
        return {
            key: torch.from_numpy(
                np.ascontiguousarray(v, np.int32 if v.dtype.kind == "i" else np.float32)
            )
            for key, v in out.items()
        }

    def contact_sheet(self, i: int, path: str | Path) -> None:
        """One sample's frames as a PNG: images, backgrounds, masks, proxy UV maps, a feature."""
        dense = copy.copy(self)
        dense.motion_per_vertex = False
        s = dense[i]
        tiles, labels = [], []
        for j, name in enumerate(("t-1", "t", "t+1")):
            img = (s["target"][j].numpy().transpose(1, 2, 0) * 255).round().astype(np.uint8)
            bg = (s["background"][j].numpy().transpose(1, 2, 0) * 255).round().astype(np.uint8)
            mask = s["target_mask"][j, 0].numpy()
            pmask = s["proxy_mask"][j, 0].numpy() > 0
            uv = colorize_uv(s["uv"][j].numpy().transpose(1, 2, 0), pmask)
            feat = colorize_scalar(s["motion"][j, 13].numpy())  # LeftUpLeg at frame t
            tiles += [img, bg, colorize_scalar(mask), uv, feat]
            labels += [
                f"{name} image",
                "background",
                "garment mask",
                "proxy UV",
                "LeftUpLeg feature",
            ]
        write_png(path, contact_sheet(tiles, labels, columns=5))
