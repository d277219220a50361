"""``dng predict proxy PROJECT --motion M.bvh --out CACHE``: the proxy for any motion.

``--out X.usd`` (or ``.usda``, ``.usdc``) writes a USD stage for Blender, Marvelous Designer or
CLO: the proxy with its UVs and, with ``--body``, the mannequin posed by the motion.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from core.body.colliders import simulation_colliders
from core.body.mannequin import make_body
from core.body.skinning import pose_body
from core.errors import InputError
from core.mesh import load_mesh
from core.motion.mapping import canonical_positions
from core.motion.retarget import retarget
from core.project import Project
from core.sim import SimCache, export_cache
from core.usd import USD_SUFFIXES, UsdMesh, write_usd
from pipeline.config import project_config, sim_config
from training.dataset import load_proxy_frames


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("predict", help="predict with a project's trained networks")
    what = p.add_subparsers(dest="output", metavar="OUTPUT")
    what.required = True
    x = what.add_parser(
        "proxy",
        help="coarse proxy positions for a motion, with Joint2Coarse (no simulation)",
        description=(
            "Load any BVH or skinned glTF/GLB (any rig: it is retargeted onto the project's "
            "mannequin), predict the proxy for every frame and write a cache (.npz ours, .pc2, "
            ".mdd, a folder for an OBJ sequence, or .usd/.usda/.usdc: metres, Y up, the "
            "project's fps)."
        ),
    )
    x.add_argument("project", help="project folder with a trained joint2coarse/")
    x.add_argument("--motion", required=True, help="BVH, glTF/GLB or DeepMimic (.txt) file")
    x.add_argument(
        "--out", required=True, help="cache to write (.npz, .pc2, .mdd, .usd, .usda or a folder)"
    )
    x.add_argument(
        "--body", action="store_true", help="USD --out only: add the mannequin posed by the motion"
    )
    x.add_argument(
        "--push-out",
        action="store_true",
        help="push vertices out of the body (the capsules the simulation collides with)",
    )
    x.set_defaults(handler=run_proxy)


def run_proxy(args: argparse.Namespace) -> int:

    from core.motion.load import load_motion, resample
    from training.joint2coarse import (
        joint2coarse_inputs,
        load_model,
        predict_proxy,
        prediction_stretch_limit,
    )

    usd = Path(args.out).suffix.lower() in USD_SUFFIXES
    if args.body and not usd:
        raise InputError("--body needs a USD --out (.usd, .usda or .usdc)", args.out)
    project = Project(args.project)
    config = project_config(project)
    model = project.path("joint2coarse", "joint2coarse.pt")
    if not model.is_file():
        raise InputError("no trained Joint2Coarse: run dng train joint2coarse first", model)
    net = load_model(model)
    source = resample(load_motion(args.motion), config.fps)
    motion = retarget(canonical_positions(source), config.fps, config.body, name=args.motion)
    joints, root_rot = joint2coarse_inputs(motion)
    proxy = load_mesh(project.path("proxy", "positions.obj"))[0]
    capsules = radii = None
    if args.push_out:  # the capsules the project's simulation collides with
        top = float(proxy.vertices[:, 1].max())
        arms = sim_config(config).arm_colliders
        capsules, radii = simulation_colliders(config.body, motion, top, arms)
    start = time.perf_counter()
    stretch = prediction_stretch_limit(proxy.vertices, proxy.faces)
    positions = predict_proxy(
        net, joints, root_rot, capsules=capsules, radii=radii, stretch=stretch
    )
    ms = 1e3 * (time.perf_counter() - start) / len(positions)
    faces = proxy.faces
    params = {"joint2coarse": str(model), "motion": args.motion, "push_out": args.push_out}
    if usd:
        write_usd(
            args.out, usd_meshes(project, config, motion, positions, faces, args.body), config.fps
        )
    else:
        export_cache(args.out, SimCache(positions, faces, config.fps, params))
    print(f"{len(positions)} frames x {positions.shape[1]} vertices, {ms:.2f} ms/frame: {args.out}")
    return 0


def usd_meshes(project, config, motion, positions, faces, body: bool) -> list:
    """The USD stage's meshes: ``Proxy`` (positions (T, V, 3) over the seam-free ``faces``
    (F, 3)); with the project's UV'd proxy (``proxy.obj``, ``seams.npz``) its topology is
    ``seam_map[uv_faces]`` and its UVs the face-varying ``st``, as the renderer sees them.
    With ``body``, also ``Body``: the project's mannequin skinned by ``motion`` (its joints)."""
    uvs = uv_faces = None
    uv_file, seams = project.path("proxy", "proxy.obj"), project.path("proxy", "seams.npz")
    if uv_file.is_file() and seams.is_file():
        frames = load_proxy_frames(project.root, positions)
        faces, uvs, uv_faces = frames.seam_map[frames.faces], frames.uvs, frames.faces
    meshes = [UsdMesh("Proxy", positions, faces, uvs, uv_faces, double_sided=True)]
    if body:
        mannequin = make_body(config.body)
        meshes.append(UsdMesh("Body", pose_body(mannequin, motion), mannequin.faces))
    return meshes
