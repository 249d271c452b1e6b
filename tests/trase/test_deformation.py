import numpy as np
import pytest
import torch

from trase.deformation import (
    DeformMLP,
    TabulatedDeformation,
    deformed,
    infer_mlp_config,
    positional_encoding,
)
from trase.gaussians import GaussianModel


def test_positional_encoding_order_matches_nerf_embedder():
    x = torch.randn(7, 3)
    ref = [x]
    for k in range(10):
        ref += [torch.sin(x * 2.0**k), torch.cos(x * 2.0**k)]
    assert torch.equal(positional_encoding(x, 10), torch.cat(ref, -1))
    assert positional_encoding(x, 10).shape == (7, 63)


def test_paper_mlp_state_dict_names_and_shapes():
    net = DeformMLP.preset("paper")
    sd = net.state_dict()
    # Deformable-3DGS DeformNetwork(D=8, W=256), real-scene variant: xyz 63 + t 21 = 84 inputs
    assert sorted(k for k in sd if k.startswith("linear.")) == sorted(
        f"linear.{i}.{p}" for i in range(8) for p in ("weight", "bias")
    )
    assert sd["linear.0.weight"].shape == (256, 84)
    assert sd["linear.5.weight"].shape == (256, 256 + 84)  # skip concat after layer 4
    for i in (1, 2, 3, 4, 6, 7):
        assert sd[f"linear.{i}.weight"].shape == (256, 256)
    assert sd["gaussian_warp.weight"].shape == (3, 256)
    assert sd["gaussian_rotation.weight"].shape == (4, 256)
    assert sd["gaussian_scaling.weight"].shape == (3, 256)
    assert len(sd) == 16 + 6


def test_blender_variant_has_timenet():
    net = DeformMLP(blender=True)
    sd = net.state_dict()
    assert sd["timenet.0.weight"].shape == (256, 13)  # 6 time frequencies
    assert sd["timenet.2.weight"].shape == (30, 256)
    assert sd["linear.0.weight"].shape == (256, 63 + 30)
    assert infer_mlp_config(sd) == net.config()


@pytest.mark.parametrize("preset", ["paper", "small", "6x96"])
def test_forward_shapes_and_config_roundtrip(preset):
    torch.manual_seed(0)
    net = DeformMLP.preset(preset)
    x = torch.randn(11, 3)
    dx, dr, ds = net(x, 0.3)
    assert dx.shape == (11, 3) and dr.shape == (11, 4) and ds.shape == (11, 3)
    # per-gaussian times give the same result as a float, up to rounding (the float's path splits
    # two layers' products by columns): an absolute tolerance, as offsets near zero have no
    # relative precision
    dx2, _, _ = net(x, torch.full((11, 1), 0.3))
    assert torch.allclose(dx, dx2, rtol=1e-5, atol=1e-6)
    cfg = infer_mlp_config(net.state_dict())
    assert cfg == net.config()
    again = DeformMLP(**cfg)
    again.load_state_dict(net.state_dict())
    assert torch.equal(again(x, 0.3)[0], dx)


@pytest.mark.parametrize("blender", [False, True])
@pytest.mark.parametrize("t", [0.0, 0.37, torch.tensor(0.81), torch.tensor([0.5])])
def test_split_forward_matches_reference_values_and_gradients(blender, t):
    """The column-split forward (one time for all gaussians) equals the concatenated one."""
    torch.manual_seed(0)
    net = DeformMLP(D=4, W=32, blender=blender).double()
    x = torch.randn(50, 3, dtype=torch.float64) * 2

    def run(fn):
        net.zero_grad()
        outs = fn(x, t)
        sum(((o * torch.linspace(-1, 1, o.numel(), dtype=o.dtype).view_as(o)) ** 2).sum() for o in outs).backward()
        return [o.detach() for o in outs], [p.grad.clone() for p in net.parameters()]

    (o_ref, g_ref), (o_fast, g_fast) = run(net.forward_reference), run(net.forward)
    for a, b in zip(o_ref, o_fast):
        assert torch.allclose(a, b, rtol=1e-12, atol=1e-12)
    for a, b in zip(g_ref, g_fast):
        assert torch.allclose(a, b, rtol=1e-10, atol=1e-12)


def test_per_gaussian_times_use_the_reference_path():
    torch.manual_seed(1)
    net = DeformMLP(D=4, W=16)
    x = torch.randn(6, 3)
    t = torch.linspace(0, 1, 6).reshape(6, 1)
    for a, b in zip(net(x, t), net.forward_reference(x, t)):
        assert torch.equal(a, b)
    # and each row equals the network evaluated at that row's time alone
    for i in (0, 5):
        assert torch.allclose(net(x[i:i + 1], float(t[i]))[0], net(x, t)[0][i:i + 1], atol=1e-6)


def test_infer_config_rejects_other_dicts():
    with pytest.raises(ValueError):
        infer_mlp_config({"foo.weight": torch.zeros(1)})


def test_tabulated_exact_at_knots_and_linear_between():
    T, N = 4, 5
    times = np.array([0.0, 0.25, 0.5, 1.0])
    rng = np.random.default_rng(0)
    dx, dr, ds = rng.normal(size=(T, N, 3)), rng.normal(size=(T, N, 4)), rng.normal(size=(T, N, 3))
    tab = TabulatedDeformation(times, dx, dr, ds)
    xyz = torch.zeros(N, 3)
    for i, t in enumerate(times):
        a, b, c = tab(xyz, float(t))
        assert torch.equal(a, torch.as_tensor(dx[i], dtype=torch.float32))
        assert torch.equal(b, torch.as_tensor(dr[i], dtype=torch.float32))
        assert torch.equal(c, torch.as_tensor(ds[i], dtype=torch.float32))
    a, _, _ = tab(xyz, 0.75)  # halfway between 0.5 and 1.0
    assert torch.allclose(a, torch.as_tensor(0.5 * (dx[2] + dx[3]), dtype=torch.float32), atol=1e-6)
    # clamped outside the table
    assert torch.equal(tab(xyz, -1.0)[0], tab(xyz, 0.0)[0])
    assert torch.equal(tab(xyz, 2.0)[0], tab(xyz, 1.0)[0])


def test_tabulated_validates_shapes():
    with pytest.raises(ValueError):
        TabulatedDeformation([0.0, 1.0], np.zeros((2, 3, 3)), np.zeros((2, 3, 3)), np.zeros((2, 3, 3)))
    with pytest.raises(ValueError):
        TabulatedDeformation([1.0, 0.0], np.zeros((2, 3, 3)), np.zeros((2, 3, 4)), np.zeros((2, 3, 3)))


def test_deformed_semantics_and_scale_clamp():
    n = 3
    g = GaussianModel(torch.zeros(n, 3), torch.zeros(n, 3), torch.tensor([[2.0, 0, 0, 0]] * n),
                      torch.zeros(n), torch.zeros(n, 1, 3))
    dx = np.ones((1, n, 3))
    dr = np.full((1, n, 4), 0.5)
    ds = np.full((1, n, 3), -5.0)  # exp(0) - 5 < 0: must clamp, stay finite and positive
    tab = TabulatedDeformation([0.0], dx, dr, ds)
    m, q, s = deformed(g, tab, 0.0)
    assert torch.allclose(m, torch.ones(n, 3))
    assert torch.allclose(q, torch.tensor([[1.5, 0.5, 0.5, 0.5]] * n))  # normalize(q) + d_rot
    assert (s > 0).all() and torch.isfinite(s).all()
    _, _, s0 = deformed(g, None, 0.0)
    assert torch.allclose(s0, torch.ones(n, 3))


def test_a_preset_is_a_name_or_depth_x_width_and_a_bad_one_fails_when_the_config_is_made():
    from trase.reconstruction_config import ReconstructionConfig

    assert (DeformMLP.preset("6x96").D, DeformMLP.preset("6x96").W) == (6, 96)
    assert (DeformMLP.preset("paper").D, DeformMLP.preset("paper").W) == (8, 256)
    for bad in ("big", "1x64", "8x", "8x0"):
        with pytest.raises(ValueError, match="unknown deformation preset"):
            ReconstructionConfig(deform_preset=bad)


def test_scale_rules_mirror_keeps_the_public_covariance_and_its_gradient():
    from trase.deformation import MIN_SCALE, offset_scales

    s = torch.tensor([[0.2, 0.3, 0.4]])
    d = torch.tensor([[-0.5, 0.1, -0.4]], requires_grad=True)  # below zero, above, exactly zero
    mirror = offset_scales(s, d, "mirror")
    # the public code's rasterizer squares s + d (its covariance): |s + d| has the same square
    assert torch.allclose(mirror[0, :2] ** 2, (s + d.detach())[0, :2] ** 2)
    assert mirror[0, 2] == torch.tensor(MIN_SCALE)
    mirror.sum().backward()
    assert d.grad[0, 0] == -1.0 and d.grad[0, 1] == 1.0  # a negative sum is still pulled on
    d.grad = None
    clamp = offset_scales(s, d, "clamp")
    assert clamp[0, 0] == torch.tensor(MIN_SCALE) and torch.isclose(clamp[0, 1], torch.tensor(0.4))
    clamp.sum().backward()
    assert d.grad[0, 0] == 0.0  # floored: gone at this time, and no gradient brings it back
    with pytest.raises(ValueError, match="scale rule"):
        offset_scales(s, d, "relu")


def test_deformed_follows_the_networks_scale_rule():
    g = GaussianModel.from_points(np.zeros((4, 3), np.float32), None, sh_degree=0)
    net = DeformMLP.preset("small").zero_heads()
    with torch.no_grad():
        net.gaussian_scaling.bias.fill_(-10.0)  # every scale offset far below zero
    assert torch.allclose(deformed(g, net, 0.5)[2], (10.0 - g.scales).detach())
    net.scale_rule = "clamp"
    assert bool((deformed(g, net, 0.5)[2] == torch.tensor(1e-7)).all())


def test_concatenating_networks_of_two_scale_rules_is_refused():
    from trase.edit.ops import ConcatDeformation

    a, b = DeformMLP.preset("small"), DeformMLP.preset("small", scale_rule="clamp")
    assert ConcatDeformation([a, None], [2, 3]).scale_rule == "mirror"
    with pytest.raises(ValueError, match="different rules"):
        ConcatDeformation([a, b], [2, 3])
