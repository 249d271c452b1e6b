import sys
import types

import numpy as np
import pytest
from mask_testutils import best_iou, shapes_image

import masks
from imagefiles import ImageFileError
from masks import MaskError
from masks.generators import make_generator, min_area_for
from masks.generators.classical import ClassicalGenerator
from masks.generators.sam import PAPER_SETTINGS, SamGenerator, maskset_from_sam_records
from masks.generators.synthetic import SyntheticGenerator, SyntheticNoise


def test_min_area_scales_with_image_size():
    assert min_area_for(536, 960) == 100
    assert min_area_for(120, 160) == 4
    assert min_area_for(1, 1) == 1


# ------------------------------------------------------------------ classical
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_classical_covers_known_regions(seed):
    img, gt = shapes_image(120, 160, seed=seed)
    ms = ClassicalGenerator().generate(img, key="x")
    assert ms.generator == "classical" and ms.score is not None
    assert ((ms.score >= 0) & (ms.score <= 1)).all()
    ious = [best_iou(ms.masks, gt == i) for i in np.unique(gt) if i > 0 and (gt == i).sum() >= 50]
    assert np.mean(np.array(ious) >= 0.8) >= 0.75, ious
    # overlapping, multi-granularity: some pixel is covered by more than one mask
    assert ms.coverage.max() >= 2
    assert ms.area.min() >= min_area_for(120, 160) and ms.area.max() < 120 * 160


def test_classical_with_slic_and_deterministic():
    img, _ = shapes_image(60, 80, seed=4, n_objects=4)
    a = ClassicalGenerator(slic=True).generate(img)
    b = ClassicalGenerator(slic=True).generate(img)
    assert a.equals(b) and a.n > 0
    assert a.n >= ClassicalGenerator().generate(img).n
    with pytest.raises(MaskError):
        ClassicalGenerator(scales=())
    with pytest.raises(MaskError):
        ClassicalGenerator().generate(np.zeros((4, 4, 7), np.uint8))


def test_classical_flat_image_gives_no_masks():
    ms = ClassicalGenerator().generate(np.full((30, 40, 3), 128, np.uint8))
    assert ms.n == 0 and ms.masks.shape == (0, 30, 40)
    assert np.array_equal(ms.pixel_mean_area, np.zeros((30, 40), np.float32))


# ------------------------------------------------------------------ synthetic
def _ids():
    ids = np.zeros((60, 80), np.int32)
    ids[5:30, 5:35] = 1
    ids[5:30, 35:60] = 2  # touches 1
    ids[35:55, 10:70] = 3
    return ids


def test_synthetic_clean_is_exact():
    ids = _ids()
    ms = SyntheticGenerator(noise=SyntheticNoise.clean()).generate(None, key="a", instance_map=ids)
    kinds = ms.info["kinds"]
    assert sorted(kinds) == ["background", "whole", "whole", "whole"]
    for i in (1, 2, 3):
        assert best_iou(ms.masks, ids == i) == 1.0
    assert np.allclose(ms.score, 1.0)


def test_synthetic_noise_properties():
    ids = _ids()
    gen = SyntheticGenerator(seed=3, p_split=1.0, p_parts_only=0.0, p_merge=1.0, p_drop=0.0,
                             jitter_px=1.5)
    ms = gen.generate(None, key="cam0/0001", instance_map=ids)
    kinds = ms.info["kinds"]
    assert kinds.count("whole") == 3 and kinds.count("part") >= 6 and "merge" in kinds
    # parts of one instance tile it (before jitter) and are smaller than the whole
    for k, m, src in zip(kinds, ms.masks, ms.info["source_ids"]):
        if k == "part":
            assert m.sum() < (ids == src[0]).sum() * 0.9
        if k == "merge":
            assert src in ([1, 2],)  # 3 touches nobody
    # jitter changes boundaries but keeps the mask close to its source
    wholes = [m for k, m in zip(kinds, ms.masks) if k == "whole"]
    ious = [best_iou(np.stack(wholes), ids == i) for i in (1, 2, 3)]
    assert all(0.75 < v for v in ious) and min(ious) < 1.0
    # deterministic per (seed, key); different keys give different masks
    again = gen.generate(None, key="cam0/0001", instance_map=ids)
    assert again.equals(ms)
    other = gen.generate(None, key="cam0/0002", instance_map=ids)
    assert not (other.masks.shape == ms.masks.shape and np.array_equal(other.masks, ms.masks))


def test_synthetic_drop_and_errors():
    ids = _ids()
    ms = SyntheticGenerator(p_drop=1.0, p_background=0.0).generate(None, "k", ids)
    assert ms.n == 0
    with pytest.raises(MaskError):
        SyntheticGenerator().generate(None, "k", None)
    with pytest.raises(MaskError):
        SyntheticGenerator().generate(None, "k", ids.astype(float))
    with pytest.raises(MaskError):
        SyntheticNoise(p_drop=2.0)


# ------------------------------------------------------------------------ SAM
def _fake_records(h, w):
    a = np.zeros((h, w), bool)
    a[:5, :5] = True
    b = np.zeros((h, w), bool)
    b[3:, 2:] = True
    full = np.ones((h, w), bool)
    return [
        {"segmentation": a, "area": 25, "predicted_iou": 0.9, "stability_score": 0.97},
        {"segmentation": full, "area": h * w, "predicted_iou": 0.99, "stability_score": 0.99},
        {"segmentation": b, "area": int(b.sum()), "predicted_iou": 0.91, "stability_score": 0.96},
    ]


def test_sam_records_conversion():
    ms = maskset_from_sam_records(_fake_records(10, 12), 10, 12)
    assert ms.n == 2 and ms.generator == "sam"  # the full-image mask is dropped
    assert np.allclose(ms.score, [0.97, 0.96]) and ms.info["predicted_iou"] == [0.9, 0.91]
    with pytest.raises(MaskError):
        maskset_from_sam_records([{"segmentation": {"counts": "x"}}], 10, 12)
    with pytest.raises(MaskError):
        maskset_from_sam_records([{"segmentation": np.zeros((3, 3), bool)}], 10, 12)


def test_sam_generator_with_fake_package(tmp_path, monkeypatch):
    ckpt = tmp_path / "sam_vit_h.pth"
    ckpt.write_bytes(b"fake")
    calls = {}

    class FakeModel:
        def to(self, device):
            calls["device"] = device
            return self

    class FakeAMG:
        def __init__(self, model, **kw):
            calls["kw"] = kw

        def generate(self, img):
            calls["img"] = img
            return _fake_records(*img.shape[:2])

    fake = types.SimpleNamespace(
        sam_model_registry={"vit_h": lambda checkpoint: calls.setdefault("ckpt", checkpoint) and FakeModel()},
        SamAutomaticMaskGenerator=FakeAMG,
    )
    monkeypatch.setitem(sys.modules, "segment_anything", fake)
    img = np.zeros((10, 12, 3), np.uint8)
    img[..., 0] = 200  # red channel
    gen = SamGenerator(ckpt, paper_bgr_quirk=True)
    ms = gen.generate(img, key="v")
    assert ms.n == 2 and calls["ckpt"] == str(ckpt) and calls["device"] == "cpu"
    for k, v in PAPER_SETTINGS.items():
        assert calls["kw"][k] == v
    assert calls["img"][0, 0, 2] == 200  # BGR quirk reversed the channels
    assert make_generator("sam", checkpoint=ckpt).model_type == "vit_h"


def test_sam_clear_errors(tmp_path, monkeypatch):
    with pytest.raises(MaskError, match="not found"):
        SamGenerator(tmp_path / "missing.pth")
    with pytest.raises(MaskError, match="model_type"):
        SamGenerator(tmp_path / "missing.pth", model_type="vit_x")
    ckpt = tmp_path / "c.pth"
    ckpt.write_bytes(b"x")
    monkeypatch.setitem(sys.modules, "segment_anything", None)  # import fails
    with pytest.raises(MaskError, match="segment-anything"):
        SamGenerator(ckpt).generate(np.zeros((4, 4, 3), np.uint8))


# ------------------------------------------------------------- scene runner
class _View:
    def __init__(self, name, image_path):
        self.name, self.image_path = name, image_path


def test_generate_scene_masks_writes_and_skips(tmp_path):
    import cv2

    views = []
    ids = {}
    for i in range(3):
        img, gt = shapes_image(40, 50, seed=i, n_objects=3)
        p = tmp_path / f"img{i}.png"
        cv2.imwrite(str(p), img[..., ::-1])
        views.append(_View(f"cam0/{i:05d}", p))
        ids[f"cam0/{i:05d}"] = gt
    out = tmp_path / "out"
    paths = masks.generate_scene_masks(views, ClassicalGenerator(), out, progress=False)
    assert [p.name for p in paths] == [f"cam0__{i:05d}.masks" for i in range(3)]
    first = [masks.load(p) for p in paths]
    assert all(m.generator == "classical" and m.info["view"] == v.name for m, v in zip(first, views))
    mtimes = [p.stat().st_mtime_ns for p in paths]
    paths[1].unlink()
    masks.generate_scene_masks(views, ClassicalGenerator(), out, progress=False)
    assert paths[0].stat().st_mtime_ns == mtimes[0] and paths[1].exists()
    with pytest.raises(MaskError, match="already holds"):
        masks.generate_scene_masks(views, SyntheticGenerator(), out, progress=False, instance_maps=ids)
    with pytest.raises(MaskError, match="instance maps"):
        masks.generate_scene_masks(views, SyntheticGenerator(), tmp_path / "s", progress=False)
    sp = masks.generate_scene_masks(views, SyntheticGenerator(), tmp_path / "s", progress=True,
                                    instance_maps=ids)
    assert masks.load(sp[0]).generator == "synthetic"


def test_unreadable_image_is_one_line_error(tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"nope")
    with pytest.raises(ImageFileError, match="bad.png: cannot decode image"):
        masks.generate_scene_masks([_View("a", bad)], ClassicalGenerator(), tmp_path / "o",
                                   progress=False)
