"""Numba CPU kernels: tile binning, forward compositing, backward compositing, gradient
reduction and per-pixel weight extraction.

Layout: ``entries`` lists, tile after tile, the gaussians overlapping each tile in front-to-back
order (one global stable depth sort, then a bucket fill, so each tile's list is depth-sorted
with ties broken by index, as in the torch reference). ``tile_off[t]:tile_off[t+1]`` is tile
t's slice. ``g_ptr``/``g_pos`` list, for each gaussian, the entry positions it occupies, so the
backward writes per-entry gradients race-free (each tile owns its slice) and then reduces them
per gaussian in parallel, deterministically.

Compositing works on SUB x SUB pixel blocks, one float32 lane per pixel (16 lanes), in the
torch reference's float32 arithmetic. The forward saves each block's culled gaussian list and,
per list slot, which lanes used the gaussian (a 16-bit mask): the backward replays exactly the
forward's decisions without recomputing culling or thresholds. The backward recovers
T_k = T_{k+1} / (1 - alpha_k) back to front in float32 (relative error grows by ~1e-7 per
step: ~3e-5 after 300 gaussians, well inside the 1e-3 gradient tolerance) and sums geometry
gradients per entry in float64. exp is ``exp_nonpositive32`` (plain arithmetic, so it
vectorises).

The per-block work is written as LLVM IR on <16 x float> vectors (numba ``@intrinsic``; plain
numba twins of the two walks in numba_plain, ``TRASE_NUMBA_WALKS=plain``):
``composite_block`` (the forward's front-to-back walk), ``backward_block`` (the backward's
walk), and the channel products ``lanes_times_rows`` (out += w * chans), ``rows_dot_lanes``
(chans . g_out) and ``lanes_dot_rows`` (d chans += w * g_out). Why: written as numba loops,
the lane state lived in memory between gaussians and the channel loops were scalar or used
one reduction per channel; as IR they keep accumulators in vector registers (3x faster).
The IR evaluates alpha with the same float32 operations in the same order as ``alpha32``
(no FMA contraction), so ``pixel_weights`` (which replays pixels one at a time with
``alpha32``) agrees with ``forward`` bit for bit; tests check the saved masks against it and
the channel helpers against numpy.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

from trase.render.numba_alpha import (  # noqa: F401 (re-exported: the kernels' constants)
    A_MAX32,
    A_MIN32,
    ALPHA_MAX,
    ALPHA_MIN,
    F32,
    LANES,
    POWER_FLOOR,
    SUB,
    T_MIN,
    T_MIN32,
    alpha32,
    exp_nonpositive32,
)
from trase.render.numba_plain import backward_block_plain, composite_block_plain

RADIX_BITS = 11


@njit(cache=True)
def stable_argsort(keys):
    """Stable ascending argsort of float64 keys (ties keep index order, as a stable sort does):
    LSD radix sort on the keys' order-preserving 64-bit patterns, 11 bits a pass, skipping
    passes where every key has the same digit (depths share their sign and exponent bits, and
    float32 depths have 29 zero mantissa bits). 3-4x faster than numba's mergesort at 20k."""
    n = keys.shape[0]
    bits = keys.view(np.uint64)
    top = np.uint64(1) << np.uint64(63)
    k = np.empty(n, np.uint64)
    for i in range(n):
        x = keys[i]
        b = bits[i]
        if x == 0.0:
            k[i] = top  # -0.0 ties with +0.0
        elif math.isnan(x):
            k[i] = ~np.uint64(0)  # NaN last, as numpy sorts
        else:
            k[i] = ~b if (b & top) != 0 else (b | top)  # negative: flip all; positive: flip sign
    order = np.arange(n)
    tmp = np.empty(n, np.int64)
    nbuck = 1 << RADIX_BITS
    mask = np.uint64(nbuck - 1)
    count = np.empty(nbuck + 1, np.int64)
    shift = 0
    while shift < 64:
        sh = np.uint64(shift)
        count[:] = 0
        for i in range(n):
            count[((k[i] >> sh) & mask) + 1] += 1
        if n == 0 or count[((k[0] >> sh) & mask) + 1] == n:
            shift += RADIX_BITS
            continue  # one digit for all: this pass keeps the order
        for d in range(nbuck):
            count[d + 1] += count[d]
        for i in range(n):
            o = order[i]
            d = (k[o] >> sh) & mask
            tmp[count[d]] = o
            count[d] += 1
        order, tmp = tmp, order
        shift += RADIX_BITS
    return order


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
    order = stable_argsort(depths)  # stable: ties by index
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


POWER_MARGIN = 1e-3  # culling is widened by this much exponent (and 1e-3 px) against rounding



def blocks_per_tile(ts: int) -> int:
    nbx = (ts + SUB - 1) // SUB
    return nbx * nbx


# --- 16-lane vector helpers, written as LLVM IR --------------------------------------------
# Why: the channel loops are small matrix products (per pixel block: 16 lanes x C channels x
# the block's gaussians). Written in numba, LLVM keeps the accumulators in memory (or in 16
# scalar registers) whatever the loop order; here they are <16 x float> values that stay in
# vector registers across the gaussian loop. Each helper is checked against plain loops in
# tests/trase/render/test_numba_simd.py.

_V16 = ir.VectorType(ir.FloatType(), LANES)


def _array(context, builder, aryty, ary):
    """-> (pointer to the first element, [shape entries]) of a C-contiguous array argument."""
    a = context.make_array(aryty)(context, builder, ary)
    return a.data, cgutils.unpack_tuple(builder, a.shape)


def _vload(builder, ptr, idx):
    return builder.load(builder.bitcast(builder.gep(ptr, [idx]), _V16.as_pointer()), align=4)


def _vstore(builder, val, ptr, idx):
    builder.store(val, builder.bitcast(builder.gep(ptr, [idx]), _V16.as_pointer()), align=4)


def _splat(builder, x):
    v = builder.insert_element(ir.Constant(_V16, ir.Undefined), x, ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(v, ir.Constant(_V16, ir.Undefined),
                                  ir.Constant(ir.VectorType(ir.IntType(32), LANES), [0] * LANES))


def _fma(builder, a, b, c):
    return builder.fadd(builder.fmul(a, b, flags=("contract",)), c, flags=("contract",))


PREFETCH_AHEAD = 8  # rows of chans requested this many gaussians ahead of their use


def _prefetch_row(builder, ids_p, j, n, rows_p, C, offsets=(0, 16, 32)):
    """Ask for rows[ids[j + PREFETCH_AHEAD], offsets] (row length C): the rows are gathered in
    depth order, i.e. at random, and their cache misses were the channel helpers' main cost
    (prefetching them measured ~3 ms of the backward's ~19 at 20k gaussians, 1 thread)."""
    i64, i32 = ir.IntType(64), ir.IntType(32)
    i8p = ir.IntType(8).as_pointer()
    ja = builder.add(j, ir.Constant(i64, PREFETCH_AHEAD))
    with builder.if_then(builder.icmp_signed("<", ja, n), likely=True):
        g = builder.sext(builder.load(builder.gep(ids_p, [ja])), i64)
        base = builder.mul(g, C)
        fn = builder.module.declare_intrinsic("llvm.prefetch", [i8p], ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]))
        for k in offsets:
            k = ir.Constant(i64, k) if isinstance(k, int) else k
            ptr = builder.bitcast(builder.gep(rows_p, [builder.add(base, k)]), i8p)
            builder.call(fn, [ptr, ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])


@intrinsic
def lanes_times_rows(typingctx, acc, wl, ids, n, rows):
    """acc[c, :] += sum_j wl[j, :] * rows[ids[j], c] for j < n and every column c of rows.

    acc [C, >=16] float32 (channel-major lanes), wl [>=n, >=16] float32 (lane weights per
    gaussian), ids [>=n] int, rows [N, C] float32. The channels go 16 at a time: 16 vector
    accumulators, one vector load of the weights and 16 broadcast FMAs per gaussian."""
    sig = types.void(acc, wl, ids, n, rows)

    def codegen(context, builder, signature, args):
        a_ty, w_ty, i_ty, _, r_ty = signature.args
        acc_p, acc_sh = _array(context, builder, a_ty, args[0])
        w_p, w_sh = _array(context, builder, w_ty, args[1])
        i_p, _ = _array(context, builder, i_ty, args[2])
        r_p, r_sh = _array(context, builder, r_ty, args[4])
        cnt = args[3]
        i64 = ir.IntType(64)
        C = r_sh[1]

        def chunk(c0, k):  # channels c0 .. c0 + k - 1
            slots = [cgutils.alloca_once(builder, _V16) for _ in range(k)]
            for m in range(k):
                idx = builder.mul(builder.add(c0, ir.Constant(i64, m)), acc_sh[1])
                builder.store(_vload(builder, acc_p, idx), slots[m])
            with cgutils.for_range(builder, cnt) as loop:
                j = loop.index
                _prefetch_row(builder, i_p, j, cnt, r_p, C, (c0, builder.add(c0, ir.Constant(i64, k - 1))))
                wv = _vload(builder, w_p, builder.mul(j, w_sh[1]))
                g = builder.sext(builder.load(builder.gep(i_p, [j])), i64)
                rp = builder.gep(r_p, [builder.add(builder.mul(g, C), c0)])
                for m in range(k):
                    x = builder.load(builder.gep(rp, [ir.Constant(i64, m)]))
                    builder.store(_fma(builder, wv, _splat(builder, x), builder.load(slots[m])), slots[m])
            for m in range(k):
                idx = builder.mul(builder.add(c0, ir.Constant(i64, m)), acc_sh[1])
                _vstore(builder, builder.load(slots[m]), acc_p, idx)

        n16 = builder.udiv(C, ir.Constant(i64, LANES))
        with cgutils.for_range(builder, n16) as loop:
            chunk(builder.mul(loop.index, ir.Constant(i64, LANES)), LANES)
        # the last C mod 16 channels as chunks of 8, 4, 2, 1 (one pass over the list each)
        c0 = builder.mul(n16, ir.Constant(i64, LANES))
        rest = builder.sub(C, c0)
        for k in (8, 4, 2, 1):
            kc = ir.Constant(i64, k)
            has = builder.icmp_unsigned("!=", builder.and_(rest, kc), ir.Constant(i64, 0))
            with builder.if_then(has):
                chunk(builder.add(c0, builder.and_(rest, ir.Constant(i64, 16 - 2 * k))), k)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def rows_dot_lanes(typingctx, out, ids, n, rows, gt):
    """out[j, :] = sum_c rows[ids[j], c] * gt[c, :] for j < n (16 lanes each).

    out [>=n, >=16], ids [>=n] int, rows [N, C], gt [C, >=16] (channel-major lanes), all
    float32. Four vector accumulators (channels c mod 4) hide the FMA latency."""
    sig = types.void(out, ids, n, rows, gt)

    def codegen(context, builder, signature, args):
        o_ty, i_ty, _, r_ty, g_ty = signature.args
        o_p, o_sh = _array(context, builder, o_ty, args[0])
        i_p, _ = _array(context, builder, i_ty, args[1])
        r_p, r_sh = _array(context, builder, r_ty, args[3])
        g_p, g_sh = _array(context, builder, g_ty, args[4])
        i64 = ir.IntType(64)
        C = r_sh[1]
        slots = [cgutils.alloca_once(builder, _V16) for _ in range(4)]
        zero = ir.Constant(_V16, [0.0] * LANES)
        with cgutils.for_range(builder, args[2]) as loop:
            j = loop.index
            _prefetch_row(builder, i_p, j, args[2], r_p, C)
            g = builder.sext(builder.load(builder.gep(i_p, [j])), i64)
            rp = builder.gep(r_p, [builder.mul(g, C)])
            for m in range(4):
                builder.store(zero, slots[m])
            n4 = builder.udiv(C, ir.Constant(i64, 4))
            with cgutils.for_range(builder, n4) as inner:
                c0 = builder.mul(inner.index, ir.Constant(i64, 4))
                for m in range(4):
                    c = builder.add(c0, ir.Constant(i64, m))
                    x = builder.load(builder.gep(rp, [c]))
                    gv = _vload(builder, g_p, builder.mul(c, g_sh[1]))
                    builder.store(_fma(builder, gv, _splat(builder, x), builder.load(slots[m])), slots[m])
            with cgutils.for_range_slice(builder, builder.mul(n4, ir.Constant(i64, 4)), C, ir.Constant(i64, 1)) as (c, _):
                x = builder.load(builder.gep(rp, [c]))
                gv = _vload(builder, g_p, builder.mul(c, g_sh[1]))
                builder.store(_fma(builder, gv, _splat(builder, x), builder.load(slots[0])), slots[0])
            tot = builder.fadd(builder.fadd(builder.load(slots[0]), builder.load(slots[1])),
                               builder.fadd(builder.load(slots[2]), builder.load(slots[3])))
            _vstore(builder, tot, o_p, builder.mul(j, o_sh[1]))
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def lanes_dot_rows(typingctx, buf, eids, n, wl, gl):
    """buf[eids[j], c] += sum_q wl[j, q] * gl[q, c] for j < n and every column c of buf.

    buf [E, CP], eids [>=n] int, wl [>=n, >=16], gl [16, >=CP], all float32; CP (buf's row
    length) must be a multiple of 16 (callers pad their channels). Per gaussian and 16-channel
    chunk: 16 FMAs into four accumulators (lanes q mod 4), so the chain is 4 deep, not 16."""
    sig = types.void(buf, eids, n, wl, gl)

    def codegen(context, builder, signature, args):
        b_ty, e_ty, _, w_ty, l_ty = signature.args
        b_p, b_sh = _array(context, builder, b_ty, args[0])
        e_p, _ = _array(context, builder, e_ty, args[1])
        w_p, w_sh = _array(context, builder, w_ty, args[3])
        l_p, l_sh = _array(context, builder, l_ty, args[4])
        i64 = ir.IntType(64)
        C = b_sh[1]
        n16 = builder.udiv(C, ir.Constant(i64, LANES))
        zero = ir.Constant(_V16, [0.0] * LANES)
        with cgutils.for_range(builder, args[2]) as loop:
            j = loop.index
            e = builder.sext(builder.load(builder.gep(e_p, [j])), i64)
            bp = builder.gep(b_p, [builder.mul(e, C)])
            wp = builder.gep(w_p, [builder.mul(j, w_sh[1])])
            ws = [builder.load(builder.gep(wp, [ir.Constant(i64, q)])) for q in range(LANES)]
            with cgutils.for_range(builder, n16) as inner:
                c0 = builder.mul(inner.index, ir.Constant(i64, LANES))
                parts = [_vload(builder, bp, c0), zero, zero, zero]
                for q in range(LANES):
                    gv = _vload(builder, l_p, builder.add(builder.mul(ir.Constant(i64, q), l_sh[1]), c0))
                    parts[q % 4] = _fma(builder, gv, _splat(builder, ws[q]), parts[q % 4])
                tot = builder.fadd(builder.fadd(parts[0], parts[1]), builder.fadd(parts[2], parts[3]))
                _vstore(builder, tot, bp, c0)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def sum_rows(typingctx, out, r, pos, lo, hi, buf):
    """out[r, :] = sum of buf[pos[j], :] over lo <= j < hi, 16 columns at a time.

    out [R, CP], buf [E, CP] float32 with CP a multiple of 16 (padded channels), pos int."""
    sig = types.void(out, r, pos, lo, hi, buf)

    def codegen(context, builder, signature, args):
        o_ty, _, p_ty, _, _, b_ty = signature.args
        o_p, o_sh = _array(context, builder, o_ty, args[0])
        p_p, _ = _array(context, builder, p_ty, args[2])
        b_p, b_sh = _array(context, builder, b_ty, args[5])
        i64 = ir.IntType(64)
        C = o_sh[1]
        op = builder.gep(o_p, [builder.mul(args[1], C)])
        slot = cgutils.alloca_once(builder, _V16)
        with cgutils.for_range(builder, builder.udiv(C, ir.Constant(i64, LANES))) as chunk:
            c0 = builder.mul(chunk.index, ir.Constant(i64, LANES))
            builder.store(ir.Constant(_V16, [0.0] * LANES), slot)
            with cgutils.for_range_slice(builder, args[3], args[4], ir.Constant(i64, 1)) as (j, _):
                e = builder.sext(builder.load(builder.gep(p_p, [j])), i64)
                v = _vload(builder, b_p, builder.add(builder.mul(e, b_sh[1]), c0))
                builder.store(builder.fadd(builder.load(slot), v), slot)
            _vstore(builder, builder.load(slot), op, c0)
        return context.get_dummy_value()

    return sig, codegen


def _vconst(xs):
    return ir.Constant(_V16, [float(np.float32(x)) for x in xs])


_EXP_COEF = [1.0, 1.0, 0.5, 1.0 / 6.0, 1.0 / 24.0, 1.0 / 120.0, 1.0 / 720.0, 1.0 / 5040.0, 1.0 / 40320.0]


def _alpha_lanes(builder, fx, fy, row):
    """IR of alpha32 at the 16 lane centres for the pk row -> (alpha vector, u, v, a, b, c, o)."""
    i64 = ir.IntType(64)
    u, v, ca, cb, cc, o = (builder.load(builder.gep(row, [ir.Constant(i64, k)])) for k in range(6))
    zero_v = _vconst([0.0] * LANES)
    dx = builder.fsub(fx, _splat(builder, u))
    dy = builder.fsub(fy, _splat(builder, v))
    quad = builder.fadd(builder.fmul(_splat(builder, ca), builder.fmul(dx, dx)),
                        builder.fmul(_splat(builder, cc), builder.fmul(dy, dy)))
    power = builder.fsub(builder.fmul(_vconst([-0.5] * LANES), quad),
                         builder.fmul(builder.fmul(_splat(builder, cb), dx), dy))
    floor = _vconst([float(POWER_FLOOR)] * LANES)
    x = builder.select(builder.fcmp_ordered(">", power, floor), power, floor)
    x = builder.select(builder.fcmp_ordered("<", x, zero_v), x, zero_v)
    y = builder.fmul(x, _vconst([0.0625] * LANES))
    poly = _vconst([_EXP_COEF[8]] * LANES)
    for k in range(7, -1, -1):
        poly = builder.fadd(_vconst([_EXP_COEF[k]] * LANES), builder.fmul(y, poly))
    for _ in range(4):
        poly = builder.fmul(poly, poly)
    alpha = builder.select(builder.fcmp_ordered("<=", power, zero_v), builder.fmul(_splat(builder, o), poly), zero_v)
    return alpha, dx, dy, ca, cb, cc, o


def _lane_centres_ir(builder, x0, y0):
    fx = builder.fadd(builder.fadd(_splat(builder, builder.sitofp(x0, ir.FloatType())),
                                   _vconst([q % SUB for q in range(LANES)])), _vconst([0.5] * LANES))
    fy = builder.fadd(builder.fadd(_splat(builder, builder.sitofp(y0, ir.FloatType())),
                                   _vconst([q // SUB for q in range(LANES)])), _vconst([0.5] * LANES))
    return fx, fy


def _hsum(builder, v):
    """Sum of a <16 x float> by halving (4 shuffle + add steps)."""
    width = LANES
    while width > 1:
        half = width // 2
        lo = builder.shuffle_vector(v, v, ir.Constant(ir.VectorType(ir.IntType(32), half), list(range(half))))
        hi = builder.shuffle_vector(v, v, ir.Constant(ir.VectorType(ir.IntType(32), half), list(range(half, width))))
        v = builder.fadd(lo, hi)
        width = half
    return builder.extract_element(v, ir.Constant(ir.IntType(32), 0))


@intrinsic
def composite_block(typingctx, pk, ids, off, n, x0, y0, live, T, asum, wl, gl, bl_mask, res):
    """The forward's front-to-back walk of one SUB x SUB block, lanes as <16 x float> values.

    Walks list slots j < n (tile-local gaussian ids[off + j], rows of pk [K, 6] = u, v, a, b,
    c, opacity) over the block at pixel (x0, y0); ``live`` has bit q set for lanes inside the
    image. Per slot it computes ``alpha32`` at the 16 pixel centres with the same float32
    operations in the same order (no FMA contraction, so bit-identical to the scalar
    pixel_weights replay) and applies the 3DGS rule; stores the lane mask of users in
    bl_mask[off + j], and for slots with a user the lane weights in wl[nu] and the id in
    gl[nu]. Stops once every lane is done. Writes T [16] and asum [16] (transmittance, alpha)
    and res [2] = (list length up to the last used slot, nu).

    Why IR: in numba the lane state (T, active lanes, alpha sum) lives in memory between slots
    and each slot waits on store-to-load forwarding; here it stays in vector registers."""
    sig = types.void(pk, ids, off, n, x0, y0, live, T, asum, wl, gl, bl_mask, res)

    def codegen(context, builder, signature, args):
        pk_ty, id_ty, _, _, _, _, _, t_ty, s_ty, w_ty, g_ty, m_ty, r_ty = signature.args
        pk_p, pk_sh = _array(context, builder, pk_ty, args[0])
        id_p, _ = _array(context, builder, id_ty, args[1])
        off_, n_, x0_, y0_, live_ = args[2], args[3], args[4], args[5], args[6]
        t_p, _ = _array(context, builder, t_ty, args[7])
        s_p, _ = _array(context, builder, s_ty, args[8])
        w_p, w_sh = _array(context, builder, w_ty, args[9])
        g_p, _ = _array(context, builder, g_ty, args[10])
        m_p, _ = _array(context, builder, m_ty, args[11])
        r_p, _ = _array(context, builder, r_ty, args[12])
        i64, i16 = ir.IntType(64), ir.IntType(16)
        b16 = ir.VectorType(ir.IntType(1), LANES)
        c64 = lambda v: ir.Constant(i64, v)
        zero_v = _vconst([0.0] * LANES)
        fx, fy = _lane_centres_ir(builder, x0_, y0_)
        # loop state in allocas (promoted to registers by mem2reg)
        s_T = cgutils.alloca_once(builder, _V16)
        s_sum = cgutils.alloca_once(builder, _V16)
        s_act = cgutils.alloca_once(builder, i16)
        s_j = cgutils.alloca_once(builder, i64)
        s_nu = cgutils.alloca_once(builder, i64)
        s_last = cgutils.alloca_once(builder, i64)
        builder.store(_vconst([1.0] * LANES), s_T)
        builder.store(zero_v, s_sum)
        builder.store(builder.trunc(live_, i16), s_act)
        for slot in (s_j, s_nu, s_last):
            builder.store(c64(0), slot)
        fn = builder.function
        head = fn.append_basic_block("cb_head")
        body = fn.append_basic_block("cb_body")
        done = fn.append_basic_block("cb_done")
        builder.branch(head)
        builder.position_at_end(head)
        j = builder.load(s_j)
        act16 = builder.load(s_act)
        more = builder.and_(builder.icmp_signed("<", j, n_), builder.icmp_unsigned("!=", act16, ir.Constant(i16, 0)))
        builder.cbranch(more, body, done)
        builder.position_at_end(body)
        slot_ix = builder.add(off_, j)
        i = builder.sext(builder.load(builder.gep(id_p, [slot_ix])), i64)
        row = builder.gep(pk_p, [builder.mul(i, pk_sh[1])])
        alpha = _alpha_lanes(builder, fx, fy, row)[0]  # alpha32, operation for operation
        amax = _vconst([ALPHA_MAX] * LANES)
        a = builder.select(builder.fcmp_ordered("<", alpha, amax), alpha, amax)
        # the 3DGS rule, all lanes at once
        Tv = builder.load(s_T)
        tt = builder.fmul(Tv, builder.fsub(_vconst([1.0] * LANES), a))
        actv = builder.bitcast(act16, b16)
        ok = builder.and_(actv, builder.fcmp_ordered(">=", a, _vconst([ALPHA_MIN] * LANES)))
        keep = builder.fcmp_ordered(">=", tt, _vconst([T_MIN] * LANES))
        use = builder.and_(ok, keep)
        w = builder.select(use, builder.fmul(a, Tv), zero_v)
        builder.store(builder.select(use, tt, Tv), s_T)
        stop = builder.and_(ok, builder.not_(keep))
        builder.store(builder.bitcast(builder.and_(actv, builder.not_(stop)), i16), s_act)
        builder.store(builder.fadd(builder.load(s_sum), w), s_sum)
        mask = builder.bitcast(use, i16)
        builder.store(mask, builder.gep(m_p, [slot_ix]))
        nu = builder.load(s_nu)
        _vstore(builder, w, w_p, builder.mul(nu, w_sh[1]))
        with builder.if_then(builder.icmp_unsigned("!=", mask, ir.Constant(i16, 0))):
            builder.store(i, builder.gep(g_p, [nu]))
            builder.store(builder.add(nu, c64(1)), s_nu)
            builder.store(builder.add(j, c64(1)), s_last)
        builder.store(builder.add(j, c64(1)), s_j)
        builder.branch(head)
        builder.position_at_end(done)
        _vstore(builder, builder.load(s_T), t_p, c64(0))
        _vstore(builder, builder.load(s_sum), s_p, c64(0))
        builder.store(builder.load(s_last), builder.gep(r_p, [c64(0)]))
        builder.store(builder.load(s_nu), builder.gep(r_p, [c64(1)]))
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def backward_block(typingctx, pk, ids, masks, sl, el, nu, x0, y0, T, tf, ga, fgl, wl, buf_geo):
    """The backward's back-to-front walk of one block's used gaussians, lanes as vectors.

    k < nu: list slot sl[k] (tile-local id ids[sl[k]], lane mask masks[sl[k]]), entry el[k],
    fgl[k] = chans . g_out per lane. T [16] holds the final transmittance on entry (and the
    front one on exit), tf [16] the final one, ga [16] d loss / d alpha. Writes wl[k] = the
    lane weights w = alpha T, and adds the geometry gradients (d mean u, v, d conic a, b, c,
    d opacity) to buf_geo[el[k]] (float64). T_k = T_{k+1} / (1 - alpha_k), per lane."""
    sig = types.void(pk, ids, masks, sl, el, nu, x0, y0, T, tf, ga, fgl, wl, buf_geo)

    def codegen(context, builder, signature, args):
        tys = signature.args
        pk_p, pk_sh = _array(context, builder, tys[0], args[0])
        id_p, _ = _array(context, builder, tys[1], args[1])
        m_p, _ = _array(context, builder, tys[2], args[2])
        sl_p, _ = _array(context, builder, tys[3], args[3])
        el_p, _ = _array(context, builder, tys[4], args[4])
        t_p, _ = _array(context, builder, tys[8], args[8])
        tf_p, _ = _array(context, builder, tys[9], args[9])
        ga_p, _ = _array(context, builder, tys[10], args[10])
        fg_p, fg_sh = _array(context, builder, tys[11], args[11])
        w_p, w_sh = _array(context, builder, tys[12], args[12])
        bg_p, bg_sh = _array(context, builder, tys[13], args[13])
        i64 = ir.IntType(64)
        c64 = lambda v: ir.Constant(i64, v)
        b16 = ir.VectorType(ir.IntType(1), LANES)
        one_v = _vconst([1.0] * LANES)
        zero_v = _vconst([0.0] * LANES)
        fx, fy = _lane_centres_ir(builder, args[6], args[7])
        s_T = cgutils.alloca_once(builder, _V16)
        s_acc = cgutils.alloca_once(builder, _V16)
        builder.store(_vload(builder, t_p, c64(0)), s_T)
        builder.store(zero_v, s_acc)
        gatf = builder.fmul(_vload(builder, ga_p, c64(0)), _vload(builder, tf_p, c64(0)))
        with cgutils.for_range(builder, args[5]) as loop:
            k = loop.index
            slot = builder.load(builder.gep(sl_p, [k]))
            i = builder.sext(builder.load(builder.gep(id_p, [slot])), i64)
            use = builder.bitcast(builder.load(builder.gep(m_p, [slot])), b16)
            row = builder.gep(pk_p, [builder.mul(i, pk_sh[1])])
            araw, dx, dy, ca, cb, cc, o = _alpha_lanes(builder, fx, fy, row)
            ar = builder.select(use, araw, zero_v)
            amax = _vconst([ALPHA_MAX] * LANES)
            a = builder.select(builder.fcmp_ordered("<", ar, amax), ar, amax)
            inv = builder.fdiv(one_v, builder.fsub(one_v, a))
            Tq = builder.fmul(builder.load(s_T), inv)  # transmittance in front of this gaussian
            wq = builder.fmul(a, Tq)
            f = _vload(builder, fg_p, builder.mul(k, fg_sh[1]))
            acc = builder.load(s_acc)
            d_a = builder.fsub(builder.fmul(Tq, f), builder.fmul(builder.fsub(acc, gatf), inv))
            builder.store(_fma(builder, wq, f, acc), s_acc)
            builder.store(Tq, s_T)
            _vstore(builder, wq, w_p, builder.mul(k, w_sh[1]))
            # a clamped alpha passes no gradient to opacity or geometry; unused lanes have ar = 0
            dp = builder.select(builder.fcmp_ordered("<=", ar, amax), builder.fmul(ar, d_a), zero_v)
            sp = lambda x: _splat(builder, x)
            half = _vconst([-0.5] * LANES)
            sums = [
                _hsum(builder, builder.fmul(dp, _fma(builder, sp(ca), dx, builder.fmul(sp(cb), dy)))),
                _hsum(builder, builder.fmul(dp, _fma(builder, sp(cc), dy, builder.fmul(sp(cb), dx)))),
                _hsum(builder, builder.fmul(dp, builder.fmul(half, builder.fmul(dx, dx)))),
                _hsum(builder, builder.fmul(dp, builder.fneg(builder.fmul(dx, dy)))),
                _hsum(builder, builder.fmul(dp, builder.fmul(half, builder.fmul(dy, dy)))),
                builder.fdiv(_hsum(builder, dp), o),
            ]
            e = builder.load(builder.gep(el_p, [k]))
            gp = builder.gep(bg_p, [builder.mul(e, bg_sh[1])])
            for m, sv in enumerate(sums):
                ptr = builder.gep(gp, [c64(m)])
                builder.store(builder.fadd(builder.load(ptr), builder.fpext(sv, ir.DoubleType())), ptr)
        _vstore(builder, builder.load(s_T), t_p, c64(0))
        return context.get_dummy_value()

    return sig, codegen


@njit(inline="always")
def _pack_tile(start, end, entries, means2d, conics, opac):
    """Gather a tile's gaussians into one contiguous [K, 6] float32 block (u, v, a, b, c, o):
    the lane loops then stream through it instead of gathering."""
    k = end - start
    pk = np.empty((k, 6), np.float32)
    for i in range(k):
        g = entries[start + i]
        pk[i, 0] = means2d[g, 0]
        pk[i, 1] = means2d[g, 1]
        pk[i, 2] = conics[g, 0]
        pk[i, 3] = conics[g, 1]
        pk[i, 4] = conics[g, 2]
        pk[i, 5] = opac[g]
    return pk


@njit(parallel=True, cache=True)
def cull_radii(conics, opac, radii):
    """radii [N, 2] float64: half-widths (rx, ry) of the axis-aligned box of the ellipse
    power >= log(ALPHA_MIN / opacity), outside which alpha < 1/255 and a gaussian is skipped
    anyway; widened by a margin (in exponent and pixels) so culling never changes a result.
    -1 marks a gaussian that never reaches 1/255 (opacity below it); 1e30 a degenerate conic.
    Once per gaussian, not per tile entry (the log and square roots were a third of the
    forward's tile setup)."""
    for g in prange(conics.shape[0]):
        o = float(opac[g])
        if not o >= ALPHA_MIN:
            radii[g, 0] = -1.0
            radii[g, 1] = -1.0
            continue
        a, b, c = float(conics[g, 0]), float(conics[g, 1]), float(conics[g, 2])
        det = a * c - b * b
        kk = -2.0 * (math.log(ALPHA_MIN / o) - POWER_MARGIN)
        if det > 0.0 and math.isfinite(det):
            radii[g, 0] = math.sqrt(kk * c / det) + 1e-3
            radii[g, 1] = math.sqrt(kk * a / det) + 1e-3
        else:
            radii[g, 0] = 1e30
            radii[g, 1] = 1e30


@njit(inline="always")
def _sub_lists(start, end, entries, means2d, radii, tx, ty, ts, bl_ids, base, n):
    """Per SUB x SUB block of the tile, the positions (into the tile's depth-sorted list) of the
    gaussians that can reach alpha >= 1/255 at one of the block's pixel centres, in order:
    block b's list is bl_ids[base + b * K : base + b * K + n[b]] (K = the tile's list length).

    Why: most of a tile's gaussians miss most of its pixels; walking every one at every pixel
    was most of the compositing time. The test is the gaussian's cull_radii box, so culling
    never changes a result."""
    k = end - start
    nbx = (ts + SUB - 1) // SUB
    x_base = tx * ts
    y_base = ty * ts
    for j in range(nbx * nbx):
        n[j] = 0
    for i in range(k):
        g = entries[start + i]
        rx = radii[g, 0]
        ry = radii[g, 1]
        if rx < 0.0:
            continue  # alpha = o * G < 1/255 everywhere
        u, v = float(means2d[g, 0]), float(means2d[g, 1])
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
                bl_ids[base + j * k + n[j]] = i
                n[j] += 1


@njit(parallel=True, cache=True)
def forward(means2d, conics, opac, radii, chans, tile_off, entries, width, height, ts, gx, gy,
            out, alpha, t_final, bl_ids, bl_mask, bl_n, plain=False):
    """out [H*W, C] = sum_i w_i chans_i; alpha [H*W] = sum_i w_i (summed, as the reference does:
    1 - T_final in float32 would lose most digits of a small alpha); t_final [H*W] float32.
    Saved for the backward, per
    SUB x SUB block of each tile: the culled depth-ordered list (bl_ids, tile-local positions,
    block b of tile t at nb * tile_off[t] + b * K), a 16-bit lane mask per list slot telling
    which of the block's pixels used that gaussian (bl_mask), and bl_n [T * nb] = the list
    length up to the last slot used anywhere in the block.

    Per tile: culled block lists (_sub_lists); per block the 3DGS front-to-back rule run for
    its SUB*SUB pixels in lock-step (one float32 lane per pixel, branch-free, so it
    vectorises; a lane stops where that pixel's sequential loop would break), then the
    block's channels in one lanes_times_rows call."""
    C = chans.shape[1]
    nbx = (ts + SUB - 1) // SUB
    nb = nbx * nbx
    for t in prange(gx * gy):
        tx = t % gx
        ty = t // gx
        start = tile_off[t]
        end = tile_off[t + 1]
        K = end - start
        x_end = min((tx + 1) * ts, width)
        y_end = min((ty + 1) * ts, height)
        pk = _pack_tile(start, end, entries, means2d, conics, opac)
        nsub = np.empty(nb, np.int64)
        base = nb * start
        _sub_lists(start, end, entries, means2d, radii, tx, ty, ts, bl_ids, base, nsub)
        T = np.empty(LANES, np.float32)
        asum = np.empty(LANES, np.float32)
        res = np.empty(2, np.int64)
        acc = np.empty((C, LANES), np.float32)  # the block's output, channel-major
        wl = np.empty((max(K, 1), LANES), np.float32)  # lane weights of the block's used gaussians
        gl = np.empty(max(K, 1), np.int64)  # and their ids
        for blk in range(nb):
            x0 = tx * ts + (blk % nbx) * SUB
            y0 = ty * ts + (blk // nbx) * SUB
            bl_n[t * nb + blk] = 0
            if x0 >= x_end or y0 >= y_end:
                continue
            live = 0
            for q in range(LANES):
                if x0 + q % SUB < x_end and y0 + q // SUB < y_end:
                    live |= 1 << q
            for c in range(C):
                for q in range(LANES):
                    acc[c, q] = 0.0
            off = base + blk * K
            if plain:  # the plain-numba twin (numba_plain), same bits
                composite_block_plain(pk, bl_ids, off, nsub[blk], x0, y0, live, T, asum, wl, gl, bl_mask, res)
            else:
                composite_block(pk, bl_ids, off, nsub[blk], x0, y0, live, T, asum, wl, gl, bl_mask, res)
            last = res[0]
            nu = res[1]
            bl_n[t * nb + blk] = last
            for k in range(nu):
                gl[k] = entries[start + gl[k]]
            lanes_times_rows(acc, wl, gl, nu, chans)
            for q in range(LANES):
                px = x0 + q % SUB
                py = y0 + q // SUB
                if px < x_end and py < y_end:
                    pix = py * width + px
                    for c in range(C):
                        out[pix, c] = acc[c, q]
                    t_final[pix] = T[q]
                    alpha[pix] = asum[q]


@njit(cache=True)
def backward_walk(pk, ids, masks, sl, el, nu, x0, y0, T, tf, ga, fgl, wl, buf_geo):
    """``backward_block`` compiled on its own, without the backward's fast-math flags (numba
    puts a function's flags on every float instruction in it, the IR's included): the walk's
    arithmetic is then exactly what its IR says, and its plain twin can reproduce it."""
    backward_block(pk, ids, masks, sl, el, nu, x0, y0, T, tf, ga, fgl, wl, buf_geo)


@njit(parallel=True, cache=True, fastmath={"reassoc", "contract", "arcp", "nsz"})
def backward(
    means2d, conics, opac, chans, tile_off, entries, width, height, ts, gx, gy,
    t_final, bl_ids, bl_mask, bl_n, g_out, g_alpha, buf_geo, buf_chan, plain=False,
):
    """Back to front over each block's saved list, the block's pixels in lock-step as in
    ``forward``; the saved lane masks say which pixels used each gaussian, so the backward
    never re-decides a threshold (fastmath here cannot flip one). g_out [H*W, C],
    g_alpha [H*W] (alpha = 1 - T_final). Writes per entry (rows of the tile zeroed first):
    buf_geo [E, 6] (d mean_u, d mean_v, d conic a, b, c, d opacity), buf_chan [E, CP] (CP = C
    rounded up to a multiple of 16; columns past C are scratch)."""
    C = chans.shape[1]
    nbx = (ts + SUB - 1) // SUB
    nb = nbx * nbx
    for t in prange(gx * gy):
        tx = t % gx
        ty = t // gx
        start = tile_off[t]
        end = tile_off[t + 1]
        K = end - start
        x_end = min((tx + 1) * ts, width)
        y_end = min((ty + 1) * ts, height)
        for e in range(start, end):
            for k in range(6):
                buf_geo[e, k] = 0.0
            for c in range(buf_chan.shape[1]):
                buf_chan[e, c] = 0.0
        pk = _pack_tile(start, end, entries, means2d, conics, opac)
        base = nb * start
        T = np.empty(LANES, np.float32)
        tf = np.empty(LANES, np.float32)
        ga = np.empty(LANES, np.float32)
        gT = np.empty((C, LANES), np.float32)  # the block's output gradients, channel-major
        CP = buf_chan.shape[1]  # >= C, a multiple of 16 (lanes_dot_rows)
        gL = np.zeros((LANES, CP), np.float32)  # the same, lane-major, zero past C
        kk = max(K, 1)
        sl = np.empty(kk, np.int64)  # the block's used list slots, back to front
        el = np.empty(kk, np.int64)  # their entries
        gl = np.empty(kk, np.int64)  # their gaussians
        fgl = np.empty((kk, LANES), np.float32)  # chans[g] . g_out[pixel] per used gaussian and lane
        wl = np.empty((kk, LANES), np.float32)  # their weights w = alpha T per lane
        for blk in range(nb):
            jn = bl_n[t * nb + blk]
            if jn == 0:
                continue
            x0 = tx * ts + (blk % nbx) * SUB
            y0 = ty * ts + (blk // nbx) * SUB
            for q in range(LANES):
                px = x0 + q % SUB
                py = y0 + q // SUB
                if px < x_end and py < y_end:
                    pix = py * width + px
                    T[q] = t_final[pix]
                    ga[q] = g_alpha[pix]
                    for c in range(C):
                        gL[q, c] = g_out[pix, c]
                else:
                    T[q] = 1.0
                    ga[q] = 0.0
                    for c in range(C):
                        gL[q, c] = 0.0
                tf[q] = T[q]
            for c in range(C):
                for q in range(LANES):
                    gT[c, q] = gL[q, c]
            off = base + blk * K
            nu = 0
            for j in range(jn - 1, -1, -1):
                if bl_mask[off + j] != 0:
                    sl[nu] = off + j
                    el[nu] = start + bl_ids[off + j]
                    gl[nu] = entries[el[nu]]
                    nu += 1
            rows_dot_lanes(fgl, gl, nu, chans, gT)
            if plain:
                backward_block_plain(pk, bl_ids, bl_mask, sl, el, nu, x0, y0, T, tf, ga, fgl, wl, buf_geo)
            else:
                backward_walk(pk, bl_ids, bl_mask, sl, el, nu, x0, y0, T, tf, ga, fgl, wl, buf_geo)
            lanes_dot_rows(buf_chan, el, nu, wl, gL)  # d chans[g] += sum over lanes of w g_out


@njit(parallel=True, cache=True)
def reduce_grads(g_ptr, g_pos, buf_geo, buf_chan, grad_geo, grad_chan):
    """Sum per-entry gradients into per-gaussian grad_geo [N, 6] and grad_chan [N, CP] (CP =
    buf_chan's padded row length; written, not accumulated: they may be uninitialised)."""
    for g in prange(grad_geo.shape[0]):
        for k in range(6):
            grad_geo[g, k] = 0.0
        for j in range(g_ptr[g], g_ptr[g + 1]):
            e = g_pos[j]
            for k in range(6):
                grad_geo[g, k] += buf_geo[e, k]
        sum_rows(grad_chan, g, g_pos, g_ptr[g], g_ptr[g + 1], buf_chan)


@njit(inline="always")
def _replay(pix, width, ts, gx, means2d, conics, opac, tile_off, entries, min_weight, idx_out, w_out, base):
    """Run the forward rule at one pixel with the forward's float32 arithmetic (alpha32, the
    same transmittance updates), so weights and decisions match ``forward`` exactly; store
    (gaussian, weight) from ``base`` if idx_out has room (count pass passes empty arrays).
    -> number of stored contributors."""
    py = pix // width
    px = pix - py * width
    t = (py // ts) * gx + px // ts
    fx = F32(px) + F32(0.5)
    fy = F32(py) + F32(0.5)
    T = F32(1.0)
    k = 0
    store = idx_out.shape[0] > 0
    for e in range(tile_off[t], tile_off[t + 1]):
        g = entries[e]
        a = min(alpha32(fx, fy, means2d[g, 0], means2d[g, 1], conics[g, 0], conics[g, 1], conics[g, 2], opac[g]),
                A_MAX32)
        if a < A_MIN32:
            continue
        test_t = T * (F32(1.0) - a)
        if test_t < T_MIN32:
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
def pixel_weight_counts(pixels, width, ts, gx, means2d, conics, opac, tile_off, entries, min_weight, counts):
    empty_i = np.empty(0, np.int64)
    empty_w = np.empty(0, np.float32)
    for i in prange(pixels.shape[0]):
        counts[i] = _replay(pixels[i], width, ts, gx, means2d, conics, opac, tile_off, entries,
                            min_weight, empty_i, empty_w, 0)


@njit(parallel=True, cache=True)
def pixel_weight_fill(pixels, width, ts, gx, means2d, conics, opac, tile_off, entries, min_weight, indptr, idx_out, w_out):
    for i in prange(pixels.shape[0]):
        _replay(pixels[i], width, ts, gx, means2d, conics, opac, tile_off, entries,
                min_weight, idx_out, w_out, indptr[i])
