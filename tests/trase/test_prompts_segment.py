import json

import numpy as np
import pytest

from benchmark.protocol.oracle import oracle_clusters
from benchmark.protocol.prompts import (
    BenchmarkPrompts,
    interior_points,
    load_or_make_prompts,
    make_benchmark_prompts,
)
from tests.trase.helpers import exact_masks, object_alpha, tiny_scene
from trase.prompts import (
    Click,
    PromptError,
    click_to_cluster,
    lift_pixels,
    mask_to_clusters,
    window_weights,
)
from trase.segment import render_masks, select_gaussians


def test_interior_points_deterministic():
    gt = np.zeros((20, 30), bool)
    gt[2:9, 3:10] = True  # 7x7 square, centre (6, 5)
    gt[12:18, 15:29] = True  # bigger region first
    gt[0, 29] = True  # tiny region ignored
    pts = interior_points(gt, min_area=5)
    assert pts == [(17.5, 14.5), (6.5, 5.5)]  # larger region first; ties: first row-major
    assert len(pts) == 2 and pts == interior_points(gt, min_area=5)
    for u, v in pts:
        assert gt[int(v), int(u)]
    assert interior_points(np.zeros((4, 4), bool)) == []


def test_click_and_mask_prompt_find_object():
    gm, deform, ids, views = tiny_scene()
    cam = views[1].camera
    ms = exact_masks(gm, deform, ids, views[1])
    for k in range(2):
        obj = ms.masks[k]
        labels = ids  # perfect clustering: cluster = object id
        (u, v), = interior_points(obj, 1)[:1]
        assert click_to_cluster(gm, deform, cam, Click(u, v), labels) == k
        assert click_to_cluster(gm, deform, cam, Click(u, v), labels, rule="weight") == k
        assert mask_to_clusters(gm, deform, cam, obj, labels) == [k]
    # a click on empty background hits nothing
    alpha = object_alpha(gm, deform, ids, cam, 0) + object_alpha(gm, deform, ids, cam, 1)
    r, c = np.argwhere(alpha < 0.01)[0]
    assert lift_pixels(gm, deform, cam, np.array([[c + 0.5, r + 0.5]]))[0] == -1
    with pytest.raises(PromptError, match="mask prompt is"):
        mask_to_clusters(gm, deform, cam, np.ones((2, 2), bool), ids)


def test_render_masks_and_oracle():
    gm, deform, ids, views = tiny_scene()
    cams = [v.camera for v in views]
    gts = [exact_masks(gm, deform, ids, v).masks[0] for v in views]
    sel = select_gaussians(ids, [0])
    preds = render_masks(gm, deform, sel, cams)
    for p, g in zip(preds, gts):
        iou = (p & g).sum() / max((p | g).sum(), 1)
        assert iou > 0.8
    assert oracle_clusters(gm, deform, cams, gts, ids) == [0]
    none = render_masks(gm, deform, select_gaussians(ids, []), cams[:1])
    assert not none[0].any()
    keep = np.zeros(len(ids), bool)
    assert not select_gaussians(ids, [0, 1], keep).any()


def test_prompts_json_roundtrip(tmp_path):
    gm, deform, ids, views = tiny_scene()
    gts = [np.zeros((views[0].camera.height, views[0].camera.width), bool)] + [
        exact_masks(gm, deform, ids, v).masks[0] for v in views[1:]
    ]
    p = tmp_path / "prompts.json"
    a = load_or_make_prompts(p, views, lambda i: gts[i])
    assert a.view_index == 1 and len(a.clicks) >= 1  # first frame with non-empty GT
    b = load_or_make_prompts(p, views, lambda i: 1 / 0)  # reused, GT not read
    assert a.to_dict() == b.to_dict()
    p.write_text("{bad")
    with pytest.raises(PromptError, match="prompts.json: not valid JSON"):
        load_or_make_prompts(p, views, lambda i: gts[i])
    p.write_text(json.dumps({"version": 3}))
    with pytest.raises(PromptError, match="malformed"):
        load_or_make_prompts(p, views, lambda i: gts[i])
    p.write_text(json.dumps({"version": 1, "points": [[1, 1]]}))  # before clicks named their frame
    with pytest.raises(PromptError, match="prompts version 1 .expected 3.; delete it"):
        load_or_make_prompts(p, views, lambda i: gts[i])


def _frames(*boxes_per_frame, shape=(20, 30)):
    out = []
    for boxes in boxes_per_frame:
        m = np.zeros(shape, bool)
        for r0, r1, c0, c1 in boxes:
            m[r0:r1, c0:c1] = True
        out.append(m)
    return out


class _View:
    def __init__(self, i):
        from trase.camera import Camera, intrinsics

        self.name = f"v{i}"
        self.camera = Camera(intrinsics(20, 20, 15, 10), np.eye(4), 30, 20, time=i / 10, name=self.name)


def test_benchmark_prompts_click_every_object_in_the_first_frame_it_appears():
    # frame 0 empty; frame 1: object A; frame 2: A moved by a pixel; frame 3: A and a new B
    # far from A; frame 4: only B (A hidden); frame 5: B and a new C touching B (missed: one
    # merged mask per frame, no identities); frame 6: A back where it was (not new: linked to
    # every earlier frame, not only the one before)
    a, a2, b, c = (2, 8, 2, 8), (2, 8, 3, 9), (12, 18, 20, 26), (12, 18, 26, 29)
    gts = _frames([], [a], [a2], [a2, b], [b], [b, c], [a, b])
    views = [_View(i) for i in range(len(gts))]
    bp = make_benchmark_prompts(views, gts, min_area=4)
    assert [(c.view, c.view_index) for c in bp.clicks] == [("v1", 1), ("v3", 3)]
    assert bp.frames() == [1, 3] and bp.view_index == 1 and bp.source == "gt-first-appearance"
    u, v = bp.clicks[1].u, bp.clicks[1].v
    assert gts[3][int(v), int(u)] and 12 <= v < 18 and 20 <= u < 26  # on B, in B's first frame
    assert bp.clicks[1].time == pytest.approx(0.3)
    # the earlier rule: the first non-empty frame only; B never gets a click
    old = make_benchmark_prompts(views, gts, min_area=4, rule="gt-first-frame")
    assert [c.view for c in old.clicks] == ["v1"]
    back = BenchmarkPrompts.from_dict(json.loads(json.dumps(bp.to_dict())))
    assert back.clicks == bp.clicks
    with pytest.raises(PromptError, match="unknown benchmark prompt rule"):
        make_benchmark_prompts(views, gts, rule="whatever")


def test_click_sets_click_the_same_objects_elsewhere_in_their_first_frames():
    a, a2, b, b2 = (2, 8, 2, 8), (2, 8, 3, 9), (10, 19, 18, 28), (10, 19, 17, 27)
    gts = _frames([], [a], [a2], [a2, b], [b2], [b2])
    views = [_View(i) for i in range(len(gts))]
    one = make_benchmark_prompts(views, gts, min_area=4)
    bp = make_benchmark_prompts(views, gts, min_area=4, click_sets=5)
    assert bp.clicks == one.clicks and one.alternatives == []  # set 0: the single-click protocol
    assert len(bp.alternatives) == 4 and all(len(cs) == 2 for cs in bp.alternatives)
    for j, cs in enumerate(bp.alternatives, start=1):
        for k, c in enumerate(cs):
            track = [1, 2, 3] if k == 0 else [3, 4, 5]  # A from frame 1, B from frame 3
            assert c.view_index == track[(j - 1) % 3] and c.view == f"v{c.view_index}"
            gt = gts[c.view_index]
            assert gt[int(c.v), int(c.u)]  # on the object
            box = (a, a2, a2)[track.index(c.view_index)] if k == 0 else (b, b2, b2)[track.index(c.view_index)]
            assert box[0] <= c.v < box[1] and box[2] <= c.u < box[3]  # on this object, not the other
    # the interior half of B (9x10): never on its one-pixel rim
    assert all(11 <= c.v < 18 for cs in bp.alternatives for c in cs[1:])
    assert make_benchmark_prompts(views, gts, min_area=4, click_sets=5) == bp  # deterministic
    sets = bp.click_sets()
    assert len(sets) == 5 and sets[0].clicks == bp.clicks and sets[3].clicks == bp.alternatives[2]
    back = BenchmarkPrompts.from_dict(json.loads(json.dumps(bp.to_dict())))
    assert back == bp
    d = bp.to_dict()
    d["alternatives"][0] = d["alternatives"][0][:1]
    with pytest.raises(PromptError, match="malformed prompts file.*another number of clicks"):
        BenchmarkPrompts.from_dict(d)
    with pytest.raises(PromptError, match="click_sets=0"):
        make_benchmark_prompts(views, gts, click_sets=0)
    # an object seen in one frame only: every set clicks it there
    short = make_benchmark_prompts(views[:2], gts[:2], min_area=4, click_sets=3)
    assert [c.view_index for cs in short.alternatives for c in cs] == [1, 1]
    first_frame = make_benchmark_prompts(views, gts, min_area=4, rule="gt-first-frame", click_sets=4)
    assert [c.view_index for c in first_frame.clicks] == [1]
    assert [cs[0].view_index for cs in first_frame.alternatives] == [1, 2, 3]


def test_render_rule_visible_drops_occluded_parts():
    """Looking along x, blob 1 hides most of blob 0: 'alone' (paper) predicts blob 0's whole
    outline, 'visible' only what is seen, which is what a view's ground truth marks."""
    from tests.trase.helpers import TinyView
    from trase.camera import Camera, intrinsics, look_at
    from trase.segment import SegmentError

    gm, deform, ids, _ = tiny_scene()
    cam = Camera(intrinsics(30, 30, 20, 15), look_at([3.2, 0.3, 0.2], [0, 0, 0]), 40, 30, time=0.0, name="side")
    seen = exact_masks(gm, deform, ids, TinyView("side", cam)).masks[0]  # blob 0 where it is visible
    sel = select_gaussians(ids, [0])
    alone = render_masks(gm, deform, sel, [cam])[0]
    visible = render_masks(gm, deform, sel, [cam], rule="visible")[0]
    assert visible.sum() < 0.8 * alone.sum() and not (visible & ~alone).any()
    iou = lambda a, b: (a & b).sum() / max((a | b).sum(), 1)
    assert iou(visible, seen) > 0.9 > iou(alone, seen)
    assert not render_masks(gm, deform, select_gaussians(ids, []), [cam], rule="visible")[0].any()
    with pytest.raises(SegmentError, match="unknown segmentation rule 'x'"):
        render_masks(gm, deform, sel, [cam], rule="x")


def test_front_click_picks_the_nearest_cluster_holding_a_share_of_the_weight():
    """A semi-transparent front sheet holding ~0.42 of the weight under the cursor, the wall
    behind it the rest, the features following the wall: "weight" and "feature" choose the
    wall, "front" the sheet; a faint floater before the sheet holding less than the share is
    passed over (chosen only at a share below its own), and at a share above the sheet's the
    wall is chosen again."""
    import torch

    gm, labels, cam = _semi_transparent_front()
    n_front = int((labels == 0).sum())
    with torch.no_grad():
        gm.opacity_logits[:n_front] = -2.0  # opacity ~0.12 per gaussian: the sheet holds ~0.42
    click = Click(16.0, 12.0)
    idx, w = window_weights(gm, None, cam, click.u, click.v, 0.5, 1)
    share = np.bincount(labels[idx], weights=w) / w.sum()
    assert 0.25 < share[0] < 0.5  # the sheet: a share, not the most
    feats = np.zeros((len(labels), 4), np.float32)
    feats[labels == 0, 0] = 1.0
    feats[labels == 1, 1] = 1.0
    assert click_to_cluster(gm, None, cam, click, labels, rule="weight") == 1
    assert click_to_cluster(gm, None, cam, click, labels, rule="feature", features=feats) == 1
    assert click_to_cluster(gm, None, cam, click, labels, rule="front", front_share=0.25) == 0
    assert click_to_cluster(gm, None, cam, click, labels, rule="front", front_share=share[0] + 0.01) == 1
    # the floater (cluster 2 here), moved before the sheet on the axis: nearest, almost no weight
    floater = labels.copy()
    floater[-1] = 2
    with torch.no_grad():
        gm.means[-1] = torch.tensor([0.0, -3.0, 0.0])  # depth 1, the sheet's 2; opacity 0.02
    idx, w = window_weights(gm, None, cam, click.u, click.v, 0.5, 1)
    floater_share = w[floater[idx] == 2].sum() / w.sum()
    assert 0 < floater_share < 0.05
    assert click_to_cluster(gm, None, cam, click, floater, rule="front", front_share=0.25) == 0
    assert click_to_cluster(gm, None, cam, click, floater, rule="front", front_share=floater_share / 2) == 2
    # off the image, nothing clustered, a bad share: nothing or a clear error
    assert click_to_cluster(gm, None, cam, Click(-1.0, 3.0), labels, rule="front") == -1
    assert click_to_cluster(gm, None, cam, click, np.full_like(labels, -1), rule="front") == -1
    with pytest.raises(PromptError, match="front_share must be in"):
        click_to_cluster(gm, None, cam, click, labels, rule="front", front_share=0.0)


def _semi_transparent_front():
    """A semi-transparent front sheet (cluster 0) at depth 2 before an opaque back sheet
    (cluster 1) at depth 6, plus one faint cluster-1 floater on the optical axis at depth 3.5,
    near the expected depth there (weights ~0.6 / 0.4: 0.6 * 2 + 0.4 * 6 ~ 3.6), as
    reconstructions leave between surfaces."""
    import torch

    from trase.camera import Camera, intrinsics, look_at
    from trase.gaussians import GaussianModel, inverse_sigmoid

    g = np.mgrid[-1:1.01:0.25, -1:1.01:0.25].reshape(2, -1).T  # [81, 2] grid in x, z
    front = np.c_[g[:, 0], np.full(len(g), -2.0), g[:, 1]]
    back = np.c_[g[:, 0] * 3, np.full(len(g), 2.0), g[:, 1] * 3]
    means = np.vstack([front, back, [[0.0, -0.5, 0.0]]])
    n = len(means)
    labels = np.r_[np.zeros(len(g)), np.ones(len(g)), [1]].astype(np.int64)
    scales = np.r_[np.full(len(g), 0.2), np.full(len(g), 0.6), [0.05]]
    opac = np.r_[np.full(len(g), 0.2), np.full(len(g), 0.99), [0.02]]
    gm = GaussianModel(torch.tensor(means, dtype=torch.float32),
                       torch.log(torch.tensor(scales, dtype=torch.float32))[:, None].repeat(1, 3),
                       torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
                       inverse_sigmoid(torch.tensor(opac, dtype=torch.float32)),
                       torch.rand(n, 1, 3))
    cam = Camera(intrinsics(20, 20, 16, 12), look_at([0.0, -4.0, 0.0], [0, 0, 0]), 32, 24, name="c")
    return gm, labels, cam


def test_weight_click_picks_what_is_rendered_under_the_cursor():
    gm, labels, cam = _semi_transparent_front()
    click = Click(16.0, 12.0)  # the optical axis
    assert click_to_cluster(gm, None, cam, click, labels, rule="depth") == 1  # lands on the floater
    assert click_to_cluster(gm, None, cam, click, labels, rule="weight") == 0
    assert click_to_cluster(gm, None, cam, click, labels, rule="weight", radius=0) == 0
    # off the image or on an empty scene: nothing; a bad rule or radius: a clear error
    assert click_to_cluster(gm, None, cam, Click(-1.0, 3.0), labels, rule="weight") == -1
    assert click_to_cluster(gm, None, cam, Click(1.0, 1.0), labels, rule="weight", min_alpha=1.01) == -1
    with pytest.raises(PromptError, match="unknown click rule 'x'"):
        click_to_cluster(gm, None, cam, click, labels, rule="x")
    with pytest.raises(PromptError, match="radius must be >= 0"):
        click_to_cluster(gm, None, cam, click, labels, rule="weight", radius=-1)


def test_feature_click_picks_the_cluster_whose_feature_is_rendered_under_the_cursor():
    """A fainter front sheet: most of the weight under the cursor is the back sheet's, so the
    weight rule chooses it; the back gaussians behind the front one carry features pulled to
    the front's (as contrastive training leaves them where the masks say "front"), so the
    feature rendered there is the front cluster's, and the feature rule chooses it."""
    import torch

    gm, labels, cam = _semi_transparent_front()
    n_front = int((labels == 0).sum())
    with torch.no_grad():
        gm.opacity_logits[:n_front] = -3.0  # opacity ~0.05
    click = Click(16.0, 12.0)
    assert click_to_cluster(gm, None, cam, click, labels, rule="weight") == 1
    feats = np.zeros((len(labels), 4), np.float32)
    feats[labels == 0, 0] = 1.0
    feats[labels == 1, 1] = 1.0
    # one-hot features: the rendered feature points where the weight is
    assert click_to_cluster(gm, None, cam, click, labels, rule="feature", features=feats) == 1
    xyz = gm.means.detach().numpy()
    behind = (labels == 1) & (np.abs(xyz[:, 0]) < 1.0) & (np.abs(xyz[:, 2]) < 1.0)
    assert 0 < behind.sum() < (labels == 1).sum() / 2
    feats[behind] = [0.9, 0.1, 0.0, 0.0]
    assert click_to_cluster(gm, None, cam, click, labels, rule="feature", features=feats) == 0
    assert click_to_cluster(gm, None, cam, click, labels, rule="feature", features=feats, radius=0) == 0
    # no surface, no feature, no cluster: nothing; missing or mismatched features: a clear error
    assert click_to_cluster(gm, None, cam, Click(1.0, 1.0), labels, rule="feature", features=feats,
                            min_alpha=1.01) == -1
    assert click_to_cluster(gm, None, cam, click, labels, rule="feature", features=np.zeros_like(feats)) == -1
    assert click_to_cluster(gm, None, cam, click, np.full_like(labels, -1), rule="feature", features=feats) == -1
    with pytest.raises(PromptError, match="needs the gaussians' features"):
        click_to_cluster(gm, None, cam, click, labels, rule="feature")
    with pytest.raises(PromptError, match="features have 3 rows for"):
        click_to_cluster(gm, None, cam, click, labels, rule="feature", features=feats[:3])


def test_feature_click_reads_the_models_own_features():
    """The editor's models carry their features on the gaussians: no argument needed."""
    import torch

    from trase.gaussians import GaussianModel

    gm, labels, cam = _semi_transparent_front()
    feats = np.zeros((len(labels), 2), np.float32)
    feats[np.arange(len(labels)), labels] = 1.0
    g = GaussianModel(gm.means, gm.log_scales, gm.quats, gm.opacity_logits, gm.sh, torch.from_numpy(feats))
    click = Click(16.0, 12.0)
    assert click_to_cluster(g, None, cam, click, labels, rule="feature") == \
        click_to_cluster(gm, None, cam, click, labels, rule="feature", features=feats) == 0


def test_mask_rules_cover_every_part_share_only_large_ones():
    """An object cut into a large and a small cluster: ``cover`` (each cluster's share inside the
    mask) chooses both parts, ``share`` (each cluster's share of the mask) only the parts above
    its threshold; a neighbour the mask grazes is chosen by neither."""
    import cv2

    gm, deform, ids, views = tiny_scene()
    cam = views[1].camera
    obj = exact_masks(gm, deform, ids, views[1]).masks[1]
    labels = ids.copy()
    xs = gm.means[:, 0].detach().numpy()
    part = (ids == 1) & (xs > np.quantile(xs[ids == 1], 0.8))  # the object's outer fifth
    labels[part] = 2
    grazing = cv2.dilate(obj.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert mask_to_clusters(gm, deform, cam, grazing, labels, rule="cover") == [1, 2]
    assert mask_to_clusters(gm, deform, cam, grazing, labels, rule="share", min_share=0.4) == [1]
    # low enough for the small part, ``share`` takes the grazed neighbour as well
    assert mask_to_clusters(gm, deform, cam, grazing, labels, rule="share", min_share=0.01) == [0, 1, 2]
    # a mask on half of the small part only: under min_cover of it
    assert 2 not in mask_to_clusters(gm, deform, cam, obj & (np.arange(obj.shape[1]) < 5)[None, :], labels,
                                     rule="cover")
    assert mask_to_clusters(gm, deform, cam, np.zeros_like(obj), labels) == []
    with pytest.raises(PromptError, match="unknown mask rule"):
        mask_to_clusters(gm, deform, cam, obj, labels, rule="best")


def test_share_counts_the_distinct_gaussians_hit_not_the_pixels(monkeypatch):
    """The paper's rule counts a cluster's associated gaussians: eight pixels on one gaussian of
    cluster 0 weigh as much as one pixel on it, so two distinct gaussians of cluster 1 hold the
    larger share."""
    from trase import prompts

    monkeypatch.setattr(prompts, "lift_pixels", lambda *a, **k: np.array([0] * 8 + [1, 2, -1]))
    cam = type("C", (), {"height": 4, "width": 4})()
    mask = np.ones((4, 4), bool)
    labels = np.array([0, 1, 1])
    assert prompts.mask_to_clusters(None, None, cam, mask, labels, rule="share", min_share=0.5) == [1]
    assert prompts.mask_to_clusters(None, None, cam, mask, labels, rule="share", min_share=0.3) == [0, 1]


def test_iou_rule_takes_the_cluster_that_mixes_the_object_with_its_surroundings():
    """An object whose gaussians share a cluster with the floor: no cluster has 70% of its pixels
    inside the object's mask, so ``cover`` chooses nothing; ``iou`` chooses the mixed cluster
    because it raises the IoU with the mask, and leaves out the floor's own cluster."""
    gm, deform, ids, views = tiny_scene()
    cam = views[1].camera
    obj = exact_masks(gm, deform, ids, views[1]).masks[1]
    labels = ids.copy()
    rng = np.random.default_rng(0)
    floor = np.flatnonzero(ids == 0)
    labels[rng.choice(floor, floor.size // 2, replace=False)] = 1  # half the floor joins the object
    assert mask_to_clusters(gm, deform, cam, obj, labels, rule="cover") == []
    assert mask_to_clusters(gm, deform, cam, obj, labels) == [1]  # iou, the default
    assert mask_to_clusters(gm, deform, cam, np.zeros_like(obj), labels, rule="iou") == []


def test_best_iou_clusters_is_the_best_subset():
    """The prefix by in/out ratio is the subset of largest IoU (brute force over small cases)."""
    import itertools

    from trase.prompts import best_iou_clusters

    rng = np.random.default_rng(1)
    for _ in range(200):
        k = int(rng.integers(1, 7))
        inside = rng.integers(0, 20, k).astype(float)
        outside = rng.integers(0, 20, k).astype(float)
        area = float(inside.sum() + rng.integers(0, 10))

        def iou(sel, inside=inside, outside=outside, area=area):
            return inside[list(sel)].sum() / (area + outside[list(sel)].sum()) if sel else 0.0

        best = max(iou(c) for n in range(k + 1) for c in itertools.combinations(range(k), n))
        assert iou(best_iou_clusters(inside, outside, area)) == pytest.approx(best)
