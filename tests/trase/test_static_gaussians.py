"""Static gaussians skip the deformation network: the partly static deformation against the
full network, the motion measure, waking up, and the trainer with them (densified children,
checkpoints, resume)."""

import csv
import dataclasses
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import pytest
import torch
from recon_scene import write_scene

from trase.checkpoint import load_model
from trase.deformation import DeformMLP, deformed, deformed_visible
from trase.reconstruct import ReconstructionConfig, reconstruct
from trase.reconstruction_presets import reconstruction_preset
from trase.render_views import evaluate_psnr
from trase.static_gaussians import (
    PartlyStaticDeformation,
    check_times,
    lagging_times,
    motion,
    time_gap,
    update_static,
)


class SideWays(torch.nn.Module):
    """Gaussians with x > 0 move by ``speed`` t along y; the others sit at a fixed offset."""

    def __init__(self, speed: float = 0.3) -> None:
        super().__init__()
        self.speed = torch.nn.Parameter(torch.tensor(speed))

    def forward(self, xyz, t):
        n = xyz.shape[0]
        d_xyz = torch.zeros(n, 3) + 0.01
        d_xyz[:, 1] = d_xyz[:, 1] + torch.where(xyz[:, 0] > 0, self.speed * float(t), 0.0)
        return d_xyz, torch.zeros(n, 4), torch.zeros(n, 3)


def _xyz(n=40):
    return torch.linspace(-1, 1, n)[:, None] * torch.tensor([[1.0, 0.5, 0.2]])


def test_partly_static_matches_the_network_on_moving_rows_and_freezes_the_others():
    net, xyz = SideWays(), _xyz()
    scales = torch.full((40, 3), 0.05)
    times = check_times([0.0, 0.25, 0.5, 0.75, 1.0, 1.0])
    assert times == [0.0, 0.25, 0.5, 0.75, 1.0]
    mv, _ = motion(net, xyz, scales, times, extent=1.0)
    assert torch.all(mv[xyz[:, 0] <= 0] == 0) and torch.all(mv[xyz[:, 0] > 0] > 0.1)
    static, frozen, counts = update_static(net, xyz, scales, times, 1.0, 1e-3, torch.zeros(40, dtype=torch.bool),
                                           torch.zeros(40, 10))
    assert torch.equal(static, xyz[:, 0] <= 0) and counts == {"static": 20, "newly": 20, "woken": 0}
    d = PartlyStaticDeformation(net, static, frozen)
    for t in (0.0, 0.6, 1.0):
        a, b = d(xyz, t), net(xyz, t)
        for x, y in zip(a, b):  # exact: the static rows' offsets did not change with time
            assert torch.equal(x, y)
    # rows: what edits and the visible-only pass evaluate
    keep = torch.arange(40) % 3 == 0
    sub = d.rows(keep)
    assert all(torch.equal(x, y[keep]) for x, y in zip(sub(xyz[keep], 0.6), d(xyz, 0.6)))
    # gradients reach the network through the moving rows only
    out = d(xyz, 1.0)[0].sum()
    out.backward()
    assert net.speed.grad == pytest.approx(20.0)


def test_a_static_gaussian_that_starts_to_move_is_woken_up():
    net, xyz, scales = SideWays(speed=0.0), _xyz(), torch.full((40, 3), 0.05)
    times = [0.0, 0.5, 1.0]
    static, frozen, c = update_static(net, xyz, scales, times, 1.0, 1e-3, torch.zeros(40, dtype=torch.bool),
                                      torch.zeros(40, 10))
    assert c["static"] == 40
    with torch.no_grad():
        net.speed.fill_(0.3)  # the right half moves now (the network learned it from its neighbours)
    static2, frozen2, c = update_static(net, xyz, scales, times, 1.0, 1e-3, static, frozen)
    assert c == {"static": 20, "newly": 0, "woken": 20} and torch.equal(static2, xyz[:, 0] <= 0)
    assert torch.equal(frozen2[static2], frozen[static2])  # the still ones keep their frozen offsets
    # a woken gaussian goes on from its frozen offsets: its mean offset over time is unchanged
    d = PartlyStaticDeformation(net, static2, frozen2)
    mean_after = torch.stack([torch.cat(d(xyz, t), 1) for t in times]).mean(0)
    assert torch.allclose(mean_after, frozen, atol=1e-6)
    # and a motion between the threshold and WAKE_FACTOR x it wakes nobody (no flicker)
    with torch.no_grad():
        net.speed.fill_(0.003)  # the right half moves 1.5e-3 from its mean: above 1e-3, below 2 x 1e-3
    _, _, c = update_static(net, xyz, scales, times, 1.0, 1e-3, static, frozen)
    assert c["woken"] == 0


def test_time_gap_is_the_worst_times_views_below_the_median_time():
    assert time_gap([30.0, 30.0, 20.0], [0.0, 0.5, 1.0]) == pytest.approx(10.0)
    # a rig's cameras at one time count as one time, by their mean squared error
    two = -10 * math.log10((1e-3 + 1e-2) / 2)
    assert time_gap([30.0, 20.0, 30.0, 30.0, 30.0], [0.0, 0.0, 0.5, 1.0, 1.0]) == pytest.approx(30.0 - two)
    assert time_gap([25.0] * 4, [0.0, 0.3, 0.6, 0.9]) == 0.0 and time_gap([], []) == 0.0
    with pytest.raises(ValueError, match="static_time_gap"):
        ReconstructionConfig(static_time_gap=-1.0)


def test_while_freezing_is_held_back_nothing_new_freezes_but_waking_goes_on():
    net, xyz, scales, times = SideWays(speed=0.0), _xyz(), torch.full((40, 3), 0.05), [0.0, 0.5, 1.0]
    static, frozen, c = update_static(net, xyz, scales, times, 1.0, 1e-3, torch.zeros(40, dtype=torch.bool),
                                      torch.zeros(40, 10), freeze=False)
    assert c["static"] == 0 and not static.any()
    static, frozen, _ = update_static(net, xyz, scales, times, 1.0, 1e-3, static, frozen)
    with torch.no_grad():
        net.speed.fill_(0.3)
    _, _, c = update_static(net, xyz, scales, times, 1.0, 1e-3, static, frozen, freeze=False)
    assert c == {"static": 20, "newly": 0, "woken": 20}


def test_lagging_times_are_those_more_than_the_gap_below_the_median_time():
    assert lagging_times([30.0, 30.0, 20.0, 29.0], [0.0, 0.5, 1.0, 0.25], 5.0) == {1.0}
    assert lagging_times([30.0, 30.0, 20.0, 29.0], [0.0, 0.5, 1.0, 0.25], 20.0) == set()
    assert lagging_times([], [], 1.0) == set()
    # a rig's cameras at one time count as one time, as time_gap counts them
    assert lagging_times([30.0, 20.0, 30.0, 30.0, 30.0, 30.0], [0.0, 0.0, 0.5, 0.5, 1.0, 1.0], 2.0) == {0.0}
    # not empty exactly when the gap exceeds it, at the boundary too
    gen = torch.Generator().manual_seed(0)
    for _ in range(200):
        ps = (20 + 10 * torch.rand(7, generator=gen)).tolist()
        ts = torch.randint(0, 4, (7,), generator=gen).float().tolist()
        for g in (time_gap(ps, ts), time_gap(ps, ts) - 1e-9, 1.0, 3.0):
            assert bool(lagging_times(ps, ts, g)) == (time_gap(ps, ts) > g)
    for bad in ({"static_hold_error": -0.1}, {"static_hold_error": 1.0, "static_time_gap": 5.0},
                {"static_hold_error": 0.2}):  # negative; no pixel is off by 1; no gap to act above
        with pytest.raises(ValueError, match="static_hold_error"):
            ReconstructionConfig(**bad)


def test_a_held_back_region_keeps_only_its_rows_from_freezing():
    net, xyz, scales, times = SideWays(speed=0.0), _xyz(), torch.full((40, 3), 0.05), [0.0, 0.5, 1.0]
    hold = torch.zeros(40, dtype=torch.bool)
    hold[:5] = True
    static, _, c = update_static(net, xyz, scales, times, 1.0, 1e-3, torch.zeros(40, dtype=torch.bool),
                                 torch.zeros(40, 10), freeze=~hold)
    assert c["static"] == 35 and not static[:5].any() and static[5:].all()


def test_visible_only_pass_takes_the_rows_of_a_partly_static_deformation():
    from trase.gaussians import GaussianModel

    g = GaussianModel(_xyz(), torch.full((40, 3), -3.0), torch.tensor([[1.0, 0, 0, 0]]).repeat(40, 1),
                      torch.zeros(40), torch.zeros(40, 3))
    net = SideWays()
    static, frozen, _ = update_static(net, g.means, g.scales, [0.0, 1.0], 1.0, 1e-3,
                                      torch.zeros(40, dtype=torch.bool), torch.zeros(40, 10))
    d = PartlyStaticDeformation(net, static, frozen)
    visible = lambda m, q, s: m[:, 1] > -0.2
    a = deformed_visible(g, d, 0.7, visible)
    b = deformed(g, d, 0.7)
    assert all(torch.allclose(x, y) for x, y in zip(a, b))


CFG = reconstruction_preset(
    "cpu",     iterations=40, warm_up=10, densify_from=5, densify_until=35, densify_interval=10,
    checkpoint_interval=20, time_noise_steps=40, position_lr_max_steps=40, deform_lr_max_steps=40,
    static_threshold=0.05, static_from=5, static_interval=10,
)


def test_training_with_static_gaussians_saves_reloads_and_resumes(tmp_path):
    views, pts, _, _ = write_scene(tmp_path / "images", num=6, size=24)
    g, d = reconstruct(views, pts, None, CFG, tmp_path / "full", progress=False)
    assert isinstance(d, PartlyStaticDeformation) and d.num_gaussians == g.num_gaussians
    assert 0 < int(d.static.sum()) <= g.num_gaussians
    rows = list(csv.DictReader((tmp_path / "full" / "train_log.csv").open()))
    assert int(rows[-1]["static_gaussians"]) == int(d.static.sum()) and int(rows[0]["static_gaussians"]) == 0
    g2, d2 = load_model(tmp_path / "full")
    assert isinstance(d2, PartlyStaticDeformation) and torch.equal(d2.static, d.static)
    assert evaluate_psnr(g2, d2, views) == pytest.approx(evaluate_psnr(g, d, views), abs=1e-6)
    # stopped at the first checkpoint, resumed: where the whole run lands
    reconstruct(views, pts, None, dataclasses.replace(CFG, iterations=20), tmp_path / "split", progress=False)
    g3, d3 = reconstruct(views, pts, None, CFG, tmp_path / "split", progress=False)
    assert g3.num_gaussians == g.num_gaussians and torch.equal(d3.static, d.static)
    assert torch.allclose(g3.means, g.means, atol=1e-4)
    # freezing held back at every check (a gap no render meets): no static rows; each check logged
    _, held = reconstruct(views, pts, None, dataclasses.replace(CFG, static_time_gap=1e-9), tmp_path / "held",
                          progress=False)
    assert isinstance(held, PartlyStaticDeformation) and not held.static.any()
    checks = list(csv.DictReader((tmp_path / "held" / "static_checks.csv").open()))
    assert [int(r["iteration"]) for r in checks] == [15, 25, 35] and all(r["freeze"] == "0" for r in checks)
    assert all(int(r["held"]) > 0 for r in checks)
    assert all(float(r["time_gap_db"]) > 0 for r in checks)
    # a gap no time reaches: nothing lagging, nothing held, and the run is the unheld one (the
    # checks only render)
    _, nothing = reconstruct(views, pts, None, dataclasses.replace(CFG, static_time_gap=1e3, static_hold_error=0.2),
                             tmp_path / "none-held", progress=False)
    assert torch.equal(nothing.static, d.static)
    checks = list(csv.DictReader((tmp_path / "none-held" / "static_checks.csv").open()))
    assert all(r["held"] == "0" and r["freeze"] == "1" for r in checks)
    # off (the default): no static rows, a plain network
    _, plain = reconstruct(views, pts, None, dataclasses.replace(CFG, static_threshold=0.0), tmp_path / "off",
                           progress=False)
    assert isinstance(plain, DeformMLP)


def test_a_hold_region_keeps_exactly_the_gaussians_drawing_bad_pixels_from_freezing(tmp_path, monkeypatch):
    import trase.static_checks as checks
    import trase.static_gaussians as sg

    views, pts, _, _ = write_scene(tmp_path / "images", num=6, size=24)
    seen = []  # per check: (hold [N], static before, static after)
    real_hold, real_update = checks.hold_region, sg.update_static

    def hold_region(*a, **k):
        h = real_hold(*a, **k)
        seen.append([h.clone()])
        return h

    def update_static(net, xyz, scales, times, extent, threshold, static, frozen, freeze=True):
        out = real_update(net, xyz, scales, times, extent, threshold, static, frozen, freeze)
        if seen and len(seen[-1]) == 1:
            assert torch.equal(freeze, ~seen[-1][0])  # the region's rows, and only they, may not freeze
            seen[-1] += [static.clone(), out[0].clone()]
        return out

    monkeypatch.setattr(checks, "hold_region", hold_region)
    monkeypatch.setattr(sg, "update_static", update_static)
    out = tmp_path / "region"
    out.mkdir()
    (out / "static_checks.csv").write_text("iteration,time_gap_db,freeze,static\n99,1.0,1,3\n")  # an older run's
    _, part = reconstruct(views, pts, None, dataclasses.replace(CFG, static_time_gap=1e-9, static_hold_error=0.2),
                          out, progress=False)
    checks = list(csv.DictReader((out / "static_checks.csv").open()))
    assert [int(r["iteration"]) for r in checks] == [15, 25, 35] and len(seen) == 3
    newly_total = 0
    for (hold, before, after), row in zip(seen, checks):
        n = hold.shape[0]
        assert 0 < int(hold.sum()) < n  # some gaussians draw the bad pixels, not all
        assert not (hold & after & ~before).any()  # none of them froze
        newly_total += int((after & ~before).sum())
        assert int(row["held"]) == int((hold & ~before).sum()) and row["freeze"] == "1"
        assert int(row["static"]) == int(after.sum())
    assert newly_total > 0 and 0 < int(part.static.sum()) < part.num_gaussians


def test_an_edit_of_a_partly_static_model_keeps_its_rows(tmp_path):
    import numpy as np

    from trase.edit.model import EditableModel
    from trase.edit.save import load_edited, save_edited
    from trase.gaussians import GaussianModel

    g = GaussianModel(_xyz(), torch.full((40, 3), -3.0), torch.tensor([[1.0, 0, 0, 0]]).repeat(40, 1),
                      torch.zeros(40), torch.zeros(40, 3))
    net = DeformMLP.preset("small")
    static, frozen, _ = update_static(net, g.means, g.scales, [0.0, 1.0], 1.0, 1e9,  # everything still
                                      torch.zeros(40, dtype=torch.bool), torch.zeros(40, 10))
    static[::2] = False
    model = EditableModel(g, PartlyStaticDeformation(net, static, frozen), np.zeros(40, int), np.ones(40, bool))
    keep = np.arange(40) % 3 != 0
    part = model.subset(keep)
    save_edited(part, tmp_path / "e")
    back = load_edited(tmp_path / "e")
    assert isinstance(back.deformation, PartlyStaticDeformation)
    assert torch.equal(back.deformation.static, static[torch.from_numpy(keep)])
    a = deformed(back.gaussians, back.deformation, 0.3)
    b = deformed(part.gaussians, part.deformation, 0.3)
    assert all(torch.allclose(x, y, atol=1e-6) for x, y in zip(a, b))


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_the_hold_region_is_the_gaussians_that_draw_the_bad_pixels(backend):
    """Three opaque gaussians: one drawn where the image agrees, one drawn where it does not, one
    out of view; only the second is held."""
    from types import SimpleNamespace

    import numpy as np

    from trase.camera import Camera, intrinsics, look_at
    from trase.gaussians import GaussianModel
    from trase.render import rasterize
    from trase.static_checks import hold_region

    cam = Camera(K=intrinsics(30, 30, 16, 12), w2c=look_at(np.array([0, -3.0, 0.0]), np.zeros(3)),
                 width=32, height=24, time=0.5)
    means = torch.tensor([[-0.8, 0.0, 0.0], [0.8, 0.0, 0.0], [0.0, 0.0, 30.0]])
    sh = torch.zeros(3, 1, 3)
    sh[:, 0, 0] = 1.5  # red
    g = GaussianModel(means, torch.full((3, 3), math.log(0.15)), torch.tensor([[1.0, 0, 0, 0]]).repeat(3, 1),
                      torch.full((3,), 8.0), sh)  # opacity 0.9997
    bg = torch.zeros(3)
    blue = sh.clone()
    blue[1, 0] = torch.tensor([-1.0, -1.0, 1.5])  # the image shows the second one blue
    with torch.no_grad():
        gt = rasterize(g.means, g.rotations, g.scales, g.opacities, cam, colors=blue, sh_degree=0, background=bg,
                       backend=backend).color
    tr = SimpleNamespace(gaussians=g, deformation=lambda: None)
    data = SimpleNamespace(cameras=[cam], images=[gt])
    hold = hold_region(tr, data, {0.5}, bg, backend, error=0.2, near=0.01)
    assert hold.tolist() == [False, True, False]
    assert not hold_region(tr, data, {0.25}, bg, backend, error=0.2, near=0.01).any()  # no view at a lagging time
