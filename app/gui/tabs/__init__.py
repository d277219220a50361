"""The studio's per-tab controllers, one class per tab of the right-hand panel. Each owns its
widgets' callbacks and the work it starts; the shared state (settings, open project, workers,
errors) lives in :class:`app.gui.controller.Studio`, which composes them, and what is playing
in :class:`app.gui.player.Player`.

- :class:`~app.gui.tabs.garment.GarmentTab`: garment, proxy derivation, use the proxy;
- :class:`~app.gui.tabs.motion.MotionTab`: project, motion, body, fine-tuning;
- :class:`~app.gui.tabs.pipeline.PipelineTab`: stage jobs, progress, loss curves;
- :class:`~app.gui.tabs.export.ExportTab`: camera path, MP4 / GIF, OBJ.
"""
