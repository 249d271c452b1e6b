"""VGG-16's convolutional layers, numbered as torchvision's ``vgg16().features`` so its ImageNet
checkpoint (``features.N.weight``) loads as it is: the style loss (trase.edit.style) uses the first
three blocks, LPIPS (trase.lpips) all five. torchvision itself has no CPU wheel in this setup."""

from __future__ import annotations

from torch import nn

# torchvision's VGG-16 "D" configuration: output channels per conv, "M" = 2x2 max pooling
VGG16_LAYOUT = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M")


def vgg16_features(n_entries: int | None = None) -> nn.Sequential:
    """Conv + ReLU (and pooling) layers of the first ``n_entries`` of VGG16_LAYOUT (all by default)."""
    layers: list[nn.Module] = []
    c_in = 3
    for v in VGG16_LAYOUT[:n_entries]:
        if v == "M":
            layers.append(nn.MaxPool2d(2, 2))
        else:
            layers += [nn.Conv2d(c_in, int(v), 3, padding=1), nn.ReLU(inplace=False)]
            c_in = int(v)
    return nn.Sequential(*layers)


__all__ = ["VGG16_LAYOUT", "vgg16_features"]
