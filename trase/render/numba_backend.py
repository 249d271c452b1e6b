"""Numba CPU compositing as a torch.autograd.Function (forward and hand-written backward
kernels in numba_kernels.py). Inputs are composited in float32 and results cast back to the
caller's dtype. The numba backend projects with numba_projection.py; SH colour evaluation
stays in torch (sh.py), shared with the reference."""

from __future__ import annotations

import os
import threading

import numba
import numpy as np
import torch

from trase.render import numba_kernels as nk

# Tiles are handed to threads in small chunks, on demand: central tiles carry far more
# gaussians than border ones, and on a shared machine a descheduled thread would otherwise
# hold back the whole parallel loop with its fixed half of the tiles.
TILE_CHUNK = 2

# Which block walks the kernels run: "ir" (LLVM IR on 16-lane vectors, the default) or "plain"
# (their plain-numba twins in numba_plain: the same bits, slower; for a numba or LLVM on which
# the IR path does not build). Read once, from the environment.
WALKS = os.environ.get("TRASE_NUMBA_WALKS", "ir")
if WALKS not in ("ir", "plain"):
    raise ImportError(f"TRASE_NUMBA_WALKS={WALKS!r}: choose 'ir' or 'plain'")


SCRATCH_KEEP_MAX = 128 * 2**20  # bytes per buffer kept between calls (larger ones are not kept)


class _Scratch(threading.local):
    """Per-thread scratch buffers reused across backward calls (grown as needed; at most
    SCRATCH_KEEP_MAX bytes each are kept, two buffers).

    Why: the backward's per-entry gradient buffers are ~10 MB at 20k gaussians; fresh ones
    cost thousands of page faults per call (a few ms of kernel time, measured with getrusage).
    Only scratch that dies inside one call lives here, never anything returned or saved.
    Buffers above SCRATCH_KEEP_MAX are allocated per call instead (big scenes: the faults are
    then small next to the work, and the memory is not held)."""

    def __init__(self):
        self.bufs: dict[str, np.ndarray] = {}

    def get(self, name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
        n = int(np.prod(shape))
        buf = self.bufs.get(name)
        if buf is None or buf.dtype != dtype or buf.size < n:
            buf = np.empty(max(n, 1), dtype)
            if buf.nbytes <= SCRATCH_KEEP_MAX:
                self.bufs[name] = buf
            else:
                self.bufs.pop(name, None)  # too big to hold between calls: used once
        return buf[:n].reshape(shape)

    def nbytes(self) -> int:
        return sum(b.nbytes for b in self.bufs.values())


_SCRATCH = _Scratch()


def scratch_bytes() -> int:
    """Bytes of backward scratch this thread keeps between calls (see _Scratch)."""
    return _SCRATCH.nbytes()


def _np32(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to("cpu", torch.float32).numpy())


def saved_state_bytes(n_entries: int, n_tiles: int, n_pixels: int, tile_size: int) -> dict[str, int]:
    """Bytes the forward keeps for the backward beyond the projected inputs and the binning:
    per block-list slot (nb * E slots, allocated with np.empty so only the slots a block's list
    reaches are touched) an int32 id and a uint16 lane mask, a per-block length, and the final
    transmittance per pixel. Bounded by 6 * nb * E + 4 * nb * T + 4 * P (nb = 16 for 16 px tiles)."""
    nb = nk.blocks_per_tile(tile_size)
    return {
        "block_lists": 4 * nb * n_entries,
        "block_masks": 2 * nb * n_entries,
        "block_lengths": 4 * nb * n_tiles,
        "t_final": 4 * n_pixels,
    }


LAST_SAVED: dict[str, int] = {}  # saved_state_bytes of the latest forward (read by perf raster)


class _Composite(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opac, chans, depths, rects, width, height, ts):
        gx = (width + ts - 1) // ts
        gy = (height + ts - 1) // ts
        m2, co, op, ch = _np32(means2d), _np32(conics), _np32(opac), _np32(chans)
        tile_off, entries, g_ptr, g_pos = nk.bin_gaussians(
            np.ascontiguousarray(rects.numpy()), depths.detach().to(torch.float64).numpy(), gx, gy
        )
        C = ch.shape[1]
        E = entries.shape[0]
        nb = nk.blocks_per_tile(ts)
        # every pixel lies in a tile's block, so the forward writes all of these
        out = np.empty((height * width, C), np.float32)
        t_final = np.empty(height * width, np.float32)
        alpha = np.empty(height * width, np.float32)
        radii = np.empty((co.shape[0], 2), np.float64)
        bl_ids = np.empty(nb * E, np.int32)
        bl_mask = np.empty(nb * E, np.uint16)
        bl_n = np.empty(nb * gx * gy, np.int32)
        nk.cull_radii(co, op, radii)  # outside the tile chunking: 2-gaussian chunks cost ~1 ms
        with numba.parallel_chunksize(TILE_CHUNK):
            nk.forward(m2, co, op, radii, ch, tile_off, entries, width, height, ts, gx, gy, out, alpha, t_final,
                       bl_ids, bl_mask, bl_n, WALKS == "plain")
        LAST_SAVED.clear()
        LAST_SAVED.update(saved_state_bytes(E, gx * gy, height * width, ts))
        ctx.state = (m2, co, op, ch, tile_off, entries, g_ptr, g_pos, t_final, bl_ids, bl_mask, bl_n,
                     width, height, ts, gx, gy)
        ctx.dtype = chans.dtype
        dt = chans.dtype
        return (
            torch.from_numpy(out).reshape(height, width, C).to(dt),
            torch.from_numpy(alpha).reshape(height, width).to(dt),
        )

    @staticmethod
    def backward(ctx, g_out, g_alpha):
        (m2, co, op, ch, tile_off, entries, g_ptr, g_pos, t_final, bl_ids, bl_mask, bl_n,
         width, height, ts, gx, gy) = ctx.state
        n, C = ch.shape
        E = entries.shape[0]
        go = np.ascontiguousarray(g_out.detach().to(torch.float32).reshape(height * width, C).numpy())
        ga = np.ascontiguousarray(g_alpha.detach().to(torch.float32).reshape(height * width).numpy())
        # every row is zeroed by its tile in the kernel
        buf_geo = _SCRATCH.get("buf_geo", (E, 6), np.float64)
        cp = -(-C // nk.LANES) * nk.LANES  # channels padded to whole 16-lane vectors
        buf_chan = _SCRATCH.get("buf_chan", (E, cp), np.float32)
        with numba.parallel_chunksize(TILE_CHUNK):
            nk.backward(m2, co, op, ch, tile_off, entries, width, height, ts, gx, gy,
                        t_final, bl_ids, bl_mask, bl_n, go, ga, buf_geo, buf_chan, WALKS == "plain")
        grad_geo = np.empty((n, 6), np.float64)
        grad_chan = np.empty((n, cp), np.float32)  # padded like buf_chan; sliced to C below
        nk.reduce_grads(g_ptr, g_pos, buf_geo, buf_chan, grad_geo, grad_chan)
        dt = ctx.dtype
        gg = torch.from_numpy(grad_geo).to(dt)
        return gg[:, 0:2], gg[:, 2:5], gg[:, 5], torch.from_numpy(grad_chan)[:, :C].to(dt), None, None, None, None, None


def composite_numba(means2d, conics, opac, chans, depths, rects, width, height, tile_size):
    """Same contract as torch_backend.composite_torch: -> (out [H, W, C], alpha [H, W])."""
    return _Composite.apply(means2d, conics, opac, chans, depths, rects, int(width), int(height), int(tile_size))


def pixel_weights_numba(means2d, conics, opac, depths, rects, width, height, tile_size, pixels, min_weight):
    """-> (indptr [P+1], indices [nnz], weights [nnz] float32) torch CPU tensors."""
    ts = int(tile_size)
    gx = (width + ts - 1) // ts
    gy = (height + ts - 1) // ts
    m2, co, op = _np32(means2d), _np32(conics), _np32(opac)
    tile_off, entries, _, _ = nk.bin_gaussians(
        np.ascontiguousarray(rects.numpy()), depths.detach().to(torch.float64).numpy(), gx, gy
    )
    pix = np.ascontiguousarray(pixels.numpy())
    counts = np.zeros(pix.shape[0], np.int64)
    nk.pixel_weight_counts(pix, width, ts, gx, m2, co, op, tile_off, entries, min_weight, counts)
    indptr = np.zeros(pix.shape[0] + 1, np.int64)
    np.cumsum(counts, out=indptr[1:])
    idx = np.empty(indptr[-1], np.int64)
    w = np.empty(indptr[-1], np.float32)
    nk.pixel_weight_fill(pix, width, ts, gx, m2, co, op, tile_off, entries, min_weight, indptr, idx, w)
    return torch.from_numpy(indptr), torch.from_numpy(idx), torch.from_numpy(w)
