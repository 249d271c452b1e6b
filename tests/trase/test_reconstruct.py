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
from trase.reconstruct import reconstruct
from trase.reconstruction_presets import reconstruction_preset
from trase.render_views import evaluate_psnr

CFG = reconstruction_preset(
    "cpu", iterations=40, warm_up=15, densify_from=10, densify_until=35, densify_interval=10,
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


@pytest.mark.parametrize("statistic", ["lstsq", "means2d"])
def test_resume_between_densifications_continues_the_statistics_exactly(scene, tmp_path, statistic):
    """A checkpoint at 25 (densified at 20, next at 30) holds the densification statistics of
    iterations 21-25; the resumed run carries them on and lands on the full run's bits."""
    views, pts = scene
    cfg = dataclasses.replace(CFG, densify_statistic=statistic)
    full_g, _ = reconstruct(views, pts, None, cfg, tmp_path / "full", progress=False)
    reconstruct(views, pts, None, dataclasses.replace(cfg, iterations=25), tmp_path / "split", progress=False)
    state = torch.load(tmp_path / "split/trainer_state/iteration_25.pt", weights_only=True)
    assert state["denom"].max() == 5 and state["grad_accum"].any()
    g, _ = reconstruct(views, pts, None, cfg, tmp_path / "split", progress=False)
    assert torch.equal(g.means, full_g.means) and torch.equal(g.opacity_logits, full_g.opacity_logits)
    a, b = (torch.load(p / "trainer_state/iteration_40.pt", weights_only=True) for p in (tmp_path / "split", tmp_path / "full"))
    assert torch.equal(a["grad_accum"], b["grad_accum"]) and torch.equal(a["denom"], b["denom"])


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


def _grads(g, deform, cam, visible_only):
    from trase.losses import l1_loss
    from trase.render_views import render_view

    for p in [g.means, *deform.parameters()]:
        p.grad = None
    target = torch.full((cam.height, cam.width, 3), 0.3)
    out, _ = render_view(g, deform, cam, torch.zeros(3), "numba", visible_only=visible_only)
    l1_loss(out.color, target).backward()
    return out.color.detach().clone(), g.means.grad.clone(), [p.grad.clone() for p in deform.parameters()]


def test_visible_only_deformation_gives_the_same_image_and_gradients():
    from recon_scene import make_cameras, make_gt

    from trase.camera import Camera
    from trase.densify import in_view

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


def test_the_near_plane_leaves_gaussians_nearer_than_it_undrawn_and_without_gradient():
    from trase.camera import Camera
    from trase.render_views import render_view

    # two gaussians on the optical axis: one 0.1 in front of the camera, one 2 units away
    g = GaussianModel.from_points(np.array([[0.0, 0.0, 0.1], [0.3, 0.0, 2.0]]), None, sh_degree=0)
    with torch.no_grad():
        g.log_scales.fill_(np.log(0.05))
        g.opacity_logits.fill_(4.0)
    g.means.requires_grad_(True)
    K = np.array([[30.0, 0, 16], [0, 30.0, 16], [0, 0, 1]])
    cam = Camera(K=K, w2c=np.eye(4), width=32, height=32, time=0.0, name="c")
    drawn = {}
    for near in (0.01, 0.2):
        g.means.grad = None
        out, _ = render_view(g, None, cam, near=near, backend="numba")
        out.color.sum().backward()
        drawn[near] = (float(out.alpha.detach().sum()), g.means.grad.abs().sum(dim=1))
    assert drawn[0.01][0] > drawn[0.2][0] > 0  # the near one covers the view at 0.01
    assert drawn[0.01][1][0] > 0 and drawn[0.2][1][0] == 0  # and learns nothing behind the plane at 0.2
    assert drawn[0.2][1][1] > 0  # the far one is drawn and learns either way


def test_opacity_entropy_setting_makes_opacities_more_binary(scene, tmp_path):
    views, pts = scene
    from trase.losses import opacity_entropy

    plain, _ = reconstruct(views, pts, None, CFG, tmp_path / "plain", progress=False)
    solid_cfg = dataclasses.replace(CFG, opacity_entropy_weight=0.5, opacity_entropy_from=10)
    solid, _ = reconstruct(views, pts, None, solid_cfg, tmp_path / "solid", progress=False)
    assert float(opacity_entropy(solid.opacities.detach())) < float(opacity_entropy(plain.opacities.detach()))


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


def test_a_motionless_capture_trains_plain_3dgs_and_resumes(tmp_path):
    from trase.reconstruct import is_motionless

    views, pts, _, _ = write_scene(tmp_path / "images", num=6, size=24, times=(0.0,))  # every view at t = 0
    assert is_motionless(views) and not is_motionless(write_scene(tmp_path / "moving", num=3, size=8)[0])
    init = GaussianModel.from_points(pts, None, sh_degree=1)
    g, d = reconstruct(views, pts, None, CFG, tmp_path / "full", progress=False)
    assert d is None  # no deformation network to learn
    assert evaluate_psnr(g, None, views) > evaluate_psnr(init, None, views) + 1.0
    assert not list((tmp_path / "full").glob("deform/*/*"))  # the public layout of a static 3DGS
    g2, d2 = load_model(tmp_path / "full")
    assert d2 is None and torch.equal(g2.means, g.means)
    reconstruct(views, pts, None, dataclasses.replace(CFG, iterations=20), tmp_path / "split", progress=False)
    g3, _ = reconstruct(views, pts, None, CFG, tmp_path / "split", progress=False)
    assert g3.num_gaussians == g.num_gaussians and torch.allclose(g3.means, g.means, atol=1e-4)
    # a moving capture's checkpoint is not continued as a static one
    moving, mpts, _, _ = write_scene(tmp_path / "m", num=6, size=24)
    reconstruct(moving, mpts, None, dataclasses.replace(CFG, iterations=20), tmp_path / "mix", progress=False)
    with pytest.raises(CheckpointError, match="has a deformation network"):
        reconstruct(views, pts, None, CFG, tmp_path / "mix", progress=False)


def test_a_run_stops_when_the_held_out_psnr_stops_rising_and_stays_stopped(scene, tmp_path):
    import json

    views, pts = scene
    # a gain of 100 dB never comes: the first check past the warm-up (15) sets the baseline, the
    # next one (20) stops with patience 1
    cfg = dataclasses.replace(CFG, stop_interval=5, stop_patience=1, stop_min_delta=100.0, stop_holdout_every=3)
    reconstruct(views, pts, None, cfg, tmp_path / "m", progress=False)
    summary = json.loads((tmp_path / "m/stopped.json").read_text())
    assert summary["stopped_at"] == 20 and summary["cap"] == 40 and len(summary["held_out"]) == 2
    assert [s for s, _ in summary["checks"]] == [15, 20] and summary["checks"][0][1] > 0
    assert available_iterations(tmp_path / "m") == [20]
    # called again (a resumed stage), it does not train past where it stopped
    reconstruct(views, pts, None, cfg, tmp_path / "m", progress=False)
    assert available_iterations(tmp_path / "m") == [20]
    assert json.loads((tmp_path / "m/stopped.json").read_text()) == summary


def test_a_resumed_run_continues_its_checks_exactly(scene, tmp_path):
    import json
    import shutil

    views, pts = scene
    # patience 3 from the first check at 15: a stop could come from 30 on (before the cap, 40)
    cfg = dataclasses.replace(CFG, stop_interval=5, stop_patience=3, stop_min_delta=0.0, stop_holdout_every=3)
    full_g, _ = reconstruct(views, pts, None, cfg, tmp_path / "full", progress=False)
    full = json.loads((tmp_path / "full/stopped.json").read_text())
    assert [s for s, _ in full["checks"]][:2] == [15, 20] and len(full["held_out"]) == 2
    end = full["stopped_at"] or 40
    # the same run cut after its checkpoint at 20 (as if killed there), then resumed
    shutil.copytree(tmp_path / "full", tmp_path / "split")
    for p in (tmp_path / "split").rglob(f"*iteration_{end}*"):
        shutil.rmtree(p) if p.is_dir() else p.unlink()
    (tmp_path / "split/stopped.json").unlink()
    assert available_iterations(tmp_path / "split") == [20]
    g, _ = reconstruct(views, pts, None, cfg, tmp_path / "split", progress=False)
    assert json.loads((tmp_path / "split/stopped.json").read_text()) == full
    assert torch.equal(g.means, full_g.means)


def test_no_stop_at_the_cap_and_none_held_out_where_no_stop_could_come(scene, tmp_path):
    import json

    views, pts = scene
    # patience 10 from the first check at 15: the earliest stop, 65, lies past the cap (40)
    cfg = dataclasses.replace(CFG, stop_interval=5, stop_patience=10, stop_min_delta=100.0, stop_holdout_every=3)
    g, _ = reconstruct(views, pts, None, cfg, tmp_path / "m", progress=False)
    full_g, _ = reconstruct(views, pts, None, CFG, tmp_path / "full", progress=False)
    assert torch.equal(g.means, full_g.means)  # every view trained
    summary = json.loads((tmp_path / "m/stopped.json").read_text())
    assert summary["stopped_at"] is None and "no stop possible" in summary["why"]


def test_too_few_views_to_hold_out_train_the_full_schedule_and_say_so(scene, tmp_path):
    import json

    views, pts = scene
    cfg = dataclasses.replace(CFG, stop_interval=5, stop_patience=1, stop_min_delta=100.0, stop_holdout_every=10)
    reconstruct(views, pts, None, cfg, tmp_path / "m", progress=False)
    summary = json.loads((tmp_path / "m/stopped.json").read_text())
    assert summary["stopped_at"] is None and "none held out" in summary["why"]
    assert available_iterations(tmp_path / "m")[-1] == 40
