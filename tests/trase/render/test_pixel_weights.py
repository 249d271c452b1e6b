"""pixel_weights (the frozen-geometry fast path) reproduces the rasterizer's features."""

import torch

from trase.render import pixel_weights, rasterize

from .scenes import camera, scene


def test_all_pixels_equal_rendered_features():
    cam = camera(width=41, height=30)
    sc = scene(n=300, d=6, seed=7)
    pw = pixel_weights(sc["means"], sc["quats"], sc["scales"], sc["opacities"], cam)
    assert pw.pixels.shape == (41 * 30,) and pw.indptr.shape == (41 * 30 + 1,)
    assert pw.indices.dtype == torch.int64 and pw.weights.dtype == torch.float32
    feats = sc["features"].detach()
    for backend in ("numba", "torch"):
        out = rasterize(camera=cam, backend=backend, **sc)
        assert (pw.render(feats) - out.features.reshape(-1, 6)).abs().max() <= 1e-5
        # the weights also sum to the rendered alpha
        row_sum = pw.render(torch.ones(300, 1))[:, 0]
        assert (row_sum - out.alpha.reshape(-1)).abs().max() <= 1e-5


def test_subset_of_pixels_in_given_order_and_min_weight():
    cam = camera(width=40, height=32)
    sc = scene(n=300, d=4, seed=8)
    out = rasterize(camera=cam, backend="numba", **sc)
    pix = torch.tensor([5 * 40 + 7, 0, 31 * 40 + 39, 16 * 40 + 20, 16 * 40 + 20])
    pw = pixel_weights(sc["means"], sc["quats"], sc["scales"], sc["opacities"], cam, pixels=pix)
    assert torch.equal(pw.pixels, pix)
    want = out.features.reshape(-1, 4)[pix]
    assert (pw.render(sc["features"].detach()) - want).abs().max() <= 1e-5
    pruned = pixel_weights(sc["means"], sc["quats"], sc["scales"], sc["opacities"], cam, pixels=pix, min_weight=0.05)
    assert pruned.weights.numel() < pw.weights.numel()
    assert (pruned.weights >= 0.05).all()


def test_rows_are_front_to_back_and_ids_in_range():
    cam = camera()
    sc = scene(n=200, d=0, seed=9)
    pw = pixel_weights(sc["means"], sc["quats"], sc["scales"], sc["opacities"], cam)
    assert pw.indices.min() >= 0 and pw.indices.max() < 200
    z = torch.as_tensor(cam.world_to_camera(sc["means"].detach().numpy())[:, 2])
    for r in range(0, len(pw.pixels), 97):
        ids = pw.indices[pw.indptr[r] : pw.indptr[r + 1]]
        assert (z[ids].diff() >= 0).all()
