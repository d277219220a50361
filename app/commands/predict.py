"""``dng predict proxy PROJECT --motion M.bvh --out CACHE``: the proxy for any motion."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("predict", help="predict with a project's trained networks")
    what = p.add_subparsers(dest="output", metavar="OUTPUT")
    what.required = True
    x = what.add_parser(
        "proxy",
        help="coarse proxy positions for a motion, with Joint2Coarse (no simulation)",
        description=(
            "Load any BVH (any rig: it is retargeted onto the project's mannequin), predict "
            "the proxy for every frame and write a cache (.npz ours, .pc2, .mdd, or a folder "
            "for an OBJ sequence)."
        ),
    )
    x.add_argument("project", help="project folder with a trained joint2coarse/")
    x.add_argument("--motion", required=True, help="BVH file")
    x.add_argument("--out", required=True, help="cache to write (.npz, .pc2, .mdd or a folder)")
    x.add_argument(
        "--push-out",
        action="store_true",
        help="push vertices out of the body (the capsules the simulation collides with)",
    )
    x.set_defaults(handler=run_proxy)


def run_proxy(args: argparse.Namespace) -> int:
    import time

    from core.errors import InputError
    from core.mesh import load_mesh
    from core.motion.load import load_motion, resample
    from core.motion.mapping import canonical_positions
    from core.motion.retarget import retarget
    from core.project import Project
    from core.sim import SimCache, export_cache
    from training.joint2coarse import joint2coarse_inputs, load_model, predict_proxy
    from training.pipeline import project_config

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
        from training.joint2coarse.collision import simulation_colliders
        from training.pipeline import sim_config

        top = float(proxy.vertices[:, 1].max())
        arms = sim_config(config).arm_colliders
        capsules, radii = simulation_colliders(config.body, motion, top, arms)
    start = time.perf_counter()
    positions = predict_proxy(net, joints, root_rot, capsules=capsules, radii=radii)
    ms = 1e3 * (time.perf_counter() - start) / len(positions)
    faces = proxy.faces
    params = {"joint2coarse": str(model), "motion": args.motion, "push_out": args.push_out}
    export_cache(args.out, SimCache(positions, faces, config.fps, params))
    print(f"{len(positions)} frames x {positions.shape[1]} vertices, {ms:.2f} ms/frame: {args.out}")
    return 0
