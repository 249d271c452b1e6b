"""``make demo``: the main job on built-in data.

Until the runner lands this scores a small generated example: ground truth of a moving disc
and a prediction that lags it by two pixels, through the same code as ``trase-bench score``.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmark.cli import main as cli_main


def write_scoring_example(out: Path, n_frames: int = 8, size: tuple[int, int] = (96, 128)) -> None:
    """Write gt/ and pred/ directories of 0/255 PNG masks into ``out``."""
    import cv2

    h, w = size
    yy, xx = np.mgrid[:h, :w]
    for i in range(n_frames):
        cx = 30 + 8 * i
        gt = ((xx - cx) ** 2 + (yy - h / 2) ** 2 <= 18**2).astype(np.uint8) * 255
        pred = ((xx - cx + 2) ** 2 + (yy - h / 2) ** 2 <= 18**2).astype(np.uint8) * 255
        for sub, m in (("gt", gt), ("pred", pred)):
            (out / sub).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(out / sub / f"{i:05d}.png"), m)


def run() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        write_scoring_example(out)
        print(f"scoring example: {out}/pred against {out}/gt")
        return cli_main(["score", str(out / "pred"), str(out / "gt")])


if __name__ == "__main__":
    sys.exit(run())
