"""Neural renderer: parts and shapes, losses and VGG loading, live inference (crop, stream)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from core.camera import make_camera
from core.errors import InputError
from core.features import joint_window
from core.mesh import Mesh
from core.raster import MeshScene
from core.shading import render_background
from tests.conftest import assert_close
from training.losses import (
    VGG19_CHANNELS,
    _tap_indices,
    detail_energy,
    detail_energy_l1,
    feature_matching,
    gan_d_loss,
    gan_g_loss,
    gradient_similarity_loss,
    laplacian_bands,
    load_perceptual,
    pyramid_l1,
    vgg_features,
)
from training.renderer import (
    PRESETS,
    FrameState,
    NeuralRenderer,
    PatchDiscriminator,
    RenderBatch,
    RendererConfig,
    RenderNet,
    synthetic_scene,
)
from training.renderer.model import NeuralTexture, receptive_field

torch.set_num_threads(1)  # 2 threads on the shared 2-core machine are ~50x slower
TINY_VGG = (4, 0, 6, 0, 8, 0, 8, 0, 8)


def _inputs(cfg: RendererConfig, b: int, size: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    mask = (torch.rand(b, 1, size, size, generator=g) > 0.5).float()
    uv = torch.rand(b, 2, size, size, generator=g) * mask
    motion = torch.rand(b, cfg.motion_channels, size, size, generator=g) * mask
    return uv, motion, mask


# -- config ------------------------------------------------------------------------------------


def test_presets_and_config_checks():
    cpu, paper = PRESETS["cpu"], PRESETS["paper"]
    assert cpu == RendererConfig()
    assert cpu.image_size == 128 and paper.image_size == 512
    assert paper.in_channels == 64 + 95 == 159
    assert paper.image_size // paper.stride == 16 and paper.max_width == 512
    assert RendererConfig(use_motion=False).in_channels == 64 + 1  # texture + coverage mask
    assert RendererConfig.from_dict(paper.to_dict()) == paper
    with pytest.raises(InputError, match="divisible"):
        RendererConfig(image_size=100, n_down=3)
    with pytest.raises(InputError, match="gan_mode"):
        RendererConfig(gan_mode="wgan")
    with pytest.raises(InputError, match="unknown renderer config"):
        RendererConfig.from_dict({"nope": 1})


# -- parts ---------------------------------------------------------------------------------------


def test_texture_samples_texel_centres_exactly_and_masks():
    tex = NeuralTexture((8, 4), 2, seed=3)
    s = 8
    rows, cols = torch.meshgrid(torch.arange(s), torch.arange(s), indexing="ij")
    uv = torch.stack([(cols + 0.5) / s, 1 - (rows + 0.5) / s])[None].float()  # (1, 2, 8, 8)
    mask = torch.ones(1, 1, s, s)
    mask[..., 0, 0] = 0
    out = tex(uv, mask)
    assert out.shape == (1, 4, s, s)
    expected = tex.levels[0][0].detach().clone()
    expected[:, 0, 0] = 0
    assert_close(out[0, :2].detach(), expected, atol=1e-6, what="level 0 at texel centres")
    assert float(out[0, :, 0, 0].detach().abs().max()) == 0.0


@pytest.mark.parametrize("name", ["tiny", "cpu"])
def test_render_net_shapes(name):
    cfg = PRESETS[name]
    torch.manual_seed(0)
    net = RenderNet(cfg)
    size = 2 * cfg.stride
    uv, motion, mask = _inputs(cfg, 2, size)
    x = net.input_features(uv, motion, mask)
    assert x.shape == (2, cfg.in_channels, size, size)
    z = net.encode(x)
    assert z.shape == (2, net.encoder.out_channels, 2, 2)
    with torch.no_grad():
        rgb, a = net(uv, motion, mask, uv, motion, mask, torch.rand(2, 3, size, size))
    assert rgb.shape == (2, 3, size, size) and a.shape == (2, 1, size, size)
    assert float(rgb.min()) >= 0 and float(rgb.max()) <= 1
    # zero in, zero out: the encoder of an empty frame is exactly zero
    with torch.no_grad():
        assert float(net.encode(torch.zeros_like(x)).abs().max()) == 0.0


def test_paper_latent_and_ablation_without_motion():
    paper = PRESETS["paper"]
    torch.manual_seed(0)
    net = RenderNet(paper)
    assert net.encoder.out_channels == 512
    x = torch.rand(1, paper.in_channels, 64, 64)  # 512 px gives 16 x 16; 64 px gives 2 x 2
    assert net.encode(x).shape == (1, 512, 2, 2)
    cfg = PRESETS["tiny"].replace(use_motion=False)
    net = RenderNet(cfg)
    uv, _, mask = _inputs(cfg, 1, 8)
    x = net.input_features(uv, None, mask)
    assert x.shape == (1, cfg.texture_out_channels + 1, 8, 8)
    # the last channel tells the network where the proxy is, as DNR's input does
    assert torch.equal(x[:, -1:], mask)
    rgb, _ = net(uv, None, mask, uv, None, mask, torch.rand(1, 3, 8, 8))
    assert rgb.shape == (1, 3, 8, 8)


def test_texture_readout_draws_the_texture_on_the_proxy_and_nothing_off_it():
    torch.manual_seed(0)
    cfg = PRESETS["tiny"]
    assert cfg.texture_readout and not PRESETS["paper"].texture_readout
    net = RenderNet(cfg).eval()
    uv, motion, mask = _inputs(cfg, 1, 8)
    bg = torch.rand(1, 3, 8, 8)
    with torch.no_grad():
        x = net.input_features(uv, motion, mask)
        z, skips = net.encode_with_skips(x)
        # the readout rides last with the skips: RGB and alpha logits, zero off the proxy
        assert len(skips) == cfg.n_down + 1 and skips[-1].shape == (1, 4, 8, 8)
        assert float((skips[-1] * (1 - mask)).abs().max()) == 0.0
        before, _ = net.decode(z, z, bg, skips)
        # a readout that turns the texture's first channel into red: the proxy turns redder,
        # by as much as the logit moved, and off the proxy nothing changes
        net.readout.weight.zero_()
        net.readout.weight[0, 0] = 1.0
        net.texture.levels[0].fill_(3.0)
        x = net.input_features(uv, motion, mask)
        z, skips = net.encode_with_skips(x)
        red, _ = net.decode(z, z, bg, skips)
        net.readout.weight.zero_()
        z, skips = net.encode_with_skips(x)
        plain, _ = net.decode(z, z, bg, skips)
    on = mask[0, 0] > 0
    assert (red[0, 0][on] > plain[0, 0][on]).all()
    assert torch.equal(red[0, 1:], plain[0, 1:]) and torch.equal(red[0, 0][~on], plain[0, 0][~on])
    assert before.shape == red.shape
    with pytest.raises(ValueError, match="texture out"):
        net.decode(z, z, bg, None)
    # its alpha carves the proxy: a large negative alpha logit shows the background there
    with torch.no_grad():
        net.readout.weight[3, 0] = -1000.0
        z, skips = net.encode_with_skips(x)
        carved, _ = net.decode(z, z, bg, skips)
    assert_close(carved[0][:, on], bg[0][:, on], atol=1e-6, what="the background on the proxy")
    without_blend = RenderNet(cfg.replace(blend_output=False))
    assert without_blend.readout.out_channels == 3


def test_model_files_from_before_the_readout_load_without_one():
    stored = {k: v for k, v in PRESETS["tiny"].to_dict().items() if k != "texture_readout"}
    assert RendererConfig.from_stored(stored).texture_readout is False
    assert RendererConfig.from_stored(PRESETS["tiny"].to_dict()).texture_readout is True
    assert RenderNet(RendererConfig.from_stored(stored)).readout is None


def test_the_alpha_prior_raises_the_blends_alpha_on_the_proxy_and_nowhere_else():
    torch.manual_seed(0)
    for use_motion in (True, False):
        cfg = PRESETS["tiny"].replace(alpha_prior=5.0, use_motion=use_motion)
        net = RenderNet(cfg).eval()
        uv, motion, mask = _inputs(cfg, 2, 8)
        with torch.no_grad():
            x = net.input_features(uv, motion if use_motion else None, mask)
            assert torch.equal(net.coverage(x), mask)
            net.readout.weight.zero_()
            logits = net.encode_with_skips(x)[1][-1]
        assert torch.equal(logits[:, 3:4], 5.0 * mask)  # the alpha's logit, on the proxy only
        assert float(logits[:, :3].abs().max()) == 0.0  # the colours untouched
    with pytest.raises(InputError, match="alpha_prior"):
        PRESETS["tiny"].replace(alpha_prior=float("nan"))


def test_the_guided_decoder_sees_the_body_where_the_unguided_one_cannot():
    """With ``background_guide`` the decoder's garment mask A depends on the body-only image
    under the proxy; without it the background reaches the image only through the blend."""
    torch.manual_seed(0)
    cfg = PRESETS["tiny"]
    uv, motion, mask = _inputs(cfg, 1, 8)
    bg, other = torch.rand(1, 3, 8, 8), torch.rand(1, 3, 8, 8)
    masks = {}
    for guided in (False, True):
        net = RenderNet(cfg.replace(background_guide=guided)).eval()
        with torch.no_grad():
            z, skips = net.encode_with_skips(net.input_features(uv, motion, mask))
            masks[guided] = [net.decode(z, z, b, skips)[1] for b in (bg, other)]
    assert torch.equal(*masks[False])
    assert float((masks[True][0] - masks[True][1]).abs().max()) > 1e-4
    # each up stage's fuse takes the background's 3 channels beside its input and skip
    net = RenderNet(cfg.replace(background_guide=True))
    plain = RenderNet(cfg)
    for up, up0 in zip(net.decoder.ups, plain.decoder.ups, strict=True):
        assert up.fuse[0].in_channels == up0.fuse[0].in_channels + 3
    with pytest.raises(ValueError, match="guided by the background"):
        net.decoder(z, skips, None)
    # model files from before the field load unguided
    stored = {k: v for k, v in cfg.to_dict().items() if k != "background_guide"}
    assert RendererConfig.from_stored(stored).background_guide is False


def test_without_temporal_conditioning_frame_t_minus_1_changes_nothing():
    torch.manual_seed(0)
    cfg = PRESETS["tiny"]
    uv, motion, mask = _inputs(cfg, 1, 8)
    uv2, motion2, mask2 = _inputs(cfg, 1, 8, seed=1)
    bg = torch.rand(1, 3, 8, 8)
    for temporal in (True, False):
        net = RenderNet(cfg.replace(use_temporal=temporal)).eval()
        with torch.no_grad():
            same, _ = net(uv, motion, mask, uv, motion, mask, bg)
            other, _ = net(uv, motion, mask, uv2, motion2, mask2, bg)
        # with it, the previous frame modulates the latent; without, it is never looked at
        assert torch.equal(same, other) is (not temporal)


def test_discriminator_is_a_70px_spectral_norm_patchgan():
    d = PatchDiscriminator(8)
    assert receptive_field([(4, 2), (4, 2), (4, 2), (4, 1), (4, 1)]) == 70
    assert all(hasattr(layer, "parametrizations") for layer in [*d.layers, d.head])
    x = torch.rand(1, 6, 128, 128, requires_grad=True)
    logits, feats = d(x)
    assert logits.shape == (1, 1, 14, 14) and len(feats) == 4
    logits[0, 0, 7, 7].backward()
    nz = (x.grad[0].abs().sum(0) > 0).nonzero()
    extent = (nz.max(0).values - nz.min(0).values + 1).tolist()
    assert extent == [70, 70]


def test_render_batch_contract():
    cfg = PRESETS["tiny"]
    s = {
        "uv": torch.zeros(3, 2, 8, 8),
        "motion": torch.zeros(3, 95, 8, 8),
        "proxy_mask": torch.zeros(3, 1, 8, 8),
        "target": torch.zeros(3, 3, 8, 8),
        "background": torch.zeros(3, 3, 8, 8),
        "target_mask": torch.zeros(3, 1, 8, 8),
    }
    b = RenderBatch.from_dict(s)
    assert b.uv.shape == (1, 3, 2, 8, 8) and b.size == (8, 8)
    inp = b.generator_inputs(cfg.use_motion)
    assert inp["motion"].shape == (1, 95, 8, 8) and inp["background"].shape == (1, 3, 8, 8)
    bad = dict(s, target=torch.zeros(3, 4, 8, 8))
    with pytest.raises(InputError, match=r"data\.pt: sample\['target'\]"):
        RenderBatch.from_dict(bad, name="data.pt")
    with pytest.raises(InputError, match="missing"):
        RenderBatch.from_dict({k: v for k, v in s.items() if k != "uv"})


def test_render_batch_with_motion_per_vertex(rng):
    """The per-vertex form of the motion features: interpolated where the batch is, equal to
    the map the loader makes (core.features.interpolate), checked like the rest."""
    from core.features import interpolate
    from core.raster import Fragments
    from training.renderer.data import motion_maps

    v, size = 7, 8
    faces = rng.integers(0, v, (5, 3))
    face_id = rng.integers(-1, 5, (3, size, size))
    bary = rng.dirichlet(np.ones(3), (3, size, size)).astype(np.float32)
    feats = rng.random((3, v, 95), dtype=np.float32)
    covered = face_id >= 0
    s = {
        "uv": torch.zeros(3, 2, size, size),
        "proxy_mask": torch.from_numpy(covered[:, None].astype(np.float32)),
        "target": torch.zeros(3, 3, size, size),
        "background": torch.zeros(3, 3, size, size),
        "target_mask": torch.zeros(3, 1, size, size),
        "motion_corners": torch.from_numpy(
            faces[np.where(covered, face_id, 0)].astype(np.int32).transpose(0, 3, 1, 2)
        ),
        "motion_weights": torch.from_numpy((bary * covered[..., None]).transpose(0, 3, 1, 2)),
        "vertex_motion": torch.from_numpy(feats),
    }
    b = RenderBatch.from_dict(s)
    assert b.motion is None and b.vertex_motion.shape == (1, 3, v, 95)
    for j in range(3):
        frags = Fragments(face_id[j], bary[j], np.zeros((size, size), np.float32))
        want = interpolate(frags, faces, feats[j]).transpose(2, 0, 1)
        assert_close(b.motion_frame(j)[0], want, atol=1e-6, what=f"frame {j}")
    inp = b.generator_inputs(True)
    assert inp["motion"].shape == (1, 95, size, size)
    assert torch.equal(inp["motion_prev"], motion_maps(*(t[:, 0] for t in (
        b.motion_corners, b.motion_weights, b.vertex_motion))))  # fmt: skip
    assert b.to("cpu").motion is None and torch.equal(b.to("cpu").motion_corners, b.motion_corners)
    bad = dict(s, motion_corners=s["motion_corners"] + v)
    with pytest.raises(InputError, match=r"d\.pt: sample\['motion_corners'\] holds ids outside"):
        RenderBatch.from_dict(bad, name="d.pt")
    bad = dict(s, vertex_motion=torch.zeros(3, v, 94))
    with pytest.raises(InputError, match=r"sample\['vertex_motion'\] must be \(B, 3, V, 95\)"):
        RenderBatch.from_dict(bad)
    with pytest.raises(InputError, match="missing"):  # neither form of the motion features
        RenderBatch.from_dict({k: t for k, t in s.items() if k != "vertex_motion"})


@pytest.mark.gpu
def test_gpu_motion_maps_match_cpu(rng):
    from training.renderer.data import motion_maps

    corners = torch.from_numpy(rng.integers(0, 40, (2, 3, 16, 16)).astype(np.int32))
    weights = torch.from_numpy(rng.random((2, 3, 16, 16), dtype=np.float32))
    feats = torch.from_numpy(rng.random((2, 40, 95), dtype=np.float32))
    cpu = motion_maps(corners, weights, feats)
    gpu = motion_maps(corners.cuda(), weights.cuda(), feats.cuda()).cpu()
    assert_close(gpu, cpu, atol=1e-6, what="motion maps")


# -- losses ----------------------------------------------------------------------------------------


def _stripes(size: int = 32) -> torch.Tensor:
    """(1, 3, size, size): dark and light rows 2 px apart (a frill tier's edges), in [0.2, 0.8]."""
    rows = (torch.arange(size) // 2 % 2).float() * 0.6 + 0.2
    return rows.view(1, 1, size, 1).expand(1, 3, size, size).clone()


def _blurred(x: torch.Tensor) -> torch.Tensor:
    return torch.nn.functional.avg_pool2d(
        torch.nn.functional.pad(x, (1, 1, 1, 1), mode="replicate"), 3, 1
    )


def test_pyramid_l1_sees_detail_and_not_colour():
    x = _stripes()
    bands = laplacian_bands(x)
    assert [b.shape[-1] for b in bands] == [32, 16, 8]
    assert float(pyramid_l1(x, x)) == 0.0
    # a constant offset is a colour (L1's business), not detail
    assert float(pyramid_l1(x + 0.1, x)) < 1e-6
    # a blurred copy loses the stripes, a shifted copy moves them, a flat one has none
    blur, shift, flat = _blurred(x), torch.roll(x, 1, 2), torch.full_like(x, 0.5)
    assert 0 < float(pyramid_l1(blur, x)) < float(pyramid_l1(flat, x))
    assert float(pyramid_l1(shift, x)) > float(pyramid_l1(blur, x))
    # on the stripes' band, more than plain L1 charges for the blur
    l1 = torch.nn.functional.l1_loss
    assert float(pyramid_l1(blur, x)) > float(l1(blur, x))


def test_detail_energy_counts_detail_wherever_it_lies():
    x = _stripes()
    e = detail_energy(x)
    assert e.shape == (1, 1, 4, 4)
    # luminance of grey stripes: |Laplacian| 0.6 on every row (each has one neighbour unlike it)
    assert_close(e[..., 1:-1, :], torch.full_like(e[..., 1:-1, :], 0.6), atol=1e-6, what="energy")
    assert float(detail_energy_l1(x, x)) == 0.0
    # moved by a row the energy is the same away from the image's edge: no charge there
    shifted = detail_energy(torch.roll(x, 1, 2))
    assert_close(shifted[..., 1:-1, :], e[..., 1:-1, :], atol=1e-6, what="moved stripes")
    blur, flat = _blurred(x), torch.full_like(x, 0.5)
    assert 0 < float(detail_energy_l1(blur, x)) < float(detail_energy_l1(flat, x))
    assert_close(detail_energy_l1(flat, x), e.mean(), atol=1e-6, what="all detail missing")


def test_gradient_similarity_sees_edges_faint_or_strong_and_stays_finite():
    x = _stripes()
    assert float(gradient_similarity_loss(x, x)) == 0.0
    # a constant offset moves no edge
    assert float(gradient_similarity_loss(x + 0.1, x)) < 1e-6
    blur, shift, flat = _blurred(x), torch.roll(x, 1, 2), torch.full_like(x, 0.5)
    assert 0 < float(gradient_similarity_loss(blur, x)) < float(gradient_similarity_loss(flat, x))
    assert float(gradient_similarity_loss(shift, x)) > 0
    # a ratio: the same stripes at a tenth of the contrast, against a flat copy, cost about
    # as much as the full stripes do (within the constant's share at that contrast)
    faint = 0.5 + (x - 0.5) * 0.1
    strong_cost = float(gradient_similarity_loss(torch.full_like(x, 0.5), x))
    faint_cost = float(gradient_similarity_loss(torch.full_like(x, 0.5), faint))
    assert faint_cost > 0.5 * strong_cost
    # flat images (the backdrop) give finite gradients: no root of zero
    pred = torch.full_like(x, 0.3).requires_grad_(True)
    gradient_similarity_loss(pred, torch.full_like(x, 0.3)).backward()
    assert torch.isfinite(pred.grad).all()


def test_gan_and_feature_matching_losses():
    real, fake = torch.full((2, 1, 3, 3), 2.0), torch.full((2, 1, 3, 3), -2.0)
    assert float(gan_d_loss(real, fake, "hinge")) == 0.0
    assert float(gan_d_loss(fake, real, "hinge")) == pytest.approx(6.0)
    assert float(gan_d_loss(torch.ones(4), torch.zeros(4), "lsgan")) == 0.0
    assert float(gan_g_loss(torch.ones(4), "lsgan")) == 0.0
    assert float(gan_g_loss(fake, "hinge")) == pytest.approx(2.0)
    f = [torch.rand(1, 4, 5, 5), torch.rand(1, 8, 2, 2)]
    assert float(feature_matching(f, f)) == 0.0
    assert float(feature_matching(f, [t + 1 for t in f])) == pytest.approx(1.0)


def test_vgg19_layout_matches_torchvision():
    feats = vgg_features(VGG19_CHANNELS)
    convs = [i for i, m in enumerate(feats) if isinstance(m, torch.nn.Conv2d)]
    assert convs == [0, 2, 5, 7, 10, 12, 14, 16, 19, 21, 23, 25, 28, 30, 32, 34]
    assert len(feats) == 37  # torchvision's vgg19().features
    assert _tap_indices(VGG19_CHANNELS) == [1, 6, 11, 20, 29]  # relu1_1 ... relu5_1
    assert tuple(feats.state_dict()["34.weight"].shape) == (512, 512, 3, 3)


def _save_vgg(path, channels, seed=0):
    torch.manual_seed(seed)
    feats = vgg_features(channels)
    state = {f"features.{k}": v for k, v in feats.state_dict().items()}
    state["classifier.0.weight"] = torch.zeros(2, 2)  # ignored, as in a full torchvision file
    torch.save(state, path)
    return feats


def test_perceptual_loss_loads_from_torchvision_layout_file(tmp_path):
    path = tmp_path / "vgg.pth"
    ref = _save_vgg(path, TINY_VGG)
    assert load_perceptual("", TINY_VGG) is None  # no file: off
    loss = load_perceptual(path, TINY_VGG)
    for k, v in ref.state_dict().items():
        assert torch.equal(loss.features.state_dict()[k], v), k
    assert not any(p.requires_grad for p in loss.parameters())
    x, y = torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32)
    assert float(loss(x, x)) == 0.0
    pred = x.clone().requires_grad_(True)
    out = loss(pred, y)
    out.backward()
    assert float(out.detach()) > 0 and pred.grad.abs().sum() > 0
    with pytest.raises(InputError, match="missing.*vgg_missing.pth|vgg_missing.pth.*not found"):
        load_perceptual(tmp_path / "vgg_missing.pth", TINY_VGG)
    with pytest.raises(InputError, match="features.0.weight has shape"):
        load_perceptual(path, (5, 0, 6))
    torch.save({"x": torch.zeros(1)}, tmp_path / "other.pth")
    with pytest.raises(InputError, match="other.pth: not a torchvision VGG"):
        load_perceptual(tmp_path / "other.pth", TINY_VGG)


# -- inference ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def live():
    sc = synthetic_scene(5)
    cam = make_camera((0.0, 0.9, 2.5), (0.0, 0.8, 0.0), width=64, height=64)
    frames = [
        FrameState(
            sc.proxy[t],
            joint_window(sc.joints, t),
            render_background(Mesh(sc.body[t], sc.body_faces), cam),
        )
        for t in range(len(sc.proxy))
    ]
    return sc, cam, frames


@pytest.mark.parametrize("name", ["tiny", "cpu"])
def test_streaming_equals_batch_and_encodes_each_frame_once(live, name):
    sc, cam, frames = live
    torch.manual_seed(1)
    r = NeuralRenderer(RenderNet(PRESETS[name]), sc.faces, sc.uvs)
    stream = [r.render(cam, f) for f in frames]
    assert r.encodes == len(frames)  # the crop stays put: t-1's latent is reused
    for t, img in enumerate(stream):
        assert img.shape == (64, 64, 3) and img.dtype == np.uint8
        ref = r.render_pair(cam, frames[t], frames[t - 1] if t else None)
        assert np.array_equal(img, ref), f"frame {t}"
    # a new camera: t-1 is encoded again in the new crop, still equal to the batch render
    cam2 = make_camera((0.8, 1.0, 2.3), (0.0, 0.8, 0.0), width=64, height=64)
    frame = FrameState(frames[2].vertices, frames[2].window, frames[2].background)
    r.reset()
    n = r.encodes
    r.render(cam2, frames[1])  # first frame of a new stream: encoded once, t-1 := t
    assert r.encodes == n + 1
    img = r.render(cam2, frame, previous=frames[1])
    same_crop = r.crop_box(cam2, frames[1]) == r.crop_box(cam2, frame)
    assert r.encodes == n + 1 + (1 if same_crop else 2)
    assert np.array_equal(img, r.render_pair(cam2, frame, frames[1]))


@pytest.mark.parametrize("guided", [False, True])
@pytest.mark.parametrize("name", ["tiny", "cpu"])
def test_crop_render_matches_full_frame_and_background_outside(live, name, guided):
    sc, cam, frames = live
    torch.manual_seed(2)
    r = NeuralRenderer(RenderNet(PRESETS[name].replace(background_guide=guided)), sc.faces, sc.uvs)
    t = 3
    crop = r.render_pair(cam, frames[t], frames[t - 1])
    full = r.render_pair(cam, frames[t], frames[t - 1], crop=False)
    box = r.crop_box(cam, frames[t])
    assert box.x0 % r.config.stride == 0 and box.width % r.config.stride == 0
    inside = np.zeros((64, 64), bool)
    inside[max(box.y0, 0) : box.y0 + box.height, max(box.x0, 0) : box.x0 + box.width] = True
    proxy = MeshScene(sc.proxy[t], sc.faces).rasterize(cam).mask
    assert proxy.any() and not (proxy & ~inside).any()
    diff = np.abs(crop.astype(int) - full.astype(int))
    assert diff[proxy].max() <= 2, diff[proxy].max()  # on the garment: within 2/255
    assert diff[inside].mean() < 1.0
    assert np.array_equal(crop[~inside], frames[t].background[~inside])
    assert not np.array_equal(crop[inside], frames[t].background[inside])


def test_render_without_visible_proxy_is_the_background(live):
    sc, _, frames = live
    away = make_camera((0.0, 0.9, 2.5), (0.0, 0.9, 10.0), width=32, height=32)  # looks away
    bg = np.full((32, 32, 3), 7, np.uint8)
    r = NeuralRenderer(RenderNet(PRESETS["tiny"]), sc.faces, sc.uvs)
    f = FrameState(frames[0].vertices, frames[0].window, bg)
    assert np.array_equal(r.render(away, f), bg)
    with pytest.raises(InputError, match="background must be"):
        r.render(make_camera((0, 0.9, 2.5), (0, 0.8, 0), width=64, height=64), f)
