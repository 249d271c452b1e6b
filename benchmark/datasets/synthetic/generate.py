"""``generate``: one synthetic scene in a benchmark's raw format, plus exact ground truth.

Steps: (1) ray cast every image of the dataset's rig at native resolution with its lens model
and write the publisher's raw files; (2) multi-view formats are prepared with the toolkit's
own ``prepare`` (frames, undistortion, principal point) into ``<scene>/prepared``; (3) the scene
is read back with ``load_scene`` and its cameras and times are checked against the rig; (4) the
truth is rendered through *the loader's* training cameras, so ground truth and loader always
agree: ``gt_masks/{idx:05d}.png`` (objects of interest merged, 0/255) and
``gt_masks/<object>/{idx:05d}.png`` per test view, ``synthetic/instances/*.png`` (uint16 ids)
for every view, ``synthetic/geometry.npz`` (gaussians + tabulated deformation at the loader's
times) and ``synthetic/manifest.json``.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmark.errors import UserError

from . import formats
from .gaussians import build_geometry
from .rays import camera_rays
from .rigs import (
    DATASET_KEYS,
    SIZE_NAMES,
    SIZES,
    hypernerf_rig,
    immersive_rig,
    nerfds_rig,
    neu3d_rig,
    technicolor_rig,
)
from .world import World, build_world, render

GENERATOR_VERSION = "1"
SEQUENCE_NAMES = {"tiny": "synthetic-tiny", "small": "synthetic", "medium": "synthetic-medium"}
TECHNICOLOR_FIRST_FRAME = 1  # publisher frame numbers of the PNGs start here

Progress = Callable[[str, int, int], None]  # (stage, done, total)


class SyntheticError(UserError):
    """Bad arguments or an inconsistency between the generator and a loader."""

    user_facing = True


def sequence_name(size: str) -> str:
    return SEQUENCE_NAMES[size]


def _check_args(dataset: str, size: str) -> None:
    if dataset not in DATASET_KEYS:
        raise SyntheticError(f"unknown dataset {dataset!r} for synthetic scenes; valid: {', '.join(DATASET_KEYS)}")
    if size not in SIZE_NAMES:
        raise SyntheticError(f"unknown size {size!r}; valid: {', '.join(SIZE_NAMES)}")


def generate(dataset: str, out_dir: Path | str, seed: int = 0, size: str = "small",
             progress: Progress | None = None) -> Path:
    """Write one synthetic scene of ``dataset`` into ``out_dir`` (created; must be empty).

    Returns ``out_dir``. Same (dataset, seed, size) -> same bytes (videos: same decoded frames).
    """
    _check_args(dataset, size)
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()):
        raise SyntheticError(f"{out}: output directory is not empty")
    out.mkdir(parents=True, exist_ok=True)
    report = progress or (lambda stage, done, total: None)
    world = build_world(seed)
    rng = np.random.default_rng([seed, DATASET_KEYS.index(dataset)])
    rs = SIZES[dataset][size]

    if dataset in ("nerfds", "hypernerf"):
        expected = _write_nerfies(dataset, out, world, rs, rng, report)
    else:
        expected = _write_multiview(dataset, out, world, rs, rng, report, sequence_name(size))

    scene = _load(dataset, out, sequence_name(size))
    _check_loader(scene, expected)
    _write_truth(scene, out, world, seed, size, rs.gaussians, report)
    return out


# -- raw formats --------------------------------------------------------------------------
def _write_nerfies(dataset, out, world, rs, rng, report) -> dict:
    """Raw nerfies scene; returns {item: (native camera in world coords, time)}."""
    rig = nerfds_rig(rs, rng) if dataset == "nerfds" else hypernerf_rig(rs, rng)
    max_tid = max(rc.frame for rc in rig)
    expected = {}
    for k, rc in enumerate(rig):
        t = rc.frame / max_tid if max_tid > 0 else 0.0  # nerfies time rule
        rgb, _, _ = render(world, rc.camera, t)
        formats.write_nerfies_image(out, rc.name, rgb, rc.camera)
        expected[rc.name] = (rc.camera, t)
        report("render", k + 1, len(rig))
    if dataset == "nerfds":
        items = [(rc.name, rc.frame, 0 if rc.name.startswith("left") else 1) for rc in rig]
        train = [rc.name for rc in rig if rc.name.startswith("left")]
        val = [rc.name for rc in rig if rc.name.startswith("right")]
    else:
        items = [(rc.name, rc.frame, 0) for rc in rig]
        ids = [rc.name for rc in rig]
        train, val = ids[0::4], ids[2::4]  # as the publisher's interp dataset.json
    points = build_geometry(world, np.zeros(1), 4000)["means"].astype(np.float64)
    formats.write_nerfies_meta(out, items, train, val, points, near=0.3, far=12.0)
    return expected


def _write_multiview(dataset, out, world, rs, rng, report, sequence) -> dict:
    """Raw multi-view scene (+ prepared frames); returns {view name: (native camera, time)}."""
    cams = {"neu3d": neu3d_rig, "immersive": immersive_rig, "technicolor": technicolor_rig}[dataset](rs, rng)
    n = rs.frames
    total = len(cams) * n
    done = 0
    writers = {}
    bounds = []
    expected = {}
    first = TECHNICOLOR_FIRST_FRAME if dataset == "technicolor" else 0
    for k, cam in enumerate(cams):
        rays = camera_rays(cam)
        if dataset == "neu3d":
            writers[cam.name] = formats.VideoWriter(out / f"{cam.name}.mp4", cam.width, cam.height)
        elif dataset == "immersive":
            writers[cam.name] = formats.VideoWriter(out / f"{cam.name}.mp4", cam.width, cam.height)
        depths = []
        for i in range(n):
            t = i / n  # multi-view time rule
            rgb, depth, _ = render(world, cam, t, rays)
            if dataset == "technicolor":
                formats.write_png(out / formats.technicolor_image_name(first + i, k), rgb)
            else:
                writers[cam.name].write(rgb)
            if i == 0:
                depths = depth[depth > 0]
            expected[f"{cam.name}/{first + i:05d}"] = (cam, t)
            done += 1
            report("render", done, total)
        if cam.name in writers:
            writers[cam.name].close()
        bounds.append((float(np.percentile(depths, 0.1)) * 0.9, float(np.percentile(depths, 99.9)) * 1.1))
    if dataset == "neu3d":
        formats.write_poses_bounds(out, cams, bounds)
    elif dataset == "immersive":
        formats.write_models_json(out, cams)
    else:
        formats.write_technicolor_params(out, cams)
    frames = [first + i for i in range(n)]
    _prepare(dataset, out, frames, report, sequence)
    return expected


def _prepare(dataset: str, out: Path, frames: list[int], report, sequence: str) -> None:
    from benchmark.datasets.prepare import prepare_sequence

    state = {"total": 0, "done": 0}

    def on_start(total):
        state["total"] = total

    def on_image():
        state["done"] += 1
        report("prepare", state["done"], state["total"])

    prepare_sequence(dataset, out, out / "prepared", sequence=sequence, frames=frames,
                     on_start=on_start, on_image=on_image)


def _load(dataset: str, out: Path, sequence: str):
    """The views as the loader builds them. The format readers are used directly because
    the ground truth ``load_scene`` would align does not exist yet."""
    from benchmark.datasets.registry import get_dataset

    spec = get_dataset(dataset)
    if spec.format == "nerfies":
        from benchmark.datasets.nerfies import load_nerfies

        return load_nerfies(spec, out, sequence)
    from benchmark.datasets.prepared import load_prepared

    return load_prepared(spec, out / "prepared", sequence)


def _check_loader(scene, expected: dict) -> None:
    """The loader must see the rig's poses, lens and times; else the truth would be wrong."""
    views = scene.train + scene.test
    names = {v.name for v in views}
    extra = sorted(names - set(expected))[:3]
    if extra or not scene.test or not scene.train:
        raise SyntheticError(f"{scene.root}: loader views differ from the rig's images (unknown: {extra}, "
                             f"{len(scene.train)} train / {len(scene.test)} test views)")
    for v in views:
        cam, t = expected[v.name]
        if abs(v.time - t) > 1e-9:
            raise SyntheticError(f"{scene.root}: view {v.name} has time {v.time}, the generator used {t}")
        if not np.allclose(v.camera.w2c, cam.w2c, atol=1e-6, rtol=0):
            raise SyntheticError(f"{scene.root}: view {v.name}: loader pose differs from the generator's")
        nat = v.native_camera
        if nat is not None and not (np.allclose(nat.K, cam.K, atol=1e-6, rtol=0)
                                    and np.allclose(nat.radial, cam.radial, atol=1e-9)
                                    and np.allclose(nat.tangential, cam.tangential, atol=1e-9)
                                    and nat.fisheye == cam.fisheye):
            raise SyntheticError(f"{scene.root}: view {v.name}: loader lens differs from the generator's")


# -- ground truth -------------------------------------------------------------------------
def instance_file(view_name: str) -> str:
    """Relative path of a view's instance map (view names may contain '/')."""
    return "instances/" + re.sub(r"[^A-Za-z0-9._-]", "__", view_name) + ".png"


def _write_truth(scene, out: Path, world: World, seed: int, size: str, budget: int, report) -> None:
    syn = out / "synthetic"
    syn.mkdir(parents=True, exist_ok=True)
    interest = world.of_interest()
    views = scene.train + scene.test
    instances = {}
    test_index = {v.name: k for k, v in enumerate(scene.test)}
    gt = out / "gt_masks"
    for k, v in enumerate(views):
        _, _, ids = render(world, v.camera, v.time)
        rel = instance_file(v.name)
        formats.write_png(syn / rel, ids.astype(np.uint16))
        instances[v.name] = rel
        if v.name in test_index:
            idx = test_index[v.name]
            merged = np.isin(ids, [o.id for o in interest])
            formats.write_png(gt / f"{idx:05d}.png", (merged * 255).astype(np.uint8))
            for o in interest:
                formats.write_png(gt / o.name / f"{idx:05d}.png", ((ids == o.id) * 255).astype(np.uint8))
        report("truth", k + 1, len(views))
    report("geometry", 0, 1)
    geom = build_geometry(world, scene.times, budget)
    np.savez_compressed(syn / "geometry.npz", **geom)
    report("geometry", 1, 1)
    manifest = {
        "generator_version": GENERATOR_VERSION,
        "dataset": scene.dataset,
        "sequence": scene.sequence,
        "seed": int(seed),
        "size": size,
        "n_gaussians": int(len(geom["means"])),
        "times": [float(t) for t in scene.times],
        "objects": world.object_table(),
        "objects_of_interest": [o.name for o in interest],
        "instances": instances,
        "gt_masks": "gt_masks/{idx:05d}.png (objects of interest merged); gt_masks/<object>/{idx:05d}.png",
        "geometry": "geometry.npz",
    }
    (syn / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
