"""``trase-bench render``: frames, an MP4 and a small animated preview of a scene folder.

Cameras: the folder's own views (``test``: a run's test views, a capture's views) in time
order, or an ``orbit``: an arc around the point the views look at, sweeping time 0..1. The
MP4 is MPEG-4 part 2 (``mp4v``, what OpenCV's wheels write everywhere); the animated WebP
beside it plays in every browser, so reports embed that one.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from benchmark.errors import UserError

CAMERA_PATHS = ("test", "orbit")


@dataclasses.dataclass(frozen=True)
class RenderOptions:
    mode: str = "rgb"
    cameras: str = "test"  # CAMERA_PATHS
    frames: int = 0  # 0: every view (test) / 60 (orbit); else evenly spread
    orbit_degrees: float = 30.0
    fps: float = 10.0
    scale: float = 1.0  # image size factor
    mp4: bool = True
    preview: bool = True  # animated WebP (<= 160 px wide)


def path_cameras(folder, opts: RenderOptions) -> list:
    """The cameras to render, in order."""
    from trase.visualize import look_centre, orbit_cameras

    if opts.cameras not in CAMERA_PATHS:
        raise UserError(f"--cameras {opts.cameras!r}: choose one of {', '.join(CAMERA_PATHS)}")
    if opts.frames < 0 or not (0 < opts.scale <= 4) or opts.fps <= 0:
        raise UserError("--frames must be >= 0, --scale in (0, 4] and --fps > 0")
    cams = sorted((c for _, c in folder.views), key=lambda c: c.time)
    if opts.cameras == "orbit":
        n = opts.frames or 60
        cams = orbit_cameras(cams[len(cams) // 2], look_centre(cams), n, opts.orbit_degrees)
    elif opts.frames and opts.frames < len(cams):
        cams = [cams[i] for i in np.linspace(0, len(cams) - 1, opts.frames).round().astype(int)]
    return [c.scaled(1.0 / opts.scale) if opts.scale != 1.0 else c for c in cams]


def render_frames(folder, opts: RenderOptions, out: Path, selection: np.ndarray | None = None,
                  progress: bool = True) -> dict:
    """Write ``<out>/<mode>/NNNN.png`` (+ ``<out>/<mode>.mp4``, ``<out>/<mode>.webp``); returns
    what was written and the seconds per frame."""
    import time

    from rich.progress import track

    from benchmark.io import atomic_directory, atomic_path
    from imagefiles import png_bytes
    from trase.visualize import Painter

    cams = path_cameras(folder, opts)
    painter = Painter(folder.model, selection)
    frames, seconds = [], []
    for cam in track(cams, description=f"render {opts.mode}", disable=not progress, transient=True):
        t0 = time.perf_counter()
        frames.append(painter.render(cam, opts.mode))
        seconds.append(time.perf_counter() - t0)
    with atomic_directory(out / opts.mode) as d:
        for k, img in enumerate(frames):
            (d / f"{k:04d}.png").write_bytes(png_bytes(img))
    written = {"frames": str(out / opts.mode), "n": len(frames)}
    if opts.mp4:
        write_mp4(frames, out / f"{opts.mode}.mp4", opts.fps)
        written["mp4"] = str(out / f"{opts.mode}.mp4")
    if opts.preview:
        with atomic_path(out / f"{opts.mode}.webp") as tmp:
            write_webp(frames, tmp, opts.fps)
        written["preview"] = str(out / f"{opts.mode}.webp")
    written["seconds_per_frame"] = float(np.median(seconds)) if seconds else 0.0
    written["size"] = [cams[0].width, cams[0].height] if cams else [0, 0]
    return written


def write_mp4(frames: list[np.ndarray], path: Path, fps: float) -> None:
    """RGB uint8 frames [H, W, 3] -> MP4 (mp4v), moved into place whole; a clear error where
    OpenCV cannot write one. (OpenCV picks the container from the name, so the temporary
    keeps the .mp4 suffix, in a temporary folder beside the target.)"""
    import os
    import tempfile

    import cv2

    path = Path(path)
    h, w = frames[0].shape[:2]
    with tempfile.TemporaryDirectory(prefix=f".{path.name}.", dir=path.parent) as tmp_dir:
        tmp = Path(tmp_dir) / path.name
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (w, h))
        if not writer.isOpened():
            raise UserError(f"{path}: OpenCV cannot write MP4 here (no mp4v encoder); use the PNG frames")
        try:
            for f in frames:
                writer.write(np.ascontiguousarray(f[..., ::-1]))
        finally:
            writer.release()
        os.replace(tmp, path)


def write_webp(frames: list[np.ndarray], path: str, fps: float, max_width: int = 160) -> None:
    """A small looping animated WebP of the frames (lossy, <= max_width px wide)."""
    from PIL import Image

    h, w = frames[0].shape[:2]
    size = (w, h) if w <= max_width else (max_width, max(1, round(h * max_width / w)))
    imgs = [Image.fromarray(f).resize(size, Image.BILINEAR) for f in frames]
    imgs[0].save(path, format="WEBP", save_all=True, append_images=imgs[1:], duration=int(1000 / fps), loop=0,
                 quality=80)


CLIP_FRAMES = 24  # test views in a report's clip, evenly spread in time


def selection_clip(run_dir: Path) -> bytes:
    """An animated WebP of a run's selection over its test views in time order (``trase-bench
    render --run DIR --mode selection --selected``): the clip a run's report embeds."""
    import tempfile

    from benchmark.scene.folders import open_scene_folder, resolve_selection

    folder = open_scene_folder(run_dir)
    _, sel = resolve_selection(folder, selected=True) if folder.selected else ([], None)
    opts = RenderOptions(mode="selection", frames=CLIP_FRAMES, mp4=False)
    with tempfile.TemporaryDirectory() as tmp:
        res = render_frames(folder, opts, Path(tmp), sel, progress=False)
        return Path(res["preview"]).read_bytes()


__all__ = ["CAMERA_PATHS", "CLIP_FRAMES", "RenderOptions", "path_cameras", "render_frames", "selection_clip", "write_mp4",
           "write_webp"]
