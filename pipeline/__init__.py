"""The project: a garment project's settings, its stages over one folder, and what runs on a
trained project (playback, fine-tuning, the demo and its report, ``dng eval joint2coarse``, the
torch bundle).

Layers (imports only go down): ``core`` <- ``templates`` <- ``training`` (networks, losses,
trainers, data sets, metrics) <- ``pipeline`` <- ``app``.

- :mod:`pipeline.config`: :class:`~pipeline.config.PipelineConfig`, presets, the resolved
  configuration of each stage; :mod:`pipeline.library`: the motions and Joint2Coarse's library.
- :mod:`pipeline.stages`: one module per stage.
- :mod:`pipeline.playback`: a trained project's renders of any motion from any camera.
- :mod:`pipeline.finetune`: the renderer adapted to a new body shape or background.
- :mod:`pipeline.demo`: every stage in order, with progress, and the report;
  :mod:`pipeline.report`: the results page (``dng report``); :mod:`pipeline.provenance`: the
  commit, date and machine a report records.
- :mod:`pipeline.joint2coarse_eval`: ``dng eval joint2coarse`` (simulation against prediction).
- :mod:`pipeline.torch_export`: the project in one file for the torch-only render path.
"""
