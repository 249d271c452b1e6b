"""What the numba forward saves for its backward (per-block culled lists and lane masks)
against independent recomputation, and scenes that stress it: all gaussians in one tile,
mostly empty tiles, long opaque lists (the float32 back-to-front transmittance recovery)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from trase.render import numba_kernels as nk
from trase.render import pixel_weights, rasterize
from trase.render.numba_projection import project_gaussians_numba

from .scenes import camera, grads, loss_of, scene


def _saved_state(sc, cam, ts=16):
    """Run the numba forward kernel as the backend does; -> (binning, saved lists, masks, lengths)."""
    with torch.no_grad():
        proj = project_gaussians_numba(sc["means"], sc["quats"], sc["scales"], cam, tile_size=ts, dtype=torch.float32)
    m2 = proj.means2d.numpy().astype(np.float32)
    co = proj.conics.numpy().astype(np.float32)
    op = sc["opacities"].detach().numpy().astype(np.float32)
    ch = np.ones((len(op), 1), np.float32)
    gx, gy = -(-cam.width // ts), -(-cam.height // ts)
    tile_off, entries, _, _ = nk.bin_gaussians(proj.rects.numpy(), proj.depths.double().numpy(), gx, gy)
    nb, E, P = nk.blocks_per_tile(ts), len(entries), cam.width * cam.height
    radii = np.empty((len(op), 2))
    nk.cull_radii(co, op, radii)
    bl_ids, bl_mask, bl_n = np.empty(nb * E, np.int32), np.empty(nb * E, np.uint16), np.empty(nb * gx * gy, np.int32)
    out, alpha, tf = np.empty((P, 1), np.float32), np.empty(P, np.float32), np.empty(P, np.float32)
    nk.forward(m2, co, op, radii, ch, tile_off, entries, cam.width, cam.height, ts, gx, gy, out, alpha, tf,
               bl_ids, bl_mask, bl_n)
    return gx, gy, tile_off, entries, bl_ids, bl_mask, bl_n, m2, co, op


@pytest.mark.parametrize("ts", [16, 8])
def test_saved_masks_list_exactly_the_per_pixel_contributors(ts):
    """Per pixel, the gaussians whose saved lane bit is set, in list order, are exactly the
    contributors pixel_weights replays one pixel at a time (a separate code path)."""
    cam = camera(width=45, height=29)
    sc = scene(n=400, d=0, seed=11)
    gx, gy, tile_off, entries, bl_ids, bl_mask, bl_n, *_ = _saved_state(sc, cam, ts)
    pw = pixel_weights(sc["means"], sc["quats"], sc["scales"], sc["opacities"], cam, tile_size=ts)
    nbx = -(-ts // nk.SUB)
    nb = nbx * nbx
    checked = 0
    for t in range(gx * gy):
        K = tile_off[t + 1] - tile_off[t]
        for b in range(nb):
            x0 = (t % gx) * ts + (b % nbx) * nk.SUB
            y0 = (t // gx) * ts + (b // nbx) * nk.SUB
            off = nb * tile_off[t] + b * K
            n = bl_n[t * nb + b]
            for q in range(nk.LANES):
                px, py = x0 + q % nk.SUB, y0 + q // nk.SUB
                if px >= min((t % gx + 1) * ts, cam.width) or py >= min((t // gx + 1) * ts, cam.height):
                    continue
                used = [entries[tile_off[t] + bl_ids[off + j]] for j in range(n) if (bl_mask[off + j] >> q) & 1]
                r = py * cam.width + px
                assert used == pw.indices[pw.indptr[r]: pw.indptr[r + 1]].tolist(), (px, py)
                checked += len(used)
    assert checked > 1000  # the scene actually covers pixels


def _agree(sc, cam, **kw):
    res = {}
    for backend in ("torch", "numba"):
        s = {k: (v.detach().clone().requires_grad_(True) if torch.is_tensor(v) else v) for k, v in sc.items()}
        out = rasterize(camera=cam, backend=backend, **s, **kw)
        loss_of(out).backward()
        res[backend] = (out, grads(s))
    (ot, gt), (on, gn) = res["torch"], res["numba"]
    for name in ("color", "features", "depth", "alpha"):
        assert torch.allclose(getattr(ot, name), getattr(on, name), atol=1e-4, rtol=0), name
    for name in gt:
        assert (gt[name] - gn[name]).abs().max() <= 1e-3 * gt[name].abs().max().clamp_min(1e-12), name
    return ot


def test_all_gaussians_in_one_tile():
    cam = camera(width=48, height=48)
    sc = scene(n=300, d=3, seed=12, spread=0.02, log_scale=-4.5)  # tiny cluster at the centre
    out = _agree(sc, cam)
    assert out.alpha.max() > 0.5 and (out.alpha > 1e-3).sum() < 16 * 16 * 2


def test_mostly_empty_tiles():
    cam = camera(width=80, height=64)
    sc = scene(n=60, d=2, seed=13, spread=0.05, log_scale=-3.0)
    sc["means"] = (sc["means"].detach() + torch.tensor([0.6, 0.0, 0.3])).requires_grad_(True)  # one corner
    out = _agree(sc, cam)
    assert (out.alpha == 0).float().mean() > 0.5


def test_long_opaque_lists_transmittance_recovery():
    """Hundreds of overlapping, fairly opaque gaussians per pixel: the backward's float32
    T_k = T_{k+1} / (1 - alpha_k) runs over long lists and must stay within tolerance."""
    cam = camera(width=32, height=32)
    sc = scene(n=600, d=2, seed=14, spread=0.3, log_scale=-1.0)
    with torch.no_grad():
        sc["opacities"].mul_(0.1)
    out = _agree(sc, cam)
    pw = pixel_weights(sc["means"], sc["quats"], sc["scales"], sc["opacities"], cam)
    assert pw.indptr.diff().max() > 300 and out.alpha.mean() > 0.8  # long lists, mostly opaque


def test_backward_scratch_is_reused_and_bounded(monkeypatch):
    from trase.render import numba_backend as nb

    s = nb._Scratch()
    a = s.get("x", (10, 4), np.float32)
    b = s.get("x", (3, 4), np.float32)  # smaller: same memory, right shape
    assert b.shape == (3, 4) and np.shares_memory(a, b)
    monkeypatch.setattr(nb, "SCRATCH_KEEP_MAX", 1000)
    big = s.get("x", (100, 4), np.float32)  # 1600 bytes: handed out, not kept
    assert big.shape == (100, 4) and s.nbytes() == 0
    # and a render + backward still agrees with the reference when nothing is kept
    _agree(scene(n=150, d=3, seed=15), camera())
