"""Reading masks under each metric version: ``v1``'s one binarisation rule, and the public
script's reading (``official``) of predictions and ground truth (the rules: benchmark.scoring)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmark.errors import UserError

METRICS = ("v1", "official")
BINARIZE_RULE = "bin2"  # v1's rule, see ``binarize``
OFFICIAL_RULE = "script1"  # metrics_segmentation.py of yunjinli/TRASE (unchanged up to 9b25f77)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".npy")
OFFICIAL_SUFFIXES = tuple(s for s in IMAGE_SUFFIXES if s != ".npy")  # the script reads images only


class ScoringError(UserError):
    """Bad scoring input; the message is one line naming the file and the problem."""


def metric_version(metric: str) -> str:
    """The string recorded with every score: ``v1/bin2`` or ``official/script1``."""
    check_metric(metric)
    return f"{metric}/{BINARIZE_RULE if metric == 'v1' else OFFICIAL_RULE}"


def check_metric(metric: str) -> None:
    if metric not in METRICS:
        raise ScoringError(f"unknown metric {metric!r}; choose one of {', '.join(METRICS)}")


# --- v1: one binarisation rule ----------------------------------------------------------------


def binarize(mask: np.ndarray, name: str = "mask") -> np.ndarray:
    """Binarise a mask image to bool [H, W] by v1's rule (``bin2``).

    * Colour [H, W, 3|4]: the mean of the colour channels (alpha ignored) is the value; an RGBA
      image whose colour is all zero while its alpha varies is an error (the mask is in alpha).
      [H, W, 1] is one channel.
    * bool: as is (colour: mean >= 0.5).
    * Integers: a mask whose values are all 0 or 1 is binary (1 = foreground); all 0 or 255 is
      binary (255 = foreground); otherwise grey levels are thresholded at half the dtype's range
      (>= 128 for 8 bits), which needs the mask to reach that value: a mask whose values are
      neither 0/1 nor 0/255 and stay below half the range (a label map, a faint or a pure-red
      mask) cannot be read as binary and is an error, never an empty mask.
    * Floats: finite values in [0, 1] are thresholded at 0.5; 0/255 is binary; other values are
      an error.
    """
    a = np.asarray(mask)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if a.ndim == 3 and a.shape[2] in (3, 4):
        colour = a[..., :3]
        if a.shape[2] == 4 and not colour.any() and a[..., 3].min() != a[..., 3].max():
            raise ScoringError(f"{name}: colour channels all zero and the mask only in the alpha "
                               "channel, which v1 ignores: store the mask in the colour channels")
        mean = colour.astype(np.float64).mean(axis=2)
        if a.dtype == np.bool_:
            return mean >= 0.5
        return _threshold(mean, a.dtype, name, "channel mean ")
    if a.ndim != 2:
        raise ScoringError(f"{name}: expected [H,W] or [H,W,3|4] mask, got shape {a.shape}")
    if a.dtype == np.bool_:
        return a
    if not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise ScoringError(f"{name}: unsupported mask dtype {a.dtype}")
    return _threshold(a, a.dtype, name, "")


def _threshold(values: np.ndarray, dtype: np.dtype, name: str, what: str) -> np.ndarray:
    """v1's rule on values of an image of ``dtype`` (``what``: how they were made, for errors)."""
    if np.issubdtype(dtype, np.floating) and not np.isfinite(values).all():
        raise ScoringError(f"{name}: mask contains NaN or Inf")
    if values.size == 0:
        return np.zeros(values.shape, bool)
    lo, hi = float(values.min()), float(values.max())
    if lo < 0:
        raise ScoringError(f"{name}: negative {what}value {lo:g} in a mask")
    if np.isin(values, (0, 1)).all():
        return values == 1
    if np.isin(values, (0, 255)).all():
        return values == 255
    if np.issubdtype(dtype, np.floating):
        if hi > 1:
            raise ScoringError(f"{name}: float mask {what}values up to {hi:g}: expected [0, 1] "
                               "(or exactly 0/255)")
        return values >= 0.5
    half = (int(np.iinfo(dtype).max) + 1) // 2
    if hi < half:
        raise ScoringError(
            f"{name}: {what}values reach only {hi:g}, below {half} (half the {np.dtype(dtype).name} "
            "range), and are neither 0/1 nor 0/255: cannot tell the foreground; save the mask as "
            "0/1 or 0/255")
    return values >= half


def read_mask(path: str | Path) -> np.ndarray:
    """Read a mask file (image or .npy) and binarise it by v1's rule -> bool [H, W]."""
    path = Path(path)
    if not path.is_file():
        raise ScoringError(f"{path}: file not found")
    if path.suffix.lower() == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except Exception as exc:  # noqa: BLE001 - numpy raises several types for corrupt files
            raise ScoringError(f"{path}: unreadable .npy ({exc.__class__.__name__})") from None
    else:
        import cv2

        arr = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if arr is None:
            raise ScoringError(f"{path}: unreadable image")
        if arr.ndim == 3 and arr.shape[2] >= 3:  # BGR(A) -> RGB(A); the mean is unchanged
            arr = arr[..., [2, 1, 0] + list(range(3, arr.shape[2]))]
    return binarize(arr, name=str(path))


# --- official: the public script's reading ----------------------------------------------------


def _read_stored(path: Path) -> tuple[np.ndarray, str]:
    """The image's samples as PIL stores them (what the public script sees) and its mode."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return np.asarray(im), im.mode
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise ScoringError(f"{path}: unreadable image ({exc.__class__.__name__})") from None


def official_prediction(stored: np.ndarray) -> np.ndarray:
    """The public script's prediction rule on stored samples -> bool [H, W]: foreground where
    the mean over all channels (alpha included) is non-zero; one channel: where it is non-zero
    (outside the script, which averages the last axis of any array)."""
    a = np.asarray(stored)
    if a.ndim == 3:
        return a.astype(np.float64).mean(axis=-1) != 0
    if a.ndim == 2:
        return a != 0
    raise ScoringError(f"prediction: expected [H,W] or [H,W,C], got shape {a.shape}")


def read_official_prediction(path: str | Path) -> tuple[np.ndarray, bool]:
    """(foreground bool [H, W], whether the file has one channel) by the public script's rule."""
    stored, _ = _read_stored(Path(path))
    return official_prediction(stored), stored.ndim == 2


def read_official_ground_truth(path: str | Path) -> np.ndarray:
    """The stored values [H, W], not binarised (the public script's ground truth)."""
    path = Path(path)
    stored, mode = _read_stored(path)
    if stored.ndim != 2:
        raise ScoringError(
            f"{path}: ground truth with {stored.shape[-1]} channels (mode {mode}); the public script "
            "compares it with a one-channel prediction and fails: save it as one channel, or use --metric v1")
    return stored
