"""Where a gaussian's identity encoding comes from.

* ``IdentityTable`` (Gaussian Grouping): one learned vector per gaussian, initialised
  RGB2SH(U[0, 1)) as the public code initialises it; the same at every time.
* ``IdentityField`` (SA4D): an MLP of the canonical position and time, each with a sin/cos
  encoding (octaves 2^0..2^(F-1), the raw value kept), ReLU between linear layers, no output
  activation, Xavier-uniform weights: the encoding, and so the class, may change over time.

Both are ``nn.Module``s: ``module(xyz [N, 3], t) -> [N, D]``; their weights travel as a base64
string (``pack`` / ``unpack``) through the benchmark's JSON records.
"""

from __future__ import annotations

import base64

import numpy as np
import torch
from torch import nn


class IdentityTable(nn.Module):
    def __init__(self, n: int, dim: int, generator: torch.Generator | None = None) -> None:
        super().__init__()
        from trase.gaussians import rgb_to_sh_dc

        self.encodings = nn.Parameter(rgb_to_sh_dc(torch.rand(n, dim, generator=generator)))

    def forward(self, xyz: torch.Tensor | None = None, t: float = 0.0) -> torch.Tensor:
        return self.encodings


def _encode(x: torch.Tensor, freqs: torch.Tensor) -> torch.Tensor:
    """[N, C] -> [N, C (1 + 2F)]: the input, then sin and cos of it times each octave."""
    scaled = (x.unsqueeze(-1) * freqs).flatten(-2)
    return torch.cat([x, scaled.sin(), scaled.cos()], -1)


class IdentityField(nn.Module):
    def __init__(self, dim: int, width: int = 256, depth: int = 4, pos_freqs: int = 10, time_freqs: int = 4,
                 generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.register_buffer("pos_freqs", 2.0 ** torch.arange(pos_freqs, dtype=torch.float32))
        self.register_buffer("time_freqs", 2.0 ** torch.arange(time_freqs, dtype=torch.float32))
        n_in = 3 * (1 + 2 * pos_freqs) + (1 + 2 * time_freqs)
        sizes = [n_in] + [width] * (max(int(depth), 1) - 1) + [dim]
        layers: list[nn.Module] = []
        for i in range(len(sizes) - 1):
            lin = nn.Linear(sizes[i], sizes[i + 1])
            with torch.no_grad():
                bound = float(np.sqrt(6.0 / (sizes[i] + sizes[i + 1])))
                lin.weight.uniform_(-bound, bound, generator=generator)
                lin.bias.uniform_(-1.0 / np.sqrt(sizes[i]), 1.0 / np.sqrt(sizes[i]), generator=generator)
            layers += [lin, nn.ReLU()]
        self.mlp = nn.Sequential(*layers[:-1])  # no activation after the last layer

    def forward(self, xyz: torch.Tensor, t: float) -> torch.Tensor:
        tt = xyz.new_full((xyz.shape[0], 1), float(t))
        return self.mlp(torch.cat([_encode(xyz, self.pos_freqs), _encode(tt, self.time_freqs)], -1))


def pack(module: nn.Module) -> str:
    """The module's parameters and buffers, in state_dict order, as base64 float32 bytes."""
    flat = torch.cat([v.detach().float().reshape(-1).cpu() for v in module.state_dict().values()])
    return base64.b64encode(flat.numpy().astype("<f4").tobytes()).decode("ascii")


def unpack(module: nn.Module, packed: str) -> nn.Module:
    """Load ``pack``'s string into a module built with the same shapes."""
    flat = torch.from_numpy(np.frombuffer(base64.b64decode(packed), dtype="<f4").copy())
    state, at = {}, 0
    for k, v in module.state_dict().items():
        state[k] = flat[at: at + v.numel()].reshape(v.shape).to(v.dtype)
        at += v.numel()
    if at != flat.numel():
        raise ValueError(f"packed weights hold {flat.numel()} values, the module {at}")
    module.load_state_dict(state)
    return module


__all__ = ["IdentityField", "IdentityTable", "pack", "unpack"]
