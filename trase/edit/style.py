"""Style transfer of a selection (the paper's restyling): the selected gaussians' colours are
optimised so renders of them match a style image's VGG-16 features by nearest-neighbour
feature matching (NNFM, Zhang et al., ARF 2022); geometry, motion and every other gaussian
stay fixed.

The feature network is VGG-16's convolutional part (torchvision's layout and parameter names,
``features.N.weight``), loaded from a weights file the user provides (torchvision's
``vgg16-397923af.pth`` or any state dict with those keys): nothing is downloaded. NNFM is
taken on the conv3 block (relu3_1..relu3_3, as ARF), with a small content term (the same
features of the unedited render, mean squared) that keeps the object readable.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from trase.edit.model import EditableModel, EditError
from trase.io import read_torch
from trase.vgg import vgg16_features

# torchvision's vgg16 "features" up to conv3_3's ReLU: the first 9 entries of its layout
STYLE_ENTRIES = 9
STYLE_LAYERS = (11, 13, 15)  # relu3_1, relu3_2, relu3_3 in torchvision's numbering
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


class VGG16Features(nn.Module):
    """VGG-16's first three conv blocks, numbered as torchvision's ``vgg16().features``."""

    def __init__(self) -> None:
        super().__init__()
        self.features = vgg16_features(STYLE_ENTRIES)
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1))

    @classmethod
    def load(cls, path: str | Path | None) -> VGG16Features:
        """From a local weights file; a clear error when none is given or it does not fit."""
        if path is None:
            raise EditError("style transfer needs VGG-16 weights: pass a local file (torchvision's "
                            "vgg16-397923af.pth or a state dict with features.N keys); nothing is downloaded")
        path = Path(path)
        if not path.is_file():
            raise EditError(f"{path}: VGG-16 weights file not found")
        sd = read_torch(path, EditError)
        if not isinstance(sd, dict):
            raise EditError(f"{path}: expected a state dict, got {type(sd).__name__}")
        net = cls()
        want = {k for k in net.state_dict() if k.startswith("features.")}
        have = {k: v for k, v in sd.items() if k in want}
        if set(have) != want:
            missing = sorted(want - set(have))[:3]
            raise EditError(f"{path}: not VGG-16 weights (missing {', '.join(missing)})")
        try:
            net.load_state_dict(have, strict=False)
        except RuntimeError as exc:
            raise EditError(f"{path}: {str(exc).splitlines()[0]}") from None
        net.eval().requires_grad_(False)
        return net

    def forward(self, image: torch.Tensor) -> list[torch.Tensor]:
        """image [3, H, W] in [0, 1] -> the STYLE_LAYERS' maps [C, h, w]."""
        x = (image[None] - self.mean) / self.std
        out = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in STYLE_LAYERS:
                out.append(x[0])
        return out


def nnfm_loss(render: Sequence[torch.Tensor], style: Sequence[torch.Tensor]) -> torch.Tensor:
    """Mean over layers and render positions of the cosine distance to the nearest style
    feature (features [C, h, w] each)."""
    total = render[0].new_zeros(())
    for r, s in zip(render, style):
        rf = F.normalize(r.flatten(1).T, dim=1)  # [P, C]
        sf = F.normalize(s.flatten(1).T, dim=1)  # [Q, C]
        total = total + (1.0 - (rf @ sf.T).max(dim=1).values).mean()
    return total / len(render)


@dataclasses.dataclass(frozen=True)
class StyleConfig:
    iterations: int = 200
    lr: float = 0.02
    content_weight: float = 0.005  # the content term (ARF has one too); small, so the style leads
    seed: int = 0


def stylize(model: EditableModel, selection: np.ndarray, cameras: Sequence, style_image: np.ndarray,
            vgg: VGG16Features, cfg: StyleConfig = StyleConfig(),
            progress: Callable[[int, float], None] | None = None) -> tuple[EditableModel, list[float]]:
    """(model with the selection's colours restyled, loss per iteration). ``style_image``
    [H, W, 3] float in [0, 1]; ``cameras`` are drawn in turn (seeded)."""
    from trase.deformation import deformed
    from trase.render import rasterize

    sel = model.check_selection(selection)
    if not sel.any():
        raise EditError("style: the selection is empty")
    if not cameras:
        raise EditError("style: no cameras to render the selection from")
    img = np.asarray(style_image, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] != 3 or not np.isfinite(img).all():
        raise EditError(f"style: the style image must be [H, W, 3] finite values, got {img.shape}")
    if cfg.iterations < 1 or cfg.lr <= 0:
        raise EditError("style: iterations must be >= 1 and lr > 0")
    g = model.gaussians
    idx = torch.from_numpy(np.flatnonzero(sel))
    with torch.no_grad():
        style_feats = [f.detach() for f in vgg(torch.from_numpy(img).permute(2, 0, 1))]
    geoms = {}  # camera -> its deformed geometry and the unedited render's features (computed once)
    dc = nn.Parameter(g.sh_dc.detach()[idx].clone())  # [S, 1, 3]: the only thing optimised
    opt = torch.optim.Adam([dc], lr=cfg.lr)
    rng = np.random.default_rng(cfg.seed)
    base_sh = g.sh_for_render().detach()
    losses = []
    for it in range(cfg.iterations):
        cam = cameras[int(rng.integers(len(cameras)))]
        key = id(cam)
        if key not in geoms:
            with torch.no_grad():
                m, q, s = deformed(g, model.deformation, float(cam.time))
                content = _render(rasterize, m, q, s, g, cam, base_sh)
                geoms[key] = (m, q, s, [f.detach() for f in vgg(content.permute(2, 0, 1))])
        m, q, s, content_feats = geoms[key]
        sh = base_sh.index_put((idx,), torch.cat([dc, base_sh[idx, 1:]], dim=1))
        image = _render(rasterize, m, q, s, g, cam, sh)
        feats = vgg(image.permute(2, 0, 1))
        loss = nnfm_loss(feats, style_feats) + cfg.content_weight * sum(
            F.mse_loss(a, b) for a, b in zip(feats, content_feats))
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
        if progress:
            progress(it, losses[-1])
    out = g.copy()
    with torch.no_grad():
        out.sh_dc[idx] = dc.detach()
    return EditableModel(out, model.deformation, model.labels.copy(), model.keep.copy()), losses


def _render(rasterize, m, q, s, g, cam, sh) -> torch.Tensor:
    return rasterize(m, q, s, g.opacities.detach(), cam, colors=sh, sh_degree=g.active_sh_degree).color.clamp(0, 1)
