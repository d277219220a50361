"""Neural renderer training: loss goes down, resume, NaN guard, fine-tuning, torchrun (DDP)."""

from __future__ import annotations

import csv
import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from core.errors import InputError
from training.losses import vgg_features
from training.renderer import (
    PRESETS,
    SyntheticDataset,
    background_finetune_parameters,
    finetune_background,
    finetune_body,
    finetune_relight,
    load_model,
    relight_parameters,
    synthetic_scene,
    train_renderer,
)

torch.set_num_threads(1)  # 2 threads on the shared 2-core machine are ~50x slower
ROOT = Path(__file__).resolve().parents[1]
TINY = PRESETS["tiny"]


@pytest.fixture(scope="module")
def data():
    return SyntheticDataset(synthetic_scene(6), TINY.image_size, cameras_per_frame=2, seed=0)


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _state(res):
    return {
        **{f"g.{k}": v.clone() for k, v in res.net.state_dict().items()},
        **{f"d.{k}": v.clone() for k, v in res.discriminator.state_dict().items()},
    }


def test_the_detail_losses_enter_the_loss_with_their_weights(data, tmp_path):
    base = TINY.replace(
        steps=4, log_every=2, w_gan=0.0, w_fm=0.0, w_perceptual=0.0, w_pyramid=0.0, w_detail=0.0
    )
    res = train_renderer(
        data,
        tmp_path / "on",
        base.replace(w_pyramid=2.0, w_detail=3.0, w_gradient=4.0),
        progress=False,
    )
    for row in _rows(res.log_path):
        l1, pyr, det, grad = (float(row[k]) for k in ("l1", "pyramid", "detail", "gradient"))
        assert pyr > 0 and det > 0 and grad > 0
        assert math.isclose(
            float(row["loss_g"]), 10 * l1 + 2 * pyr + 3 * det + 4 * grad, rel_tol=1e-4
        )
    res = train_renderer(data, tmp_path / "off", base, progress=False)
    assert all(
        r["pyramid"] == "off" and r["detail"] == "off" and r["gradient"] == "off"
        for r in _rows(res.log_path)
    )


def test_training_lowers_the_loss_with_perceptual_on(data, tmp_path):
    vgg = tmp_path / "vgg.pth"
    torch.manual_seed(0)
    channels = (4, 0, 6, 0, 8)
    torch.save({f"features.{k}": v for k, v in vgg_features(channels).state_dict().items()}, vgg)
    cfg = TINY.replace(
        steps=30,
        log_every=10,
        lr_g=2e-3,
        preview_every=30,
        vgg_path=str(vgg),
        vgg_channels=channels,
    )
    res = train_renderer(data, tmp_path / "run", cfg, progress=False)
    rows = _rows(res.log_path)
    assert [int(r["step"]) for r in rows] == [10, 20, 30]
    assert res.perceptual and rows[0]["perceptual"] != "off"
    l1 = [float(r["l1"]) for r in rows]
    assert l1[-1] < 0.8 * l1[0], l1
    assert (tmp_path / "run" / "previews" / "step_000030.png").is_file()
    cfg2, net, disc = load_model(res.model_path)
    assert cfg2 == cfg and disc is not None
    for k, v in res.net.state_dict().items():
        assert torch.equal(net.state_dict()[k], v)
    # A file from before lr_decay_from existed was trained at constant rates and reads so.
    assert cfg.lr_decay_from == 0.5
    payload = torch.load(res.model_path, weights_only=True)
    del payload["config"]["lr_decay_from"]
    torch.save(payload, tmp_path / "old.pt")
    assert load_model(tmp_path / "old.pt")[0] == cfg.replace(lr_decay_from=1.0)
    # ... and one from before adam_eps at torch's default eps
    del payload["config"]["adam_eps"]
    torch.save(payload, tmp_path / "older.pt")
    assert load_model(tmp_path / "older.pt")[0] == cfg.replace(lr_decay_from=1.0, adam_eps=1e-8)
    # ... and one from before texture_lr_scale at one rate
    assert cfg.texture_lr_scale == 100.0
    del payload["config"]["texture_lr_scale"]
    torch.save(payload, tmp_path / "oldest.pt")
    old = cfg.replace(lr_decay_from=1.0, adam_eps=1e-8, texture_lr_scale=1.0)
    assert load_model(tmp_path / "oldest.pt")[0] == old


def test_resume_after_kill_gives_the_same_weights(data, tmp_path):
    # The learning rates decay from step 4.5: the resumed run must follow the same schedule.
    cfg = TINY.replace(steps=9, checkpoint_every=4, log_every=2, preview_every=0, lr_decay_from=0.5)
    full = train_renderer(data, tmp_path / "a", cfg, progress=False)
    assert full.perceptual is False and _rows(full.log_path)[0]["perceptual"] == "off"

    class Kill(Exception):
        pass

    def kill(step, losses):
        if step == 6:
            raise Kill

    with pytest.raises(Kill):
        train_renderer(data, tmp_path / "b", cfg, progress=False, callback=kill)
    resumed = train_renderer(data, tmp_path / "b", cfg, progress=False)
    assert resumed.resumed_at_step == 4
    a, b = _state(full), _state(resumed)
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k
    strip = lambda rows: [{k: v for k, v in r.items() if k != "seconds"} for r in rows]  # noqa: E731
    assert strip(_rows(full.log_path)) == strip(_rows(resumed.log_path))
    with pytest.raises(InputError, match="different config"):
        train_renderer(data, tmp_path / "b", cfg.replace(lr_d=1e-3), progress=False)


class _Poisoned(torch.utils.data.Dataset):
    """The synthetic set with NaN in one sample's target."""

    def __init__(self, base, bad: int):
        self.base, self.bad = base, bad

    def __len__(self):
        return len(self.base)

    def __getitem__(self, i):
        s = self.base[i]
        if i == self.bad:
            s = dict(s, target=torch.full_like(s["target"], float("nan")))
        return s


def test_nan_guard_skips_reports_and_counts(data, tmp_path, monkeypatch):
    from training.adversarial import AdversarialTrainer

    cfg = TINY.replace(steps=6, log_every=3, preview_every=0)
    seen, untouched = [], []
    orig = AdversarialTrainer.train_step

    def step(self, batch):  # record whether a skipped step left the weights alone
        before = [p.detach().clone() for p in (*self.net.parameters(), *self.disc.parameters())]
        out = orig(self, batch)
        after = [*self.net.parameters(), *self.disc.parameters()]
        if out is None:
            untouched.append(all(torch.equal(a, b) for a, b in zip(before, after)))
        return out

    monkeypatch.setattr(AdversarialTrainer, "train_step", step)
    res = train_renderer(
        _Poisoned(data, 3), tmp_path, cfg, progress=False, callback=lambda s, l: seen.append(l)
    )
    snapshots = [(losses, None) for losses in seen]
    n_skip = sum(losses is None for losses, _ in snapshots)
    assert 1 <= n_skip < 6 and res.skipped_steps == n_skip
    assert untouched == [True] * n_skip  # skipped steps leave the weights untouched
    rows = _rows(res.log_path)
    assert int(rows[-1]["skipped"]) == n_skip
    assert all(math.isfinite(float(r["loss_g"])) for r in rows if r["loss_g"])
    assert all(torch.isfinite(p).all() for p in res.net.parameters())


def test_relighting_trains_exactly_the_last_two_layers_and_the_discriminator(data, tmp_path):
    cfg = TINY.replace(steps=4, preview_every=0)
    base = train_renderer(data, tmp_path / "base", cfg, progress=False)
    g0 = _state(base)
    lit = finetune_relight(base.model_path, data, tmp_path / "lit", steps=3, progress=False)
    assert lit.steps == 3
    names = set(relight_parameters(lit.net))
    # The last two layers before the image: the refinement's last residual block, the output.
    assert names == {
        f"refiner.{layer}.{p}"
        for layer in ("blocks.1.conv1", "blocks.1.conv2", "to_rgb")
        for p in ("weight", "bias")
    }
    for n, p in lit.net.named_parameters():
        if n in names:
            assert not torch.equal(p, g0[f"g.{n}"]), f"{n} did not train"
        else:
            assert torch.equal(p, g0[f"g.{n}"]), f"{n} changed but is frozen"
    d1 = dict(lit.discriminator.named_parameters())
    d0 = {k[2:]: v for k, v in g0.items() if k.startswith("d.") and k[2:] in d1}
    assert d0 and any(not torch.equal(d1[k], v) for k, v in d0.items())  # it trains too


def test_finetuning_touches_only_what_it_should(data, tmp_path):
    cfg = TINY.replace(steps=8, preview_every=0)
    base = train_renderer(data, tmp_path / "base", cfg, progress=False)
    g0, d0 = _state(base), None
    d0 = {k: v for k, v in g0.items() if k.startswith("d.")}

    bg = finetune_background(base.model_path, data, tmp_path / "bg", steps=3, progress=False)
    assert bg.steps == 3
    names = set(background_finetune_parameters(bg.net))
    assert any(n.startswith("refiner.") for n in names)
    assert any(n.startswith("decoder.ups.") for n in names)
    assert not any(n.startswith(("texture.", "encoder.", "spade.")) for n in names)
    for n, p in bg.net.named_parameters():
        if n in names:
            assert not torch.equal(p, g0[f"g.{n}"]), f"{n} did not train"
        else:
            assert torch.equal(p, g0[f"g.{n}"]), f"{n} changed but is frozen"
    d1 = dict(bg.discriminator.named_parameters())
    assert any(not torch.equal(d1[k[2:]], v) for k, v in d0.items() if k[2:] in d1)

    body = finetune_body(base.model_path, data, tmp_path / "body", progress=False)
    assert body.steps == math.ceil(0.25 * cfg.steps) == 2
    changed = [not torch.equal(p, g0[f"g.{n}"]) for n, p in body.net.named_parameters()]
    assert all(changed), "body fine-tuning trains every parameter"


def test_torchrun_two_processes_end_with_equal_weights(tmp_path):
    out = tmp_path / "ddp"
    cmd = [
        sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
        "-m", "training.renderer.ddp", "--out", str(out), "--preset", "tiny", "--steps", "3",
        "--synthetic", "4", "--cameras", "2", "--dump-weights",
    ]  # fmt: skip
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-3000:]
    w0 = torch.load(out / "rank0_weights.pt", weights_only=True)
    w1 = torch.load(out / "rank1_weights.pt", weights_only=True)
    for part in ("generator", "discriminator"):
        assert w0[part].keys() == w1[part].keys()
        for k in w0[part]:
            assert torch.equal(w0[part][k], w1[part][k]), f"{part}.{k}"
    torch.manual_seed(TINY.seed)
    from training.renderer import RenderNet

    init = RenderNet(TINY).state_dict()
    assert any(not torch.equal(init[k], w0["generator"][k]) for k in init)  # it trained
    assert len(_rows(out / "renderer_loss.csv")) >= 1


def test_sigkill_mid_run_then_rerun_continues_to_the_same_weights(tmp_path):
    """A real ``kill -9`` of a training process; the rerun resumes from the last checkpoint."""
    import os
    import signal
    import time

    def cmd(out):
        return [
            sys.executable, "-m", "training.renderer.ddp", "--out", str(out), "--preset", "tiny",
            "--steps", "60", "--synthetic", "4", "--cameras", "2", "--dump-weights",
        ]  # fmt: skip

    ref = subprocess.run(cmd(tmp_path / "ref"), cwd=ROOT, capture_output=True, timeout=240)
    assert ref.returncode == 0, ref.stderr[-2000:]
    out = tmp_path / "killed"
    proc = subprocess.Popen(
        cmd(out), cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    deadline = time.time() + 120
    while not (out / "renderer_train.pt").is_file() and time.time() < deadline:
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (out / "renderer.pt").is_file(), "the run finished before it was killed"
    again = subprocess.run(cmd(out), cwd=ROOT, capture_output=True, timeout=240)
    assert again.returncode == 0, again.stderr[-2000:]
    a = torch.load(tmp_path / "ref" / "rank0_weights.pt", weights_only=True)
    b = torch.load(out / "rank0_weights.pt", weights_only=True)
    for part in ("generator", "discriminator"):
        for k in a[part]:
            assert torch.equal(a[part][k], b[part][k]), f"{part}.{k}"


def test_learning_rates_follow_the_schedule(data, tmp_path, monkeypatch):
    import training.adversarial as train_module  # the one trainer's step

    seen = []
    real = train_module.set_lr
    monkeypatch.setattr(train_module, "set_lr", lambda opt, lr: (seen.append(lr), real(opt, lr)))
    cfg = TINY.replace(steps=4, lr_g=1e-3, lr_d=2e-3, lr_decay_from=0.5, preview_every=0)
    res = train_renderer(data, tmp_path, cfg, progress=False)
    # (G, D) per step: constant for steps 0 and 1, then 2/2 and 1/2 of the base rates.
    assert seen == pytest.approx([1e-3, 2e-3, 1e-3, 2e-3, 1e-3, 2e-3, 5e-4, 1e-3])
    assert PRESETS["cpu"].lr_decay_from == 0.5 and PRESETS["paper"].lr_decay_from == 1.0
    assert res.steps == 4
    for bad in (-0.1, 1.5, float("nan"), True, "half"):
        with pytest.raises(InputError, match="lr_decay_from"):
            TINY.replace(lr_decay_from=bad)


def test_l1_alone_trains_no_discriminator_and_the_same_generator(data, tmp_path, monkeypatch):
    """With no GAN or feature-matching term the discriminator changes no generator weight: the
    run builds none (faster) and ends with the generator a discriminator run would give."""
    import training.renderer.train as train_module

    cfg = TINY.replace(steps=6, log_every=2, w_fm=0.0, w_gan=0.0, w_perceptual=0.0)
    plain = train_renderer(data, tmp_path / "plain", cfg, progress=False)
    assert plain.discriminator is None and load_model(plain.model_path)[2] is None
    # the same run, but with the discriminator built and updated every step as before
    monkeypatch.setattr(train_module, "_needs_discriminator", lambda config: True)
    with_d = train_renderer(data, tmp_path / "with-d", cfg, progress=False)
    assert with_d.discriminator is not None
    for k, v in plain.net.state_dict().items():
        assert torch.equal(v, with_d.net.state_dict()[k]), k


def test_adam_eps_reaches_both_optimisers_and_bad_values_are_refused(data, tmp_path, monkeypatch):
    import training.adversarial as train_module  # the one trainer's optimisers

    seen = []
    real = train_module.adam
    monkeypatch.setattr(train_module, "adam", lambda *a: (seen.append(a[3]), real(*a))[1])
    cfg = TINY.replace(steps=1, adam_eps=1e-15, preview_every=0)
    train_renderer(data, tmp_path, cfg, progress=False)
    assert seen == [1e-15, 1e-15]  # the generator's and the discriminator's
    for bad in (0.0, -1e-8, float("nan"), True, "small"):
        with pytest.raises(InputError, match="adam_eps"):
            TINY.replace(adam_eps=bad)


def test_texture_regulariser_pulls_our_texture_towards_the_image(data, tmp_path):
    """``w_texture`` gives our renderer DNR's regulariser: trained on it alone, the first 3
    sampled texture channels come closer to the image on the proxy; at 0 it is not computed."""
    from training.renderer.data import CUR, RenderBatch
    from training.renderer.model import RenderNet, texture_colour_loss
    from training.renderer.train import RendererMethod

    batch = RenderBatch.from_dict({k: torch.as_tensor(v) for k, v in data[0].items()})
    inputs = batch.generator_inputs(True)

    def regulariser(net):
        with torch.no_grad():
            rgb, alpha, tex = net(**inputs, with_texture=True)
            assert torch.equal(tex, net.texture(inputs["uv"], inputs["mask"]))
            assert torch.equal(rgb, net(**inputs)[0])
            return float(texture_colour_loss(tex, batch.target[:, CUR], inputs["mask"]))

    cfg = TINY.replace(
        steps=8,
        lr_g=0.02,
        texture_lr_scale=1.0,
        w_l1=0.0,
        w_perceptual=0.0,
        w_fm=0.0,
        w_gan=0.0,
        w_texture=1.0,
    )
    torch.manual_seed(cfg.seed)
    before = regulariser(RenderNet(cfg))
    after = regulariser(train_renderer(data, tmp_path, cfg, progress=False).net)
    assert after < 0.9 * before  # 0.487 -> 0.393 when written
    assert RendererMethod(True).generate(RenderNet(TINY), batch)[1] is None
    # the regulariser's value by hand: |0.5 - 0.25| on the one masked pixel
    tex, img = torch.full((1, 4, 1, 2), 0.5), torch.full((1, 3, 1, 2), 0.25)
    mask = torch.tensor([[[[1.0, 0.0]]]])
    assert float(texture_colour_loss(tex, img, mask)) == pytest.approx(0.25)
    assert float(texture_colour_loss(tex, img, mask * 0)) == 0.0
    for bad in (-1.0, float("nan"), "strong"):
        with pytest.raises(InputError, match="w_texture"):
            TINY.replace(w_texture=bad)


def test_texture_lr_scale_gives_the_texels_their_own_rate_on_the_schedule(
    data, tmp_path, monkeypatch
):
    import training.adversarial as train_module
    from training.adversarial import generator_groups
    from training.renderer.model import RenderNet

    seen = []
    real = train_module.set_lr

    def spy(opt, lr):
        real(opt, lr)
        if opt is not None and len(opt.param_groups) == 2:  # the generator's
            seen.extend(g["lr"] for g in opt.param_groups)

    monkeypatch.setattr(train_module, "set_lr", spy)
    cfg = TINY.replace(
        steps=4, lr_g=1e-3, lr_decay_from=0.5, texture_lr_scale=10.0, preview_every=0
    )
    train_renderer(data, tmp_path, cfg, progress=False)
    # (network, texture) per step: constant for steps 0 and 1, then 2/2 and 1/2 of the rates
    assert seen == pytest.approx([1e-3, 1e-2, 1e-3, 1e-2, 1e-3, 1e-2, 5e-4, 5e-3])
    groups = generator_groups(RenderNet(cfg), 1e-3, 10.0)
    texels = sum(p.numel() for p in groups[1]["params"])
    assert texels == sum(p.numel() for p in RenderNet(cfg).texture.parameters())
    for bad in (0.0, -1.0, float("inf"), True):
        with pytest.raises(InputError, match="texture_lr_scale"):
            TINY.replace(texture_lr_scale=bad)
