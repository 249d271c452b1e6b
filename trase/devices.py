"""Where trase computes: "cpu" (the numba kernels) or "cuda" (torch on the GPU, the gsplat
rasterizer). One resolver, so "auto" means the same in training, rendering and viewing."""

from __future__ import annotations

import torch

DEVICES = ("auto", "cpu", "cuda")


class DeviceError(ValueError):
    """A device name that is unknown, or a GPU asked for where torch sees none."""


def resolve_device(device: str) -> torch.device:
    """"auto" (a GPU when torch sees one), "cpu" or "cuda" -> torch.device; one-line errors."""
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    if device not in DEVICES:
        raise DeviceError(f"unknown device {device!r}; choose {', '.join(DEVICES)}")
    if device == "cuda" and not torch.cuda.is_available():
        raise DeviceError("device cuda: torch sees no GPU here (this torch build or machine has none)")
    return torch.device(device)


def gsplat_missing(device: torch.device | str) -> str | None:
    """Why ``device`` cannot rasterize, or None: CUDA draws with gsplat, an optional package
    (the CPU needs nothing more). Callers add their own way out (another device setting)."""
    import importlib.util

    if torch.device(device).type == "cuda" and importlib.util.find_spec("gsplat") is None:
        return "device cuda draws with gsplat, which is not installed (pip install -e '.[gpu]')"
    return None


def reset_peak_memory(device: torch.device | str) -> None:
    """Start counting ``peak_memory_mib`` afresh (nothing to do off a GPU)."""
    if torch.device(device).type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)


def peak_memory_mib(device: torch.device | str) -> float | None:
    """The most GPU memory torch held since ``reset_peak_memory`` (MiB), or None off a GPU."""
    if torch.device(device).type != "cuda":
        return None
    return round(torch.cuda.max_memory_allocated(device) / 2**20, 1)


def geometry_on(gaussians, deformation, dev: torch.device):
    """The frozen geometry on ``dev``: the caller's own objects when already there, else copies
    (the caller's stay where they are)."""
    if gaussians.means.device == dev:
        return gaussians, deformation
    import copy

    return gaussians.copy().to(dev), (None if deformation is None else copy.deepcopy(deformation).to(dev))
