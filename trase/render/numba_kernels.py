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
Compositing evaluates exp with ``exp_nonpositive`` (vectorisable, relative error < 1e-12);
``pixel_weights`` replays pixels one at a time with math.exp: the two can only disagree on a
gaussian whose alpha lies within 1e-12 of the 1/255 cut (tests compare them to 1e-5).
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


SUB = 4  # sub-block side in pixels: a tile's gaussians are culled per SUB x SUB block
POWER_MARGIN = 1e-3  # culling is widened by this much exponent (and 1e-3 px) against rounding


@njit(inline="always")
def _sub_lists(pk, tx, ty, ts):
    """Per SUB x SUB block of the tile, the positions (into the tile's depth-sorted list) of the
    gaussians that can reach alpha >= 1/255 at one of the block's pixel centres, in order.

    Why: most of a tile's gaussians miss most of its pixels; walking every one at every pixel
    was most of the compositing time. The test is the axis-aligned box of the ellipse
    power >= log(ALPHA_MIN / opacity), where alpha < 1/255 and the gaussian is skipped anyway,
    widened by a margin, so culling never changes a result. -> (ids [nb, K] int32, n [nb])."""
    k = pk.shape[0]
    nbx = (ts + SUB - 1) // SUB
    nb = nbx * nbx
    ids = np.empty((nb, max(k, 1)), np.int32)
    n = np.zeros(nb, np.int64)
    x_base = tx * ts
    y_base = ty * ts
    for i in range(k):
        o = pk[i, 5]
        if o < ALPHA_MIN:
            continue  # alpha = o * G < 1/255 everywhere
        a, b, c = pk[i, 2], pk[i, 3], pk[i, 4]
        det = a * c - b * b
        kk = -2.0 * (math.log(ALPHA_MIN / o) - POWER_MARGIN)
        if det > 0.0 and math.isfinite(det):
            rx = math.sqrt(kk * c / det) + 1e-3
            ry = math.sqrt(kk * a / det) + 1e-3
        else:
            rx = 1e30
            ry = 1e30
        u, v = pk[i, 0], pk[i, 1]
        # pixel centres px + 0.5 inside [u - rx, u + rx] (clamped to the tile before int())
        px_lo = math.ceil(min(max(u - rx - 0.5, x_base - 1.0), x_base + ts + 1.0))
        px_hi = math.floor(min(max(u + rx - 0.5, x_base - 1.0), x_base + ts + 1.0))
        py_lo = math.ceil(min(max(v - ry - 0.5, y_base - 1.0), y_base + ts + 1.0))
        py_hi = math.floor(min(max(v + ry - 0.5, y_base - 1.0), y_base + ts + 1.0))
        bx0 = max(0, (px_lo - x_base) // SUB)
        bx1 = min(nbx - 1, (px_hi - x_base) // SUB)
        by0 = max(0, (py_lo - y_base) // SUB)
        by1 = min(nbx - 1, (py_hi - y_base) // SUB)
        for by in range(by0, by1 + 1):
            for bx in range(bx0, bx1 + 1):
                j = by * nbx + bx
                ids[j, n[j]] = i
                n[j] += 1
    return ids, n


@njit(inline="always")
def exp_nonpositive(x):
    """exp(x) for -8 <= x <= 0 as plain arithmetic (relative error < 1e-12).

    Why not math.exp: LLVM lowers it to a libm call, which stops the per-block alpha loop
    below from being vectorised. exp(x) = exp(x / 16) ** 16 with a degree-10 Taylor polynomial
    on [-0.5, 0] (truncation < 3e-14) and four squarings."""
    y = x * 0.0625
    p = 1.0 + y * (1.0 + y * (0.5 + y * (1.0 / 6.0 + y * (1.0 / 24.0 + y * (1.0 / 120.0 + y * (
        1.0 / 720.0 + y * (1.0 / 5040.0 + y * (1.0 / 40320.0 + y * (1.0 / 362880.0 + y * (1.0 / 3628800.0))))))))))
    p = p * p
    p = p * p
    p = p * p
    return p * p


POWER_FLOOR = -8.0  # exp(-8) * opacity < 1/255: below it a gaussian never contributes


@njit(inline="always")
def _block_alphas(pk, ids, blk, n, x0, y0, alph):
    """alph[j, q] = raw alpha o * G of the block's j-th listed gaussian at its q-th pixel
    (q = row * SUB + col), 0 where the gaussian is skipped (power > 0). Branch-free over the
    SUB*SUB pixels so the loop vectorises. (The backward's G is alph / o: listed gaussians
    have o >= 1/255.)"""
    for j in range(n):
        i = ids[blk, j]
        u, v, ca, cb, cc, o = pk[i, 0], pk[i, 1], pk[i, 2], pk[i, 3], pk[i, 4], pk[i, 5]
        for q in range(SUB * SUB):
            dx = x0 + (q % SUB) + 0.5 - u
            dy = y0 + (q // SUB) + 0.5 - v
            power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
            G = exp_nonpositive(min(max(power, POWER_FLOOR), 0.0))
            alph[j, q] = o * G if power <= 0.0 else 0.0


@njit(inline="always")
def _tile_setup(t, tile_off, entries, means2d, conics, opac, width, height, ts, gx):
    """Tile t's origin, pixel bounds, packed gaussians, culled block lists and an alpha buffer
    for one block: -> (tx, ty, start, x_end, y_end, pk, ids, nsub, alph [K, SUB*SUB])."""
    tx = t % gx
    ty = t // gx
    start = tile_off[t]
    end = tile_off[t + 1]
    pk = _pack_tile(start, end, entries, means2d, conics, opac)
    ids, nsub = _sub_lists(pk, tx, ty, ts)
    alph = np.empty((max(1, end - start), SUB * SUB), np.float64)
    return tx, ty, start, min((tx + 1) * ts, width), min((ty + 1) * ts, height), pk, ids, nsub, alph


@njit(parallel=True, cache=True)
def forward(means2d, conics, opac, chans, tile_off, entries, width, height, ts, gx, gy, out, t_final, n_done):
    """out [H*W, C] = sum_i w_i chans_i; t_final [H*W] float64; n_done [H*W] = number of
    positions of the pixel's sub-block list walked (where the backward starts).

    Per tile: culled sub-block lists (_sub_lists); per sub-block all alphas at once
    (_block_alphas), then the 3DGS front-to-back rule run for the block's SUB*SUB pixels in
    lock-step (one lane per pixel, branch-free, so it vectorises; a lane stops where that
    pixel's sequential loop would break)."""
    C = chans.shape[1]
    nbx = (ts + SUB - 1) // SUB
    L = SUB * SUB
    for t in prange(gx * gy):
        tx, ty, start, x_end, y_end, pk, ids, nsub, alph = _tile_setup(
            t, tile_off, entries, means2d, conics, opac, width, height, ts, gx)
        T = np.empty(L, np.float64)
        w = np.empty(L, np.float64)
        act = np.empty(L, np.int64)
        walked = np.empty(L, np.int64)
        acc = np.empty((L, C), np.float32)
        for blk in range(nbx * nbx):
            x0 = tx * ts + (blk % nbx) * SUB
            y0 = ty * ts + (blk // nbx) * SUB
            if x0 >= x_end or y0 >= y_end:
                continue
            n = nsub[blk]
            _block_alphas(pk, ids, blk, n, x0, y0, alph)
            for q in range(L):
                act[q] = 1 if (x0 + q % SUB < x_end and y0 + q // SUB < y_end) else 0
                T[q] = 1.0
                walked[q] = 0
                for c in range(C):
                    acc[q, c] = 0.0
            for j in range(n):
                n_act = 0
                n_use = 0
                for q in range(L):
                    a = min(alph[j, q], ALPHA_MAX)
                    tt = T[q] * (1.0 - a)
                    ok = act[q] == 1 and a >= ALPHA_MIN
                    use = ok and tt >= T_MIN
                    w[q] = a * T[q] if use else 0.0
                    T[q] = tt if use else T[q]
                    walked[q] = j + 1 if use else walked[q]
                    act[q] = 0 if (ok and tt < T_MIN) else act[q]
                    n_act += act[q]
                    n_use += 1 if use else 0
                if n_use > 0:
                    g = entries[start + ids[blk, j]]
                    for q in range(L):
                        wf = np.float32(w[q])
                        if wf != 0.0:
                            for c in range(C):
                                acc[q, c] += wf * chans[g, c]
                if n_act == 0:
                    break
            for q in range(L):
                px = x0 + q % SUB
                py = y0 + q // SUB
                if px < x_end and py < y_end:
                    pix = py * width + px
                    for c in range(C):
                        out[pix, c] = acc[q, c]
                    t_final[pix] = T[q]
                    n_done[pix] = walked[q]


@njit(parallel=True, cache=True, fastmath={"reassoc", "contract"})
def backward(
    means2d, conics, opac, chans, tile_off, entries, width, height, ts, gx, gy,
    t_final, n_done, g_out, g_alpha, buf_geo, buf_chan,
):
    """Back to front, the block's pixels in lock-step as in ``forward``. g_out [H*W, C],
    g_alpha [H*W] (alpha = 1 - T_final). Writes per entry: buf_geo [E, 6] (d mean_u,
    d mean_v, d conic a, b, c, d opacity), buf_chan [E, C]."""
    C = chans.shape[1]
    nbx = (ts + SUB - 1) // SUB
    L = SUB * SUB
    for t in prange(gx * gy):
        tx, ty, start, x_end, y_end, pk, ids, nsub, alph = _tile_setup(
            t, tile_off, entries, means2d, conics, opac, width, height, ts, gx)
        T = np.empty(L, np.float64)
        tf = np.empty(L, np.float64)
        ga = np.empty(L, np.float64)
        acc = np.empty(L, np.float64)  # per pixel: sum over gaussians behind of w (chans . g_out)
        nd = np.empty(L, np.int64)
        w = np.empty(L, np.float64)
        fg = np.empty(L, np.float32)
        gblk = np.empty((L, C), np.float32)  # the block's output gradients
        for blk in range(nbx * nbx):
            x0 = tx * ts + (blk % nbx) * SUB
            y0 = ty * ts + (blk // nbx) * SUB
            if x0 >= x_end or y0 >= y_end:
                continue
            jmax = 0
            for q in range(L):
                px = x0 + q % SUB
                py = y0 + q // SUB
                if px < x_end and py < y_end:
                    pix = py * width + px
                    T[q] = t_final[pix]
                    ga[q] = g_alpha[pix]
                    nd[q] = n_done[pix]
                    for c in range(C):
                        gblk[q, c] = g_out[pix, c]
                else:
                    T[q] = 1.0
                    ga[q] = 0.0
                    nd[q] = 0
                    for c in range(C):
                        gblk[q, c] = 0.0
                tf[q] = T[q]
                acc[q] = 0.0
                jmax = max(jmax, nd[q])
            if jmax == 0:
                continue
            _block_alphas(pk, ids, blk, jmax, x0, y0, alph)
            for j in range(jmax - 1, -1, -1):
                i = ids[blk, j]
                e = start + i
                g = entries[e]
                n_use = 0
                for q in range(L):
                    a = min(alph[j, q], ALPHA_MAX)
                    use = j < nd[q] and a >= ALPHA_MIN
                    w[q] = a if use else 0.0
                    n_use += 1 if use else 0
                if n_use == 0:
                    continue
                for q in range(L):
                    sq = np.float32(0.0)
                    if w[q] > 0.0:  # only lanes this gaussian reaches (about half of them)
                        for c in range(C):  # a reduction: vectorised thanks to "reassoc"
                            sq += chans[g, c] * gblk[q, c]
                    fg[q] = sq
                o = pk[i, 5]
                inv_o = 1.0 / o
                ca, cb, cc = pk[i, 2], pk[i, 3], pk[i, 4]
                u, v = pk[i, 0], pk[i, 1]
                s0 = 0.0
                s1 = 0.0
                s2 = 0.0
                s3 = 0.0
                s4 = 0.0
                s5 = 0.0
                for q in range(L):
                    # branch-free: an unused lane has a = 0, so T and acc stay as they are
                    a = w[q]
                    inv = 1.0 / (1.0 - a)
                    Tq = T[q] * inv  # transmittance in front of this gaussian
                    wq = a * Tq
                    f = float(fg[q])
                    d_a = Tq * f - (acc[q] - ga[q] * tf[q]) * inv
                    acc[q] += wq * f
                    T[q] = Tq
                    w[q] = wq
                    # a clamped alpha passes no gradient to opacity or geometry
                    live = a > 0.0 and alph[j, q] <= ALPHA_MAX
                    d_op = alph[j, q] * inv_o * d_a if live else 0.0  # G d_a
                    dp = o * d_op
                    dx = x0 + q % SUB + 0.5 - u
                    dy = y0 + q // SUB + 0.5 - v
                    s0 += dp * (ca * dx + cb * dy)
                    s1 += dp * (cc * dy + cb * dx)
                    s2 += dp * (-0.5 * dx * dx)
                    s3 += dp * (-dx * dy)
                    s4 += dp * (-0.5 * dy * dy)
                    s5 += d_op
                for q in range(L):
                    wf = np.float32(w[q])
                    if wf != 0.0:
                        for c in range(C):
                            buf_chan[e, c] += wf * gblk[q, c]
                buf_geo[e, 0] += s0
                buf_geo[e, 1] += s1
                buf_geo[e, 2] += s2
                buf_geo[e, 3] += s3
                buf_geo[e, 4] += s4
                buf_geo[e, 5] += s5


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
