"""Joint2Coarse's splits keep apart: no test kind or test capture in training, no window of a
capture shared between splits, one name per motion."""

from __future__ import annotations

import pytest

from pipeline.config import CMU_CLIP, PRESETS, MotionSpec


def _splits(config) -> dict[str, tuple[MotionSpec, ...]]:
    return {
        "train": (config.train_motion, *config.joint2coarse_extra),
        "validation": tuple(config.joint2coarse_validation),
        "test": tuple(config.test_motions),
    }


def _window_s(spec: MotionSpec, fps: float) -> tuple[float, float]:
    """Seconds of the source file a clip uses (a clip played faster covers more of it)."""
    return spec.start_s, spec.start_s + (spec.frames - 1) * spec.speed / fps


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_splits_share_no_motion(preset):
    config = PRESETS[preset]
    splits = _splits(config)
    names = [m.name for specs in splits.values() for m in specs]
    assert len(names) == len(set(names))
    test_kinds = {m.kind for m in splits["test"] if m.kind != "file"}
    for split in ("train", "validation"):
        for m in splits[split]:
            assert m.kind not in test_kinds, f"{m.name}: a test kind in {split}"
            assert m.path != str(CMU_CLIP), f"{m.name}: the test capture in {split}"
    files = [(split, m) for split, specs in splits.items() for m in specs if m.kind == "file"]
    for i, (split_a, a) in enumerate(files):
        for split_b, b in files[i + 1 :]:
            if split_a == split_b or a.path != b.path:
                continue
            (a0, a1), (b0, b1) = _window_s(a, config.fps), _window_s(b, config.fps)
            assert a1 <= b0 or b1 <= a0, f"{a.name} ({split_a}) overlaps {b.name} ({split_b})"


def test_the_quick_library_spins_both_ways_and_holds_real_capture():
    config = PRESETS["quick"]
    spins = [m.turn_deg_s for m in config.joint2coarse_extra if m.turn_deg_s]
    assert min(spins) < 0 < max(spins)
    captures = [m for m in config.joint2coarse_extra if m.kind == "file"]
    assert len({m.path for m in captures}) == 2 and len(captures) >= 10
