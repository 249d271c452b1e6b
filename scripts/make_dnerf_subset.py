"""Write a downscaled subset of a D-NeRF scene for the tests (tests/data/dnerf/<scene>-tiny).

    python3 scripts/make_dnerf_subset.py ../shared/data/dnerf/hook tests/data/dnerf/hook-tiny

Keeps the published layout as it is (transforms_{train,val,test}.json with camera_angle_x,
frames named without an extension, a time per frame, RGBA PNGs in train/ val/ test/), with a
few frames of each split, the images scaled to SIZE x SIZE by area in premultiplied alpha and
stored as 8-bit RGBA. The intrinsics stay right because D-NeRF gives them as an angle.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np

SIZE = 40
KEEP = {"train": [0, 20, 40, 60, 80, 99], "val": [0, 10], "test": [0, 10]}


def scaled_rgba(src: Path) -> np.ndarray:
    img = cv2.imread(str(src), cv2.IMREAD_UNCHANGED).astype(np.float64) / 255.0  # BGRA
    a = img[:, :, 3:]
    pre = cv2.resize(np.concatenate([img[:, :, :3] * a, a], axis=2), (SIZE, SIZE), interpolation=cv2.INTER_AREA)
    alpha = pre[:, :, 3:]
    rgb = np.divide(pre[:, :, :3], alpha, out=np.zeros_like(pre[:, :, :3]), where=alpha > 1e-9)
    return np.round(np.clip(np.concatenate([rgb, alpha], axis=2), 0, 1) * 255).astype(np.uint8)


def main(src: str, out: str) -> None:
    src_dir, out_dir = Path(src), Path(out)
    for split, keep in KEEP.items():
        doc = json.loads((src_dir / f"transforms_{split}.json").read_text())
        frames = [doc["frames"][i] for i in keep]
        for fr in frames:
            rel = fr["file_path"].removeprefix("./")
            dst = out_dir / f"{rel}.png"
            dst.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(dst), scaled_rgba(src_dir / f"{rel}.png"))
        (out_dir / f"transforms_{split}.json").write_text(json.dumps({**doc, "frames": frames}, indent=1) + "\n")


if __name__ == "__main__":
    main(*sys.argv[1:3])
