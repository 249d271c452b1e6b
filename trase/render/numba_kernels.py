"""Numba CPU kernels: tile binning, forward compositing, backward compositing, gradient
reduction and per-pixel weight extraction.

Layout: ``entries`` lists, tile after tile, the gaussians overlapping each tile in front-to-back
order (one global stable depth sort, then a bucket fill, so each tile's list is depth-sorted
with ties broken by index, as in the torch reference). ``tile_off[t]:tile_off[t+1]`` is tile
t's slice. ``g_ptr``/``g_pos`` list, for each gaussian, the entry positions it occupies, so the
backward writes per-entry gradients race-free (each tile owns its slice) and then reduces them
per gaussian in parallel, deterministically.

Numbers: inputs float32; per-pixel transmittance and geometry gradients in float64 (the
backward recovers T_k = T_{k+1} / (1 - alpha_k) back to front, which float32 would drift on).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4


@njit(cache=True)
def bin_gaussians(rects, depths, gx, gy):
    """rects [N, 4] int64 (x0, x1, y0, y1), depths [N] -> (tile_off [T+1], entries [E] gaussian
    ids, g_ptr [N+1], g_pos [E] entry positions per gaussian)."""
    n = rects.shape[0]
    n_tiles = gx * gy
    tile_count = np.zeros(n_tiles, np.int64)
    g_ptr = np.zeros(n + 1, np.int64)
    for g in range(n):
        x0, x1, y0, y1 = rects[g, 0], rects[g, 1], rects[g, 2], rects[g, 3]
        g_ptr[g + 1] = g_ptr[g] + (x1 - x0) * (y1 - y0)
        for ty in range(y0, y1):
            for tx in range(x0, x1):
                tile_count[ty * gx + tx] += 1
    tile_off = np.zeros(n_tiles + 1, np.int64)
    for t in range(n_tiles):
        tile_off[t + 1] = tile_off[t] + tile_count[t]
    n_entries = tile_off[n_tiles]
    entries = np.empty(n_entries, np.int64)
    g_pos = np.empty(n_entries, np.int64)
    cursor = tile_off[:-1].copy()
    order = np.argsort(depths, kind="mergesort")  # stable: ties by index
    for i in range(n):
        g = order[i]
        x0, x1, y0, y1 = rects[g, 0], rects[g, 1], rects[g, 2], rects[g, 3]
        j = g_ptr[g]
        for ty in range(y0, y1):
            for tx in range(x0, x1):
                t = ty * gx + tx
                pos = cursor[t]
                cursor[t] = pos + 1
                entries[pos] = g
                g_pos[j] = pos
                j += 1
    return tile_off, entries, g_ptr, g_pos


@njit(inline="always")
def _alpha_at(fx, fy, means2d, conics, opac, g, p_min):
    """-> (power, G = exp(power), raw alpha o*G, dx, dy); power > 0 means skip. ``p_min`` =
    log(ALPHA_MIN / max opacity): below it alpha < 1/255 for sure, so exp is not evaluated
    and power is reported as +1 (skip)."""
    dx = fx - means2d[g, 0]
    dy = fy - means2d[g, 1]
    a, b, c = conics[g, 0], conics[g, 1], conics[g, 2]
    power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
    if power > 0.0 or power < p_min:
        return 1.0, 0.0, 0.0, dx, dy
    G = math.exp(power)
    return power, G, opac[g] * G, dx, dy


@njit(inline="always")
def _pack_tile(start, end, entries, means2d, conics, opac):
    """Gather a tile's gaussians into one contiguous [K, 6] float64 block (u, v, a, b, c, o):
    the per-pixel loops then stream through it instead of gathering."""
    k = end - start
    pk = np.empty((k, 6), np.float64)
    for i in range(k):
        g = entries[start + i]
        pk[i, 0] = means2d[g, 0]
        pk[i, 1] = means2d[g, 1]
        pk[i, 2] = conics[g, 0]
        pk[i, 3] = conics[g, 1]
        pk[i, 4] = conics[g, 2]
        pk[i, 5] = opac[g]
    return pk


@njit(inline="always")
def _alpha_packed(fx, fy, pk, i, p_min):
    """As _alpha_at, from a packed tile block row."""
    dx = fx - pk[i, 0]
    dy = fy - pk[i, 1]
    power = -0.5 * (pk[i, 2] * dx * dx + pk[i, 4] * dy * dy) - pk[i, 3] * dx * dy
    if power > 0.0 or power < p_min:
        return 1.0, 0.0, 0.0, dx, dy
    G = math.exp(power)
    return power, G, pk[i, 5] * G, dx, dy


@njit(parallel=True, cache=True)
def forward(means2d, conics, opac, chans, tile_off, entries, width, height, ts, gx, gy, p_min, out, t_final, n_done):
    """out [H*W, C] += sum_i w_i chans_i; t_final [H*W] float64; n_done [H*W] = entry index
    one past the last gaussian used (where the backward starts)."""
    C = chans.shape[1]
    for t in prange(gx * gy):
        tx = t % gx
        ty = t // gx
        start = tile_off[t]
        end = tile_off[t + 1]
        pk = _pack_tile(start, end, entries, means2d, conics, opac)
        for py in range(ty * ts, min((ty + 1) * ts, height)):
            for px in range(tx * ts, min((tx + 1) * ts, width)):
                pix = py * width + px
                fx = px + 0.5
                fy = py + 0.5
                T = 1.0
                last = start
                for e in range(start, end):
                    power, _G, a, _dx, _dy = _alpha_packed(fx, fy, pk, e - start, p_min)
                    if power > 0.0:
                        continue
                    a = min(a, ALPHA_MAX)
                    if a < ALPHA_MIN:
                        continue
                    test_t = T * (1.0 - a)
                    if test_t < T_MIN:
                        break
                    wf = np.float32(a * T)
                    g = entries[e]
                    for c in range(C):
                        out[pix, c] += wf * chans[g, c]
                    T = test_t
                    last = e + 1
                t_final[pix] = T
                n_done[pix] = last


@njit(fastmath=True, cache=True)
def _dot_axpy(chans, g, g_out, pix, w, buf_chan, e):
    """-> sum_c chans[g, c] g_out[pix, c], and buf_chan[e] += w * g_out[pix] (float32 SIMD;
    reassociating this float32 sum is the only fast-math freedom taken)."""
    fg = np.float32(0.0)
    wf = np.float32(w)
    for c in range(chans.shape[1]):
        go = g_out[pix, c]
        fg += chans[g, c] * go
        buf_chan[e, c] += wf * go
    return fg


@njit(parallel=True, cache=True)
def backward(
    means2d, conics, opac, chans, tile_off, entries, width, height, ts, gx, gy, p_min,
    t_final, n_done, g_out, g_alpha, buf_geo, buf_chan,
):
    """Back to front per pixel. g_out [H*W, C], g_alpha [H*W] (alpha = 1 - T_final).
    Writes per entry: buf_geo [E, 6] (d mean_u, d mean_v, d conic a, b, c, d opacity),
    buf_chan [E, C]."""
    for t in prange(gx * gy):
        tx = t % gx
        ty = t // gx
        start = tile_off[t]
        pk = _pack_tile(start, tile_off[t + 1], entries, means2d, conics, opac)
        for py in range(ty * ts, min((ty + 1) * ts, height)):
            for px in range(tx * ts, min((tx + 1) * ts, width)):
                pix = py * width + px
                fx = px + 0.5
                fy = py + 0.5
                tf = t_final[pix]
                T = tf
                acc = 0.0  # sum over gaussians behind of w_j (chans_j . g_out)
                ga = g_alpha[pix]
                for e in range(n_done[pix] - 1, start - 1, -1):
                    power, G, a_raw, dx, dy = _alpha_packed(fx, fy, pk, e - start, p_min)
                    if power > 0.0:
                        continue
                    a = min(a_raw, ALPHA_MAX)
                    if a < ALPHA_MIN:
                        continue
                    g = entries[e]
                    one_m = 1.0 - a
                    T = T / one_m  # transmittance in front of this gaussian
                    w = a * T
                    fg = float(_dot_axpy(chans, g, g_out, pix, w, buf_chan, e))
                    d_a = T * fg - acc / one_m + ga * tf / one_m
                    acc += w * fg
                    if a_raw > ALPHA_MAX:
                        continue  # clamped alpha: no gradient to opacity or geometry
                    i = e - start
                    d_power = pk[i, 5] * d_a * G
                    ca, cb, cc = pk[i, 2], pk[i, 3], pk[i, 4]
                    buf_geo[e, 0] += d_power * (ca * dx + cb * dy)
                    buf_geo[e, 1] += d_power * (cc * dy + cb * dx)
                    buf_geo[e, 2] += d_power * (-0.5 * dx * dx)
                    buf_geo[e, 3] += d_power * (-dx * dy)
                    buf_geo[e, 4] += d_power * (-0.5 * dy * dy)
                    buf_geo[e, 5] += G * d_a


@njit(parallel=True, cache=True)
def reduce_grads(g_ptr, g_pos, buf_geo, buf_chan, grad_geo, grad_chan):
    """Sum per-entry gradients into per-gaussian grad_geo [N, 6] and grad_chan [N, C]."""
    n = grad_geo.shape[0]
    C = grad_chan.shape[1]
    for g in prange(n):
        for j in range(g_ptr[g], g_ptr[g + 1]):
            e = g_pos[j]
            for k in range(6):
                grad_geo[g, k] += buf_geo[e, k]
            for c in range(C):
                grad_chan[g, c] += buf_chan[e, c]


@njit(inline="always")
def _replay(pix, width, ts, gx, means2d, conics, opac, tile_off, entries, p_min, min_weight, idx_out, w_out, base):
    """Run the forward rule at one pixel; store (gaussian, weight) from ``base`` if idx_out has
    room (count pass passes empty arrays). -> number of stored contributors."""
    py = pix // width
    px = pix - py * width
    t = (py // ts) * gx + px // ts
    fx = px + 0.5
    fy = py + 0.5
    T = 1.0
    k = 0
    store = idx_out.shape[0] > 0
    for e in range(tile_off[t], tile_off[t + 1]):
        g = entries[e]
        power, _G, a, _dx, _dy = _alpha_at(fx, fy, means2d, conics, opac, g, p_min)
        if power > 0.0:
            continue
        a = min(a, ALPHA_MAX)
        if a < ALPHA_MIN:
            continue
        test_t = T * (1.0 - a)
        if test_t < T_MIN:
            break
        w = a * T
        if w >= min_weight:
            if store:
                idx_out[base + k] = g
                w_out[base + k] = w
            k += 1
        T = test_t
    return k


@njit(parallel=True, cache=True)
def pixel_weight_counts(pixels, width, ts, gx, means2d, conics, opac, tile_off, entries, p_min, min_weight, counts):
    empty_i = np.empty(0, np.int64)
    empty_w = np.empty(0, np.float32)
    for i in prange(pixels.shape[0]):
        counts[i] = _replay(pixels[i], width, ts, gx, means2d, conics, opac, tile_off, entries, p_min,
                            min_weight, empty_i, empty_w, 0)


@njit(parallel=True, cache=True)
def pixel_weight_fill(pixels, width, ts, gx, means2d, conics, opac, tile_off, entries, p_min, min_weight, indptr, idx_out, w_out):
    for i in prange(pixels.shape[0]):
        _replay(pixels[i], width, ts, gx, means2d, conics, opac, tile_off, entries, p_min,
                min_weight, idx_out, w_out, indptr[i])
