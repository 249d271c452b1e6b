"""Segmentation scores for novel views: per-frame IoU and accuracy, mIoU/mAcc, pooled IoU.

Two metric versions. Published numbers were made with the public evaluation script of the
paper's code (``metrics_segmentation.py``), whose rules we reproduce but do not want to
inherit silently:

* ``official`` (label ``official/script1``): that script, rule for rule, so its numbers are the
  published kind.

  - Pairing: every image file in the ground-truth folder is a frame; its prediction is the file
    of the *same name* in the prediction folder (``00000.png`` <-> ``00000.png``). A frame with
    no prediction file is skipped (not scored) and listed in ``missing``; a prediction with no
    ground truth is ignored and listed in ``extra``.
  - Prediction: read as stored (PIL); a pixel is foreground when the mean of *all* its channels,
    alpha included, is non-zero: any grey fringe of an anti-aliased mask, any colour, and any
    opaque pixel of an RGBA file count. A one-channel file is outside the script (it averages
    the last axis, the image's width, and fails); here its non-zero pixels are foreground and
    the result says so (``notes``).
  - Ground truth: read as stored, never binarised. IoU counts its non-zero pixels as foreground;
    accuracy counts the pixels where the prediction (0 or 1) *equals the stored value*, so the
    foreground of a 0/255 file is never correct. That accuracy is the metric's; the pixel
    accuracy (ground truth read as non-zero = foreground) is given beside it (``pixel_acc``,
    ``pixel_macc``) and a note says when the two differ. A ground truth with channels is an
    error (the script fails on it).
  - IoU of a frame whose union is empty is 0; mIoU and mAcc are plain means over the scored
    frames (when every scored frame has an empty union the script itself stops; 0 is given and
    a note says so).

* ``v1`` (label ``v1/bin2``, ours, the default): every mask is binarised by one rule
  (``binarize``: 0/1 and 0/255 masks are binary, grey levels are thresholded at half the
  range, and a mask that cannot be read as binary is an error naming the file); a frame with
  no prediction is scored as an empty prediction and listed in ``missing``; a prediction with
  no ground truth is an error; frames where prediction and ground truth are both empty have no
  IoU and are left out of mIoU (accuracy still counts them) and listed in ``both_empty``.

The label (``metric_version``) is recorded with every score and changes whenever a metric's
rules change, so results of different rules are never mixed unnoticed. ``bin1`` (before): both
metrics binarised every mask at half the range (a 0/1 mask read as empty) and scored missing
predictions as empty.
"""


from benchmark.scoring.folders import score_directories
from benchmark.scoring.reading import (
    BINARIZE_RULE,
    IMAGE_SUFFIXES,
    METRICS,
    OFFICIAL_RULE,
    OFFICIAL_SUFFIXES,
    ScoringError,
    binarize,
    metric_version,
    official_prediction,
    read_mask,
    read_official_ground_truth,
    read_official_prediction,
)
from benchmark.scoring.scores import FrameScore, ScoreResult, mean_over, score_frame, score_masks

__all__ = ["BINARIZE_RULE", "IMAGE_SUFFIXES", "METRICS", "OFFICIAL_RULE", "OFFICIAL_SUFFIXES", "FrameScore",
           "ScoreResult", "ScoringError", "binarize", "mean_over", "metric_version", "official_prediction",
           "read_mask", "read_official_ground_truth", "read_official_prediction", "score_directories",
           "score_frame", "score_masks"]
