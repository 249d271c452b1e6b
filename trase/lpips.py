"""LPIPS (Zhang et al., CVPR 2018), the VGG variant the field reports, from weights on disk.

    lp = LPIPS.from_files("vgg16-397923af.pth", "vgg.pth")   # torchvision's VGG16, lpips' heads
    d = lp(render, image)                                      # [H, W, 3] in [0, 1] -> float

Why here and not the ``lpips`` package: it builds its backbone with torchvision, which has no CPU
wheel in this project's setup; the network is small enough to write out. The backbone is VGG16's
convolutional part in torchvision's layer order, so torchvision's ImageNet checkpoint (keys
``features.N.weight``) loads as it is; the linear heads are the ``lpips`` package's v0.1 weights
(keys ``linK.model.1.weight``, [1, C, 1, 1]). Neither can be downloaded here; a user who has
them points at the files. The distance is the package's: inputs mapped from [0, 1] to [-1, 1]
(its ``normalize=True``), its scaling layer, unit-normalised features at relu1_2, relu2_2,
relu3_3, relu4_3 and relu5_3, squared differences weighted by the heads, averaged over space,
summed over layers.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from trase.io import read_torch
from trase.vgg import vgg16_features

TAPS = (3, 8, 15, 22, 29)  # indices of relu1_2, relu2_2, relu3_3, relu4_3, relu5_3 in features
CHANNELS = (64, 128, 256, 512, 512)
SHIFT = (-0.030, -0.088, -0.188)  # the lpips package's ScalingLayer
SCALE = (0.458, 0.448, 0.450)


class LPIPSError(ValueError):
    """Weights that are missing or not the networks they should be (one line, naming the file)."""

    user_facing = True


class LPIPS(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.features = vgg16_features()
        self.lins = nn.ModuleList([nn.Conv2d(c, 1, 1, bias=False) for c in CHANNELS])
        self.register_buffer("shift", torch.tensor(SHIFT).reshape(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(SCALE).reshape(1, 3, 1, 1))
        self.requires_grad_(False)
        self.eval()

    @classmethod
    def from_files(cls, vgg_path: str | Path, lin_path: str | Path) -> LPIPS:
        """The metric with torchvision's VGG16 checkpoint and the lpips package's VGG heads."""
        net = cls()
        vgg = _read(vgg_path)
        feats = {k.removeprefix("features."): v for k, v in vgg.items() if k.startswith("features.")}
        try:
            net.features.load_state_dict(feats, strict=True)
        except RuntimeError as exc:
            raise LPIPSError(f"{vgg_path}: not torchvision's VGG16 ({str(exc).splitlines()[0][:120]})") from None
        lin = _read(lin_path)
        try:
            for k, layer in enumerate(net.lins):
                w = lin[f"lin{k}.model.1.weight"]
                if tuple(w.shape) != (1, CHANNELS[k], 1, 1):
                    raise KeyError(f"lin{k}.model.1.weight is {tuple(w.shape)}, not (1, {CHANNELS[k]}, 1, 1)")
                layer.weight.copy_(w)
        except KeyError as exc:
            raise LPIPSError(f"{lin_path}: not the lpips VGG heads (missing or wrong {exc})") from None
        return net

    @torch.no_grad()
    def forward(self, a: torch.Tensor, b: torch.Tensor) -> float:
        """LPIPS of two [H, W, 3] images in [0, 1]."""
        if a.shape != b.shape or a.dim() != 3 or a.shape[-1] != 3:
            raise ValueError(f"LPIPS: two [H, W, 3] images, got {tuple(a.shape)} and {tuple(b.shape)}")
        dev = self.shift.device
        x = torch.stack([a, b]).permute(0, 3, 1, 2).to(dev, torch.float32) * 2.0 - 1.0  # [2, 3, H, W]
        h = (x - self.shift) / self.scale
        total = 0.0
        lin = iter(self.lins)
        for i, layer in enumerate(self.features):
            h = layer(h)
            if i in TAPS:
                f = h / (h.pow(2).sum(dim=1, keepdim=True).sqrt() + 1e-10)
                total += float(next(lin)((f[0:1] - f[1:2]) ** 2).mean())
                if i == TAPS[-1]:
                    break
        return total


def _read(path: str | Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise LPIPSError(f"{path}: weights file not found")
    sd = read_torch(path, LPIPSError, "unreadable weights")
    if not isinstance(sd, dict):
        raise LPIPSError(f"{path}: not a state dict")
    return sd


__all__ = ["LPIPS", "LPIPSError"]
