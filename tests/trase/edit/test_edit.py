"""Edits on the two-object tiny scene: what changes, what must not, and reloading."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from tests.trase.helpers import exact_masks, object_alpha, tiny_scene
from trase.camera import Camera
from trase.checkpoint import load_model
from trase.deformation import DeformMLP, TabulatedDeformation, deformed
from trase.edit import (
    EditableModel,
    EditError,
    RigidTransform,
    by_click,
    by_clusters,
    by_mask,
    compose,
    export_object_ply,
    extract,
    load_edited,
    recolor,
    remove,
    save_edited,
)
from trase.edit.rigid import quat_mul, transform_gaussians
from trase.gaussians import GaussianModel
from trase.render_views import render_view


def rgb(model: EditableModel, cam: Camera) -> np.ndarray:
    with torch.no_grad():
        return render_view(model.gaussians, model.deformation, cam)[0].color.numpy()


@pytest.fixture(scope="module")
def scene():
    gm, deform, ids, views = tiny_scene()
    return EditableModel(gm, deform, ids, np.ones(len(ids), bool)), ids, views


def test_remove_leaves_pixels_the_object_never_covered(scene):
    model, ids, views = scene
    edited = remove(model, by_clusters(model, [0]))
    assert edited.num_gaussians == int((ids == 1).sum())
    for v in views:
        cam = v.camera
        never = object_alpha(model.gaussians, model.deformation, ids, cam, 0) == 0.0
        before, after = rgb(model, cam), rgb(edited, cam)
        assert never.any() and np.abs(before - after)[never].max() <= 1e-5
        gt = exact_masks(model.gaussians, model.deformation, ids, v).masks[0]
        assert np.abs(before - after)[gt].max() > 0.1  # the object's own region changed
    assert model.num_gaussians == len(ids)  # the input is untouched


def test_extract_then_remove_composes_back_to_the_scene(scene):
    model, _, views = scene
    sel = by_clusters(model, [1])
    back = compose(remove(model, sel), extract(model, sel))
    for v in views:
        assert np.abs(rgb(back, v.camera) - rgb(model, v.camera)).max() <= 1e-5


def test_recolor_sets_and_shifts_only_the_selection(scene):
    model, ids, views = scene
    sel = by_clusters(model, [0])
    red = recolor(model, sel, rgb=(1.0, 0.0, 0.0))
    assert np.allclose(red.gaussians.colors_dc[torch.from_numpy(sel)].detach().numpy(), [1.0, 0.0, 0.0], atol=1e-6)
    assert torch.equal(red.gaussians.sh_dc[torch.from_numpy(~sel)], model.gaussians.sh_dc[torch.from_numpy(~sel)])
    cam = views[1].camera
    never = object_alpha(model.gaussians, model.deformation, ids, cam, 0) == 0.0
    assert np.abs(rgb(red, cam) - rgb(model, cam))[never].max() <= 1e-5
    shifted = recolor(model, sel, shift=(0.1, 0.0, -0.1))
    delta = (shifted.gaussians.colors_dc - model.gaussians.colors_dc).detach().numpy()
    assert np.allclose(delta[sel], [0.1, 0.0, -0.1], atol=1e-6) and np.abs(delta[~sel]).max() == 0
    for bad in ({"rgb": (1, 0, 0), "shift": (0, 0, 0)}, {}, {"rgb": (2, 0, 0)}, {"shift": (0, 0)}):
        with pytest.raises(EditError, match="recolor"):
            recolor(model, sel, **bad)


def test_selections_by_click_and_mask(scene):
    model, ids, views = scene
    v = views[1]
    gt = exact_masks(model.gaussians, model.deformation, ids, v).masks[1]
    r, c = np.argwhere(gt)[len(np.argwhere(gt)) // 2]
    k, sel = by_click(model, v.camera, c + 0.5, r + 0.5)
    assert k == 1 and np.array_equal(sel, ids == 1)
    ks, sel = by_mask(model, v.camera, gt)
    assert ks == [1] and np.array_equal(sel, ids == 1)
    k, sel = by_click(model, v.camera, -5.0, 3.0)  # off the image: nothing
    assert k == -1 and not sel.any()
    with pytest.raises(EditError, match="bool array of shape"):
        remove(model, np.ones(3, bool))


def _random_sh_model(n=60, seed=1) -> GaussianModel:
    g = torch.Generator().manual_seed(seed)
    return GaussianModel(0.3 * torch.randn(n, 3, generator=g), torch.full((n, 3), -2.5),
                         torch.randn(n, 4, generator=g), torch.full((n,), 2.0),
                         0.4 * torch.randn(n, 16, 3, generator=g))


def test_rigid_transform_renders_as_the_inverse_moved_camera():
    """An object moved by (R, T) seen from a camera looks like the original seen from the
    camera moved by the inverse: geometry, and view-dependent colour (SH degree 3)."""
    gm = _random_sh_model()
    n = gm.num_gaussians
    torch.manual_seed(0)  # the network's draw (1 of 40 draws misses the tolerance: an unseeded test was flaky)
    net = DeformMLP(D=2, W=16, t_freqs=2)
    torch.nn.init.normal_(net.gaussian_warp.weight, std=0.02)
    torch.nn.init.normal_(net.gaussian_rotation.weight, std=0.02)
    part = EditableModel(gm, net, np.zeros(n), np.ones(n, bool))
    tf = RigidTransform.from_euler((20.0, -35.0, 50.0), (0.2, -0.1, 0.3))
    moved = compose(EditableModel.unlabelled(gm.copy(), None).subset(np.zeros(n, bool)), part, tf, time_offset=0.25)
    from tests.trase.helpers import tiny_scene as _ts

    cam = _ts()[3][1].camera
    cam = dataclasses.replace(cam, time=0.5)
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = np.asarray(tf.rotation), np.asarray(tf.translation)
    cam_back = dataclasses.replace(cam, w2c=cam.w2c @ M, time=0.75)
    a, b = rgb(moved, cam), rgb(part, cam_back)
    assert np.abs(a - b).max() < 1e-4 and a.max() > 0.1
    with torch.no_grad():  # offsets rotate with the part
        m1, q1, _ = deformed(moved.gaussians, moved.deformation, 0.5)
        m0, q0, _ = deformed(gm, net, 0.75)
    assert torch.allclose(m1, tf.apply_points(m0), atol=1e-5)
    assert torch.allclose(q1, quat_mul(tf.quaternion(), q0), atol=1e-5)
    with pytest.raises(EditError, match="orthonormal"):
        RigidTransform(((2.0, 0, 0), (0, 1, 0), (0, 0, 1)))
    assert torch.equal(transform_gaussians(gm, RigidTransform()).means, gm.means)


def test_composition_shows_both_objects_at_their_times(scene):
    model, ids, views = scene
    other = extract(model, by_clusters(model, [1]))
    tf = RigidTransform(translation=(0.0, 0.0, 0.6))
    both = compose(model, other, tf, time_offset=-0.5)
    assert both.n_clusters == 4 and set(np.unique(both.labels[len(ids):])) == {3}
    for t in (0.0, 0.5, 1.0):
        with torch.no_grad():
            m, _, _ = deformed(both.gaussians, both.deformation, t)
            base_m, _, _ = deformed(model.gaussians, model.deformation, t)
            part_m, _, _ = deformed(other.gaussians, other.deformation, min(max(t - 0.5, 0.0), 1.0))
        assert torch.allclose(m[: len(ids)], base_m, atol=1e-6)
        assert torch.allclose(m[len(ids):], part_m + torch.tensor([0.0, 0.0, 0.6]), atol=1e-6)
    cam = views[2].camera
    alone = by_clusters(both, [3])
    from trase.segment import render_alpha

    assert render_alpha(both.gaussians, both.deformation, alone, cam).max() > 0.5
    with pytest.raises(EditError, match="no gaussians"):
        compose(model, extract(model, np.zeros(len(ids), bool)))


def test_saved_edits_reload_and_render_the_same(tmp_path, scene):
    model, ids, views = scene
    # a network-deformed model: written in the public layout (deform.pth)
    net = DeformMLP(D=2, W=16, t_freqs=2)
    torch.nn.init.normal_(net.gaussian_warp.weight, std=0.02)
    netted = EditableModel(model.gaussians, net, ids, np.ones(len(ids), bool))
    edited = recolor(remove(netted, by_clusters(netted, [0])), np.ones(int((ids == 1).sum()), bool), shift=(0.1, 0, 0))
    save_edited(edited, tmp_path / "a")
    assert (tmp_path / "a/model/deform/iteration_1/deform.pth").is_file()
    _, d = load_model(tmp_path / "a/model")
    assert isinstance(d, DeformMLP)
    back = load_edited(tmp_path / "a")
    assert np.array_equal(back.labels, edited.labels)
    for v in views:
        assert np.abs(rgb(back, v.camera) - rgb(edited, v.camera)).max() <= 1e-5
    # a composition: its motion is baked at the given times, exact there
    both = compose(model, extract(model, by_clusters(model, [1])), RigidTransform(translation=(0, 0, 0.5)), 0.2)
    with pytest.raises(EditError, match="times to bake"):
        save_edited(both, tmp_path / "b")
    times = sorted({v.camera.time for v in views})
    save_edited(both, tmp_path / "b", times=times)
    back = load_edited(tmp_path / "b")
    assert isinstance(back.deformation, TabulatedDeformation)
    for v in views:
        assert np.abs(rgb(back, v.camera) - rgb(both, v.camera)).max() <= 1e-5
    with pytest.raises(EditError, match="not found"):
        load_edited(tmp_path / "a/model")


def test_object_ply_canonical_and_at_a_time(tmp_path, scene):
    model, ids, _ = scene
    sel = by_clusters(model, [0])
    p = export_object_ply(model, sel, tmp_path / "obj.ply")
    g = GaussianModel.load_ply(p)
    assert g.num_gaussians == int(sel.sum())
    assert torch.allclose(g.means, model.gaussians.means[torch.from_numpy(sel)])
    p = export_object_ply(model, sel, tmp_path / "obj_t1.ply", time=1.0)
    with torch.no_grad():
        m, _, _ = deformed(model.gaussians, model.deformation, 1.0)
    assert torch.allclose(GaussianModel.load_ply(p).means, m[torch.from_numpy(sel)], atol=1e-6)
    with pytest.raises(EditError, match="empty"):
        export_object_ply(model, np.zeros(len(ids), bool), tmp_path / "none.ply")


def test_tabulated_rows_follow_the_selection():
    _, deform, ids, _ = tiny_scene()
    sub = deform.rows(torch.from_numpy(ids == 1))
    assert sub.num_gaussians == int((ids == 1).sum())
    assert torch.equal(sub.d_xyz, deform.d_xyz[:, torch.from_numpy(ids == 1)])


def _vgg_file(tmp_path, full: bool = True):
    from trase.edit.style import VGG16Features

    torch.manual_seed(0)
    net = VGG16Features()
    sd = {k: v for k, v in net.state_dict().items() if k.startswith("features.")}
    if full:  # torchvision's whole vgg16 dict carries the classifier too
        sd["classifier.0.weight"] = torch.zeros(2, 2)
    path = tmp_path / "vgg16.pth"
    torch.save(sd, path)
    return path


def test_style_changes_only_the_selection_and_lowers_the_loss(tmp_path, scene):
    from trase.edit.style import StyleConfig, VGG16Features, stylize

    model, _, views = scene
    vgg = VGG16Features.load(_vgg_file(tmp_path))
    stripes = np.zeros((24, 32, 3), np.float32)
    stripes[:, ::4] = (1.0, 0.8, 0.0)
    sel = by_clusters(model, [0])
    styled, losses = stylize(model, sel, [v.camera for v in views], stripes, vgg, StyleConfig(iterations=10, lr=0.1))
    s = torch.from_numpy(sel)
    assert torch.equal(styled.gaussians.sh_dc[~s], model.gaussians.sh_dc[~s])
    assert not torch.equal(styled.gaussians.sh_dc[s], model.gaussians.sh_dc[s])
    assert torch.equal(styled.gaussians.means, model.gaussians.means)
    assert np.mean(losses[-3:]) < np.mean(losses[:3])


def test_style_needs_a_weights_file(tmp_path):
    from trase.edit.style import VGG16Features

    with pytest.raises(EditError, match="needs VGG-16 weights"):
        VGG16Features.load(None)
    with pytest.raises(EditError, match="not found"):
        VGG16Features.load(tmp_path / "none.pth")
    torch.save({"linear.weight": torch.zeros(1)}, tmp_path / "other.pth")
    with pytest.raises(EditError, match="not VGG-16 weights"):
        VGG16Features.load(tmp_path / "other.pth")
    (tmp_path / "bad.pth").write_bytes(b"garbage")
    with pytest.raises(EditError, match="not a readable"):
        VGG16Features.load(tmp_path / "bad.pth")
    assert VGG16Features.load(_vgg_file(tmp_path, full=False)) is not None  # features only
