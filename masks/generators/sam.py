"""Adapter over segment-anything's automatic mask generator, with the paper's settings.

The paper (its extract_masks.py) runs ``SamAutomaticMaskGenerator(points_per_side=32,
pred_iou_thresh=0.88, stability_score_thresh=0.95, box_nms_thresh=0.7, crop_n_layers=0,
crop_n_points_downscale_factor=1, min_mask_region_area=100)`` on a ViT-H model and drops masks
that are empty or cover the whole image. Two quirks of the public script are recorded, not
copied by default:
  * it feeds ``cv2.imread`` output, i.e. BGR, to a model trained on RGB
    (``paper_bgr_quirk=True`` reproduces that);
  * it stores no scores. We keep SAM's ``stability_score`` as the score (the paper's "by
    score" ablation uses it) and its ``predicted_iou`` in ``info``.

``segment_anything`` is imported on first use; a missing package or checkpoint is a one-line
``MaskError``. Install with ``pip install 'trase-bench[sam]'``; the checkpoint is a local file, or
the official one fetched by ``masks.checkpoints.sam_checkpoint`` (``masks.model`` in a run).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from masks.generators.base import check_image
from masks.maskset import MaskError, MaskSet

PAPER_SETTINGS = {
    "points_per_side": 32,
    "pred_iou_thresh": 0.88,
    "stability_score_thresh": 0.95,
    "box_nms_thresh": 0.7,
    "crop_n_layers": 0,
    "crop_n_points_downscale_factor": 1,
    "min_mask_region_area": 100,
}
MODEL_TYPES = ("vit_h", "vit_l", "vit_b", "default")


def maskset_from_sam_records(records: list[dict], height: int, width: int,
                             info: dict | None = None) -> MaskSet:
    """Convert ``SamAutomaticMaskGenerator.generate`` output (binary_mask mode) to a MaskSet.

    Drops masks with a single value (empty or full image) as the paper does. Score =
    stability_score; predicted_iou goes to ``info["predicted_iou"]``.
    """
    masks, stab, piou = [], [], []
    for i, r in enumerate(records):
        if "segmentation" not in r:
            raise MaskError(f"SAM record {i} has no 'segmentation' (use output_mode='binary_mask')")
        seg = np.asarray(r["segmentation"])
        if seg.dtype == object or seg.ndim != 2:
            raise MaskError(f"SAM record {i}: segmentation must be a [H, W] array "
                            "(output_mode='binary_mask'), got "
                            f"{type(r['segmentation']).__name__}")
        if seg.shape != (height, width):
            raise MaskError(f"SAM record {i}: mask shape {seg.shape} != image {(height, width)}")
        seg = seg.astype(bool)
        if not seg.any() or seg.all():
            continue
        masks.append(seg)
        stab.append(float(r.get("stability_score", np.nan)))
        piou.append(float(r.get("predicted_iou", np.nan)))
    info = dict(info or {})
    info["predicted_iou"] = piou
    if not masks:
        return MaskSet.empty(height, width, "sam", info)
    score = np.asarray(stab, np.float32)
    if np.isnan(score).any():  # a record without stability_score: no score for the set
        score = None
    return MaskSet.from_masks(np.stack(masks), score=score, generator="sam", info=info)


@dataclasses.dataclass
class SamGenerator:
    checkpoint: str | Path
    model_type: str = "vit_h"
    device: str = "cpu"
    points_per_side: int = 32
    pred_iou_thresh: float = 0.88
    stability_score_thresh: float = 0.95
    box_nms_thresh: float = 0.7
    crop_n_layers: int = 0
    crop_n_points_downscale_factor: int = 1
    min_mask_region_area: int = 100
    paper_bgr_quirk: bool = False  # feed BGR like the public script's cv2.imread
    name: str = dataclasses.field(default="sam", init=False)
    needs_instance_map: bool = dataclasses.field(default=False, init=False)

    def __post_init__(self) -> None:
        if self.model_type not in MODEL_TYPES:
            raise MaskError(f"SAM model_type {self.model_type!r} unknown; choose {', '.join(MODEL_TYPES)}")
        if self.checkpoint is None or str(self.checkpoint) == "":
            raise MaskError("SAM needs a checkpoint: pass --checkpoint PATH (e.g. sam_vit_h_4b8939.pth)")
        self.checkpoint = Path(self.checkpoint)
        if not self.checkpoint.is_file():
            raise MaskError(f"{self.checkpoint}: SAM checkpoint not found")
        self._amg = None

    def settings(self) -> dict:
        return {
            "checkpoint": self.checkpoint.name, "model_type": self.model_type,
            "points_per_side": self.points_per_side, "pred_iou_thresh": self.pred_iou_thresh,
            "stability_score_thresh": self.stability_score_thresh,
            "box_nms_thresh": self.box_nms_thresh, "crop_n_layers": self.crop_n_layers,
            "crop_n_points_downscale_factor": self.crop_n_points_downscale_factor,
            "min_mask_region_area": self.min_mask_region_area,
            "paper_bgr_quirk": self.paper_bgr_quirk,
        }

    def _generator(self):
        if self._amg is None:
            try:
                import segment_anything as sa
            except ImportError:
                raise MaskError("the SAM generator needs the segment-anything package: "
                                "pip install 'trase-bench[sam]'") from None
            try:
                model = sa.sam_model_registry[self.model_type](checkpoint=str(self.checkpoint))
            except Exception as exc:  # noqa: BLE001 - torch raises many types for a bad checkpoint
                msg = str(exc).strip().splitlines()
                raise MaskError(f"{self.checkpoint}: cannot load SAM {self.model_type} checkpoint "
                                f"({type(exc).__name__}: {msg[0][:160] if msg else ''})") from None
            model.to(self.device)
            self._amg = sa.SamAutomaticMaskGenerator(
                model=model,
                points_per_side=self.points_per_side,
                pred_iou_thresh=self.pred_iou_thresh,
                stability_score_thresh=self.stability_score_thresh,
                box_nms_thresh=self.box_nms_thresh,
                crop_n_layers=self.crop_n_layers,
                crop_n_points_downscale_factor=self.crop_n_points_downscale_factor,
                min_mask_region_area=self.min_mask_region_area,
                output_mode="binary_mask",
            )
        return self._amg

    def generate(self, image: np.ndarray | None, key: str = "",
                 instance_map: np.ndarray | None = None) -> MaskSet:
        img = check_image(image, "SAM generator")
        if self.paper_bgr_quirk:
            img = np.ascontiguousarray(img[..., ::-1])
        records = self._generator().generate(img)
        return maskset_from_sam_records(records, img.shape[0], img.shape[1],
                                        info={"key": key, "settings": self.settings()})
