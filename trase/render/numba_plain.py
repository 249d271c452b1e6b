"""Plain-numba twins of the two LLVM-IR block walks in numba_kernels (``composite_block``, the
forward's front-to-back walk, and ``backward_block``, the backward's back-to-front walk).

Why: the IR walks reach into numba internals (``@intrinsic``, llvmlite builders), which a numba
or LLVM upgrade can break. These twins are ordinary numba loops over the 16 lanes with the
IR's float32 operations in the IR's order; ``TRASE_NUMBA_WALKS=plain`` makes the rasterizer
use them. What the tests show (tests/trase/render/test_numba_plain.py):
* the forward walk is the same bit for bit: colour, features, depth and alpha of whole renders;
* the backward walk agrees to float32 rounding (gradients within ~2e-7 of the largest one),
  not bit for bit: LLVM's x86 backend fuses some of the IR walk's multiply-adds beyond the
  three the IR marks ``contract``, and not the same ones in both 8-lane halves of a 16-lane
  vector (measured: one lane's alpha matched only with its quadratic form fused, another's only
  unfused), so no scalar program pins the compiled walk's roundings.
Two details follow the IR: its lane sums are trees (``hsum16``: 16 -> 8 -> 4 -> 2 -> 1), and
its marked multiply-adds are fused on a CPU with FMA (``fma32``: a correctly rounded float32
a * b + c: the product is exact in float64 and the float64 sum is rounded to odd, after which
one rounding to float32 is correct; ``FUSED`` says whether the host has FMA).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from trase.render.numba_alpha import A_MAX32 as ALPHA_MAX
from trase.render.numba_alpha import A_MIN32 as ALPHA_MIN
from trase.render.numba_alpha import F32, LANES, SUB, alpha32
from trase.render.numba_alpha import T_MIN32 as T_MIN


def _host_has_fma() -> bool:
    from llvmlite import binding

    try:
        return bool(binding.get_host_cpu_features().get("fma", False))
    except RuntimeError:  # features unknown on this host: numba then targets a generic CPU
        return False


FUSED = _host_has_fma()


@njit(inline="always")
def _round_to_odd_sum(p, c):
    """float64 p + c rounded to odd (an inexact sum gets an odd last bit): TwoSum gives the
    rounding error exactly; when it is non-zero and the nearest sum is even, step one ulp
    towards the exact sum. No allocation: this runs per lane and gaussian."""
    s = p + c
    bp = s - p
    err = (p - (s - bp)) + (c - bp)
    if err != 0.0:
        m, _ = math.frexp(s)  # s = m 2^e, |m| in [0.5, 1): 53 significant bits
        if int(abs(m) * 9007199254740992.0) % 2 == 0:
            s = np.nextafter(s, math.inf if err > 0.0 else -math.inf)
    return s


@njit(inline="always")
def fma32(a, b, c):
    """float32 a * b + c, rounded once (what a fused multiply-add gives) when FUSED, else
    rounded after the product and after the sum."""
    if FUSED:
        return F32(_round_to_odd_sum(np.float64(a) * np.float64(b), np.float64(c)))
    return a * b + c


@njit(inline="always")
def hsum16(v):
    """Sum of 16 float32 lanes in the IR's tree order (halves added: 16 -> 8 -> 4 -> 2 -> 1)."""
    return ((((v[0] + v[8]) + (v[4] + v[12])) + ((v[2] + v[10]) + (v[6] + v[14])))
            + (((v[1] + v[9]) + (v[5] + v[13])) + ((v[3] + v[11]) + (v[7] + v[15]))))


@njit(cache=True)
def composite_block_plain(pk, ids, off, n, x0, y0, live, T, asum, wl, gl, bl_mask, res):
    """Plain twin of numba_kernels.composite_block."""
    act = np.zeros(LANES, np.bool_)
    for q in range(LANES):
        T[q] = F32(1.0)
        asum[q] = F32(0.0)
        act[q] = ((live >> q) & 1) == 1
    fxs = np.empty(LANES, np.float32)
    fys = np.empty(LANES, np.float32)
    for q in range(LANES):
        fxs[q] = (F32(x0) + F32(q % SUB)) + F32(0.5)
        fys[q] = (F32(y0) + F32(q // SUB)) + F32(0.5)
    j = 0
    nu = 0
    last = 0
    any_active = live & 0xFFFF != 0
    while j < n and any_active:
        slot = off + j
        i = np.int64(ids[slot])
        u, v, ca, cb, cc, o = pk[i, 0], pk[i, 1], pk[i, 2], pk[i, 3], pk[i, 4], pk[i, 5]
        mask = 0
        any_active = False
        for q in range(LANES):
            a = alpha32(fxs[q], fys[q], u, v, ca, cb, cc, o)
            a = min(ALPHA_MAX, a)
            Tv = T[q]
            tt = Tv * (F32(1.0) - a)
            ok = act[q] and a >= ALPHA_MIN
            keep = tt >= T_MIN
            use = ok and keep
            w = a * Tv if use else F32(0.0)
            if use:
                T[q] = tt
                mask |= 1 << q
            if ok and not keep:
                act[q] = False
            asum[q] = asum[q] + w
            wl[nu, q] = w
            any_active = any_active or act[q]
        bl_mask[slot] = mask
        if mask != 0:
            gl[nu] = i
            nu += 1
            last = j + 1
        j += 1
    res[0] = last
    res[1] = nu


@njit(cache=True)
def backward_block_plain(pk, ids, masks, sl, el, nu, x0, y0, T, tf, ga, fgl, wl, buf_geo):
    """Plain twin of numba_kernels.backward_block."""
    fxs = np.empty(LANES, np.float32)
    fys = np.empty(LANES, np.float32)
    gatf = np.empty(LANES, np.float32)
    acc = np.zeros(LANES, np.float32)
    for q in range(LANES):
        fxs[q] = (F32(x0) + F32(q % SUB)) + F32(0.5)
        fys[q] = (F32(y0) + F32(q // SUB)) + F32(0.5)
        gatf[q] = ga[q] * tf[q]
    terms = np.empty((6, LANES), np.float32)
    for k in range(nu):
        slot = sl[k]
        i = np.int64(ids[slot])
        m = masks[slot]
        u, v, ca, cb, cc, o = pk[i, 0], pk[i, 1], pk[i, 2], pk[i, 3], pk[i, 4], pk[i, 5]
        for q in range(LANES):
            fx, fy = fxs[q], fys[q]
            dx = fx - u
            dy = fy - v
            araw = alpha32(fx, fy, u, v, ca, cb, cc, o)
            ar = araw if ((m >> q) & 1) == 1 else F32(0.0)
            a = min(ALPHA_MAX, ar)
            inv = F32(1.0) / (F32(1.0) - a)
            Tq = T[q] * inv
            wq = a * Tq
            f = fgl[k, q]
            d_a = Tq * f - (acc[q] - gatf[q]) * inv
            acc[q] = fma32(wq, f, acc[q])
            T[q] = Tq
            wl[k, q] = wq
            dp = ar * d_a if ar <= ALPHA_MAX else F32(0.0)
            terms[0, q] = dp * fma32(ca, dx, cb * dy)
            terms[1, q] = dp * fma32(cc, dy, cb * dx)
            terms[2, q] = dp * (F32(-0.5) * (dx * dx))
            terms[3, q] = dp * (-(dx * dy))
            terms[4, q] = dp * (F32(-0.5) * (dy * dy))
            terms[5, q] = dp
        e = el[k]
        for r in range(5):
            buf_geo[e, r] += np.float64(hsum16(terms[r]))
        buf_geo[e, 5] += np.float64(hsum16(terms[5]) / o)


__all__ = ["FUSED", "backward_block_plain", "composite_block_plain", "fma32", "hsum16"]
