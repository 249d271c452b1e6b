"""The bad-input catalogue: corruptions of valid inputs and the one-line error each must give.

Each ``Case`` corrupts one file (or directory) of a valid input built from the synthetic
generator (five dataset formats), a mask file, a checkpoint or a results file, then runs the
matching entry point: the CLI where one reads that input (``trase-bench run`` for nerfies
scenes, ``prepare`` for multi-view raw downloads, ``score`` for mask images, ``leaderboard``
for results files), else the public function (``masks.load``, ``trase.checkpoint``).

Expected: exit code 1 and exactly one stderr line ``error: <msg>`` (CLI) or an exception with
``user_facing = True`` (function), the message naming the corrupted file (``names``) and
containing ``fragment``; no partial output (no results.json, no prepared.json, no temporary
file, no finished stage directory).

``python tests/stress/catalogue.py`` prints the table as markdown for the README.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

# -- corruptions ------------------------------------------------------------------------------


def truncate(path: Path, keep: float = 0.5) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def garbage(path: Path) -> None:
    path.write_bytes(b"\x00\x13garbage, not the expected format" * 4)


def empty_file(path: Path) -> None:
    path.write_bytes(b"")


def non_utf8(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data.replace(b'"', b'"\xff\xfe', 1))


def edit_json(fn: Callable[[object], object]) -> Callable[[Path], None]:
    def apply(path: Path) -> None:
        obj = json.loads(path.read_text())
        out = fn(obj)
        path.write_text(json.dumps(obj if out is None else out).replace("NaN", "NaN"))

    return apply


def delete(path: Path) -> None:
    import shutil

    if path.is_dir():
        shutil.rmtree(path)
    else:
        path.unlink()


def empty_dir(path: Path) -> None:
    import shutil

    shutil.rmtree(path)
    path.mkdir()


def edit_npy(fn: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def apply(path: Path) -> None:
        a = np.load(path)
        np.save(path, fn(a))  # np.save keeps the name when it ends in .npy

    return apply


def image_resize(path: Path) -> None:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(path), cv2.resize(img, (img.shape[1] // 2 + 1, img.shape[0] // 2 + 1)))


def _set(obj, key, value):
    obj[key] = value


def _del(obj, key):
    del obj[key]


def text_edit(fn: Callable[[str], str]) -> Callable[[Path], None]:
    def apply(path: Path) -> None:
        path.write_text(fn(path.read_text()))

    return apply


def npz_edit(fn: Callable[[dict], None]) -> Callable[[Path], None]:
    def apply(path: Path) -> None:
        with np.load(path) as z:
            d = {k: z[k] for k in z.files}
        fn(d)
        with open(path, "wb") as f:
            np.savez(f, **d)

    return apply


def torch_edit(fn: Callable[[dict], object]) -> Callable[[Path], None]:
    def apply(path: Path) -> None:
        import torch

        obj = torch.load(path, map_location="cpu", weights_only=False)
        out = fn(obj)
        torch.save(obj if out is None else out, path)

    return apply


# -- the table ----------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Case:
    id: str
    target: str  # which input kind and entry point (see TARGETS)
    file: str  # the corrupted path, relative to the input's root ("@out/...": the output dir)
    corruption: str  # what was done, for the README table
    fragment: str  # must appear in the error message (case-insensitive)
    apply: Callable[[Path], None]
    names: str | None = None  # the path the message must name (default: ``file``)


# target -> (what it is, how it is run)
TARGETS = {
    "hypernerf": "HyperNeRF-format scene (nerfies), `trase-bench run`",
    "hypernerf-named": "HyperNeRF scene under a paper sequence name, `trase-bench run --sequence americano`",
    "nerfds": "NeRF-DS-format scene (nerfies), `trase-bench run`",
    "neu3d": "Neu3D raw download, `trase-bench prepare`",
    "immersive": "Immersive raw download, `trase-bench prepare`",
    "technicolor": "Technicolor raw download, `trase-bench prepare`",
    "gt": "mask images, `trase-bench score`",
    "masks": "mask file, `masks.load`",
    "checkpoint": "model directory, `trase.checkpoint.load_model`",
    "geometry": "synthetic geometry.npz, `trase.checkpoint.load_tabulated_geometry`",
    "results": "results.json, `trase-bench leaderboard`",
}

NAN = float("nan")

CASES: list[Case] = [
    # ---- nerfies (HyperNeRF) through `trase-bench run` ----
    Case("hn-dataset-truncated", "hypernerf", "dataset.json", "truncated to half", "malformed JSON", truncate),
    Case("hn-dataset-not-utf8", "hypernerf", "dataset.json", "invalid UTF-8 bytes", "not UTF-8", non_utf8),
    Case("hn-dataset-no-ids", "hypernerf", "dataset.json", "key `ids` removed", "missing key 'ids'",
         edit_json(lambda d: _del(d, "ids"))),
    Case("hn-dataset-ids-not-list", "hypernerf", "dataset.json", "`ids` is a number", "ids must be a list",
         edit_json(lambda d: _set(d, "ids", 7))),
    Case("hn-metadata-missing-item", "hypernerf", "metadata.json", "one item's entry removed (counts differ)", "no entry for item '000004'",
         edit_json(lambda d: _del(d, "000004"))),
    Case("hn-metadata-empty", "hypernerf", "metadata.json", "empty file", "malformed JSON", empty_file),
    Case("hn-camera-nan-pose", "hypernerf", "camera/000004.json", "NaN in orientation", "orientation contains NaN",
         edit_json(lambda d: d["orientation"][0].__setitem__(0, NAN))),
    Case("hn-camera-no-focal", "hypernerf", "camera/000004.json", "key `focal_length` removed", "missing key 'focal_length'",
         edit_json(lambda d: _del(d, "focal_length"))),
    Case("hn-camera-bad-shape", "hypernerf", "camera/000004.json", "orientation is 2x3", "orientation has shape (2, 3)",
         edit_json(lambda d: _set(d, "orientation", d["orientation"][:2]))),
    Case("hn-camera-missing", "hypernerf", "camera/000004.json", "file deleted", "camera file not found", delete),
    Case("hn-camera-string-focal", "hypernerf", "camera/000008.json", "focal_length is a string", "focal_length is not a number",
         edit_json(lambda d: _set(d, "focal_length", "big"))),
    Case("hn-image-unreadable", "hypernerf", "rgb/2x/000004.png", "garbage bytes", "cannot read image", garbage),
    Case("hn-image-truncated", "hypernerf", "rgb/2x/000002.png", "test view's PNG truncated", "cannot decode image", truncate),
    Case("hn-image-missing", "hypernerf", "rgb/2x/000008.png", "file deleted", "missing image", delete),
    Case("hn-image-wrong-size", "hypernerf", "rgb/2x/000004.png", "image resized", "image is 33x25", image_resize),
    Case("hn-points-truncated", "hypernerf", "points.npy", "truncated .npy", "cannot read", truncate),
    Case("hn-points-wrong-shape", "hypernerf", "points.npy", "points are [N, 2]", "points must be [N, 3]",
         edit_npy(lambda a: a[:, :2])),
    Case("hn-points-nan", "hypernerf", "points.npy", "NaN coordinates", "NaN",
         edit_npy(lambda a: np.where(np.arange(a.shape[0])[:, None] == 0, np.nan, a))),
    Case("hn-scene-no-scale", "hypernerf", "scene.json", "key `scale` removed", "missing key 'scale'",
         edit_json(lambda d: _del(d, "scale"))),
    Case("hn-empty-dir", "hypernerf-named", ".", "scene directory emptied", "dataset.json: file not found", empty_dir),
    # ---- nerfies (NeRF-DS) ----
    Case("nd-dataset-no-val", "nerfds", "dataset.json", "key `val_ids` removed", "missing key 'val_ids'",
         edit_json(lambda d: _del(d, "val_ids"))),
    Case("nd-camera-nan-position", "nerfds", "camera/left_00002.json", "NaN in position", "position contains NaN",
         edit_json(lambda d: d["position"].__setitem__(1, NAN))),
    Case("nd-metadata-not-object", "nerfds", "metadata.json", "top level is a list", "top level is not a JSON object",
         edit_json(lambda d: list(d.values()))),
    Case("nd-image-truncated", "nerfds", "rgb/2x/right_00001.png", "test view's PNG truncated", "cannot decode image",
         truncate),
    # ---- Neu3D raw through `trase-bench prepare` ----
    Case("n3-poses-truncated", "neu3d", "poses_bounds.npy", "truncated .npy", "cannot read", truncate),
    Case("n3-poses-wrong-shape", "neu3d", "poses_bounds.npy", "N x 15 instead of N x 17", "expected shape [N, 17]",
         edit_npy(lambda a: a[:, :15])),
    Case("n3-poses-nan", "neu3d", "poses_bounds.npy", "NaN in a pose", "contains NaN",
         edit_npy(lambda a: np.where(np.arange(a.size).reshape(a.shape) == 3, np.nan, a))),
    Case("n3-poses-count", "neu3d", "poses_bounds.npy", "one row fewer than videos", "17 poses for 18 videos",
         edit_npy(lambda a: a[:-1])),
    Case("n3-video-garbage", "neu3d", "cam01.mp4", "garbage bytes", "cannot open video", garbage),
    Case("n3-video-truncated", "neu3d", "cam02.mp4", "truncated video", "cannot open video", lambda p: truncate(p, 0.05)),
    Case("n3-old-manifest-garbage", "neu3d", "@out/prepared.json", "OUT_DIR holds a damaged prepared.json",
         "malformed JSON in prepared manifest", garbage),
    Case("n3-old-manifest-list", "neu3d", "@out/prepared.json", "OUT_DIR's prepared.json is a list",
         "not a JSON object", lambda p: p.write_text("[1, 2]")),
    Case("n3-empty-dir", "neu3d", ".", "raw directory emptied", "no camNN.mp4 videos", empty_dir),
    # ---- Immersive raw ----
    Case("im-models-not-utf8", "immersive", "models.json", "invalid UTF-8 bytes", "not UTF-8", non_utf8),
    Case("im-models-no-focal", "immersive", "models.json", "focal_length removed from a camera", "missing key 'focal_length'",
         edit_json(lambda d: _del(d[1], "focal_length"))),
    Case("im-models-nan", "immersive", "models.json", "NaN orientation", "contains NaN",
         edit_json(lambda d: d[2]["orientation"].__setitem__(0, NAN))),
    Case("im-models-extra-camera", "immersive", "models.json", "a camera without a video", "no video for camera_0099",
         edit_json(lambda d: d.append(dict(d[-1], name="camera_0099")))),
    Case("im-video-garbage", "immersive", "camera_0002.mp4", "garbage bytes", "cannot open video", garbage),
    # ---- Technicolor raw ----
    Case("tc-params-truncated", "technicolor", "cameras_parameters.txt", "last rows cut", "13 camera rows but images for 16 cameras",
         text_edit(lambda s: "\n".join(s.splitlines()[:-3]) + "\n")),
    Case("tc-params-not-number", "technicolor", "cameras_parameters.txt", "a value is text", "is not numeric",
         text_edit(lambda s: "\n".join([*s.splitlines()[:2], "x" + s.splitlines()[2], *s.splitlines()[3:]]))),
    Case("tc-params-nan", "technicolor", "cameras_parameters.txt", "NaN quaternion", "contains NaN",
         text_edit(lambda s: "\n".join([*s.splitlines()[:3], " ".join(
             s.splitlines()[3].split()[:5] + ["nan"] + s.splitlines()[3].split()[6:]), *s.splitlines()[4:]]))),
    Case("tc-image-unreadable", "technicolor", "Synthetic_undist_00002_03.png", "garbage bytes", "cannot read image", garbage),
    # ---- mask images through `trase-bench score` ----
    Case("gt-unreadable", "gt", "gt/00001.png", "garbage bytes", "unreadable image", garbage),
    Case("gt-wrong-size", "gt", "pred/00001.png", "prediction resized", "differs from ground truth", image_resize),
    Case("gt-npy-float-nan", "gt", "pred/00002.npy", "NaN in a float mask", "NaN",
         lambda p: np.save(p, np.full((12, 16), np.nan, np.float32))),
    # ---- mask files through masks.load ----
    Case("mask-truncated", "masks", "view.masks", "truncated to half", "truncated", truncate),
    Case("mask-garbage", "masks", "view.masks", "garbage bytes", "not a mask file", garbage),
    Case("mask-empty", "masks", "view.masks", "empty file", "empty file", empty_file),
    Case("mask-official-truncated", "masks", "official.pt", "truncated torch file", "truncated or damaged", truncate),
    Case("mask-official-bitcount", "masks", "official.pt", "N does not match the bit count", "wrong bit count",
         torch_edit(lambda d: _set(d, "N", d["N"] + 1))),
    Case("mask-official-no-H", "masks", "official.pt", "key `H` removed", "missing key(s) 'H'",
         torch_edit(lambda d: _del(d, "H"))),
    # ---- checkpoints ----
    Case("ckpt-ply-truncated", "checkpoint", "point_cloud/iteration_7/point_cloud.ply", "truncated PLY", "not a readable PLY",
         truncate),
    Case("ckpt-ply-garbage", "checkpoint", "point_cloud/iteration_7/point_cloud.ply", "garbage bytes", "not a readable PLY",
         garbage),
    Case("ckpt-deform-garbage", "checkpoint", "deform/iteration_7/deform.pth", "garbage bytes", "not a readable torch state dict", garbage),
    Case("ckpt-deform-missing", "checkpoint", "deform/iteration_7/deform.pth", "file deleted", "deformation weights not found", delete),
    Case("ckpt-empty-dir", "checkpoint", ".", "model directory emptied", "no point_cloud/iteration_N", empty_dir),
    Case("geo-truncated", "geometry", "geometry.npz", "truncated .npz", "not a readable .npz", truncate),
    Case("geo-missing-array", "geometry", "geometry.npz", "array `quats` removed", "missing arrays quats",
         npz_edit(lambda d: _del(d, "quats"))),
    Case("geo-wrong-shape", "geometry", "geometry.npz", "means are [N, 2]", "array means has shape",
         npz_edit(lambda d: _set(d, "means", d["means"][:, :2]))),
    Case("geo-nan", "geometry", "geometry.npz", "NaN in d_xyz", "non-finite",
         npz_edit(lambda d: d["d_xyz"].__setitem__((0, 0, 0), np.nan))),
    # ---- results files through `trase-bench leaderboard` ----
    Case("res-not-utf8", "results", "m/hypernerf/s/main/results.json", "invalid UTF-8 bytes", "not UTF-8", non_utf8),
    Case("res-truncated", "results", "m/hypernerf/s/main/results.json", "truncated JSON", "malformed JSON in results file", truncate),
    Case("res-no-metrics", "results", "m/hypernerf/s/main/results.json", "key `metrics` removed", "lacks key 'metrics'",
         edit_json(lambda d: _del(d, "metrics"))),
    Case("res-miou-range", "results", "m/hypernerf/s/main/results.json", "miou = 2.5", "must be a number in [0, 1]",
         edit_json(lambda d: _set(d["metrics"], "miou", 2.5))),
    Case("res-schema", "results", "m/hypernerf/s/main/results.json", "unknown schema", "unknown results schema",
         edit_json(lambda d: _set(d, "schema", "other/9"))),
    Case("res-not-object", "results", "m/hypernerf/s/main/results.json", "a JSON list", "must be a JSON object",
         edit_json(lambda d: [d])),
]


def markdown_table(cases: list[Case] = CASES) -> str:
    """The catalogue as a markdown table (for the README)."""
    rows = ["| # | id | input (entry point) | file | corruption | error says |",
            "|---|---|---|---|---|---|"]
    for i, c in enumerate(cases, 1):
        rows.append(f"| {i} | `{c.id}` | {TARGETS[c.target]} | `{c.file}` | {c.corruption} | "
                    f"{c.fragment} |")
    return "\n".join(rows)


if __name__ == "__main__":
    print(markdown_table())
