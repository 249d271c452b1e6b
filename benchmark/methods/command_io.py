"""What a command method reads and writes (benchmark.methods.command): the input folder the
toolkit writes for one sequence, and the predicted masks it reads back.

The input folder (``LAYOUT_VERSION``; docs/command-methods.md)::

    scene/              the sequence's folder in its publisher's layout (the public code's input):
                        each entry of the dataset folder linked, not copied, the ground truth left
                        out (gt_masks/, the synthetic scenes' truth), plus
      masks/<stem>.pt   each training view's anything-masks in the public code's format,
                        torch.save({'masks': bitarray(N*H*W), 'N', 'H', 'W'}), <stem> the image's
                        file name without suffix (the view's name where two images share a stem)
    cameras.json        training views (image, masks, camera, time) and test views (frame name,
                        camera, time), in the benchmark's order
    points.npy          the initial point cloud [N, 3] (float64, the cameras' world frame);
                        point_colors.npy [N, 3] in [0, 1] where the format has colours
    prompts.json        the benchmark's clicks: per object its click, per test frame its clicks
    prompts/<frame>.png per test frame with clicks: uint8 (uint16 beyond 255 objects), 0
                        everywhere but object k's click pixel, which holds k (1, 2, ...)

The output folder: ``<frame>.png`` per test view, ``frame`` the ground truth's name of it
(``00000``, ``00001``, ... in the order of cameras.json's ``test``), a binary mask of the
objects of interest at the view's size (0/255 or 0/1; any mask ``trase-bench score`` reads as
binary); other files are ignored.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from benchmark.methods.command import CommandError

LAYOUT_VERSION = 1
SCENE_DIR, CAMERAS, PROMPTS, PROMPT_MAPS = "scene", "cameras.json", "prompts.json", "prompts"
NEVER_LINKED = ("gt_masks", "gt_masks_object", "masks")  # ground truth, and the masks written here


def frame_names(n: int) -> list[str]:
    """The ground truth's frame names of ``n`` test views (benchmark.pipeline.evaluate)."""
    return [f"{i:05d}" for i in range(n)]


def _hidden(scene) -> list[Path]:
    """What a method must not see: the ground-truth masks and a synthetic scene's truth."""
    paths = [Path(p) for p in scene.gt_masks]
    truth = getattr(scene, "truth", None)
    if truth is not None:
        paths += [Path(truth.manifest_path), Path(truth.geometry_path), *map(Path, truth.instance_maps.values())]
    return [p.resolve() for p in paths]


def link_scene(scene, dest: Path) -> list[str]:
    """Link every entry of the scene's folder into ``dest`` but the ground truth (an entry that
    holds a ground-truth or truth file, or is named in NEVER_LINKED); returns the linked names."""
    hidden = _hidden(scene)
    dest.mkdir(parents=True, exist_ok=True)
    linked = []
    for entry in sorted(Path(scene.root).iterdir()):
        real = entry.resolve()
        if entry.name in NEVER_LINKED or any(p == real or real in p.parents for p in hidden):
            continue
        os.symlink(real, dest / entry.name, target_is_directory=real.is_dir())
        linked.append(entry.name)
    return linked


def mask_files(views) -> list[str]:
    """Per training view, its masks file under the scene folder: masks/<image stem>.pt, the
    public code's name, or masks/<view name>.pt where two images share a stem."""
    stems = [Path(v.image_path).stem for v in views]
    names = stems if len(set(stems)) == len(stems) else [v.name for v in views]
    return [f"{SCENE_DIR}/masks/{n}.pt" for n in names]


def camera_dict(camera) -> dict:
    """A camera as cameras.json writes it: OpenCV axes (x right, y down, z forward), K 3x3,
    w2c 4x4 (world to camera), size in pixels, time in [0, 1], lens (zero: pinhole), and the
    near plane where it is not the default 0.01 (trase.camera.Camera.to_dict)."""
    d = camera.to_dict()
    d.pop("name", None)
    return d


def write_cameras(scene, dataset: str, masks: list[str], out: Path) -> None:
    root = Path(scene.root).resolve()

    def in_scene(path: Path) -> str | None:
        real = Path(path).resolve()
        return f"{SCENE_DIR}/{real.relative_to(root).as_posix()}" if root in real.parents else None

    doc = {
        "version": LAYOUT_VERSION, "dataset": dataset, "sequence": scene.sequence, "variant": scene.variant,
        "note": "OpenCV camera axes; w2c maps world to camera; test frames are named as the ground truth "
                "(write <output>/<frame>.png for each)",
        "train": [{"view": v.name, "time_step": int(v.frame), "time": float(v.time),
                   "image": str(Path(v.image_path).resolve()), "image_in_scene": in_scene(v.image_path),
                   "masks": m, "camera": camera_dict(v.camera)} for v, m in zip(scene.train, masks)],
        "test": [{"frame": f, "view": v.name, "time_step": int(v.frame), "time": float(v.time),
                  "camera": camera_dict(v.camera)} for f, v in zip(frame_names(len(scene.test)), scene.test)],
    }
    (out / CAMERAS).write_text(json.dumps(doc, indent=1))


def write_prompts(prompts, scene, out: Path) -> int:
    """prompts.json and the click maps; returns the number of clicks. Object k (1, 2, ...) is
    the k-th click of the benchmark's prompts (set 0: the run's own clicks)."""
    import cv2

    names = frame_names(len(scene.test))
    objects, frames = [], {}
    for k, c in enumerate(prompts.clicks, start=1):
        cam = scene.test[c.view_index].camera
        x, y = min(int(c.u), cam.width - 1), min(int(c.v), cam.height - 1)
        click = {"object": k, "u": float(c.u), "v": float(c.v), "x": x, "y": y, "positive": c.positive}
        objects.append({**click, "frame": names[c.view_index], "view": c.view})
        frames.setdefault(names[c.view_index], []).append(click)
    doc = {"version": LAYOUT_VERSION, "rule": prompts.source,
           "note": "one click per object of interest, in the first test frame it appears in; (u, v) continuous "
                   "pixel coordinates (pixel centres at +0.5), (x, y) the clicked pixel; predict every object "
                   "in every test frame, merged into one mask per frame",
           "objects": objects, "frames": frames}
    (out / PROMPTS).write_text(json.dumps(doc, indent=1))
    maps = out / PROMPT_MAPS
    maps.mkdir(exist_ok=True)
    dtype = np.uint8 if len(objects) < 256 else np.uint16
    for frame, clicks in frames.items():
        cam = scene.test[names.index(frame)].camera
        img = np.zeros((cam.height, cam.width), dtype)
        for c in clicks:
            img[c["y"], c["x"]] = c["object"]
        cv2.imwrite(str(maps / f"{frame}.png"), img)
    return len(objects)


def write_inputs(scene, dataset: str, masks_dir: Path, prompts, out: Path) -> dict:
    """The input folder of one sequence (module docstring) -> facts for the stage record."""
    import masks as masklib

    out = Path(out)
    linked = link_scene(scene, out / SCENE_DIR)
    files = mask_files(scene.train)
    for v, rel in zip(scene.train, files):
        src = masklib.mask_path(masks_dir, v.name)
        masklib.save_official(out / rel, masklib.load(src))
    write_cameras(scene, dataset, files, out)
    np.save(out / "points.npy", np.asarray(scene.points, dtype=np.float64))
    if scene.point_colors is not None:
        np.save(out / "point_colors.npy", np.asarray(scene.point_colors, dtype=np.float32))
    n_clicks = write_prompts(prompts, scene, out)
    return {"layout": LAYOUT_VERSION, "linked": linked, "n_train": len(scene.train), "n_test": len(scene.test),
            "n_clicks": n_clicks, "masks_bytes": sum((out / f).stat().st_size for f in files)}


def read_outputs(out_dir: Path, scene, label: str | None = None) -> list[np.ndarray]:
    """The predicted masks of every test view, bool [H, W] in order, from ``<out_dir>/<frame>.png``;
    a CommandError (one line) when none was written, one is missing, unreadable or of
    another size than its view. ``label`` names the folder in messages (default: its path)."""
    from benchmark.errors import UserError
    from benchmark.scoring import read_mask

    out_dir = Path(out_dir)
    where = label or str(out_dir)
    names = frame_names(len(scene.test))
    written = {p.stem for p in out_dir.glob("*.png")} & set(names) if out_dir.is_dir() else set()
    if not written:
        raise CommandError(f"{where}: no masks written (expected one PNG per test frame: "
                           f"{names[0]}.png ... {names[-1]}.png)")
    missing = [n for n in names if n not in written]
    if missing:
        raise CommandError(f"{where}: no mask for {len(missing)} of {len(names)} test frames "
                           f"({', '.join(f'{n}.png' for n in missing[:5])}{', ...' if len(missing) > 5 else ''})")
    out = []
    for n, view in zip(names, scene.test):
        path = out_dir / f"{n}.png"
        name = f"{n}.png in {label}" if label else str(path)
        try:
            mask = read_mask(path)
        except UserError as exc:
            raise CommandError(str(exc).replace(str(path), name)) from None
        want = (view.camera.height, view.camera.width)
        if mask.shape != want:
            raise CommandError(f"{name}: {mask.shape[1]}x{mask.shape[0]} pixels, its test view is "
                               f"{want[1]}x{want[0]}")
        out.append(mask)
    return out


__all__ = ["LAYOUT_VERSION", "camera_dict", "frame_names", "link_scene", "mask_files", "read_outputs",
           "write_inputs"]
