"""The rasterizer on a GPU: the torch backend on CUDA against the CPU reference, and the
gsplat backend against the torch backend on CUDA (outputs and the gradient of every input).
Skipped without CUDA (and the gsplat comparison without gsplat): run them on a GPU machine.

gsplat's own kernels differ from the reference at the margins (alpha clamped at 0.999, not
0.99; a slightly larger screen extent), so its comparison bounds the mean and largest
differences and asks the gradients to point the same way, where the CPU backends agree to
1e-4; an adapter error (a convention of quaternions, cameras, channels or depth) fails them
by orders of magnitude."""

import pytest
import torch

from trase.render import rasterize

from .scenes import camera, grads, loss_of, scene

cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")

CASES = [
    ({"n": 300, "d": 5, "seed": 0}, camera()),
    ({"n": 200, "d": 3, "sh_degree": 3, "seed": 1}, camera(width=45, height=29, cx=12.3, cy=20.9)),
    ({"n": 400, "d": 0, "sh_degree": 1, "seed": 2, "log_scale": -1.5}, camera(width=33, height=40)),
    ({"n": 3000, "d": 32, "seed": 3}, camera(width=96, height=72, f=90.0)),
]
OUTPUTS = ("color", "features", "depth", "alpha")


def _run(backend, device, cam, **kw):
    sc = {k: (v.detach().to(device).requires_grad_(True) if torch.is_tensor(v) else v)
          for k, v in scene(**kw).items()}
    out = rasterize(camera=cam, backend=backend, **sc)
    out.means2d.retain_grad()
    loss_of(_cpu(out)).backward()
    # the screen-space gradient 3DGS densifies on, as the trainer reads it
    screen = {"screen means2d": out.means2d.grad.cpu()} if out.means2d.grad is not None else {}
    return _cpu(out), {k: v.cpu() for k, v in grads(sc).items()} | screen


def _cpu(out):
    import dataclasses

    return dataclasses.replace(out, **{k: (None if getattr(out, k) is None else getattr(out, k).cpu())
                                       for k in (*OUTPUTS, "means2d", "radii")})


@cuda
@pytest.mark.parametrize("kw, cam", CASES)
def test_torch_backend_on_cuda_matches_the_cpu_reference(kw, cam):
    out_c, g_c = _run("torch", "cpu", cam, **kw)
    out_g, g_g = _run("torch", "cuda", cam, **kw)
    assert out_c.alpha.max() > 0.5
    for name in OUTPUTS:
        a, b = getattr(out_c, name), getattr(out_g, name)
        assert (a is None) == (b is None), name
        if a is not None:
            diff = float((a - b).abs().max())
            assert diff <= 1e-4, (name, diff)
    assert set(g_c) == set(g_g)
    for name in g_c:
        ref = float(g_c[name].abs().max())
        diff = float((g_c[name] - g_g[name]).abs().max())
        assert ref > 0 and diff <= 1e-3 * ref, (name, diff, ref)


def _cosine(a, b):
    a, b = a.reshape(-1).double(), b.reshape(-1).double()
    return float(a @ b / (a.norm() * b.norm()).clamp_min(1e-30))


@cuda
@pytest.mark.parametrize("kw, cam", CASES)
def test_gsplat_matches_the_torch_backend_on_cuda(kw, cam):
    pytest.importorskip("gsplat")
    out_t, g_t = _run("torch", "cuda", cam, **kw)
    out_s, g_s = _run("gsplat", "cuda", cam, **kw)
    report = {}
    for name in OUTPUTS:
        a, b = getattr(out_t, name), getattr(out_s, name)
        assert (a is None) == (b is None), name
        if a is None:
            continue
        if name == "depth":  # expected depth is unstable where almost nothing is drawn
            keep = out_t.alpha > 0.2
            a, b = a[keep], b[keep]
        diff = (a - b).abs()
        scale = max(float(a.abs().max()), 1e-6)
        report[name] = (float(diff.mean()) / scale, float(diff.max()) / scale)
    for name in g_t:
        report[f"grad {name}"] = _cosine(g_t[name], g_s[name])
    print(report)  # the figures, for the record of a GPU run (pytest -s)
    for name in OUTPUTS:
        if name in report:
            mean, worst = report[name]
            assert mean <= 5e-3 and worst <= 0.1, (name, report)
    assert set(g_t) == set(g_s) and "screen means2d" in g_s, sorted(g_s)
    for name in g_t:
        assert report[f"grad {name}"] >= 0.98, (name, report)
    visible = (out_t.radii > 0) & (out_s.radii > 0)
    assert visible.sum() > 0.5 * (out_t.radii > 0).sum()
    assert torch.allclose(out_t.means2d[visible], out_s.means2d[visible].to(out_t.means2d.dtype), atol=1e-3)
