"""The project's stages, one module each, in the order ``dng demo`` runs them.

Each stage is a function of a :class:`core.project.Project` and a
:class:`pipeline.config.PipelineConfig`; it writes its outputs into its own folder of the
project with the parameters that made them, and is skipped when neither its parameters nor its
input files changed. ``dng demo``, the other commands and the GUI all call these functions.

========================  ====================================================================
module                    folder of the project
========================  ====================================================================
:mod:`.motions`           ``motions/NAME.bvh``: every motion on the mannequin
:mod:`.garment`           ``garment/target.obj``: the detailed garment
:mod:`.proxy`             ``proxy/``: proxy.obj (UVs), positions.obj (seam-free), seams.npz
:mod:`.simulate`          ``sim/NAME-proxy/``, ``sim/NAME-target/``: cache.npz + report.json
:mod:`.dataset`           ``dataset/``: training samples; ``testset/NAME/``: unseen cameras
:mod:`.joint2coarse`      ``joint2coarse/``: the model, pred-MOTION.npz, report.json
:mod:`.renderer`          ``renderer/``: renderer.pt, loss log and plot, previews
:mod:`.baselines`         ``baselines/KIND/``: Pix2Pix, DNR, DNR with our loss
:mod:`.ablations`         ``ablations/NAME/``: renderer variants in sub-projects
:mod:`.evaluate`          ``eval/report.json``: every method on every test motion
:mod:`.videos`            ``videos/NAME.gif``: ground truth beside the neural render
========================  ====================================================================
"""
