"""The trainers' sample order and feed (training.loader): the order is the one the trainers
always had, DataLoader workers change nothing but where batches are made, and a renderer trained
with workers ends with the same weights as one without."""

from __future__ import annotations

import functools

import pytest
import torch

from training.loader import SampleOrder, batches, next_indices
from training.renderer import PRESETS, SyntheticDataset, synthetic_scene, train_renderer

torch.set_num_threads(1)


def _old_order(n: int, seed: int, batch: int, world: int, rank: int, steps: int) -> list:
    """The trainers' shuffling as it was written inline before training.loader existed."""
    shuffle = torch.Generator().manual_seed(seed)
    perm, pos, out = torch.randperm(n, generator=shuffle), 0, []
    for _ in range(steps):
        g = batch * world
        if pos + g > len(perm):
            perm, pos = torch.randperm(n, generator=shuffle), 0
        idx = perm[pos : pos + g].tolist()
        pos += g
        out.append(idx[rank * batch : (rank + 1) * batch])
    return out


@pytest.mark.parametrize(("world", "rank"), [(1, 0), (2, 0), (2, 1)])
def test_the_order_is_the_trainers_old_one(world, rank):
    order, got = SampleOrder.start(11, 5), []
    for _ in range(20):  # several epochs of 11 samples
        idx, order = next_indices(order, 2, world, rank)
        got.append(idx)
    assert got == _old_order(11, 5, 2, world, rank, 20)
    assert order.epoch == 20 // (11 // (2 * world)) - 1  # the permutations used up


def _collate(samples: list, scale: float) -> dict:
    return {"x": torch.stack([s["x"] for s in samples]) * scale}


class _Numbers(torch.utils.data.Dataset):
    def __len__(self) -> int:
        return 9

    def __getitem__(self, i: int) -> dict:
        return {"x": torch.tensor([float(i)])}


def test_workers_give_the_same_batches_and_orders():
    start = SampleOrder.start(9, 3)
    collate = functools.partial(_collate, scale=2.0)
    plain = list(batches(_Numbers(), start, 13, 2, collate))
    loaded = list(batches(_Numbers(), start, 13, 2, collate, workers=2))
    assert len(plain) == len(loaded) == 13
    for (a, oa), (b, ob) in zip(plain, loaded, strict=True):
        assert torch.equal(a["x"], b["x"])
        assert (oa.pos, oa.epoch) == (ob.pos, ob.epoch) and torch.equal(oa.perm, ob.perm)
        assert torch.equal(oa.rng, ob.rng)
    with pytest.raises(ValueError):
        next(batches(_Numbers(), start, 1, 2, collate, workers=-1))


def test_renderer_trained_with_workers_has_the_same_weights(tmp_path):
    data = SyntheticDataset(synthetic_scene(6), 32, cameras_per_frame=2, seed=0)
    cfg = PRESETS["tiny"].replace(steps=6, checkpoint_every=4, preview_every=0)
    a = train_renderer(data, tmp_path / "a", cfg, progress=False)
    b = train_renderer(data, tmp_path / "b", cfg, progress=False, workers=2)
    for k, v in a.net.state_dict().items():
        assert torch.equal(v, b.net.state_dict()[k]), k
    # the checkpoint holds the order of the batches consumed, not of those loaded ahead
    ca = torch.load(a.checkpoint_path, weights_only=True)
    cb = torch.load(b.checkpoint_path, weights_only=True)
    assert (ca["pos"], ca["epoch"]) == (cb["pos"], cb["epoch"])
    assert torch.equal(ca["perm"], cb["perm"]) and torch.equal(ca["shuffle_rng"], cb["shuffle_rng"])


def test_baseline_trained_with_workers_has_the_same_weights(tmp_path):
    from training.baselines import preset, train_baseline

    data = SyntheticDataset(synthetic_scene(6), 32, cameras_per_frame=2, seed=0)
    cfg = preset("dnr", "tiny").replace(steps=5, checkpoint_every=3)
    a = train_baseline("dnr", data, tmp_path / "a", cfg, progress=False)
    b = train_baseline("dnr", data, tmp_path / "b", cfg, progress=False, workers=2)
    for k, v in a.model.state_dict().items():
        assert torch.equal(v, b.model.state_dict()[k]), k
