import numpy as np
import pytest
import torch

from trase.camera import Camera, intrinsics, look_at
from trase.deformation import TabulatedDeformation
from trase.fastpath import FastPathError, RasterizerPath, ViewWeights, render_rows
from trase.gaussians import GaussianModel


def _scene(n=200, seed=0):
    g = torch.Generator().manual_seed(seed)
    means = torch.rand(n, 3, generator=g) * 2 - 1
    log_s = torch.log(torch.rand(n, 3, generator=g) * 0.08 + 0.02)
    quats = torch.randn(n, 4, generator=g)
    logits = torch.randn(n, generator=g)
    sh = torch.rand(n, 1, 3, generator=g)
    gm = GaussianModel(means, log_s, quats, logits, sh)
    T = 3
    d_xyz = torch.randn(T, n, 3, generator=g) * 0.05
    deform = TabulatedDeformation(torch.linspace(0, 1, T), d_xyz, torch.zeros(T, n, 4), torch.zeros(T, n, 3))
    cam = Camera(intrinsics(40, 40, 24, 16), look_at([0, -4, 0.5], [0, 0, 0]), 48, 32, time=0.5, name="v/0")
    return gm, deform, cam


def test_fast_path_equals_rasterizer(tmp_path):
    gm, deform, cam = _scene()
    valid = np.zeros((cam.height, cam.width), bool)
    valid[4:28, 5:40] = True
    feats = torch.randn(gm.num_gaussians, 8, dtype=torch.float32)
    vw = ViewWeights(gm, deform, tmp_path)
    vw.register(0, cam.name, cam, valid)
    pix = torch.from_numpy(np.flatnonzero(valid.reshape(-1)))[::3]
    fast = vw.render(0, feats, pix)
    rp = RasterizerPath(gm, deform, backend="numba")
    rp.register(0, cam.name, cam, valid)
    ref = rp.render(0, feats, pix)
    assert ref.abs().max() > 0.1  # the view sees the gaussians
    assert (fast - ref).abs().max() <= 1e-5
    # cached on disk, reloaded identically with a fresh object; the file name is sanitised
    assert (tmp_path / "v_0.npz").is_file()
    vw2 = ViewWeights(gm, deform, tmp_path)
    vw2.register(0, cam.name, cam, valid)
    torch.testing.assert_close(vw2.render(0, feats, pix), fast, rtol=0, atol=0)
    assert vw2.hits["disk"] == 1 and vw2.hits["computed"] == 0
    assert vw.stats()["bytes_per_view_max"] > 0


def test_stale_cache_is_recomputed(tmp_path):
    gm, deform, cam = _scene()
    valid = np.ones((cam.height, cam.width), bool)
    vw = ViewWeights(gm, deform, tmp_path)
    vw.register(0, cam.name, cam, valid)
    vw.get(0)
    with torch.no_grad():
        gm.means += 0.1
    vw2 = ViewWeights(gm, deform, tmp_path)
    vw2.register(0, cam.name, cam, valid)
    vw2.get(0)
    assert vw2.hits["computed"] == 1


def test_gradient_matches_rasterizer(tmp_path):
    gm, deform, cam = _scene(n=60, seed=1)
    valid = np.ones((cam.height, cam.width), bool)
    pix = torch.arange(0, cam.width * cam.height, 7)
    grads = []
    for path in (ViewWeights(gm, deform, None), RasterizerPath(gm, deform, backend="numba")):
        path.register(0, cam.name, cam, valid)
        f = torch.randn(60, 4, generator=torch.Generator().manual_seed(0)).requires_grad_(True)
        (path.render(0, f, pix) ** 2).sum().backward()
        grads.append(f.grad)
    assert (grads[0] - grads[1]).abs().max() <= 1e-4


def test_memory_bound_evicts(tmp_path):
    gm, deform, cam = _scene()
    valid = np.ones((cam.height, cam.width), bool)
    vw = ViewWeights(gm, deform, tmp_path, max_bytes=1)
    for k in range(3):
        vw.register(k, f"v{k}", cam.with_time(k / 2), valid)
        vw.get(k)
    assert len(vw._ram) == 1
    vw.get(0)
    assert vw.hits["disk"] == 1


def test_reloads_within_a_run_do_not_deform_again(tmp_path, monkeypatch):
    from trase import fastpath

    gm, deform, cam = _scene()
    valid = np.ones((cam.height, cam.width), bool)
    vw = ViewWeights(gm, deform, tmp_path, max_bytes=1)  # RAM holds one view: others reload
    for k in range(2):
        vw.register(k, f"v{k}", cam.with_time(k / 2), valid)
    first = vw.get(0).weights.clone()
    vw.get(1)
    calls = []
    real = fastpath.frozen_geometry
    monkeypatch.setattr(fastpath, "frozen_geometry", lambda *a: calls.append(a) or real(*a))
    torch.testing.assert_close(vw.get(0).weights, first, rtol=0, atol=0)  # from disk
    assert vw.hits["disk"] == 1 and calls == []  # the fingerprint was known
    (tmp_path / "v1.npz").unlink()  # a file that vanished is computed again, geometry included
    vw.get(1)
    assert vw.hits["computed"] == 3 and len(calls) == 1


def test_outside_pixels_and_empty(tmp_path):
    gm, deform, cam = _scene()
    valid = np.zeros((cam.height, cam.width), bool)
    vw = ViewWeights(gm, deform, None)
    vw.register(0, "empty", cam, valid)
    out = vw.render(0, torch.randn(gm.num_gaussians, 3), torch.zeros(0, dtype=torch.long))
    assert out.shape == (0, 3)
    with pytest.raises(FastPathError, match="outside"):
        vw.render(0, torch.randn(gm.num_gaussians, 3), torch.tensor([5]))
    with pytest.raises(FastPathError, match="differs from camera"):
        vw.register(1, "bad", cam, np.ones((3, 3), bool))


def test_render_rows_rows_without_contributors():
    from trase.render import PixelWeights

    pw = PixelWeights(torch.tensor([0, 1, 2]), torch.tensor([0, 0, 2, 2]), torch.tensor([0, 1]), torch.tensor([0.5, 0.25]))
    f = torch.tensor([[1.0, 2.0], [4.0, 8.0]], requires_grad=True)
    out = render_rows(pw, torch.tensor([2, 1, 0, 1]), f)
    torch.testing.assert_close(out, torch.tensor([[0.0, 0.0], [1.5, 3.0], [0.0, 0.0], [1.5, 3.0]]))
    out.sum().backward()
    torch.testing.assert_close(f.grad, torch.tensor([[1.0, 1.0], [0.5, 0.5]]))


def _random_pw(n_rows, n_gauss, gen):
    from trase.render import PixelWeights

    lengths = torch.randint(0, 30, (n_rows,), generator=gen)
    lengths[::7] = 0  # rows without contributors
    indptr = torch.cat([torch.zeros(1, dtype=torch.long), torch.cumsum(lengths, 0)])
    nnz = int(indptr[-1])
    return PixelWeights(torch.arange(n_rows) * 3, indptr, torch.randint(0, n_gauss, (nnz,), generator=gen),
                        torch.rand(nnz, generator=gen))


@pytest.mark.parametrize("dtype,D,tol", [(torch.float32, 32, 1e-6), (torch.float64, 7, 1e-12), (torch.float32, 1, 1e-6)])
def test_render_rows_fused_matches_reference(dtype, D, tol):
    from trase.fastpath import render_rows_reference

    gen = torch.Generator().manual_seed(3)
    pw = _random_pw(500, 200, gen)
    rows = torch.randint(0, 500, (900,), generator=gen)  # repeated rows too
    f0 = torch.randn(200, D, generator=gen, dtype=dtype)
    gout = torch.randn(900, D, generator=gen, dtype=dtype)
    res = []
    for fn in (render_rows_reference, lambda p, r, f: render_rows(p, r, f, "fused")):
        f = f0.clone().requires_grad_(True)
        out = fn(pw, rows, f)
        out.backward(gout)
        res.append((out.detach(), f.grad))
    assert res[1][0].dtype == dtype
    torch.testing.assert_close(res[1][0], res[0][0], rtol=0, atol=tol * float(res[0][0].abs().max()))
    torch.testing.assert_close(res[1][1], res[0][1], rtol=0, atol=tol * float(res[0][1].abs().max()))


def test_render_rows_fused_threads_identical():
    gen = torch.Generator().manual_seed(4)
    pw = _random_pw(4000, 3000, gen)
    rows = torch.randint(0, 4000, (3000,), generator=gen)
    f0 = torch.randn(3000, 32, generator=gen)
    gout = torch.randn(3000, 32, generator=gen)
    old = torch.get_num_threads()
    res = []
    try:
        for nt in (1, 2):
            torch.set_num_threads(nt)
            f = f0.clone().requires_grad_(True)
            out = render_rows(pw, rows, f, "fused")
            out.backward(gout)
            res.append((out.detach(), f.grad))
    finally:
        torch.set_num_threads(old)
    assert torch.equal(res[0][0], res[1][0]) and torch.equal(res[0][1], res[1][1])
