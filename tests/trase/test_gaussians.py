import math

import numpy as np
import pytest
import torch

from trase.gaussians import GaussianFileError, GaussianModel, rgb_to_sh_dc


def random_model(n=20, deg=3, feat=0, seed=0):
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.randn(*s, generator=g)
    return GaussianModel(r(n, 3), r(n, 3) * 0.3 - 2, r(n, 4), r(n), r(n, (deg + 1) ** 2, 3),
                         r(n, feat) if feat else None)


def test_from_points_matches_3dgs_init():
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3], [5, 5, 5]])
    cols = np.array([[1.0, 0, 0.5]] * 5)
    g = GaussianModel.from_points(pts, cols, sh_degree=2)
    # point 0: neighbours at distance 1, 2, 3 -> sqrt(mean(1, 4, 9))
    assert math.isclose(float(g.scales[0, 0].detach()), math.sqrt(14 / 3), rel_tol=1e-5)
    assert torch.allclose(g.opacities, torch.full((5,), 0.1))
    assert torch.equal(g.quats, torch.tensor([[1.0, 0, 0, 0]] * 5))
    assert g.sh.shape == (5, 9, 3) and g.max_sh_degree == 2 and g.active_sh_degree == 0
    assert torch.allclose(g.colors_dc, torch.as_tensor(cols, dtype=torch.float32), atol=1e-6)
    assert torch.equal(g.sh_rest, torch.zeros(5, 8, 3))
    # duplicate points: scales stay finite
    g2 = GaussianModel.from_points(np.zeros((4, 3)))
    assert torch.isfinite(g2.log_scales).all()
    with pytest.raises(ValueError):
        GaussianModel.from_points(np.zeros((0, 3)))


def test_rotations_normalised_and_zero_quat_is_identity():
    g = random_model(4)
    with torch.no_grad():
        g.quats[0] = 0
    r = g.rotations
    assert torch.allclose(r.norm(dim=1), torch.ones(4))
    assert torch.equal(r[0], torch.tensor([1.0, 0, 0, 0]))


@pytest.mark.parametrize("deg,feat", [(0, 0), (3, 0), (3, 32), (1, 5)])
def test_ply_round_trip(tmp_path, deg, feat):
    g = random_model(30, deg, feat)
    path = tmp_path / "pc" / "point_cloud.ply"
    g.save_ply(path)
    h = GaussianModel.load_ply(path)
    for name in ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest"):
        assert torch.equal(getattr(g, name), getattr(h, name)), name
    if feat:
        assert torch.equal(g.features, h.features)
    else:
        assert h.features is None
    assert h.max_sh_degree == deg


def test_ply_attribute_order_is_3dgs(tmp_path):
    from plyfile import PlyData

    g = random_model(3, 1, 2)
    g.save_ply(tmp_path / "a.ply")
    names = [p.name for p in PlyData.read(str(tmp_path / "a.ply"))["vertex"].properties]
    assert names == (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
                     + [f"f_rest_{i}" for i in range(9)]
                     + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
                        "gaussian_feats_0", "gaussian_feats_1"])
    # f_rest is channel-major: f_rest_0..2 are the red coefficients of bands 1..3
    v = PlyData.read(str(tmp_path / "a.ply"))["vertex"]
    assert np.allclose(v["f_rest_1"], g.sh_rest[:, 1, 0].detach().numpy())
    assert np.allclose(v["f_rest_3"], g.sh_rest[:, 0, 1].detach().numpy())


def test_corrupt_ply_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nend_header\n\x00")
    with pytest.raises(GaussianFileError, match="bad.ply"):
        GaussianModel.load_ply(bad)
    with pytest.raises(GaussianFileError, match="not found"):
        GaussianModel.load_ply(tmp_path / "missing.ply")
    junk = tmp_path / "junk.ply"
    junk.write_bytes(b"\x89PNG garbage")
    with pytest.raises(GaussianFileError, match="junk.ply"):
        GaussianModel.load_ply(junk)
    assert GaussianFileError.user_facing


def _adam(g):
    opt = torch.optim.Adam([{"params": [p], "name": n} for n, p in g.param_tensors().items()], lr=0.01)
    loss = sum((p * (i + 1)).sum() ** 2 for i, p in enumerate(g.param_tensors().values()))
    loss.backward()
    opt.step()
    return opt


def test_prune_clone_split_keep_adam_state_consistent():
    g = random_model(10, 1, 4)
    opt = _adam(g)
    before = {n: opt.state[p]["exp_avg"].clone() for n, p in g.param_tensors().items()}
    keep = torch.tensor([True, False] * 5)
    g.prune(keep, opt)
    assert g.num_gaussians == 5
    for n, p in g.param_tensors().items():
        assert opt.state[p]["exp_avg"].shape == p.shape
        assert torch.equal(opt.state[p]["exp_avg"], before[n][keep])
        assert any(p is q for grp in opt.param_groups for q in grp["params"])
    clone = torch.tensor([True, False, False, True, False])
    means = g.means.detach().clone()
    g.clone_gaussians(clone, opt)
    assert g.num_gaussians == 7
    assert torch.equal(g.means[5:], means[clone])
    assert torch.equal(opt.state[g.means]["exp_avg"][5:], torch.zeros(2, 3))
    split = torch.zeros(7, dtype=torch.bool)
    split[0] = True
    s0 = g.scales[0].detach().clone()
    g.split_gaussians(split, opt, generator=torch.Generator().manual_seed(0))
    assert g.num_gaussians == 8
    assert torch.allclose(g.scales[-2:], (s0 / 1.6).expand(2, 3))
    for p in g.param_tensors().values():
        assert opt.state[p]["exp_avg_sq"].shape == p.shape
    # the optimizer still steps on the new tensors
    (g.means.sum() + g.features.sum()).backward()
    opt.step()


def test_reset_opacity_caps_and_zeroes_moments():
    g = random_model(6)
    opt = _adam(g)
    g.reset_opacity(opt)
    assert (g.opacities <= 0.01 + 1e-6).all()
    assert torch.equal(opt.state[g.opacity_logits]["exp_avg"], torch.zeros(6))
    assert opt.state[g.means]["exp_avg"].abs().sum() > 0


def test_rgb_sh_dc_inverse():
    assert np.allclose(rgb_to_sh_dc(np.array([0.5])), 0.0)
