"""``dng bench raster``: rasterization + UV map + motion-feature map per view of a 2k proxy.

A skirt-like proxy (a flared cylinder grid of 2040 vertices with UVs), synthetic joints from the
mannequin's rest skeleton, and the data set's cameras (``--views`` random cameras per frame on a
circle around the body). Two framings: ``body`` (the whole body in view, the garment covers
about 7% of the image) and ``garment`` (the skirt fills about 42%). Per frame: the scene build
(vertices move every frame, so the Embree BVH is rebuilt) and the per-vertex motion features,
both shared by the frame's views. Per view: rasterize, UV map, the dense (H, W, 95) feature
map. ``per_view_ms`` is a view's own time plus its share of the frame's; medians and minima
over all timed views, and the process CPU time of a view. Writes ``OUT/raster.json`` and a
stacked-bar plot ``OUT/raster.png``; ``--sheet PATH`` also writes a contact sheet (ground
truth, background, mask, UV map, one motion-feature channel) of one view.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from app.bench import add_output_arguments
from core.body.shape import BodyShape, mannequin_skeleton
from core.camera import CameraRigConfig, random_cameras
from core.errors import InputError
from core.features import (
    FeatureConfig,
    interpolate,
    motion_feature_map,
    uv_map,
    vertex_motion_features,
)
from core.fileio import atomic_path, write_json
from core.mesh import Mesh
from core.raster import MeshScene, RasterConfig, rasterize
from core.shading import (
    Material,
    ShadingConfig,
    colorize_scalar,
    colorize_uv,
    contact_sheet,
    render_ground_truth,
    render_views,
    write_png,
)
from core.skeleton import CANONICAL_JOINTS

HELP = "rasterization + UV + motion-feature maps per view of a 2k-vertex proxy"

#: The paper's resolutions of interest; 512 is the one with a target.
DEFAULT_SIZES = (128, 256, 512)
#: Camera rigs of the bench: the whole body in view, or the skirt filling the view.
FRAMINGS = {
    "body": {},
    "garment": {"target": (0.0, 0.75, 0.0), "radius_range": (1.5, 1.8), "fov_y_deg": 30.0},
}
#: Target for rasterization + feature maps per view at 512 px on 2 CPU cores.
TARGET_MS_512 = 30.0


def skirt_mesh(rings: int = 40, segments: int = 50, waist_y: float = 1.0, length: float = 0.55,
               waist_radius: float = 0.16, hem_radius: float = 0.36):  # fmt: skip
    """A flared open cylinder (a skirt-like proxy) with UVs: ``Mesh`` of ``rings * (segments + 1)``
    vertices (the UV seam column is duplicated so UVs are continuous), hem at the bottom.

    The waist is slightly elliptic like a body; the defaults give 2040 vertices, 3900 faces.
    """
    s = np.linspace(0.0, 1.0, rings)  # 0 at the waist, 1 at the hem
    th = np.linspace(0.0, 2.0 * math.pi, segments + 1)
    r = waist_radius + (hem_radius - waist_radius) * s**0.8
    # A few soft folds growing towards the hem, so shading and features have something to show.
    fold = 1.0 + 0.06 * s[:, None] * np.sin(8.0 * th[None, :])
    x = (r[:, None] * fold) * np.sin(th)[None, :]
    z = 0.8 * (r[:, None] * fold) * np.cos(th)[None, :]
    y = np.repeat((waist_y - length * s)[:, None], segments + 1, 1)
    verts = np.stack([x, y, z], -1).reshape(-1, 3).astype(np.float32)
    uv = np.stack(np.meshgrid(th / (2 * math.pi), 1.0 - s), -1).reshape(-1, 2).astype(np.float32)
    i, j = np.meshgrid(np.arange(rings - 1), np.arange(segments), indexing="ij")
    a = (i * (segments + 1) + j).ravel()
    b, c, d = a + 1, a + segments + 1, a + segments + 2
    # Counter-clockwise seen from outside: normals point away from the legs.
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    return Mesh(verts, faces.astype(np.int64), uv)


def capsule_body(shape=None):
    """A body-like mesh of capsules along the mannequin's rest bones, and its joints.

    Returns
    -------
    mesh : Mesh, the body (overlapping closed capsules; fine for ray casting).
    joints : (19, 3) float32, the canonical joints (``CANONICAL_JOINTS`` order).
    """
    import trimesh

    skel = mannequin_skeleton(shape or BodyShape())
    rest = skel.rest_positions().astype(np.float64)
    p = {n: rest[i] for i, n in enumerate(skel.names)}
    top = p["Head"] + skel.end_sites[skel.index("Head")]
    bones = [
        ("Hips", "Spine2", 0.13), ("Spine2", "Neck", 0.12), ("Neck", "Head", 0.05),
        ("LeftUpLeg", "RightUpLeg", 0.11),
    ]  # fmt: skip
    for side in ("Left", "Right"):
        bones += [
            (f"{side}Arm", f"{side}ForeArm", 0.045), (f"{side}ForeArm", f"{side}Hand", 0.037),
            (f"{side}UpLeg", f"{side}Leg", 0.07), (f"{side}Leg", f"{side}Foot", 0.05),
            (f"{side}Shoulder", f"{side}Arm", 0.05),
        ]  # fmt: skip
    parts = []
    for a, b, radius in bones:
        parts.append(_capsule(p[a], p[b], radius))
    head = trimesh.creation.icosphere(3, radius=0.095)
    head.apply_translation(0.5 * (p["Head"] + top) + np.array([0.0, 0.01, 0.01]))
    parts.append((np.asarray(head.vertices), np.asarray(head.faces)))
    for side in ("Left", "Right"):
        toe = p[f"{side}Foot"] + skel.end_sites[skel.index(f"{side}Foot")] + np.array([0, 0.03, 0])
        parts.append(_capsule(p[f"{side}Foot"], toe, 0.04))
    verts, faces, base = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + base)
        base += len(v)
    joints = np.stack([p[n] for n in CANONICAL_JOINTS]).astype(np.float32)
    return Mesh(
        np.concatenate(verts).astype(np.float32), np.concatenate(faces).astype(np.int64)
    ), joints


def _capsule(a: np.ndarray, b: np.ndarray, radius: float):
    import trimesh

    axis = b - a
    length = float(np.linalg.norm(axis))
    cap = trimesh.creation.capsule(height=length, radius=radius, count=[16, 16])
    # trimesh's capsule runs along Z, centred on the origin (sphere centres at +-height/2).
    cap.apply_transform(trimesh.geometry.align_vectors([0, 0, 1], axis / length))
    cap.apply_translation(0.5 * (a + b))
    return np.asarray(cap.vertices), np.asarray(cap.faces)


def swaying_joint_window(joints: np.ndarray, offsets=(0, 2, 4, 6, 8), amplitude: float = 0.04):
    """A synthetic joint history (K, 19, 3) float32: the body sways along X, one frame per 1/30 s."""
    k = np.asarray(offsets, np.float64)
    shift = amplitude * np.sin(2 * math.pi * 0.8 * (-k / 30.0))
    window = np.repeat(joints[None].astype(np.float64), len(k), 0)
    window[:, :, 0] += shift[:, None]
    return window.astype(np.float32)


def add_arguments(parser: argparse.ArgumentParser) -> None:

    add_output_arguments(parser)
    parser.add_argument(
        "--sizes", type=int, nargs="+", default=list(DEFAULT_SIZES), help="image sizes in pixels"
    )
    parser.add_argument("--repeats", type=int, default=5, help="frames timed per size (median)")
    parser.add_argument("--views", type=int, default=10, help="cameras per frame (the paper: 10)")
    parser.add_argument("--threads", type=int, default=0, help="Embree threads (0: all cores)")
    parser.add_argument("--half", action="store_true", help="float16 motion-feature maps")
    parser.add_argument("--seed", type=int, default=0, help="camera seed")
    parser.add_argument(
        "--framing", nargs="+", choices=sorted(FRAMINGS), default=list(FRAMINGS),
        help="camera rigs: 'body' frames the whole body (the garment covers ~7%% of the image), "
        "'garment' frames the skirt (~30%%); default both",
    )  # fmt: skip
    parser.add_argument(
        "--sheet", metavar="PATH", help="also write a contact sheet PNG of one view"
    )
    parser.add_argument(
        "--ground-truth", action="store_true",
        help="also time ground-truth renders (garment + body and body alone, supersampled 3x3)",
    )  # fmt: skip


def measure(sizes=DEFAULT_SIZES, repeats: int = 5, views: int = 10, threads: int = 0,
            half: bool = False, seed: int = 0, framings=tuple(FRAMINGS)) -> dict:  # fmt: skip
    """Time the per-view pipeline; returns a JSON-ready dict (times in milliseconds).

    Per frame (shared by its ``views`` cameras): the scene build and the per-vertex motion
    features. Per view: rasterize, UV map, interpolated motion-feature map. ``per_view_ms`` is
    a view's own time plus its share of the frame's. Medians and minima over all timed views
    (the minimum shows the cost on an idle machine when others share the CPUs);
    ``view_cpu_ms`` is the process CPU time of a view (all threads), without the frame share.
    """
    if repeats < 1 or views < 1 or any(s <= 0 for s in sizes):
        raise InputError("repeats, views and sizes must be positive")
    proxy = skirt_mesh()
    _, joints = capsule_body()
    window = swaying_joint_window(joints)
    fcfg = FeatureConfig(dtype="float16" if half else "float32")
    rcfg = RasterConfig(threads=threads)
    results = []
    for framing, size in [(fr, sz) for fr in framings for sz in sizes]:
        rig = CameraRigConfig(width=size, height=size, **FRAMINGS[framing])
        rows = []
        for frame in range(repeats + 1):  # the first frame warms up and is not counted
            cams = random_cameras(views, (seed, frame), rig)
            # The proxy moves every frame: a fresh scene and fresh vertex features.
            verts = proxy.vertices + np.float32(0.001 * frame)
            t0 = time.perf_counter()
            scene = MeshScene(verts, proxy.faces).build()
            t1 = time.perf_counter()
            feats = vertex_motion_features(verts, window, fcfg.sigma)
            t2 = time.perf_counter()
            build, vfeat = t1 - t0, t2 - t1
            for cam in cams:
                c3 = time.process_time()
                t3 = time.perf_counter()
                frags = scene.rasterize(cam, rcfg)
                t4 = time.perf_counter()
                uv_map(frags, proxy.faces, proxy.uvs)
                t5 = time.perf_counter()
                interpolate(frags, proxy.faces, feats, fcfg.dtype)
                t6 = time.perf_counter()
                c6 = time.process_time()
                if frame:
                    share = (build + vfeat) / views
                    rows.append((build, vfeat, t4 - t3, t5 - t4, t6 - t5, share + t6 - t3,
                                 float(frags.mask.mean()), c6 - c3))  # fmt: skip
        a = np.array(rows)
        med, low = np.median(a, 0), a.min(0)

        def ms(x):
            return round(1e3 * float(x), 3)

        results.append(
            {
                "framing": framing,
                "size": size,
                "build_ms": ms(med[0]),
                "vertex_features_ms": ms(med[1]),
                "raster_ms": ms(med[2]),
                "uv_ms": ms(med[3]),
                "features_ms": ms(med[4]),
                "per_view_ms": ms(med[5]),
                "per_view_p90_ms": ms(np.percentile(a[:, 5], 90)),
                "per_view_min_ms": ms(low[5]),
                "raster_min_ms": ms(low[2]),
                "features_min_ms": ms(low[4]),
                "view_cpu_ms": ms(med[7]),
                "coverage": round(float(med[6]), 4),
            }
        )
    return {
        "proxy_vertices": int(len(proxy.vertices)),
        "proxy_faces": int(len(proxy.faces)),
        "views_per_frame": views,
        "frames": repeats,
        "feature_channels": int(window.shape[0] * window.shape[1]),
        "feature_dtype": fcfg.dtype,
        "cpu_count": os.cpu_count(),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "target_ms_512": TARGET_MS_512,
        "results": results,
    }


def measure_ground_truth(sizes=DEFAULT_SIZES, views: int = 2, seed: int = 0) -> list[dict]:
    """Time :func:`core.shading.render_views` (ground truth + body-only background) per view:
    the skirt (checker pattern) on the capsule body, default shading (3 x 3 supersampling)."""
    proxy = skirt_mesh()
    body, _ = capsule_body()
    cfg = ShadingConfig(garment=Material(pattern="checker"))
    out = []
    for size in sizes:
        cams = random_cameras(views, (seed, 1), CameraRigConfig(width=size, height=size))
        render_views(proxy, body, cams[:1], cfg)  # warm-up
        t0, c0 = time.perf_counter(), time.process_time()
        render_views(proxy, body, cams, cfg)
        wall, cpu = (time.perf_counter() - t0) / views, (time.process_time() - c0) / views
        out.append(
            {
                "size": size,
                "supersample": cfg.supersample,
                "body_faces": int(len(body.faces)),
                "per_view_ms": round(1e3 * wall, 1),
                "view_cpu_ms": round(1e3 * cpu, 1),
            }
        )
    return out


def sheet_body():
    """The mannequin (``core.body.mannequin.make_body``) when installed, else the capsule body.

    Returns ``(Mesh, joints (19, 3) float32)``.
    """
    try:
        from core.body.mannequin import make_body
    except ImportError:
        return capsule_body()

    body = make_body()
    rest = body.skeleton.rest_positions()
    joints = np.stack([rest[body.skeleton.index(n)] for n in CANONICAL_JOINTS])
    return Mesh(body.vertices, body.faces), joints.astype(np.float32)


def write_sheet(path: str, size: int = 256, seed: int = 0) -> None:
    """Contact sheet of one view: ground truth, background, mask, UV map, a motion feature.

    The skirt proxy (checker pattern from its UVs) on the mannequin when it is installed.
    """
    proxy = skirt_mesh()
    body, joints = sheet_body()
    window = swaying_joint_window(joints)
    cam = random_cameras(1, seed, CameraRigConfig(width=size, height=size))[0]
    cfg = ShadingConfig(garment=Material(pattern="checker"))
    gt = render_ground_truth(proxy, body, cam, cfg)
    frags = rasterize(proxy.vertices, proxy.faces, cam)
    uv = uv_map(frags, proxy.faces, proxy.uvs)
    feats = motion_feature_map(frags, proxy.faces, proxy.vertices, window, FeatureConfig())
    j = CANONICAL_JOINTS.index("LeftUpLeg")
    sheet = contact_sheet(
        [
            gt.image,
            gt.background,
            gt.mask,
            colorize_uv(uv, frags.mask),
            colorize_scalar(feats[..., j]),
        ],
        ["ground truth", "background", "garment mask", "UV map", "feature LeftUpLeg t"],
    )
    write_png(path, sheet)


def plot(report: dict, path) -> None:
    """Stacked bars of the per-view time by stage for each size, with the 512 px target."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = report["results"]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(6.4, 3.4))
    bottom = np.zeros(len(rows))
    views = report["views_per_frame"]
    per_frame = ("build_ms", "vertex_features_ms")
    stages = (("build_ms", "scene build / views"), ("vertex_features_ms", "vertex features / views"),
              ("raster_ms", "raster"), ("uv_ms", "UV map"), ("features_ms", "feature map"))  # fmt: skip
    for key, label in stages:
        h = np.array([r[key] / (views if key in per_frame else 1) for r in rows])
        ax.bar(x, h, bottom=bottom, label=label)
        bottom += h
    ax.axhline(
        TARGET_MS_512, color="k", ls="--", lw=1, label=f"target at 512 px ({TARGET_MS_512:g} ms)"
    )
    ax.set_xticks(x, [f"{r['framing']}\n{r['size']} px" for r in rows], fontsize=7)
    ax.set_ylabel("ms per view (median)")
    ax.set_title(f"{report['proxy_vertices']}-vertex proxy, {report['cpu_count']} CPUs")
    ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:

    report = measure(
        args.sizes, args.repeats, args.views, args.threads, args.half, args.seed, args.framing
    )
    if args.ground_truth:
        report["ground_truth"] = measure_ground_truth(args.sizes, seed=args.seed)
    if args.sheet:
        write_sheet(args.sheet)
        report["sheet"] = args.sheet
    out = Path(args.out)
    write_json(out / "raster.json", report)
    plot(report, out / "raster.png")
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(
        f"raster + UV + motion features per view: proxy {report['proxy_vertices']} vertices, "
        f"{report['proxy_faces']} faces, {report['feature_channels']} {report['feature_dtype']} "
        f"channels, {report['views_per_frame']} views per frame, {report['cpu_count']} CPUs"
    )
    head = (
        "framing",
        "size",
        "build",
        "vfeat",
        "raster",
        "uv",
        "features",
        "per view",
        "p90",
        "min",
        "cover",
    )
    print(" ".join(f"{h:>8}" for h in head))
    keys = ("build_ms", "vertex_features_ms", "raster_ms", "uv_ms", "features_ms",
            "per_view_ms", "per_view_p90_ms", "per_view_min_ms")  # fmt: skip
    for r in report["results"]:
        print(
            f"{r['framing']:>8} {r['size']:>8} "
            + " ".join(f"{r[k]:>8.2f}" for k in keys)
            + f" {r['coverage']:>8.3f}"
        )
    print(
        f"(ms, medians unless 'min'; build and vfeat are per frame, shared by its views; "
        f"load average {report['load_average']}; target at 512 px: {TARGET_MS_512:g} ms per view)"
    )
    for g in report.get("ground_truth", []):
        print(
            f"ground truth + background at {g['size']} px ({g['supersample']}x{g['supersample']} "
            f"samples): {g['per_view_ms']:.0f} ms per view ({g['view_cpu_ms']:.0f} ms CPU)"
        )
    print(f"wrote {out / 'raster.json'} and {out / 'raster.png'}")
    if args.sheet:
        print(f"contact sheet: {args.sheet}")
    return 0
