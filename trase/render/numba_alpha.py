"""The compositing rule's constants and one gaussian's alpha at a pixel in float32, shared by
the numba kernels (numba_kernels), their plain twins (numba_plain) and ``pixel_weights``."""

from __future__ import annotations

import numpy as np
from numba import njit

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4

F32 = np.float32
A_MIN32 = np.float32(ALPHA_MIN)
A_MAX32 = np.float32(ALPHA_MAX)
T_MIN32 = np.float32(T_MIN)
SUB = 4  # sub-block side in pixels: a tile's gaussians are culled per SUB x SUB block
LANES = SUB * SUB  # one lane per pixel of a block (16 float32 = one AVX-512 register)
POWER_FLOOR = np.float32(-8.0)  # exp(-8) * opacity < 1/255: below it a gaussian never contributes


@njit(inline="always")
def exp_nonpositive32(x):
    """exp(x) in float32 for -8 <= x <= 0 as plain arithmetic (relative error ~1e-6, from
    float32 rounding amplified by the squarings; truncation < 1e-8).

    Why not math.exp: LLVM lowers it to a libm call, which stops the lane loops from being
    vectorised. exp(x) = exp(x / 16) ** 16, a degree-8 Taylor polynomial on [-0.5, 0] and four
    squarings."""
    y = x * F32(0.0625)
    p = F32(1.0) + y * (F32(1.0) + y * (F32(0.5) + y * (F32(1.0 / 6.0) + y * (F32(1.0 / 24.0) + y * (
        F32(1.0 / 120.0) + y * (F32(1.0 / 720.0) + y * (F32(1.0 / 5040.0) + y * F32(1.0 / 40320.0))))))))
    p = p * p
    p = p * p
    p = p * p
    return p * p


@njit(inline="always")
def alpha32(fx, fy, u, v, ca, cb, cc, o):
    """Raw alpha o * exp(power) of one gaussian at pixel centre (fx, fy), all float32, with the
    reference's operation order; 0 where power > 0 (skipped). Used by pixel_weights; the
    forward's ``composite_block`` emits the same operations as vector IR (_alpha_lanes)."""
    dx = fx - u
    dy = fy - v
    power = F32(-0.5) * (ca * (dx * dx) + cc * (dy * dy)) - (cb * dx) * dy
    G = exp_nonpositive32(min(max(power, POWER_FLOOR), F32(0.0)))
    return o * G if power <= F32(0.0) else F32(0.0)
