"""``python -m training.baselines --bench [KIND ...]``: time the cpu presets' training steps."""

from training.baselines.train import main

raise SystemExit(main())
