"""``trase-bench perf viewer``: what the web viewer costs per frame and per click on 2 cores.

The viewer (``trase-bench view``) renders every frame on the server: a deformation of all
gaussians at the frame's time, one rasterisation (colour plus the mode's features), and a
JPEG for the browser. This suite times those on the default HyperNeRF-format scene fitted by
``trase-bench run`` (geometry and features come from the suite's own stage cache, so a second
invocation only measures), at 320x240 and 640x480, from a camera between the test views,
with the time changing every frame (as when playing). A click selection is the method's click
rule at the click's pixel plus the re-render that shows it. ``--quick``: the tiny scene with
ground-truth geometry.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from benchmark.perf.common import fmt, load_average, stats, table

SIZES = ((320, 240), (640, 480))
MODES = ("rgb", "selection", "clusters", "pca")
QUICK_SET = ["geometry.source=ground-truth", "method.features.iterations=40", "method.features.n_pixels=400"]


def fitted_run(out_dir: Path, quick: bool, echo) -> Path:
    """The run folder of trase on the default (quick: tiny) HyperNeRF-format scene."""
    from benchmark.cli import main

    root = Path(out_dir) / "viewer"
    args = ["run", "--method", "trase", "--dataset", "hypernerf", "--runs", str(root / "runs"), "--quiet"]
    if quick:
        args += ["--sequence", "synthetic-tiny"] + [a for s in QUICK_SET for a in ("--set", s)]
    t0 = time.perf_counter()
    if main(args) != 0:
        raise RuntimeError("the run the viewer suite measures failed")
    (results,) = sorted((root / "runs").glob("trase/hypernerf/*/*/results.json"))[-1:]
    echo(f"run {results.parent} ready in {time.perf_counter() - t0:.1f}s (stages reused from the suite's cache)")
    return results.parent


def run(quick: bool, echo, out_dir: Path) -> dict:
    from benchmark.scene.folders import open_scene_folder, resolve_selection
    from trase.edit import by_click
    from trase.visualize import Painter

    folder = open_scene_folder(fitted_run(out_dir, quick, echo))
    model = folder.model
    _, sel = resolve_selection(folder, selected=True) if folder.selected else ([], None)
    painter = Painter(model, sel)
    cams = sorted((c for _, c in folder.views), key=lambda c: c.time)
    home = cams[len(cams) // 2]
    n_frames = 6 if quick else 30
    times = np.linspace(0.0, 1.0, n_frames)
    rows, figures = [], {"n_gaussians": model.num_gaussians, "frames_per_setting": n_frames, "sizes": {}}
    for w, h in SIZES:
        cam = home.scaled(home.width / w)  # the default scene's views are 4:3: exactly w x h
        painter.render(cam, "rgb")  # warm-up: numba's compiled kernels load
        per_mode = {}
        for mode in MODES:
            secs, jpeg = [], []
            for t in times:
                c = cam.with_time(float(t))
                t0 = time.perf_counter()
                img = painter.render(c, mode)
                secs.append(time.perf_counter() - t0)
                t1 = time.perf_counter()
                _jpeg(img)
                jpeg.append(time.perf_counter() - t1)
            s, j = stats(secs), stats(jpeg)
            fps = 1.0 / (s["median"] + j["median"])
            per_mode[mode] = {"render_s": s, "jpeg_s": j, "fps": fps}
            rows.append([f"{cam.width}x{cam.height}", mode, fmt(s), fmt(j), f"{fps:.1f}"])
        figures["sizes"][f"{cam.width}x{cam.height}"] = per_mode
    echo(table(rows, ["size", "mode", "render", "jpeg", "fps"]))

    # click latency: the click rule at random pixels, then the frame that shows the selection
    cam = home.scaled(home.width / SIZES[0][0])
    rng = np.random.default_rng(0)
    pixels = [(rng.uniform(0, cam.width), rng.uniform(0, cam.height)) for _ in range(12 if not quick else 4)]
    lat, hits = [], 0
    for u, v in pixels:
        t0 = time.perf_counter()
        k, chosen = by_click(model, cam, u, v, rule=folder.click_rule)
        painter.set_selection(chosen)
        painter.render(cam, "selection")
        lat.append(time.perf_counter() - t0)
        hits += k >= 0
    figures["click"] = {"latency_s": stats(lat), "clicks": len(pixels), "hit_a_surface": hits,
                        "rule": folder.click_rule, "size": list(SIZES[0])}
    echo(f"click selection + re-render at {SIZES[0][0]}x{SIZES[0][1]}: {fmt(stats(lat))} "
         f"({hits}/{len(pixels)} random pixels hit a surface; rule {folder.click_rule})")
    figures["load_average"] = load_average()
    return figures


def _jpeg(img: np.ndarray) -> bytes:
    """The browser's frame: JPEG quality 90 through OpenCV, the encoder viser sends it with."""
    import cv2

    _, buf = cv2.imencode(".jpg", np.ascontiguousarray(img[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 90])
    return buf.tobytes()
