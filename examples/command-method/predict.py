"""A method in its own environment, for `trase-bench run --method method.toml`: the standard
library only, so any Python 3 runs it.

It predicts, in every test frame, a disc around each object's click (the benchmark's prompts):
a floor to measure real methods against, and a template of the input and output layouts
(docs/command-methods.md).

    python predict.py INPUT OUTPUT [--radius FRACTION]
"""

import argparse
import json
import struct
import sys
import zlib
from pathlib import Path


def write_png(path: Path, rows: list[bytes], width: int) -> None:
    """An 8-bit grey PNG from its rows (one byte per pixel)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    raw = b"".join(b"\0" + r for r in rows)  # filter 0 on every row
    header = struct.pack(">IIBBBBB", width, len(rows), 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw))
                     + chunk(b"IEND", b""))


def disc_mask(width: int, height: int, centres: list[tuple[float, float]], radius: float) -> list[bytes]:
    rows = []
    for y in range(height):
        row = bytearray(width)
        for u, v in centres:
            dy = y + 0.5 - v
            if abs(dy) > radius:
                continue
            half = (radius * radius - dy * dy) ** 0.5
            for x in range(max(0, int(u - half)), min(width, int(u + half) + 1)):
                row[x] = 255
        rows.append(bytes(row))
    return rows


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("input", type=Path)
    ap.add_argument("output", type=Path)
    ap.add_argument("--radius", type=float, default=0.12, help="disc radius, a fraction of the shorter side")
    args = ap.parse_args()
    cameras = json.loads((args.input / "cameras.json").read_text())
    prompts = json.loads((args.input / "prompts.json").read_text())
    have_masks = sum((args.input / v["masks"]).is_file() for v in cameras["train"])
    print(f"{cameras['dataset']}/{cameras['sequence']}: {len(cameras['train'])} training views "
          f"({have_masks} with masks), {len(cameras['test'])} test views, {len(prompts['objects'])} clicks")
    centres = [(o["u"], o["v"]) for o in prompts["objects"]]
    for view in cameras["test"]:
        w, h = view["camera"]["width"], view["camera"]["height"]
        write_png(args.output / f"{view['frame']}.png", disc_mask(w, h, centres, args.radius * min(w, h)), w)
    print(f"wrote {len(cameras['test'])} masks to {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
