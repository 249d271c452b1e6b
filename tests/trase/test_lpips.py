"""LPIPS (VGG) from weights on disk, in torchvision's and the lpips package's key layouts: the
module against a plain functional reference, its metric properties and its file errors."""

import pytest
import torch
import torch.nn.functional as F

from trase.lpips import CHANNELS, LPIPS, SCALE, SHIFT, LPIPSError
from trase.vgg import VGG16_LAYOUT as VGG16


def _weights(tmp_path, seed=0):
    """Random weights saved as torchvision's vgg16 (features + a classifier) and lpips' heads."""
    g = torch.Generator().manual_seed(seed)
    vgg, c_in, i = {}, 3, 0
    for v in VGG16:
        if v == "M":
            i += 1
            continue
        vgg[f"features.{i}.weight"] = torch.randn(v, c_in, 3, 3, generator=g) * (2.0 / (9 * c_in)) ** 0.5
        vgg[f"features.{i}.bias"] = torch.randn(v, generator=g) * 0.01
        c_in, i = v, i + 2
    vgg["classifier.0.weight"] = torch.zeros(2, 2)  # torchvision's head: ignored
    lin = {f"lin{k}.model.1.weight": torch.rand(1, c, 1, 1, generator=g) for k, c in enumerate(CHANNELS)}
    torch.save(vgg, tmp_path / "vgg16.pth")
    torch.save(lin, tmp_path / "vgg.pth")
    return vgg, lin


def _reference(vgg, lin, a, b):
    """LPIPS written out: every conv by name, taps after relu1_2 .. relu5_3."""
    x = torch.stack([a, b]).permute(0, 3, 1, 2) * 2 - 1
    h = (x - torch.tensor(SHIFT).view(1, 3, 1, 1)) / torch.tensor(SCALE).view(1, 3, 1, 1)
    blocks = [[0, 2], [5, 7], [10, 12, 14], [17, 19, 21], [24, 26, 28]]
    total = 0.0
    for k, convs in enumerate(blocks):
        if k:
            h = F.max_pool2d(h, 2)
        for i in convs:
            h = F.relu(F.conv2d(h, vgg[f"features.{i}.weight"], vgg[f"features.{i}.bias"], padding=1))
        n = h / (h.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
        total += float(F.conv2d((n[0:1] - n[1:2]) ** 2, lin[f"lin{k}.model.1.weight"]).mean())
    return total


def test_lpips_matches_the_plain_reference_and_is_a_distance(tmp_path):
    vgg, lin = _weights(tmp_path)
    lp = LPIPS.from_files(tmp_path / "vgg16.pth", tmp_path / "vgg.pth")
    g = torch.Generator().manual_seed(1)
    a, b = torch.rand(40, 48, 3, generator=g), torch.rand(40, 48, 3, generator=g)
    assert lp(a, b) == pytest.approx(_reference(vgg, lin, a, b), rel=1e-5)
    assert lp(a, a) == 0.0 and lp(a, b) == pytest.approx(lp(b, a), rel=1e-6) and lp(a, b) > 0
    near = (a + 0.01 * torch.randn(a.shape, generator=g)).clamp(0, 1)
    assert lp(a, near) < lp(a, b)
    with pytest.raises(ValueError, match=r"two \[H, W, 3\] images"):
        lp(a, b[:20])


def test_lpips_weights_errors_name_the_file(tmp_path):
    vgg, lin = _weights(tmp_path)
    with pytest.raises(LPIPSError, match="nope.pth: weights file not found"):
        LPIPS.from_files(tmp_path / "nope.pth", tmp_path / "vgg.pth")
    (tmp_path / "bad.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(LPIPSError, match="bad.pth: unreadable weights"):
        LPIPS.from_files(tmp_path / "bad.pth", tmp_path / "vgg.pth")
    torch.save({k: v for k, v in vgg.items() if k != "features.28.weight"}, tmp_path / "short.pth")
    with pytest.raises(LPIPSError, match="short.pth: not torchvision's VGG16"):
        LPIPS.from_files(tmp_path / "short.pth", tmp_path / "vgg.pth")
    torch.save({**lin, "lin2.model.1.weight": torch.zeros(1, 3, 1, 1)}, tmp_path / "lin.pth")
    with pytest.raises(LPIPSError, match=r"lin.pth: not the lpips VGG heads .*lin2.model.1.weight is \(1, 3, 1, 1\)"):
        LPIPS.from_files(tmp_path / "vgg16.pth", tmp_path / "lin.pth")
