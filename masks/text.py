"""Text -> 2D mask: an open-vocabulary detector finds boxes for a phrase, a box-prompted
segmenter turns the best box into a mask (the Grounded-SAM recipe the paper's text prompts use).

    seg = TextSegmenter(TextModels())             # OWLv2 boxes, SAM masks, fetched on first use
    found = seg.find(image, "the cup")            # a Found (mask [H, W] bool, box, score)

Why OWLv2 and SAM through ``transformers``: both are published there under Apache-2.0 with
configs and processors, so one library loads them by hub id or local folder, and tests build
the same classes small and untrained from their configs; Grounding DINO would serve as well but
is a heavier backbone for the same boxes. ``transformers`` is imported on first use only (the
``text`` extra). ``Detector`` and ``BoxSegmenter`` are protocols: a benchmark or a test may pass
its own (e.g. one that returns known boxes).
"""

from __future__ import annotations

import dataclasses
from typing import Protocol

import numpy as np

from masks.maskset import MaskError

DEFAULT_DETECTOR = "google/owlv2-base-patch16-ensemble"  # 155M parameters, 620 MB, Apache-2.0
DEFAULT_SEGMENTER = "facebook/sam-vit-base"  # 94M parameters, 375 MB, Apache-2.0
# OWLv2's own examples keep boxes scored above 0.1 (its scores are sigmoid, not softmax)
MIN_SCORE = 0.1


class TextPromptError(MaskError):
    user_facing = True


@dataclasses.dataclass(frozen=True)
class Detection:
    box: tuple[float, float, float, float]  # x0, y0, x1, y1 in pixels
    score: float


@dataclasses.dataclass(frozen=True)
class Found:
    """The mask a phrase found in one image, with the box and score it came from."""

    mask: np.ndarray  # [H, W] bool
    box: tuple[float, float, float, float]
    score: float
    phrase: str


class Detector(Protocol):
    def detect(self, image: np.ndarray, phrase: str) -> list[Detection]: ...


class BoxSegmenter(Protocol):
    def segment(self, image: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray: ...


@dataclasses.dataclass(frozen=True)
class TextModels:
    """Which models make a text prompt's mask: hub ids or local folders."""

    detector: str = DEFAULT_DETECTOR
    segmenter: str = DEFAULT_SEGMENTER
    min_score: float = MIN_SCORE
    device: str = "cpu"


def _transformers():
    try:
        import transformers
    except ImportError:
        raise TextPromptError("text prompts need the 'text' extra: pip install 'trase-bench[text]'") from None
    return transformers


def _load_pair(kind: str, folder, processor_class: str, model_class: str, device: str):
    """(processor, model in eval mode on ``device``) of the transformers classes named, from
    ``folder``; anything that fails to load is one line naming the folder."""
    tf = _transformers()
    loaded = []
    for what, cls in ((f"{kind}'s processor", processor_class), (kind, model_class)):
        try:
            loaded.append(getattr(tf, cls).from_pretrained(str(folder)))
        except Exception as exc:  # noqa: BLE001 - a corrupt checkpoint raises many kinds (safetensors', torch's)
            raise TextPromptError(f"{folder}: cannot load the {what} ({type(exc).__name__}: "
                                  f"{str(exc).splitlines()[0] if str(exc) else 'no detail'})") from None
    processor, model = loaded
    return processor, model.to(device).eval()


class OwlDetector:
    """OWLv2 (``Owlv2ForObjectDetection``): boxes for a phrase, best first."""

    def __init__(self, folder, device: str = "cpu") -> None:
        self.processor, self.model = _load_pair("detector", folder, "Owlv2Processor", "Owlv2ForObjectDetection", device)
        self.device = device

    def detect(self, image: np.ndarray, phrase: str) -> list[Detection]:
        import torch

        H, W = image.shape[:2]
        inputs = self.processor(text=[[phrase]], images=image, return_tensors="pt").to(self.device)
        with torch.no_grad():
            out = self.model(**inputs)
        # OWLv2 pads the image to a square of its longer side: boxes come back in that square
        side = max(H, W)
        found = self.processor.post_process_grounded_object_detection(
            out, threshold=0.0, target_sizes=torch.tensor([[side, side]]))[0]
        boxes = found["boxes"].cpu().numpy().reshape(-1, 4)
        scores = found["scores"].cpu().numpy().reshape(-1)
        dets = [Detection(_clip_box(b, W, H), float(s)) for b, s in zip(boxes, scores)]
        return sorted((d for d in dets if d.box[2] > d.box[0] and d.box[3] > d.box[1]), key=lambda d: -d.score)


class SamBoxSegmenter:
    """SAM (``SamModel``) prompted with one box: the mask its IoU head scores best."""

    def __init__(self, folder, device: str = "cpu") -> None:
        self.processor, self.model = _load_pair("segmenter", folder, "SamProcessor", "SamModel", device)
        self.device = device

    def segment(self, image: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray:
        import torch

        inputs = self.processor(images=image, input_boxes=[[list(map(float, box))]], return_tensors="pt").to(self.device)
        with torch.no_grad():
            out = self.model(**inputs)
        masks = self.processor.image_processor.post_process_masks(
            out.pred_masks.cpu(), inputs["original_sizes"].cpu(), inputs["reshaped_input_sizes"].cpu())[0]
        best = int(out.iou_scores[0, 0].argmax())
        return masks[0, best].numpy().astype(bool)  # [H, W]


def _clip_box(box, W: int, H: int) -> tuple[float, float, float, float]:
    x0, y0, x1, y1 = (float(v) for v in box)
    return (min(max(x0, 0.0), W), min(max(y0, 0.0), H), min(max(x1, 0.0), W), min(max(y1, 0.0), H))


class TextSegmenter:
    """A phrase -> the mask of its best-scoring box in an image."""

    def __init__(self, detector: Detector, segmenter: BoxSegmenter, min_score: float = MIN_SCORE) -> None:
        self.detector, self.segmenter, self.min_score = detector, segmenter, float(min_score)

    @classmethod
    def load(cls, models: TextModels = TextModels(), cache_dir=None, progress: bool = True) -> TextSegmenter:
        """The models of ``models``, fetched into the cache on first use (masks.hub)."""
        from masks.hub import model_folder

        _transformers()
        det = OwlDetector(model_folder(models.detector, cache_dir, progress=progress), models.device)
        seg = SamBoxSegmenter(model_folder(models.segmenter, cache_dir, progress=progress), models.device)
        return cls(det, seg, models.min_score)

    def best(self, image: np.ndarray, phrase: str) -> Detection | None:
        """The phrase's best box in ``image`` scored at least min_score, else None."""
        phrase = _phrase(phrase)
        image = _rgb(image)
        dets = [d for d in self.detector.detect(image, phrase) if d.score >= self.min_score]
        return dets[0] if dets else None

    def find(self, image: np.ndarray, phrase: str, where: str = "the image") -> Found:
        """The mask of ``phrase`` in ``image``; a phrase found nowhere is a one-line error."""
        image, phrase = _rgb(image), _phrase(phrase)
        det = self.best(image, phrase)
        if det is None:
            raise TextPromptError(f"{where}: nothing matches {phrase!r} (no box scored >= {self.min_score})")
        return self.mask_of(image, phrase, det, where)

    def mask_of(self, image: np.ndarray, phrase: str, det: Detection, where: str = "the image") -> Found:
        """The segmenter's mask of the detection ``det`` of ``phrase`` in ``image``."""
        image = _rgb(image)
        mask = np.asarray(self.segmenter.segment(image, det.box), dtype=bool)
        if mask.shape != image.shape[:2]:
            raise TextPromptError(f"{where}: the segmenter's mask is {mask.shape}, the image {image.shape[:2]}")
        if not mask.any():
            raise TextPromptError(f"{where}: the box of {phrase!r} (score {det.score:.2f}) gave an empty mask")
        return Found(mask, det.box, det.score, _phrase(phrase))


def _phrase(phrase: str) -> str:
    text = " ".join(str(phrase).split())
    if not text:
        raise TextPromptError("a text prompt needs words (got an empty phrase)")
    return text


def _rgb(image: np.ndarray) -> np.ndarray:
    """[H, W, 3] uint8 (float images in [0, 1] are scaled; an alpha channel is dropped)."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise TextPromptError(f"a text prompt needs an [H, W, 3] image, got shape {img.shape}")
    img = img[..., :3]
    if img.dtype != np.uint8:
        img = (np.clip(np.nan_to_num(img.astype(np.float32)), 0.0, 1.0) * 255 + 0.5).astype(np.uint8)
    return img


__all__ = ["DEFAULT_DETECTOR", "DEFAULT_SEGMENTER", "MIN_SCORE", "BoxSegmenter", "Detection", "Detector", "Found",
           "OwlDetector", "SamBoxSegmenter", "TextModels", "TextPromptError", "TextSegmenter"]
