"""The geometry's label ceiling: instance votes are compositing weights, and they recover objects."""

import numpy as np
import pytest
import torch

from benchmark.protocol.ceiling import CeilingError, instance_votes, truth_selection
from tests.trase.helpers import exact_masks, tiny_scene
from trase.deformation import deformed
from trase.render import rasterize


def _instance_map(gm, deform, ids, view) -> np.ndarray:
    """0 = background, object k -> id k + 1 (as the synthetic generator's maps)."""
    ms = exact_masks(gm, deform, ids, view)
    out = np.zeros(ms.masks.shape[1:], np.int64)
    for k, m in enumerate(ms.masks):
        out[m] = k + 1
    return out


def test_votes_are_summed_compositing_weights():
    gm, deform, _, views = tiny_scene(n_per=20)
    cam = views[1].camera
    everywhere_one = np.ones((cam.height, cam.width), np.int64)
    votes = instance_votes(gm, deform, [cam], [everywhere_one], 3)
    with torch.no_grad():
        m, q, s = deformed(gm, deform, cam.time)
        n = gm.num_gaussians
        per_gaussian = rasterize(m, q, s, gm.opacities, cam, features=torch.eye(n)).features.sum((0, 1))
    assert votes.shape == (n, 3)
    assert np.abs(votes[:, [0, 2]]).max() == 0.0
    np.testing.assert_allclose(votes[:, 1], per_gaussian.double().numpy(), rtol=1e-4, atol=1e-5)
    assert votes[:, 1].sum() > 1.0  # something is seen


def test_votes_recover_the_objects():
    gm, deform, ids, views = tiny_scene()
    maps = [_instance_map(gm, deform, ids, v) for v in views]
    votes = instance_votes(gm, deform, [v.camera for v in views], maps, 3)
    seen = votes.sum(1) > 0
    assert seen.mean() > 0.9
    agree = (votes[seen].argmax(1) - 1) == ids[seen]
    assert agree.mean() > 0.95
    sel = truth_selection(votes, [1])
    assert sel.sum() > 0 and (ids[sel] == 0).mean() > 0.95


def test_truth_selection_skips_unseen_gaussians():
    votes = np.array([[0.0, 0.0, 0.0], [0.1, 2.0, 0.0], [0.0, 0.3, 0.5], [0.0, 0.0, 0.0]])
    assert truth_selection(votes, [1]).tolist() == [False, True, False, False]
    assert truth_selection(votes, [1, 2]).tolist() == [False, True, True, False]
    assert truth_selection(np.zeros((0, 3)), [1]).shape == (0,)


def test_instance_map_of_wrong_size_names_the_view():
    gm, deform, _, views = tiny_scene(n_per=5)
    cam = views[0].camera
    with pytest.raises(CeilingError, match="cam/00.*WxH"):
        instance_votes(gm, deform, [cam], [np.zeros((cam.height + 1, cam.width), np.int64)], 2)


def test_object_alpha_stats_measure_holes_inside_the_ground_truth():
    from benchmark.protocol.ceiling import object_alpha_stats

    gt = np.zeros((4, 4), bool)
    gt[1:3, 1:3] = True  # 4 object pixels
    alpha = np.full((4, 4), 0.9, np.float32)  # solid everywhere ...
    alpha[1, 1] = 0.2  # ... but one see-through pixel inside the object
    st = object_alpha_stats([alpha, alpha], [gt, gt])
    assert st["holes"] == 0.25 and st["gt_pixels"] == 8
    assert st["spill"] == 12 / 4  # the 12 solid pixels around the object, per object pixel
    alpha[0, :] = 0.0  # a tighter render: 8 pixels outside remain
    assert object_alpha_stats([alpha], [gt])["spill"] == 2.0
    assert st["mean_in_gt"] == pytest.approx((3 * 0.9 + 0.2) / 4, abs=1e-4)
    assert object_alpha_stats([alpha], [np.zeros((4, 4), bool)])["holes"] is None  # nothing to measure


def test_per_object_stats_name_each_object_its_holes_and_its_gaussians_opacity(tmp_path):
    """Two objects of interest and a wall: holes are measured on each object's own pixels, the
    opacity over the gaussians voted for it; a test view without an instance map is left out."""
    from types import SimpleNamespace

    from PIL import Image

    from benchmark.datasets.truth import SceneObject
    from benchmark.protocol.ceiling import instance_maps_of_test_views, per_object_stats

    ids = np.zeros((4, 4), np.uint16)
    ids[:2, :2] = 4  # ball: 4 pixels
    ids[2:, 2:] = 5  # ring: 4 pixels
    Image.fromarray(ids).save(tmp_path / "t0.png")
    truth = SimpleNamespace(objects=(SceneObject(1, "wall", False), SceneObject(4, "ball", True),
                                     SceneObject(5, "ring", True)),
                            instance_maps={"t0": tmp_path / "t0.png"}, interest_ids=[4, 5])
    scene = SimpleNamespace(truth=truth, test=[SimpleNamespace(name="t0"), SimpleNamespace(name="t1")])
    alpha = np.full((4, 4), 0.9, np.float32)
    alpha[2, 2] = 0.1  # one hole in the ring
    # gaussians: two ball (opacity 0.9, 0.8), three ring (0.05, 0.1, 0.95), one wall, one never seen
    votes = np.zeros((7, 6))
    votes[[0, 1], 4] = 1.0
    votes[[2, 3, 4], 5] = 1.0
    votes[5, 1] = 1.0
    gaussians = SimpleNamespace(opacities=torch.tensor([0.9, 0.8, 0.05, 0.1, 0.95, 0.9, 0.01]))
    maps = instance_maps_of_test_views(scene)
    assert maps[1] is None  # t1 has no instance map
    out = per_object_stats(gaussians, votes, truth, maps, [alpha, np.zeros((4, 4))])
    assert set(out) == {"ball", "ring"}
    assert out["ball"]["holes"] == 0.0 and out["ball"]["gt_pixels"] == 4 and out["ball"]["gaussians"] == 2
    assert out["ring"]["holes"] == 0.25 and out["ring"]["gt_pixels"] == 4 and out["ring"]["gaussians"] == 3
    assert out["ring"]["opacity_median"] == pytest.approx(0.1) and out["ring"]["opacity_below_half"] == pytest.approx(2 / 3, abs=1e-4)
    assert out["ball"]["opacity_below_half"] == 0.0
    assert "spill" not in out["ball"]  # the merged render cannot tell one object's spill from another object


def test_mover_frame_split_separates_the_frames_a_mover_touches(tmp_path):
    """A mover beside or in front of an object of interest (within 2 px) puts the frame in the
    first group; frames without an instance map or a score are left out."""
    from types import SimpleNamespace

    from PIL import Image

    from benchmark.datasets.truth import SceneObject
    from benchmark.protocol.ceiling import instance_maps_of_test_views, mover_frame_split

    far, near, alone = (np.zeros((8, 8), np.uint16) for _ in range(3))
    for ids in (far, near, alone):
        ids[:3, :3] = 4  # the ball, of interest
    far[:, 6] = 7  # the pillar, 4 px away from the ball
    near[:, 4] = 7  # 2 px away: touches
    for name, ids in (("far", far), ("near", near), ("alone", alone), ("nan", near)):
        Image.fromarray(ids).save(tmp_path / f"{name}.png")
    objects = (SceneObject(1, "wall", False, "static"), SceneObject(4, "ball", True, "rigid"),
               SceneObject(7, "pillar", False, "rigid"))
    maps = {n: tmp_path / f"{n}.png" for n in ("far", "near", "alone", "nan")}
    truth = SimpleNamespace(objects=objects, instance_maps=maps, interest_ids=[4], mover_ids=[7])
    views = [SimpleNamespace(name=n) for n in ("far", "near", "alone", "nan", "no-map")]
    maps = instance_maps_of_test_views(SimpleNamespace(truth=truth, test=views))
    out = mover_frame_split(truth, maps, [0.9, 0.5, 0.8, float("nan"), 0.1])
    assert out == {"frames": 1, "miou": 0.5, "other_frames": 2, "other_miou": 0.85}


def test_per_object_stats_of_chosen_ids_report_a_mover(tmp_path):
    """``ids`` picks the objects reported (the movers): a pillar the geometry does not show is
    all holes, whatever the objects of interest do."""
    from types import SimpleNamespace

    from PIL import Image

    from benchmark.datasets.truth import SceneObject
    from benchmark.protocol.ceiling import instance_maps_of_test_views, per_object_stats

    ids = np.zeros((4, 4), np.uint16)
    ids[:2, :2] = 4
    ids[:, 3] = 7
    Image.fromarray(ids).save(tmp_path / "t0.png")
    truth = SimpleNamespace(objects=(SceneObject(4, "ball", True, "rigid"), SceneObject(7, "pillar", False, "rigid")),
                            instance_maps={"t0": tmp_path / "t0.png"}, interest_ids=[4])
    scene = SimpleNamespace(truth=truth, test=[SimpleNamespace(name="t0")])
    votes = np.zeros((2, 8))
    votes[0, 4] = 1.0  # one ball gaussian; nothing voted for the pillar
    gaussians = SimpleNamespace(opacities=torch.tensor([0.9, 0.9]))
    alpha = np.zeros((4, 4), np.float32)  # the movers' render: nothing
    out = per_object_stats(gaussians, votes, truth, instance_maps_of_test_views(scene), [alpha], ids=[7])
    assert set(out) == {"pillar"}
    assert out["pillar"]["holes"] == 1.0 and out["pillar"]["gt_pixels"] == 4 and out["pillar"]["gaussians"] == 0
    assert out["pillar"]["opacity_median"] is None


def test_training_view_score_is_the_selection_iou_on_the_views_instance_maps():
    from benchmark.protocol.ceiling import training_view_score
    from trase.segment import render_alpha

    gm, deform, ids, views = tiny_scene(n_per=20)
    maps = [_instance_map(gm, deform, ids, v) for v in views[:3]]
    cams = [v.camera for v in views[:3]]
    sel = ids == 0  # the gaussians of object id 1
    got = training_view_score(gm, deform, sel, cams, maps, [1], render_alpha, 0.5)
    ious = []
    for cam, m in zip(cams, maps):
        pred, truth = render_alpha(gm, deform, sel, cam) >= 0.5, m == 1
        ious.append((pred & truth).sum() / (pred | truth).sum())
    assert got["n_views"] == 3 and got["miou"] == round(float(np.mean(ious)), 4)
    assert got["miou"] > 0.9
    nothing = training_view_score(gm, deform, np.zeros_like(sel), cams, maps, [1], render_alpha, 0.5)
    assert nothing["miou"] == 0.0
    assert training_view_score(gm, deform, sel, [], [], [1], render_alpha, 0.5) == {"miou": None, "n_views": 0}
