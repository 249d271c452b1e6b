import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import numpy as np
import pytest
import torch
from recon_scene import write_scene

from imagefiles import ImageFileError
from trase.checkpoint import CheckpointError, available_iterations, load_model
from trase.deformation import DeformMLP
from trase.gaussians import GaussianModel
from trase.reconstruct import (
    ReconstructionConfig,
    evaluate_psnr,
    expon_lr,
    reconstruct,
)

CFG = ReconstructionConfig.cpu(
    iterations=40, warm_up=15, densify_from=10, densify_until=35, densify_interval=10,
    checkpoint_interval=20, time_noise_steps=40, position_lr_max_steps=40, deform_lr_max_steps=40,
)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("tiny")
    views, pts, _, _ = write_scene(root / "images", num=6, size=24)
    return views, pts


def test_training_improves_psnr_and_writes_public_layout(scene, tmp_path):
    views, pts = scene
    init = GaussianModel.from_points(pts, None, sh_degree=1)
    p0 = evaluate_psnr(init, None, views)
    g, d = reconstruct(views, pts, None, CFG, tmp_path / "m", progress=False)
    p1 = evaluate_psnr(g, d, views)
    assert p1 > p0 + 1.0, (p0, p1)
    assert available_iterations(tmp_path / "m") == [20, 40]
    g2, d2 = load_model(tmp_path / "m")
    assert torch.equal(g2.means, g.means) and isinstance(d2, DeformMLP)


def test_resume_continues_from_checkpoint(scene, tmp_path):
    views, pts = scene
    full_g, _ = reconstruct(views, pts, None, CFG, tmp_path / "full", progress=False)
    # stop after the first checkpoint, then resume to the end
    half = dataclasses.replace(CFG, iterations=20)
    reconstruct(views, pts, None, half, tmp_path / "split", progress=False)
    assert available_iterations(tmp_path / "split") == [20]
    g, _ = reconstruct(views, pts, None, CFG, tmp_path / "split", progress=False)
    assert available_iterations(tmp_path / "split") == [20, 40]
    state = torch.load(tmp_path / "split/trainer_state/iteration_40.pt", weights_only=True)
    assert state["iteration"] == 40
    # same seed, same schedule, same random draws: the resumed run lands where the full one does
    assert g.num_gaussians == full_g.num_gaussians
    assert torch.allclose(g.means, full_g.means, atol=1e-4)


def test_resume_without_trainer_state_is_an_error(scene, tmp_path):
    views, pts = scene
    half = dataclasses.replace(CFG, iterations=20)
    reconstruct(views, pts, None, half, tmp_path / "m", progress=False)
    sp = tmp_path / "m/trainer_state/iteration_20.pt"
    torch.save({"iteration": 20}, sp)
    with pytest.raises(CheckpointError, match="iteration_20.pt: trainer state lacks"):
        reconstruct(views, pts, None, CFG, tmp_path / "m", progress=False)
    sp.write_bytes(b"garbage")
    with pytest.raises(CheckpointError, match="iteration_20.pt: unreadable"):
        reconstruct(views, pts, None, CFG, tmp_path / "m", progress=False)
    sp.unlink()
    with pytest.raises(CheckpointError, match="iteration_20.pt"):
        reconstruct(views, pts, None, CFG, tmp_path / "m", progress=False)


def test_bad_image_is_a_one_line_error(scene, tmp_path):
    views, pts = scene
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not a png")
    views = [dataclasses.replace(views[0], image_path=bad)] + list(views[1:])
    with pytest.raises(ImageFileError, match="bad.png: cannot decode"):
        reconstruct(views, pts, None, CFG, tmp_path / "m", progress=False)


def test_presets_and_schedule():
    cfg = ReconstructionConfig.paper(warm_up=1500, densify_until=9000)
    assert (cfg.warm_up, cfg.densify_until) == (1500, 9000)
    assert cfg.deform_preset == "paper" and cfg.lambda_dssim == 0.2
    # the public TRASE code's defaults, not Deformable-3DGS's (0.0007, 0.001)
    assert (cfg.densify_grad_threshold, cfg.scaling_lr) == (0.0002, 0.005)
    with pytest.raises(TypeError):
        ReconstructionConfig.paper(no_such_setting=1)
    assert expon_lr(0, 1e-3, 1e-5, 100) == pytest.approx(1e-3)
    assert expon_lr(100, 1e-3, 1e-5, 100) == pytest.approx(1e-5)
    assert expon_lr(50, 1e-3, 1e-5, 100) == pytest.approx(1e-4)
    assert np.isfinite(expon_lr(10**9, 1e-3, 1e-5, 100))


def test_cpu_preset_keeps_the_long_lr_decay_for_any_run_length():
    from trase.reconstruct import CPU_CHANGES

    v1 = ReconstructionConfig.cpu_v1()
    assert v1.iterations == 2000 and v1.densify_until == 1500 and v1.warm_up == 300 and v1.torch_threads == 1
    new = ReconstructionConfig.cpu()
    changed = {k for k, v in dataclasses.asdict(new).items() if v != getattr(v1, k)}
    assert changed == set(CPU_CHANGES)
    short = ReconstructionConfig.cpu(iterations=2000)
    # the runner's 2000 steps: learning rates still decay over 20000 steps (annealing inside a
    # short run cost 1.2-1.7 dB), the densification/warm-up points are not rescaled
    assert (short.position_lr_max_steps, short.deform_lr_max_steps) == (20_000, 20_000)
    assert (short.warm_up, short.densify_until, short.time_noise_steps) == (300, 1500, 2000)
    assert ReconstructionConfig.cpu(iterations=2000, position_lr_max_steps=2000).position_lr_max_steps == 2000


def test_screen_grad_norm_recovers_pixel_gradient():
    from trase.camera import Camera, intrinsics, look_at
    from trase.reconstruct import _screen_grad_norm

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
    got = _screen_grad_norm(mm.grad, m, cam)
    want = (w * torch.tensor([50.0, 40.0], dtype=torch.float64)).norm(dim=1).float()  # NDC units
    assert torch.allclose(got[:5], want[:5], rtol=1e-4)
    assert got[5] == 0


def _grads(g, deform, cam, visible_only):
    from trase.losses import l1_loss
    from trase.reconstruct import render_view

    for p in [g.means, *deform.parameters()]:
        p.grad = None
    target = torch.full((cam.height, cam.width, 3), 0.3)
    out, _ = render_view(g, deform, cam, torch.zeros(3), "numba", visible_only=visible_only)
    l1_loss(out.color, target).backward()
    return out.color.detach().clone(), g.means.grad.clone(), [p.grad.clone() for p in deform.parameters()]


def test_visible_only_deformation_gives_the_same_image_and_gradients():
    from recon_scene import make_cameras, make_gt

    from trase.camera import Camera
    from trase.reconstruct import in_view

    g, _ = make_gt(n=300)
    g.means.requires_grad_(True)
    # a third of the gaussians far to one side: outside the view
    with torch.no_grad():
        g.means[:100, 0] += 8.0
    torch.manual_seed(0)
    deform = DeformMLP(D=4, W=32)  # random heads: a real deformation, not the identity
    cam0 = make_cameras(1, 40)[0]
    cam = Camera(K=cam0.K, w2c=cam0.w2c, width=40, height=40, time=0.4, name="c")
    with torch.no_grad():
        from trase.deformation import deformed

        vis = in_view(*[x.detach() for x in deformed(g, deform, cam.time)], cam)
    assert 0 < int(vis.sum()) < g.num_gaussians  # the test covers both kinds of gaussian
    img_a, gm_a, gp_a = _grads(g, deform, cam, visible_only=False)
    rows = []
    hook = deform.register_forward_pre_hook(lambda m, args: rows.append((args[0].shape[0], torch.is_grad_enabled())))
    img_b, gm_b, gp_b = _grads(g, deform, cam, visible_only=True)
    hook.remove()
    # one pass without autograd over all, one with autograd over the visible rows only
    assert rows == [(g.num_gaussians, False), (int(vis.sum()), True)]
    assert torch.allclose(img_a, img_b, atol=1e-6)
    assert torch.allclose(gm_a, gm_b, atol=1e-7, rtol=1e-5)
    assert gm_b[~vis].abs().max() == 0  # invisible gaussians learn nothing either way
    for a, b in zip(gp_a, gp_b):
        assert torch.allclose(a, b, atol=1e-7, rtol=1e-4), (a - b).abs().max()
    assert any(float(a.abs().max()) > 0 for a in gp_a)  # the network does get gradients


def test_opacity_entropy_is_zero_at_binary_opacities_and_pushes_towards_them():
    from trase.reconstruct import opacity_entropy

    assert float(opacity_entropy(torch.tensor([0.0, 1.0, 1.0]))) == pytest.approx(0.0, abs=1e-4)
    assert float(opacity_entropy(torch.tensor([0.5]))) == pytest.approx(np.log(2), rel=1e-6)
    x = torch.tensor([-1.0, 0.5, 2.0], requires_grad=True)  # logits
    opacity_entropy(torch.sigmoid(x)).backward()
    # descent moves each logit away from 0: opacities towards the nearer of 0 and 1
    assert x.grad[0] > 0 and x.grad[1] < 0 and x.grad[2] < 0
    assert torch.isfinite(x.grad).all()


def test_opacity_entropy_setting_makes_opacities_more_binary(scene, tmp_path):
    views, pts = scene
    from trase.reconstruct import opacity_entropy

    plain, _ = reconstruct(views, pts, None, CFG, tmp_path / "plain", progress=False)
    solid_cfg = dataclasses.replace(CFG, opacity_entropy_weight=0.5, opacity_entropy_from=10)
    solid, _ = reconstruct(views, pts, None, solid_cfg, tmp_path / "solid", progress=False)
    assert float(opacity_entropy(solid.opacities.detach())) < float(opacity_entropy(plain.opacities.detach()))


def _densify_points_under_cap(cap: int) -> tuple[GaussianModel, np.ndarray]:
    """200 gaussians, gradients rising with the row (row 0 below the threshold), densified once
    under ``cap``."""
    from trase.reconstruct import _densify_and_prune, _make_optimizers

    pts = np.random.default_rng(0).uniform(-1, 1, (200, 3))
    g = GaussianModel.from_points(pts, None, sh_degree=0)
    cfg = ReconstructionConfig.cpu(max_gaussians=cap, min_opacity=0.0)
    opt, _ = _make_optimizers(g, DeformMLP.preset("small"), cfg)
    grads = torch.linspace(0.0, 1.0, 200)
    grads[0] = 0.0  # 199 candidates above the 0.0004 threshold
    _densify_and_prune(g, opt, cfg, grads, torch.ones(200), 1.0, False, torch.Generator().manual_seed(0))
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
    from trase.camera import Camera, intrinsics
    from trase.reconstruct import screen_grad_norm

    cam = Camera(K=intrinsics(50, 50, 50, 40), w2c=np.eye(4), width=100, height=80)
    g = torch.tensor([[1.0, 0.0], [0.0, 2.0], [3.0, 4.0], [float("nan"), 0.0]])
    assert screen_grad_norm(g, cam).tolist() == pytest.approx([50.0, 80.0, float(np.hypot(150, 160)), 0.0])


@pytest.mark.parametrize("statistic", ["means2d", "lstsq"])
def test_both_densification_statistics_densify(scene, tmp_path, statistic):
    """The render's own projection drives densification (no second projection): with either
    statistic the run densifies and trains."""
    views, pts = scene
    cfg = dataclasses.replace(CFG, densify_statistic=statistic, densify_grad_threshold=1e-6)
    g, d = reconstruct(views, pts, None, cfg, tmp_path / statistic, progress=False)
    assert g.num_gaussians > len(pts)
    assert np.isfinite(evaluate_psnr(g, d, views))
    with pytest.raises(ValueError, match="densify_statistic must be one of means2d, lstsq"):
        dataclasses.replace(CFG, densify_statistic="screen")


def test_presets_name_their_densification_statistic():
    assert ReconstructionConfig.paper().densify_statistic == "means2d"  # 3DGS's statistic
    assert ReconstructionConfig.cpu().densify_statistic == "lstsq"  # what the cpu presets were tuned with
    assert ReconstructionConfig.cpu_v1().densify_statistic == "lstsq"
