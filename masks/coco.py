"""Masks as COCO RLE (pycocotools): per-mask records and a JSON file of them."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from masks.maskset import MaskError, MaskSet
from masks.store import MaskFileError, atomic_write, first_line


def to_rle(ms: MaskSet) -> list[dict]:
    """COCO RLE of every mask: ``{"size": [H, W], "counts": str}`` (pycocotools)."""
    from pycocotools import mask as cocomask

    if ms.n == 0:
        return []
    fortran = np.asfortranarray(ms.masks.transpose(1, 2, 0).astype(np.uint8))  # [H, W, N]
    rles = cocomask.encode(fortran)
    return [{"size": [int(s) for s in r["size"]], "counts": r["counts"].decode("ascii")} for r in rles]


def from_rle(
    rles: list[dict],
    height: int,
    width: int,
    score: np.ndarray | None = None,
    generator: str = "unknown",
    info: dict | None = None,
) -> MaskSet:
    """Inverse of ``to_rle`` (``height``/``width`` are needed when the list is empty)."""
    from pycocotools import mask as cocomask

    if not rles:
        return MaskSet.empty(height, width, generator, info)
    enc = []
    for i, r in enumerate(rles):
        if list(r.get("size", [])) != [height, width]:
            raise MaskError(f"RLE {i} has size {r.get('size')}, expected {[height, width]}")
        c = r["counts"]
        enc.append({"size": [height, width], "counts": c.encode("ascii") if isinstance(c, str) else c})
    dec = cocomask.decode(enc)  # [H, W, N] uint8
    masks = np.ascontiguousarray(dec.transpose(2, 0, 1)).astype(bool)
    return MaskSet.from_masks(masks, score=score, generator=generator, info=info)


def to_coco_dict(ms: MaskSet) -> dict:
    """A JSON-ready dict: image size, generator, info and one COCO-style record per mask."""
    anns = []
    for i, rle in enumerate(to_rle(ms)):
        rec = {"segmentation": rle, "area": int(ms.area[i])}
        if ms.score is not None:
            rec["score"] = float(ms.score[i])
        anns.append(rec)
    return {"height": ms.height, "width": ms.width, "generator": ms.generator, "info": ms.info,
            "annotations": anns}


def from_coco_dict(d: dict, source: str = "<dict>") -> MaskSet:
    try:
        anns = d["annotations"]
        h, w = int(d["height"]), int(d["width"])
        scores = [a["score"] for a in anns] if anns and all("score" in a for a in anns) else None
        ms = from_rle([a["segmentation"] for a in anns], h, w,
                      None if scores is None else np.asarray(scores, np.float32),
                      d.get("generator", "unknown"), d.get("info") or {})
    except (KeyError, TypeError, ValueError) as exc:
        raise MaskFileError(source, f"not a COCO mask record ({first_line(exc)})") from None
    areas = [a.get("area") for a in anns]
    if all(a is not None for a in areas) and not np.array_equal(np.asarray(areas, np.int64), ms.area):
        raise MaskFileError(source, "stored areas do not match the decoded masks")
    return ms


def save_coco_json(path: os.PathLike | str, ms: MaskSet) -> Path:
    atomic_write(path, json.dumps(to_coco_dict(ms)).encode())
    return Path(path)


def load_coco_json(path: os.PathLike | str) -> MaskSet:
    try:
        d = json.loads(Path(path).read_text())
    except OSError as exc:
        raise MaskFileError(path, f"unreadable ({exc.strerror or exc})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise MaskFileError(path, f"not JSON ({first_line(exc)})") from None
    return from_coco_dict(d, str(path))
