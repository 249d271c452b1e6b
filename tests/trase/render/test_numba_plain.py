"""The plain-numba twins of the IR block walks (trase.render.numba_plain) against the IR path."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from numba import njit, types
from numba.extending import intrinsic

from trase.render import numba_backend, rasterize
from trase.render.numba_kernels import LANES, composite_block
from trase.render.numba_plain import composite_block_plain, fma32, hsum16

from .scenes import camera, loss_of, scene


@njit(cache=False)
def _ir_forward(pk, ids, off, n, x0, y0, live, T, asum, wl, gl, mask, res):
    composite_block(pk, ids, off, n, x0, y0, live, T, asum, wl, gl, mask, res)


def _block(seed, k=40):
    rng = np.random.default_rng(seed)
    pk = np.zeros((k, 6), np.float32)
    pk[:, 0:2] = rng.uniform(-1, 5, (k, 2))
    pk[:, 2] = rng.uniform(0.05, 0.8, k)
    pk[:, 3] = rng.uniform(-0.05, 0.05, k)
    pk[:, 4] = rng.uniform(0.05, 0.8, k)
    pk[:, 5] = rng.uniform(0.02, 1.0, k)  # up to 1: the 0.99 clamp is exercised
    return pk, rng.permutation(k).astype(np.int32)


@pytest.mark.parametrize("live", [0xFFFF, 0x0F0F, 0x0001, 0x7777, 0])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_forward_walk_is_the_ir_walk_bit_for_bit(live, seed):
    pk, ids = _block(seed)
    outs = []
    for walk in (_ir_forward, composite_block_plain):
        T, asum = np.empty(LANES, np.float32), np.empty(LANES, np.float32)
        wl, gl = np.full((len(ids), LANES), np.nan, np.float32), np.full(len(ids), -1, np.int64)
        mask, res = np.zeros(len(ids) + 3, np.uint16), np.zeros(2, np.int64)
        walk(pk, ids, 3, len(ids) - 3, 8, 4, live, T, asum, wl, gl, mask, res)
        nu = res[1]
        outs.append((T, asum, wl[:nu], gl[:nu], mask, res))
    for a, b in zip(*outs):
        assert np.array_equal(a, b)
    if live:
        assert outs[0][5][1] > 0  # some gaussian was used


@pytest.mark.parametrize("shape", [(200, 0, 40, 32), (1500, 1, 57, 45)])
def test_renders_and_gradients_with_the_plain_walks(shape, monkeypatch):
    """Whole renders: the forward's outputs identical, the gradients within float32 rounding."""
    n, seed, w, h = shape
    results = []
    for walks in ("ir", "plain"):
        monkeypatch.setattr(numba_backend, "WALKS", walks)
        sc = scene(n=n, seed=seed, spread=0.8, log_scale=-2.0)
        out = rasterize(camera=camera(width=w, height=h), backend="numba", **sc)
        loss_of(out).backward()
        results.append(([out.color, out.features, out.depth, out.alpha],
                        [sc[k].grad for k in ("means", "quats", "scales", "opacities", "colors", "features")]))
    (img_ir, g_ir), (img_plain, g_plain) = results
    for a, b in zip(img_ir, img_plain):
        assert torch.equal(a, b)
    for a, b in zip(g_ir, g_plain):
        assert torch.isfinite(b).all()
        assert float((a - b).abs().max()) <= 1e-5 * float(a.abs().max()) + 1e-12


def test_fma32_rounds_once_and_hsum16_is_a_tree():
    rng = np.random.default_rng(3)
    a, b, c = (rng.standard_normal(2000).astype(np.float32) for _ in range(3))
    exact = [float(np.float32(np.longdouble(x) * np.longdouble(y) + np.longdouble(z))) for x, y, z in zip(a, b, c)]
    got = [float(fma32(x, y, z)) for x, y, z in zip(a, b, c)]
    from trase.render.numba_plain import FUSED

    if FUSED:
        # long double carries 64 bits: a * b + c rounded once, then to float32 (a double rounding
        # only at ties, which random inputs do not hit)
        assert got == exact
    rng = np.random.default_rng(4)
    for _ in range(50):  # magnitudes spread over 1e-6..1e6: the order of the additions shows
        v = (rng.standard_normal(16) * 10.0 ** rng.uniform(-6, 6, 16)).astype(np.float32)
        assert hsum16(v) == _ir_hsum(v)


@intrinsic
def _hsum_ir(typingctx, v):
    """The IR walks' lane sum (numba_kernels._hsum) of a float32 [16] array."""
    from llvmlite import ir

    from trase.render.numba_kernels import _array, _hsum, _vload

    def codegen(context, builder, signature, args):
        ptr, _ = _array(context, builder, signature.args[0], args[0])
        return _hsum(builder, _vload(builder, ptr, ir.Constant(ir.IntType(64), 0)))

    return types.float32(v), codegen


@njit(cache=False)
def _ir_hsum(v):
    return _hsum_ir(v)


def test_walks_setting_is_checked():
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", "import trase.render.numba_backend"], capture_output=True, text=True, check=False,
                       env={"TRASE_NUMBA_WALKS": "fast", "PATH": ""})
    assert r.returncode != 0 and "TRASE_NUMBA_WALKS='fast': choose 'ir' or 'plain'" in r.stderr
