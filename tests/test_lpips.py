"""``training.lpips``: LPIPS on an AlexNet of the ``lpips`` package's layout, and tLP, from a
weights file the test writes (no weights are downloaded)."""

from __future__ import annotations

import pytest
import torch

from core.errors import InputError
from training.lpips import LPIPS, UNAVAILABLE, load_lpips, tlp

SCALE = 0.25  # a small AlexNet: the same layers, a quarter of the channels


@pytest.fixture
def weights(tmp_path):
    """A random small LPIPS saved as the package saves its module: with the ``lins.K``
    duplicates of the heads and the input scaling's buffers; positive heads, as trained ones are."""
    torch.manual_seed(0)
    net = LPIPS(SCALE)
    state = net.state_dict()
    for k in range(5):
        w = state[f"lin{k}.model.1.weight"].abs()
        state[f"lin{k}.model.1.weight"] = w
        state[f"lins.{k}.model.1.weight"] = w
    path = tmp_path / "lpips-small.pth"
    torch.save(state, path)
    return path


def _frames(n: int, seed: int) -> torch.Tensor:
    return torch.rand(n, 3, 64, 64, generator=torch.Generator().manual_seed(seed))


def test_the_layout_is_the_packages():
    keys = set(LPIPS().state_dict())
    assert {"net.slice1.0.weight", "net.slice2.3.weight", "net.slice3.6.weight",
            "net.slice4.8.weight", "net.slice5.10.bias", "lin0.model.1.weight",
            "lin4.model.1.weight", "scaling_layer.shift"} <= keys  # fmt: skip
    assert LPIPS().state_dict()["lin1.model.1.weight"].shape == (1, 192, 1, 1)
    assert LPIPS().state_dict()["net.slice1.0.weight"].shape == (64, 3, 11, 11)


def test_lpips_known_answers(weights):
    net = load_lpips(weights, SCALE)
    a, b = _frames(2, 1), _frames(2, 2)
    with torch.no_grad():
        assert torch.allclose(net(a, a), torch.zeros(2), atol=1e-7)  # identical: 0
        ab, ba = net(a, b), net(b, a)
        assert (ab > 0).all() and torch.allclose(ab, ba)  # different: > 0, symmetric
        # a little noise is nearer than another image altogether
        near = net(a, (a + 0.02 * torch.randn_like(a)).clamp(0, 1))
        assert (near < ab).all()


def test_tlp_known_answers(weights):
    gt = _frames(4, 3)
    real = [gt[i : i + 2] for i in range(3)]
    assert tlp(real, real, weights, SCALE).value == pytest.approx(0.0, abs=1e-7)  # the same video
    frozen = [torch.stack([p[0], p[0]]) for p in real]  # a render stuck on frame t
    net = load_lpips(weights, SCALE)
    with torch.no_grad():
        expected = float(torch.stack([net(p[:1], p[1:]) for p in real]).mean())
    result = tlp(real, frozen, weights, SCALE)
    assert result.status == "ok" and result.pairs == 3
    assert result.value == pytest.approx(expected, rel=1e-5) and result.value > 0


def test_tlp_without_weights_and_bad_files(tmp_path, weights):
    off = tlp([], [], None)
    assert off.value is None and off.status == UNAVAILABLE and off.to_dict()["value"] is None
    with pytest.raises(InputError, match="not found"):
        load_lpips(tmp_path / "none.pth")
    junk = tmp_path / "junk.pth"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(InputError, match="cannot read LPIPS weights"):
        load_lpips(junk)
    with pytest.raises(InputError, match="expected"):
        load_lpips(weights, 0.5)  # the file's channels are a quarter's
    other = tmp_path / "other.pth"
    torch.save({"fc.weight": torch.zeros(2, 2)}, other)
    with pytest.raises(InputError, match="not an lpips"):
        load_lpips(other)
