"""Bytes needed to store one image's masks in each representation (dense, bits, the paper's
file, ours, COCO RLE JSON), and a table of them."""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from masks.coco import to_coco_dict
from masks.maskset import MaskSet
from masks.store import official_to_bytes, to_bytes


@dataclasses.dataclass
class CompressionReport:
    """Bytes needed to store one image's masks in each representation."""

    n: int
    height: int
    width: int
    dense_bool: int  # numpy bool [N, H, W]
    packed_bits: int  # np.packbits, no container
    official: int  # the paper's torch.save(bitarray) file
    ours: int  # our file (zlib)
    ours_uncompressed: int  # our file, codec "none"
    coco_rle_json: int  # JSON with COCO RLE strings

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def compression_report(ms: MaskSet) -> CompressionReport:
    return CompressionReport(
        n=ms.n, height=ms.height, width=ms.width,
        dense_bool=ms.n * ms.height * ms.width,
        packed_bits=(ms.n * ms.height * ms.width + 7) // 8,
        official=len(official_to_bytes(ms)),
        ours=len(to_bytes(ms, "zlib")),
        ours_uncompressed=len(to_bytes(ms, "none")),
        coco_rle_json=len(json.dumps(to_coco_dict(ms)).encode()),
    )


def format_compression_table(reports: list[CompressionReport]) -> str:
    """Mean bytes per image and the ratio to dense bool, one row per representation."""
    if not reports:
        return "no images"
    fields = ["dense_bool", "packed_bits", "official", "ours_uncompressed", "ours", "coco_rle_json"]
    dense = float(np.mean([r.dense_bool for r in reports]))
    lines = [(f"{len(reports)} image(s), mean {np.mean([r.n for r in reports]):.1f} masks of "
              f"{reports[0].height}x{reports[0].width}"),
             f"{'representation':<18} {'bytes/image':>12} {'x smaller than dense':>21}"]
    for f in fields:
        b = float(np.mean([getattr(r, f) for r in reports]))
        lines.append(f"{f:<18} {b:>12.0f} {dense / b if b else float('inf'):>21.1f}")
    return "\n".join(lines)
