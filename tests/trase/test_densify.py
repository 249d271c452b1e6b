"""Densification: the screen-space gradient statistics, the capped densify-and-prune step, and
the strategy that runs them beside the training loop (state, both steps, the statistic switch)."""

import numpy as np
import pytest
import torch

from trase.camera import Camera, intrinsics, look_at
from trase.deformation import DeformMLP
from trase.densify import (
    DensifyStrategy,
    densify_and_prune,
    lstsq_screen_grad_norm,
    screen_grad_norm,
)
from trase.gaussians import GaussianModel
from trase.reconstruction_presets import reconstruction_preset


def test_screen_grad_norm_recovers_pixel_gradient():
    cam = Camera(K=intrinsics(100, 90, 50, 40), w2c=look_at(np.array([0.3, -3, 0.5]), np.zeros(3)), width=100, height=80)
    g = torch.Generator().manual_seed(0)
    m = torch.randn(6, 3, dtype=torch.float64, generator=g) * 0.5
    m[5] = torch.as_tensor(cam.center) + torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)  # behind the camera
    w = torch.randn(6, 2, dtype=torch.float64, generator=g)  # loss = sum w . uv  ->  dL/duv = w
    mm = m.clone().requires_grad_()
    R, t = torch.as_tensor(cam.w2c[:3, :3]), torch.as_tensor(cam.w2c[:3, 3])
    p = mm @ R.T + t
    uv = torch.stack([100 * p[:, 0] / p[:, 2] + 50, 90 * p[:, 1] / p[:, 2] + 40], 1)
    (uv * w).sum().backward()
    got = lstsq_screen_grad_norm(mm.grad, m, cam)
    want = (w * torch.tensor([50.0, 40.0], dtype=torch.float64)).norm(dim=1).float()  # NDC units
    assert torch.allclose(got[:5], want[:5], rtol=1e-4)
    assert got[5] == 0


def _densify_points_under_cap(cap: int) -> tuple[GaussianModel, np.ndarray]:
    """200 gaussians, gradients rising with the row (row 0 below the threshold), densified once
    under ``cap``."""
    from trase.trainer import make_optimizers

    pts = np.random.default_rng(0).uniform(-1, 1, (200, 3))
    g = GaussianModel.from_points(pts, None, sh_degree=0)
    cfg = reconstruction_preset("cpu", max_gaussians=cap, min_opacity=0.0)
    opt, _ = make_optimizers(g, DeformMLP.preset("small"), cfg)
    grads = torch.linspace(0.0, 1.0, 200)
    grads[0] = 0.0  # 199 candidates above the 0.0004 threshold
    densify_and_prune(g, opt, cfg, grads, torch.ones(200), 1.0, False, torch.Generator().manual_seed(0))
    return g, pts


def test_densification_never_exceeds_the_gaussian_cap_and_keeps_the_largest_gradients():
    # the cpu preset's 15k cap decides a step's cost; densification must respect it exactly
    g, pts = _densify_points_under_cap(230)
    assert g.num_gaussians == 230  # 30 room left: 30 of 199 candidates densified
    # these gaussians are larger than percent_dense x extent, so a densified one is split
    # (its row removed): the first 170 rows stay in place only if the 30 largest-gradient
    # gaussians (the last rows) were the ones chosen
    assert torch.equal(g.means[:170], torch.as_tensor(pts[:170], dtype=g.means.dtype))
    full, _ = _densify_points_under_cap(200)
    assert full.num_gaussians == 200  # at the cap: nothing added


def test_screen_grad_norm_is_ndc_units_of_the_pixel_gradient():
    cam = Camera(K=intrinsics(50, 50, 50, 40), w2c=np.eye(4), width=100, height=80)
    g = torch.tensor([[1.0, 0.0], [0.0, 2.0], [3.0, 4.0], [float("nan"), 0.0]])
    assert screen_grad_norm(g, cam).tolist() == pytest.approx([50.0, 80.0, float(np.hypot(150, 160)), 0.0])


# -- DensifyStrategy --------------------------------------------------------------------------
def _strategy(statistic: str, n: int = 40, extent: float = 1.0,
              **cfg_kw) -> tuple[GaussianModel, Camera, DensifyStrategy, object]:
    """n gaussians in front of a 40x30 camera, a strategy with fresh state and the optimizer."""
    from trase.trainer import make_optimizers

    pts = np.random.default_rng(0).uniform(-0.5, 0.5, (n, 3))
    g = GaussianModel.from_points(pts, None, sh_degree=0)
    cam = Camera(K=intrinsics(40, 40, 20, 15), w2c=look_at(np.array([0.3, -3, 0.5]), np.zeros(3)), width=40, height=30)
    cfg = reconstruction_preset("cpu", densify_statistic=statistic, **cfg_kw)
    opt, _ = make_optimizers(g, DeformMLP.preset("small"), cfg)
    s = DensifyStrategy(cfg, extent=extent)
    s.initialize_state(g.num_gaussians, "cpu")
    return g, cam, s, opt


def _loss_weights(n: int) -> torch.Tensor:
    """[N, 2] the stand-in loss's gradient with respect to the pixel centres."""
    return torch.linspace(-1e-3, 2e-3, 2 * n).reshape(n, 2)


def _stand_in_render(g: GaussianModel, cam: Camera):
    """A render's projection data without rasterizing: deformed means [N, 3] (a non-leaf, like
    the deformation's output), pixel centres [N, 2] in their graph, radii [N] with every third
    gaussian culled; the loss is a fixed weighting of the pixel centres."""
    from trase.render.types import RenderOutput

    means = g.means * 1.0  # [N, 3]
    R = torch.as_tensor(cam.w2c[:3, :3], dtype=torch.float32)
    t = torch.as_tensor(cam.w2c[:3, 3], dtype=torch.float32)
    p = means @ R.T + t  # [N, 3] camera space
    uv = torch.stack([cam.fx * p[:, 0] / p[:, 2] + 20, cam.fy * p[:, 1] / p[:, 2] + 15], 1)  # [N, 2]
    n = g.num_gaussians
    radii = torch.where(torch.arange(n) % 3 == 0, 0, 2).long()  # [N]
    out = RenderOutput(color=None, features=None, depth=torch.zeros(30, 40), alpha=torch.zeros(30, 40),
                       means2d=uv, radii=radii)
    return out, means, (uv * _loss_weights(n)).sum()


def _one_step(g, cam, s, opt, step):
    out, means, loss = _stand_in_render(g, cam)
    s.step_pre_backward(out, means)
    loss.backward()
    s.step_post_backward(step, g, opt, out, means, cam, torch.Generator().manual_seed(0))
    opt.zero_grad(set_to_none=True)
    return out, means


def test_strategy_initial_state_is_zero_per_gaussian():
    g, _, s, _ = _strategy("means2d")
    for t in (s.grad_accum, s.denom):
        assert t.shape == (g.num_gaussians,) and t.dtype == torch.float32 and not t.any()


def test_strategy_keeps_the_gradient_of_the_chosen_statistic_only():
    # the statistic switch: means2d reads the render's screen positions, lstsq the 3D means
    for statistic in ("means2d", "lstsq"):
        g, cam, s, _ = _strategy(statistic)
        out, means, _ = _stand_in_render(g, cam)
        s.step_pre_backward(out, means)
        chosen = out.means2d if statistic == "means2d" else means
        other = means if statistic == "means2d" else out.means2d
        assert s.screen_tensor(out, means) is chosen
        assert chosen.retains_grad and not other.retains_grad


def test_strategy_means2d_accumulates_the_screen_gradient_of_rendered_gaussians():
    g, cam, s, opt = _strategy("means2d")
    out, _ = _one_step(g, cam, s, opt, step=1)
    vis = out.radii > 0
    want = screen_grad_norm(out.means2d.grad, cam)
    assert torch.equal(s.grad_accum, torch.where(vis, want, torch.zeros_like(want)))
    assert torch.equal(s.denom, vis.float())


def test_strategy_lstsq_accumulates_the_recovered_gradient_of_gaussians_in_view():
    from trase.densify import in_view

    g, cam, s, opt = _strategy("lstsq")
    _, means = _one_step(g, cam, s, opt, step=1)
    mt = means.detach()
    vis = in_view(mt, g.rotations.detach(), g.scales.detach(), cam)  # not the render's radii
    assert 0 < int(vis.sum())
    want = lstsq_screen_grad_norm(means.grad, mt, cam)
    assert torch.equal(s.grad_accum, torch.where(vis, want, torch.zeros_like(want)))
    assert torch.equal(s.denom, vis.float())
    # the least-squares statistic recovers the pixel gradient the loss put on the centres
    pix = screen_grad_norm(_loss_weights(g.num_gaussians), cam)
    assert torch.allclose(s.grad_accum[vis], pix[vis], rtol=1e-3)


def test_strategy_without_a_gradient_counts_nothing():
    g, cam, s, opt = _strategy("means2d")
    out, means, _ = _stand_in_render(g, cam)
    s.step_pre_backward(out, means)
    s.step_post_backward(1, g, opt, out, means, cam, torch.Generator().manual_seed(0))  # no backward
    assert not s.grad_accum.any() and not s.denom.any()


def test_strategy_schedule_densifies_resets_opacity_and_stops():
    # extent 100: every gaussian is small (cloned, not split) and none too large to keep
    g, cam, s, opt = _strategy("means2d", extent=100.0, densify_from=2, densify_interval=2, densify_until=6,
                               densify_grad_threshold=1e-9, opacity_reset_interval=3, min_opacity=0.0,
                               max_gaussians=0)
    n0 = g.num_gaussians
    _one_step(g, cam, s, opt, step=2)  # not past densify_from: accumulate only
    assert g.num_gaussians == n0 and s.denom.max() == 1
    _one_step(g, cam, s, opt, step=3)  # opacity reset
    assert g.num_gaussians == n0 and float(g.opacities.detach().max()) <= 0.01 + 1e-6
    out, _ = _one_step(g, cam, s, opt, step=4)  # densify: every rendered gaussian, then fresh statistics
    assert g.num_gaussians == n0 + int((out.radii > 0).sum())
    assert s.grad_accum.shape == (g.num_gaussians,) and not s.grad_accum.any() and not s.denom.any()
    n1 = g.num_gaussians
    op = g.opacities.detach().clone()
    _one_step(g, cam, s, opt, step=6)  # from densify_until on: nothing (6 is also a reset step)
    assert g.num_gaussians == n1 and torch.equal(g.opacities, op) and not s.denom.any()


def test_strategy_state_round_trips_through_a_trainer_state_file(tmp_path):
    g, cam, s, opt = _strategy("lstsq")
    _one_step(g, cam, s, opt, step=1)
    _one_step(g, cam, s, opt, step=2)
    sd = s.state_dict()
    assert tuple(sd) == DensifyStrategy.STATE_KEYS == ("grad_accum", "denom")  # the file's keys
    torch.save({"iteration": 2, **sd}, tmp_path / "state.pt")
    back = torch.load(tmp_path / "state.pt", weights_only=True)
    fresh = DensifyStrategy(s.cfg, extent=1.0)
    fresh.load_state_dict(back, g.num_gaussians, "cpu")
    assert torch.equal(fresh.grad_accum, s.grad_accum) and torch.equal(fresh.denom, s.denom)
    assert fresh.denom.max() == 2
    with pytest.raises(ValueError, match=f"trainer state is for {g.num_gaussians} gaussians, the point cloud has 3"):
        fresh.load_state_dict(back, 3, "cpu")


def test_rows_carried_through_densification_follow_their_gaussians():
    """Clones and split children get their parent's row of a carried tensor (static flags),
    pruned gaussians lose theirs."""
    from trase.trainer import make_optimizers

    rng = np.random.default_rng(1)
    pts = rng.uniform(-1, 1, (60, 3))
    g = GaussianModel.from_points(pts, None, sh_degree=0)
    with torch.no_grad():
        g.log_scales[:30] = -8.0  # small: cloned; the others large: split
        g.opacity_logits[::7] = -20.0  # transparent: pruned
    cfg = reconstruction_preset("cpu", min_opacity=0.005)
    opt, _ = make_optimizers(g, DeformMLP.preset("small"), cfg)
    before_means, before_scales = g.means.detach().clone(), g.log_scales.detach().clone()
    grads = torch.zeros(60)
    grads[10:50] = 1.0  # candidates: 10..29 cloned, 30..49 split
    carry = {"id": torch.arange(60), "frozen": torch.arange(60).float()[:, None].repeat(1, 10)}
    out = densify_and_prune(g, opt, cfg, grads, torch.ones(60), 1.0, False, torch.Generator().manual_seed(0), carry)
    ids = out["id"]
    assert ids.shape[0] == g.num_gaussians and torch.equal(out["frozen"][:, 0].long(), ids)
    assert not bool(torch.isin(ids, torch.arange(0, 60, 7)).any())  # the pruned rows are gone
    for row, k in enumerate(ids.tolist()):
        if 30 <= k < 50:  # a split child: its parent's scale / 1.6, near its parent
            assert torch.allclose(g.log_scales[row], before_scales[k] - np.log(1.6), atol=1e-5)
        else:  # kept or cloned: unchanged
            assert torch.equal(g.means[row], before_means[k])
    counts = torch.bincount(ids, minlength=60)
    assert all(counts[k] == 2 for k in range(10, 50) if k % 7)  # two rows each: original + clone, or 2 children
