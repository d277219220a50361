"""Baselines (Pix2Pix, DNR, DNR + GAN): shapes, learning, resume, guard, bad input, loading."""

from __future__ import annotations

import csv

import pytest
import torch

from core.errors import InputError
from training.baselines import (
    KINDS,
    build_model,
    check_batch,
    load_baseline,
    load_for_evaluation,
    preset,
    save_baseline,
    synthetic_batch,
    train_baseline,
)
from training.renderer import PRESETS as RENDERER_PRESETS
from training.renderer import RenderNet, SyntheticDataset, save_model, synthetic_scene

torch.set_num_threads(1)  # the shared 2-core machine


class ShadedDataset:
    """A renderer data set plus ``proxy_shading`` (a stand-in: brighter towards the top of the
    UV chart, 0 off the proxy)."""

    def __init__(self, base, corrupt: bool = False):
        self.base = base
        self.corrupt = corrupt

    def __len__(self):
        return len(self.base)

    def __getitem__(self, i):
        s = dict(self.base[i])
        s["proxy_shading"] = s["proxy_mask"] * (0.3 + 0.7 * s["uv"][:, 1:2])
        if self.corrupt:
            s["target"] = torch.full_like(s["target"], float("nan"))
        return s


@pytest.fixture(scope="module")
def data():
    return ShadedDataset(SyntheticDataset(synthetic_scene(6), 32, cameras_per_frame=2, seed=0))


def _collate(data, idx=None):
    idx = range(len(data)) if idx is None else idx
    return torch.utils.data.default_collate([data[i] for i in idx])


def _l1(model, batch):
    return (model.render(batch) - batch["target"][:, 1]).abs().mean().item()


def _rows(path):
    with open(path, newline="") as f:
        return [{k: v for k, v in r.items() if k != "seconds"} for r in csv.DictReader(f)]


@pytest.mark.parametrize("kind", KINDS)
def test_render_shapes_and_range(kind):
    torch.manual_seed(0)
    model = build_model(preset(kind, "tiny"))
    batch = synthetic_batch(32, 3)
    out = model.render(batch)
    assert out.shape == (3, 3, 32, 32) and out.dtype == torch.float32
    assert 0 <= out.min() and out.max() <= 1
    one = model.render({k: v[0] for k, v in batch.items()})  # a single sample, no B
    assert one.shape == (1, 3, 32, 32)
    assert torch.allclose(one[0], out[0], atol=1e-6)  # eval mode: no batch dependence
    assert model.training  # render restores the mode
    big = model.render(synthetic_batch(64, 1))  # any size divisible by the stride
    assert big.shape == (1, 3, 64, 64)


@pytest.mark.parametrize("kind", KINDS)
def test_training_lowers_l1(kind, data, tmp_path):
    batch = _collate(data)
    cfg = preset(kind, "tiny").replace(steps=40, log_every=10, checkpoint_every=40)
    torch.manual_seed(0)
    before = _l1(build_model(cfg), batch)
    res = train_baseline(kind, data, tmp_path, cfg, progress=False)
    after = _l1(res.model, batch)
    assert after < 0.7 * before, (before, after)
    assert res.skipped_steps == 0 and res.steps == 40
    rows = _rows(res.log_path)
    assert [int(r["step"]) for r in rows] == [10, 20, 30, 40]
    assert (rows[0]["gan_g"] == "off") == (kind == "dnr")
    assert (tmp_path / f"{kind}.pt").is_file()
    loaded = load_baseline(tmp_path / f"{kind}.pt")
    assert not loaded.training
    assert torch.equal(loaded.render(batch), res.model.render(batch))


class _Stop(Exception):
    pass


def _stop_at(n):
    def cb(step, losses):
        if step == n:
            raise _Stop

    return cb


@pytest.mark.parametrize("kind", ["pix2pix", "dnr-gan"])
def test_resume_gives_the_weights_of_an_uninterrupted_run(kind, data, tmp_path):
    # Rates decay from step 4: the resumed run must follow the same schedule.
    cfg = preset(kind, "tiny").replace(steps=8, checkpoint_every=3, log_every=2, lr_decay_from=0.5)
    full = train_baseline(kind, data, tmp_path / "full", cfg, progress=False)
    with pytest.raises(_Stop):
        train_baseline(kind, data, tmp_path / "cut", cfg, progress=False, callback=_stop_at(5))
    resumed = train_baseline(kind, data, tmp_path / "cut", cfg, progress=False)
    assert resumed.resumed_at_step == 3
    a, b = full.model.state_dict(), resumed.model.state_dict()
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k
    da, db = full.discriminator.state_dict(), resumed.discriminator.state_dict()
    assert all(torch.equal(da[k], db[k]) for k in da)
    assert _rows(full.log_path) == _rows(resumed.log_path)
    again = train_baseline(kind, data, tmp_path / "cut", cfg, progress=False)  # finished
    assert again.resumed_at_step == 8
    with pytest.raises(InputError, match="different config"):
        train_baseline(kind, data, tmp_path / "cut", cfg.replace(lr_g=1e-4), progress=False)


def test_non_finite_steps_are_skipped(data, tmp_path):
    bad = ShadedDataset(data.base, corrupt=True)
    cfg = preset("dnr", "tiny").replace(steps=3, log_every=1)
    torch.manual_seed(0)
    fresh = build_model(cfg).state_dict()
    res = train_baseline("dnr", bad, tmp_path, cfg, progress=False)
    assert res.skipped_steps == 3
    state = res.model.state_dict()
    assert all(torch.equal(fresh[k], state[k]) for k in fresh)
    assert [r["skipped"] for r in _rows(res.log_path)] == ["1", "2", "3"]


def test_bad_inputs_raise(data, tmp_path):
    model = build_model(preset("pix2pix", "tiny"))
    batch = synthetic_batch(32, 2)
    missing = {k: v for k, v in batch.items() if k != "proxy_shading"}
    with pytest.raises(InputError, match="proxy_shading"):
        model.render(missing)
    wrong = dict(batch, proxy_shading=torch.zeros(2, 3, 3, 32, 32))
    with pytest.raises(InputError, match="proxy_shading"):
        model.render(wrong)
    mismatch = dict(batch, background=torch.zeros(2, 3, 3, 16, 16))
    with pytest.raises(InputError, match="background"):
        model.render(mismatch)
    with pytest.raises(InputError, match="divisible"):
        model.render(synthetic_batch(36, 1))
    with pytest.raises(InputError):
        check_batch([1, 2], ["uv"])
    with pytest.raises(InputError, match="proxy_shading"):  # renderer samples only
        train_baseline("pix2pix", data.base, tmp_path / "p", preset("pix2pix", "tiny"),
                       steps=1, progress=False)  # fmt: skip
    with pytest.raises(InputError, match="not 'dnr'"):
        train_baseline("dnr", data, tmp_path / "d", preset("dnr-gan", "tiny"), progress=False)
    with pytest.raises(InputError, match="unknown baseline"):
        train_baseline("cyclegan", data, tmp_path / "c", progress=False)
    with pytest.raises(InputError, match="L1 only"):
        preset("dnr", "tiny").replace(w_gan=1.0)


def test_too_small_data_sets_are_refused_by_both_trainers(data, tmp_path):
    """The one trainer refuses an empty data set, and one smaller than a batch, with a message
    (ours and a baseline alike), before any file is written."""
    from training.renderer import train_renderer

    class _First:
        def __init__(self, base, n):
            self.base, self.n = base, n

        def __len__(self):
            return self.n

        def __getitem__(self, i):
            if not 0 <= i < self.n:
                raise IndexError(i)
            return self.base[i]

    tiny = preset("dnr", "tiny")
    for n, message in ((0, "data set is empty"), (tiny.batch_size - 1, "fewer than one batch")):
        small = _First(data, n)
        with pytest.raises(InputError, match=message):
            train_baseline("dnr", small, tmp_path / f"dnr-{n}", tiny, progress=False)
        with pytest.raises(InputError, match=message):
            train_renderer(small, tmp_path / f"ours-{n}", RENDERER_PRESETS["tiny"], progress=False)
        assert not any((tmp_path / f"dnr-{n}").glob("*.pt"))
        assert not any((tmp_path / f"ours-{n}").glob("*.pt"))


def test_bad_model_files(tmp_path):
    with pytest.raises(InputError, match="not found") as e:
        load_baseline(tmp_path / "nope.pt")
    assert "nope.pt" in str(e.value)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"garbage")
    with pytest.raises(InputError, match="junk.pt"):
        load_baseline(junk)
    other = tmp_path / "other.pt"
    torch.save({"format": "something/1"}, other)
    with pytest.raises(InputError, match="not a baseline model"):
        load_for_evaluation(other)


def test_load_for_evaluation_treats_our_renderer_the_same_way(tmp_path):
    cfg = RENDERER_PRESETS["tiny"]
    torch.manual_seed(0)
    net = RenderNet(cfg).eval()
    save_model(tmp_path / "renderer.pt", net, None)
    model = load_for_evaluation(tmp_path / "renderer.pt")
    batch = synthetic_batch(32, 2)
    out = model.render(batch)
    assert out.shape == (2, 3, 32, 32)
    p2p = build_model(preset("pix2pix", "tiny"))
    save_baseline(tmp_path / "pix2pix.pt", p2p)
    assert load_for_evaluation(tmp_path / "pix2pix.pt").render(batch).shape == (2, 3, 32, 32)


def test_baseline_learning_rates_follow_the_schedule(data, tmp_path, monkeypatch):
    import training.adversarial as train_module  # the one trainer's step

    seen = []
    real = train_module.set_lr
    monkeypatch.setattr(train_module, "set_lr", lambda opt, lr: (seen.append(lr), real(opt, lr)))
    cfg = preset("dnr", "tiny").replace(steps=4, lr_g=1e-3, lr_decay_from=0.5)
    train_baseline("dnr", data, tmp_path, cfg, progress=False)
    assert seen[::2] == pytest.approx([1e-3, 1e-3, 1e-3, 5e-4])  # the generator's, per step
    assert preset("dnr", "cpu").lr_decay_from == 1.0  # measured: decay made the baselines worse
    with pytest.raises(InputError, match="lr_decay_from"):
        preset("pix2pix", "tiny").replace(lr_decay_from=2)


def test_baseline_adam_eps_reaches_its_optimiser(data, tmp_path, monkeypatch):
    import training.adversarial as train_module  # the one trainer's optimisers

    seen = []
    real = train_module.adam
    monkeypatch.setattr(train_module, "adam", lambda *a: (seen.append(a[3]), real(*a))[1])
    cfg = preset("dnr", "tiny").replace(steps=1, adam_eps=1e-15)
    res = train_baseline("dnr", data, tmp_path, cfg, progress=False)
    assert seen[0] == 1e-15
    # a model file from before adam_eps reads as trained, at torch's default
    payload = torch.load(res.model_path, weights_only=True)
    del payload["config"]["adam_eps"]
    torch.save(payload, tmp_path / "old.pt")
    assert load_baseline(tmp_path / "old.pt").config == cfg.replace(adam_eps=1e-8)
    with pytest.raises(InputError, match="adam_eps"):
        preset("pix2pix", "tiny").replace(adam_eps=0)
