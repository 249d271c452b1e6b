"""Pictures of a run's report: overlays of a prediction on its test view, PNG bytes, and
images embedded in the page."""

from __future__ import annotations

import base64
import html
from pathlib import Path

import numpy as np

MAX_FRAMES_SHOWN = 8  # test frames a report shows (pictures, click frames)


def overlay(image: np.ndarray, pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """RGB uint8 [H,W,3] with true positives green, false positives red, misses blue."""
    out = image.astype(np.float32) * 0.55
    tp, fp, fn = pred & gt, pred & ~gt, ~pred & gt
    for m, colour in ((tp, (40, 200, 40)), (fp, (230, 40, 40)), (fn, (40, 90, 240))):
        out[m] = out[m] * 0.35 + np.array(colour, np.float32) * 0.65
    return out.clip(0, 255).astype(np.uint8)


def read_rgb(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """[H, W, 3] uint8 picture of a test view (imagefiles' rule) at the mask's size."""
    import cv2

    from imagefiles import ImageFileError, read_rgb8

    try:
        img = read_rgb8(path)
    except ImageFileError:
        return np.full((*shape, 3), 128, np.uint8)  # image moved away: grey backdrop, stated below
    if img.shape[:2] != shape:
        img = cv2.resize(img, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    return img


def png(rgb: np.ndarray) -> bytes:
    from imagefiles import png_bytes

    return png_bytes(rgb)


def img_tag(data: bytes, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{base64.b64encode(data).decode()}">'


def score_plot(x, series: list[tuple], xlabel: str, size: tuple[float, float], legend: str,
               hlines=(), xticks=None) -> bytes:
    """A PNG of scores in [0, 1] against ``x``: ``series`` (label, values, marker, size, alpha),
    dashed ``hlines``, the report's axes and grid."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=size, dpi=100)
    for label, values, marker, ms, alpha in series:
        ax.plot(x, values, marker=marker, ms=ms, label=label, alpha=alpha)
    for t in hlines:
        ax.axhline(t, ls="--", lw=0.8, color="grey")
    if xticks is not None:
        ax.set_xticks(xticks)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel(xlabel)
    ax.legend(loc=legend)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()

