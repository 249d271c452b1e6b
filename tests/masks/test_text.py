"""The text-to-mask adapter: the real transformers classes, small and untrained (no download);
a detector that returns known boxes drives the rest."""

import numpy as np
import pytest

pytest.importorskip("transformers")

from masks.text import Detection, SamBoxSegmenter, TextModels, TextPromptError, TextSegmenter
from tests.masks.text_models import tiny_owlv2, tiny_sam

IMAGE = (np.random.default_rng(0).random((48, 64, 3)) * 255).astype(np.uint8)


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("text-models")
    return tiny_owlv2(root / "owl"), tiny_sam(root / "sam")


class KnownBoxes:
    def __init__(self, boxes):
        self.boxes, self.seen = boxes, []

    def detect(self, image, phrase):
        self.seen.append(phrase)
        return list(self.boxes)


def test_models_load_from_folders_and_an_untrained_detector_finds_nothing(folders):
    seg = TextSegmenter.load(TextModels(str(folders[0]), str(folders[1])))
    dets = seg.detector.detect(IMAGE, "the cup")
    assert all(isinstance(d, Detection) and d.box[2] > d.box[0] for d in dets)
    assert seg.best(IMAGE, "the cup") is None  # an untrained OWLv2 scores ~0 everywhere
    with pytest.raises(TextPromptError, match=r"^view 3: nothing matches 'the cup' \(no box scored >= 0.1\)$"):
        seg.find(IMAGE, "  the   cup ", where="view 3")


def test_sam_turns_the_best_box_into_a_mask_of_the_image_size(folders):
    boxes = KnownBoxes([Detection((10, 8, 40, 30), 0.3), Detection((0, 0, 5, 5), 0.9), Detection((1, 1, 2, 2), 0.05)])
    seg = TextSegmenter(boxes, SamBoxSegmenter(folders[1]), min_score=0.1)
    assert seg.best(IMAGE, "the ball").box == (10, 8, 40, 30)  # detectors return best first; the first kept
    mask = seg.segmenter.segment(IMAGE, (10, 8, 40, 30))
    assert mask.shape == (48, 64) and mask.dtype == bool
    assert boxes.seen == ["the ball"]


def test_float_and_rgba_images_are_accepted_and_wrong_shapes_refused(folders):
    seg = TextSegmenter(KnownBoxes([]), SamBoxSegmenter(folders[1]))
    assert seg.best(np.dstack([IMAGE / 255.0, np.ones((48, 64))]), "the ring") is None
    with pytest.raises(TextPromptError, match=r"an \[H, W, 3\] image, got shape \(48, 64\)"):
        seg.best(IMAGE[..., 0], "the ring")
    with pytest.raises(TextPromptError, match="needs words"):
        seg.best(IMAGE, "   ")


def test_an_empty_mask_is_a_one_line_error():
    class Nothing:
        def segment(self, image, box):
            return np.zeros(image.shape[:2], bool)

    seg = TextSegmenter(KnownBoxes([Detection((1, 1, 9, 9), 0.8)]), Nothing())
    with pytest.raises(TextPromptError, match=r"^the image: the box of 'the cup' \(score 0.80\) gave an empty mask$"):
        seg.find(IMAGE, "the cup")


def test_missing_and_unreadable_models_are_one_line_errors(tmp_path, folders):
    from masks.hub import model_folder
    from masks.maskset import MaskError

    with pytest.raises(MaskError, match=r"no such folder, and not a hub id"):
        model_folder(str(tmp_path / "nowhere" / "x" / "y"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(MaskError, match=r"empty: not a model folder \(no config.json\)"):
        model_folder(str(tmp_path / "empty"))
    import shutil

    broken = shutil.copytree(folders[1], tmp_path / "broken")
    (broken / "model.safetensors").write_bytes(b"not a safetensors file")
    with pytest.raises(TextPromptError, match=r"broken: cannot load the segmenter \("):
        SamBoxSegmenter(broken)
