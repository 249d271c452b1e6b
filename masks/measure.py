"""Measure mask generation time and storage per image: ``python -m masks.measure``.

Procedural test images (coloured, partly checker-textured ellipses over a shaded background,
with pixel noise) and their instance maps, at each requested size; or your own images with
``--image`` (classical only). Prints, per size and generator: masks per image, seconds per
image, bytes per image in every representation, and our file's save / load times.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from masks.compression import compression_report
from masks.maskset import MaskSet
from masks.store import from_bytes, to_bytes


def procedural_scene(h: int, w: int, seed: int = 0, n_objects: int = 10):
    """([H, W, 3] uint8 RGB, [H, W] int32 instance ids); every other object is checkered."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    img = np.zeros((h, w, 3), np.float64)
    img[:] = np.array([90, 110, 130]) + (yy / h * 40)[..., None]
    ids = np.zeros((h, w), np.int32)
    period = max(2.0, min(h, w) / 24)
    for i in range(1, n_objects + 1):
        cy, cx = rng.uniform(0.15, 0.85) * h, rng.uniform(0.15, 0.85) * w
        ry, rx = rng.uniform(0.06, 0.2) * h, rng.uniform(0.06, 0.2) * w
        m = ((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2 <= 1
        col = rng.uniform(0, 255, 3)
        if i % 2 == 0:
            checker = ((yy[m] // period + xx[m] // period) % 2)[:, None]
            img[m] = col * (0.6 + 0.4 * checker)
        else:
            img[m] = col + (xx[m, None] - cx) / rx * 15
        ids[m] = i
    img += rng.normal(0, 5, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8), ids


def _time(fn, repeats: int):
    best, out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def measure(ms: MaskSet, seconds: float, label: str) -> dict:
    r = compression_report(ms)
    data = to_bytes(ms)
    t_save, _ = _time(lambda: to_bytes(ms), 3)
    t_load, _ = _time(lambda: from_bytes(data), 3)
    return {"case": label, "masks": ms.n, "gen_s": seconds, "save_s": t_save, "load_s": t_load,
            **{k: v for k, v in r.as_dict().items() if k not in ("n", "height", "width")}}


def main(argv: list[str] | None = None) -> None:
    from masks.generators.classical import ClassicalGenerator
    from masks.generators.synthetic import SyntheticGenerator

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="120x160,536x960", help="HxW,HxW,...")
    ap.add_argument("--repeats", type=int, default=2, help="best of N timings")
    ap.add_argument("--image", action="append", default=[], help="also time these images (classical)")
    args = ap.parse_args(argv)

    rows = []
    for size in args.sizes.split(","):
        h, w = (int(v) for v in size.lower().split("x"))
        img, ids = procedural_scene(h, w)
        t, ms = _time(lambda img=img: ClassicalGenerator().generate(img), args.repeats)
        rows.append(measure(ms, t, f"classical {h}x{w}"))
        t, ms = _time(lambda ids=ids: SyntheticGenerator().generate(None, "k", ids), args.repeats)
        rows.append(measure(ms, t, f"synthetic {h}x{w}"))
    for path in args.image:
        from imagefiles import read_rgb8

        img = read_rgb8(path)
        t, ms = _time(lambda img=img: ClassicalGenerator().generate(img), args.repeats)
        rows.append(measure(ms, t, f"classical {path} {img.shape[0]}x{img.shape[1]}"))

    cols = ["masks", "gen_s", "save_s", "load_s", "dense_bool", "packed_bits", "official",
            "ours_uncompressed", "ours", "coco_rle_json"]
    print(f"{'case':<24}" + "".join(f"{c:>18}" for c in cols))
    for r in rows:
        cells = [f"{r[c]:.4f}" if c.endswith("_s") else f"{r[c]}" for c in cols]
        print(f"{r['case']:<24}" + "".join(f"{c:>18}" for c in cells))
    print("bytes are per image; *_s are seconds per image (best of --repeats); "
          "ours = zlib-compressed bit-packed file")


if __name__ == "__main__":
    main()
