"""The neural renderer's parts: neural texture, encoder, SPADE block, decoder, blend, refinement,
and the temporal PatchGAN discriminator.

A render is three small swappable steps (STYLE 5): sample the texture at the pixel UVs and
concatenate the motion features (:meth:`RenderNet.input_features`), encode frames t and t-1
(:meth:`RenderNet.encode`), then decode and composite over the background
(:meth:`RenderNet.decode`).

**Decisions.**

- The encoder has no biases and LeakyReLU activations, so an all-zero input (off the proxy) stays
  exactly zero: a crop around the garment sees the same latent as the full frame except within
  a few latent cells of the crop's edge (inference crops with a margin).
- The SPADE block normalises each latent cell over its channels (positional normalisation)
  instead of batch statistics: the result does not depend on the batch, the crop or the other
  frames, so batch-1 streaming and batch training agree.
- With ``texture_readout`` a 1 x 1 conv (no bias: zero off the proxy) reads frame t's texture
  sample straight into the last layer's logits (RGB, and the alpha of the blend with the
  background, which carves the gaps between tiers out of the proxy's silhouette), beside the
  refinement's: the texture's detail reaches the
  image in one layer, as in DNR, not only through the encoder, decoder and refinement, which in a
  few hundred steps learned it too slowly to draw the frill tiers (docs/decisions.md,
  "texture_readout"). It travels with the encoder's skips, as their last entry, so every caller
  of :meth:`RenderNet.encode_with_skips` and :meth:`RenderNet.decode` carries it unchanged.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from training.renderer.config import RendererConfig

_SLOPE = 0.2


class NeuralTexture(nn.Module):
    """A multi-scale learned texture: level k is (C, S_k, S_k), sampled bilinearly.

    Parameters
    ----------
    sizes : texels per side of each level (512, 256, 128, 64 in the paper)
    channels : channels per level (16)
    seed : initial values are drawn from ``N(0, 0.01)`` with this seed
    """

    def __init__(self, sizes: tuple[int, ...], channels: int, seed: int = 0):
        super().__init__()
        g = torch.Generator().manual_seed(seed)
        self.levels = nn.ParameterList(
            [nn.Parameter(torch.randn(1, channels, s, s, generator=g) * 0.01) for s in sizes]
        )

    @property
    def out_channels(self) -> int:
        return sum(t.shape[1] for t in self.levels)

    def forward(self, uv: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Sample every level at ``uv``.

        Parameters
        ----------
        uv : (B, 2, H, W) float32 in [0, 1] (u right, v up: v = 1 is the texture's top row)
        mask : (B, 1, H, W) float32, 1 on the proxy; the output is 0 elsewhere

        Returns
        -------
        (B, L * C, H, W) float32
        """
        b = uv.shape[0]
        grid = torch.stack([uv[:, 0] * 2 - 1, 1 - uv[:, 1] * 2], -1)  # (B, H, W, 2)
        out = [
            F.grid_sample(
                t.expand(b, -1, -1, -1).to(uv.dtype),
                grid,
                mode="bilinear",
                padding_mode="border",
                align_corners=False,
            )
            for t in self.levels
        ]
        return torch.cat(out, 1) * mask


def texture_colour_loss(
    texture: torch.Tensor, image: torch.Tensor, mask: torch.Tensor
) -> torch.Tensor:
    """DNR's texture regulariser: L1 of a sampled neural texture's first 3 channels to the image,
    on the proxy, so the texture's first level starts as a colour texture.

    texture (B, L * C, H, W) (:class:`NeuralTexture`'s output), image (B, 3, H, W), mask
    (B, 1, H, W), 1 on the proxy -> scalar: the mean over the proxy's pixels and the 3 channels
    (0 for an empty mask).
    """
    diff = (texture[:, :3] - image).abs() * mask
    return diff.sum() / (3 * mask.sum()).clamp_min(1.0)


def _act() -> nn.Module:
    return nn.LeakyReLU(_SLOPE)


class Encoder(nn.Module):
    """Input features (B, Cin, H, W) -> latent (B, Cz, H / 2**n, W / 2**n); zero in, zero out.

    ``forward(x, skips=True)`` also returns the activations at every finer scale (full
    resolution first), for the decoder's skip connections.
    """

    def __init__(self, in_channels: int, base: int, max_width: int, n_down: int):
        super().__init__()
        self.stem = nn.Sequential(nn.Conv2d(in_channels, base, 3, 1, 1, bias=False), _act())
        downs = []
        w = base
        for _ in range(n_down):
            w2 = min(w * 2, max_width)
            downs.append(
                nn.Sequential(
                    nn.Conv2d(w, w2, 4, 2, 1, bias=False),
                    _act(),
                    nn.Conv2d(w2, w2, 3, 1, 1, bias=False),
                    _act(),
                )
            )
            w = w2
        self.downs = nn.ModuleList(downs)
        self.out_channels = w

    def forward(self, x: torch.Tensor, skips: bool = False):
        x = self.stem(x)
        feats = [x]
        for down in self.downs:
            x = down(x)
            feats.append(x)
        return (x, feats[:-1]) if skips else x


def positional_norm(x: torch.Tensor, eps: float = 1e-5) -> torch.Tensor:
    """Normalise each pixel over its channels: (B, C, H, W) -> same shape, zero mean, unit var."""
    mean = x.mean(1, keepdim=True)
    var = x.var(1, keepdim=True, unbiased=False)
    return (x - mean) * torch.rsqrt(var + eps)


class SPADE(nn.Module):
    """``norm(x) * (1 + gamma(cond)) + beta(cond)`` with per-cell gamma, beta from a conv."""

    def __init__(self, channels: int, cond_channels: int, hidden: int):
        super().__init__()
        self.shared = nn.Sequential(nn.Conv2d(cond_channels, hidden, 3, 1, 1), nn.ReLU())
        self.gamma = nn.Conv2d(hidden, channels, 3, 1, 1)
        self.beta = nn.Conv2d(hidden, channels, 3, 1, 1)

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        h = self.shared(cond)
        return positional_norm(x) * (1 + self.gamma(h)) + self.beta(h)


class SPADEResBlock(nn.Module):
    """SPADE residual block: Z_t normalised and modulated by ``[Z_t, Z_{t-1}]``."""

    def __init__(self, channels: int):
        super().__init__()
        hidden = min(channels, 128)
        self.norm1 = SPADE(channels, 2 * channels, hidden)
        self.conv1 = nn.Conv2d(channels, channels, 3, 1, 1)
        self.norm2 = SPADE(channels, 2 * channels, hidden)
        self.conv2 = nn.Conv2d(channels, channels, 3, 1, 1)

    def forward(self, z: torch.Tensor, z_prev: torch.Tensor) -> torch.Tensor:
        """z, z_prev : (B, C, h, w) -> (B, C, h, w)."""
        cond = torch.cat([z, z_prev], 1)
        dx = self.conv1(F.leaky_relu(self.norm1(z, cond), _SLOPE))
        dx = self.conv2(F.leaky_relu(self.norm2(dx, cond), _SLOPE))
        return z + dx


class UpStage(nn.Module):
    """x2 transposed conv; with a skip, the encoder's activation at the new scale is
    concatenated, and with ``extra`` channels so is a guide image at that scale (the
    background, :class:`Decoder`); then a 3x3 conv fuses them."""

    def __init__(self, w_in: int, w_out: int, skip: bool, extra: int = 0):
        super().__init__()
        self.up = nn.Sequential(nn.ConvTranspose2d(w_in, w_out, 4, 2, 1), _act())
        width = w_out * (2 if skip else 1) + extra
        self.fuse = (
            nn.Sequential(nn.Conv2d(width, w_out, 3, 1, 1), _act()) if width > w_out else None
        )
        self.skip = skip

    def forward(
        self, z: torch.Tensor, skip: torch.Tensor | None = None, guide: torch.Tensor | None = None
    ) -> torch.Tensor:
        z = self.up(z)
        if self.fuse is not None:
            parts = [z]
            if self.skip:
                if skip is None:
                    raise ValueError("this decoder has skip connections: pass the encoder's skips")
                parts.append(skip)
            if guide is not None:
                parts.append(guide)
            z = self.fuse(torch.cat(parts, 1))
        return z


class Decoder(nn.Module):
    """Latent (B, Cz, h, w) -> garment features U (B, F, H, W) and mask A (B, 1, H, W) in (0, 1).

    ``ups[-1]``, ``features_head`` and ``mask_head`` are "the last decoder layers" that
    background fine-tuning trains. With ``skips`` every up stage also takes the encoder's
    activation of frame t at its scale (a U-Net; the paper's decoder has none). With
    ``guided`` every up stage also takes the body-only background image, averaged down to its
    scale (3 channels in [-1, 1]): the decoder sees where the body is, in front of the proxy or
    between its tiers, which the encoder's input (zero off the proxy, no body) never shows.
    """

    def __init__(
        self,
        latent: int,
        base: int,
        n_down: int,
        features: int,
        skips: bool = False,
        guided: bool = False,
    ):
        super().__init__()
        widths = [min(base * 2**i, latent) for i in range(n_down)][::-1]  # coarse -> fine
        ups = []
        w = latent
        for w2 in widths:
            ups.append(UpStage(w, w2, skips, 3 if guided else 0))
            w = w2
        self.ups = nn.ModuleList(ups)
        self.skips = skips
        self.guided = guided
        self.features_head = nn.Conv2d(w, features, 3, 1, 1)
        self.mask_head = nn.Conv2d(w, 1, 3, 1, 1)

    def forward(
        self,
        z: torch.Tensor,
        skips: list[torch.Tensor] | None = None,
        guide: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """z (B, Cz, h, w); skips: the encoder's activations, full resolution first (needed
        with ``skips``); guide (B, 3, h * 2**n, w * 2**n) the background in [-1, 1] (needed
        with ``guided``)."""
        if self.guided and guide is None:
            raise ValueError("this decoder is guided by the background: pass it")
        n = len(self.ups)
        for i, up in enumerate(self.ups):
            g = None
            if self.guided:
                f = 2 ** (n - 1 - i)  # this stage's output is 1 / f of the full resolution
                g = F.avg_pool2d(guide, f) if f > 1 else guide
            z = up(z, skips[n - 1 - i] if self.skips and skips is not None else None, g)
        return self.features_head(z), torch.sigmoid(self.mask_head(z))


class ResBlock(nn.Module):
    """Plain residual block: x + conv(act(conv(x)))."""

    def __init__(self, channels: int):
        super().__init__()
        self.conv1 = nn.Conv2d(channels, channels, 3, 1, 1)
        self.conv2 = nn.Conv2d(channels, channels, 3, 1, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv2(F.leaky_relu(self.conv1(x), _SLOPE))


class Refiner(nn.Module):
    """Blended features (B, F, H, W) -> two residual blocks -> RGB (B, 3, H, W) in (0, 1).

    With ``blend_output`` the last layer also predicts an alpha, and the result is
    ``alpha * rgb + (1 - alpha) * background``: the body off the garment is the background
    image itself, not a learned copy of it (alpha starts near 0.1).
    """

    def __init__(self, features: int, blend_output: bool = False):
        super().__init__()
        self.blocks = nn.Sequential(ResBlock(features), ResBlock(features))
        self.blend_output = blend_output
        self.to_rgb = nn.Conv2d(features, 4 if blend_output else 3, 1)
        if blend_output:
            with torch.no_grad():
                self.to_rgb.bias[3] = -2.0

    def forward(
        self,
        x: torch.Tensor,
        background: torch.Tensor | None = None,
        readout: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """x (B, F, H, W), background (B, 3, H, W), readout (B, 3 or 4, H, W) logits added to the
        last layer's (the texture readout: RGB, and alpha with ``blend_output``) or None ->
        (B, 3, H, W) in (0, 1)."""
        out = self.to_rgb(F.leaky_relu(self.blocks(x), _SLOPE))
        if readout is not None:
            out = out + readout
        if not self.blend_output:
            return torch.sigmoid(out)
        alpha = torch.sigmoid(out[:, 3:4])
        return alpha * torch.sigmoid(out[:, :3]) + (1 - alpha) * background


class RenderNet(nn.Module):
    """Neural texture + rendering network (the generator).

    Parameters
    ----------
    config : RendererConfig (widths, depth, texture sizes, motion switch)
    """

    def __init__(self, config: RendererConfig):
        super().__init__()
        self.config = config
        self.texture = NeuralTexture(config.texture_sizes, config.texture_channels, config.seed)
        self.encoder = Encoder(
            config.in_channels, config.base_width, config.max_width, config.n_down
        )
        cz = self.encoder.out_channels
        self.spade = SPADEResBlock(cz)
        self.decoder = Decoder(
            cz, config.base_width, config.n_down, config.decoder_features,
            config.skip_connections, config.background_guide,
        )  # fmt: skip
        self.background_net = nn.Sequential(
            nn.Conv2d(3, config.background_width, 3, 1, 1),
            _act(),
            nn.Conv2d(config.background_width, config.decoder_features, 3, 1, 1),
        )
        self.refiner = Refiner(config.decoder_features, config.blend_output)
        self.readout = (
            nn.Conv2d(config.texture_out_channels, 4 if config.blend_output else 3, 1, bias=False)
            if config.texture_readout
            else None
        )

    @property
    def stride(self) -> int:
        return self.config.stride

    def input_features(
        self, uv: torch.Tensor, motion: torch.Tensor | None, mask: torch.Tensor
    ) -> torch.Tensor:
        """Step 1: texture sample + motion features (without motion: + the mask): (B,
        in_channels, H, W), 0 off the proxy.

        uv (B, 2, H, W), motion (B, 95, H, W) or None without motion, mask (B, 1, H, W).
        """
        tex = self.texture(uv, mask)
        if not self.config.use_motion:
            return torch.cat([tex, mask.to(tex.dtype)], 1)
        return torch.cat([tex, motion.to(tex.dtype) * mask], 1)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """Step 2: input features (B, Cin, H, W) -> latent (B, Cz, H / s, W / s), s = stride."""
        return self.encoder(x)

    def encode_with_skips(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """Step 2 for the frame being rendered: the latent and what the decoder takes of this
        frame: the encoder's finer activations (full resolution first; the skip connections'),
        then, with ``texture_readout``, the texture sample's readout (B, 3, H, W) RGB logits, and
        an alpha logit fourth with ``blend_output``."""
        z, skips = self.encoder(x, skips=True)
        if self.readout is not None:
            logits = self.readout(x[:, : self.config.texture_out_channels])
            if self.config.alpha_prior and self.config.blend_output:
                alpha = logits[:, 3:4] + self.config.alpha_prior * self.coverage(x)
                logits = torch.cat([logits[:, :3], alpha], 1)
            skips = [*skips, logits]
        return z, skips

    def coverage(self, x: torch.Tensor) -> torch.Tensor:
        """The proxy's coverage (B, 1, H, W) in {0, 1}, read off input features (B, Cin, H, W):
        every channel is zero off the proxy, and on it the motion features (Gaussians of the
        distances to the joints) or, without them, the coverage mask are positive."""
        return (x[:, self.config.texture_out_channels :].amax(1, keepdim=True) > 0).to(x.dtype)

    def decode(
        self,
        z: torch.Tensor,
        z_prev: torch.Tensor,
        background: torch.Tensor,
        skips: list[torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Step 3: latents of t and t-1 and the background (B, 3, H, W) -> (rgb, mask A).

        rgb (B, 3, H, W) in (0, 1); A (B, 1, H, W) the garment mask of the blend. ``skips``
        (frame t's, from :meth:`encode_with_skips`) are needed when the config has
        ``skip_connections`` or ``texture_readout``.
        """
        if not self.config.use_temporal:  # the ablation: nothing of frame t-1 reaches SPADE
            z_prev = torch.zeros_like(z)
        readout = None
        if self.readout is not None:
            if skips is None:
                raise ValueError("this renderer reads its texture out: pass the encoder's skips")
            readout = skips[-1]
        guide = background * 2 - 1
        u, a = self.decoder(self.spade(z, z_prev), skips, guide if self.decoder.guided else None)
        bg = self.background_net(guide)
        return self.refiner((1 - a) * bg + a * u, background, readout), a

    def forward(
        self,
        uv: torch.Tensor,
        motion: torch.Tensor | None,
        mask: torch.Tensor,
        uv_prev: torch.Tensor,
        motion_prev: torch.Tensor | None,
        mask_prev: torch.Tensor,
        background: torch.Tensor,
        with_texture: bool = False,
    ) -> tuple[torch.Tensor, ...]:
        """Render frame t from its inputs and frame t-1's: (rgb (B, 3, H, W), A (B, 1, H, W)),
        and with ``with_texture`` frame t's texture sample (B, L * C, H, W) third (what a
        texture regulariser reads, through the same forward as the image)."""
        b = uv.shape[0]
        if not self.config.use_temporal:  # frame t-1 is never looked at: not encoded either
            x = self.input_features(uv, motion, mask)
            z, skips = self.encode_with_skips(x)
            out = self.decode(z, z, background, skips)
        else:
            x = self.input_features(
                torch.cat([uv, uv_prev]),
                None if motion is None else torch.cat([motion, motion_prev]),
                torch.cat([mask, mask_prev]),
            )
            z, skips = self.encode_with_skips(x)
            out = self.decode(z[:b], z[b:], background, [f[:b] for f in skips])
        if with_texture:
            return (*out, x[:b, : self.config.texture_out_channels])
        return out


def background_finetune_parameters(net: RenderNet) -> list[str]:
    """Names of the parameters background / lighting fine-tuning trains (the rest is frozen):
    the last decoder up-stage, the decoder heads, the refinement blocks and the texture
    readout (the layers that make the image's colours)."""
    prefixes = (
        f"decoder.ups.{len(net.decoder.ups) - 1}.",
        "decoder.features_head.",
        "decoder.mask_head.",
        "refiner.",
        "readout.",
    )
    return [n for n, _ in net.named_parameters() if n.startswith(prefixes)]


def relight_parameters(net: RenderNet) -> list[str]:
    """Names of the parameters relighting trains (the paper's section (iv): "the last two
    decoder layers"): the refinement's last residual block and its output convolution, the two
    layers nearest the image. Everything else, the texture readout included, stays frozen."""
    last = len(net.refiner.blocks) - 1
    prefixes = (f"refiner.blocks.{last}.", "refiner.to_rgb.")
    return [n for n, _ in net.named_parameters() if n.startswith(prefixes)]


class PatchDiscriminator(nn.Module):
    """Spectral-norm PatchGAN on pairs of consecutive frames (70 px receptive field).

    Input (B, 6, H, W) in [0, 1] (a later frame's RGB, then the earlier one's); output logits
    (B, 1, H / 8 - 2, W / 8 - 2) and the four hidden activations for feature matching.
    """

    def __init__(self, width: int = 64, in_channels: int = 6):
        super().__init__()
        sn = nn.utils.parametrizations.spectral_norm
        w = width
        spec = [(in_channels, w, 2), (w, 2 * w, 2), (2 * w, 4 * w, 2), (4 * w, 8 * w, 1)]
        self.layers = nn.ModuleList([sn(nn.Conv2d(i, o, 4, s, 1)) for i, o, s in spec])
        self.head = sn(nn.Conv2d(8 * w, 1, 4, 1, 1))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        h = x * 2 - 1
        feats = []
        for layer in self.layers:
            h = F.leaky_relu(layer(h), _SLOPE)
            feats.append(h)
        return self.head(h), feats


def receptive_field(kernels_strides: list[tuple[int, int]]) -> int:
    """Receptive field (pixels) of a chain of convs given as (kernel, stride)."""
    rf, jump = 1, 1
    for k, s in kernels_strides:
        rf += (k - 1) * jump
        jump *= s
    return rf
