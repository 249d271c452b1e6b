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

import dataclasses
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmark.datasets.truth import write_manifest
from benchmark.errors import UserError
from trase.camera import Camera
from trase.checkpoint import save_tabulated_geometry

from . import formats
from .fit import calibrate_insets, pixel_footprint
from .gaussians import build_geometry
from .rays import camera_rays
from .rigs import (
    DATASET_KEYS,
    DIFFICULTIES,
    SIZE_NAMES,
    STANDARD_TIME,
    hypernerf_rig,
    immersive_rig,
    nerfds_rig,
    neu3d_rig,
    rig_size,
    technicolor_rig,
)
from .world import World, build_world, render

# bump whenever generated files change, so cached scenes of an older generator are never reused
# 2: ground-truth disks sunk by a per-object inset in pixels fitted on the training cameras
# 3: difficulty axis: standard scenes with the benchmarks' frames per sequence and motion per
#    frame (rigs.STANDARD_TIME); the earlier scenes are the "hard" difficulty
GENERATOR_VERSION = "3"
SEQUENCE_NAMES = {"tiny": "synthetic-tiny", "small": "synthetic", "medium": "synthetic-medium"}
HARD_SUFFIX = "-hard"
TECHNICOLOR_FIRST_FRAME = 1  # publisher frame numbers of the PNGs start here

Progress = Callable[[str, int, int], None]  # (stage, done, total)


class SyntheticError(UserError):
    """Bad arguments or an inconsistency between the generator and a loader."""

    user_facing = True


def sequence_name(size: str, difficulty: str = "standard") -> str:
    """The sequence name: "synthetic", "synthetic-medium", ...; the hard variant adds "-hard"."""
    return SEQUENCE_NAMES[size] + (HARD_SUFFIX if difficulty == "hard" else "")


def parse_sequence_name(name: str) -> tuple[str, str] | None:
    """(size, difficulty) of a synthetic sequence name, None for any other name."""
    for difficulty in DIFFICULTIES:
        for size in SIZE_NAMES:
            if sequence_name(size, difficulty) == name:
                return size, difficulty
    return None


def _check_args(dataset: str, size: str, difficulty: str = "standard") -> None:
    if dataset not in DATASET_KEYS:
        raise SyntheticError(f"unknown dataset {dataset!r} for synthetic scenes; valid: {', '.join(DATASET_KEYS)}")
    if size not in SIZE_NAMES:
        raise SyntheticError(f"unknown size {size!r}; valid: {', '.join(SIZE_NAMES)}")
    if difficulty not in DIFFICULTIES:
        raise SyntheticError(f"unknown difficulty {difficulty!r}; valid: {', '.join(DIFFICULTIES)}")


def generate(dataset: str, out_dir: Path | str, seed: int = 0, size: str = "small",
             progress: Progress | None = None, difficulty: str = "standard") -> Path:
    """Write one synthetic scene of ``dataset`` into ``out_dir`` (created; must be empty).

    Returns ``out_dir``. Same (dataset, seed, size, difficulty) -> same bytes (videos: same
    decoded frames).
    """
    _check_args(dataset, size, difficulty)
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()):
        raise SyntheticError(f"{out}: output directory is not empty")
    existed = out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        _generate_into(dataset, out, seed, size, difficulty, progress or (lambda stage, done, total: None))
    except BaseException:
        # everything inside was written by this call (the directory was empty): leave no
        # partial scene behind that a rerun would refuse or, worse, trust
        shutil.rmtree(out, ignore_errors=True)
        if existed:
            out.mkdir(parents=True, exist_ok=True)
        raise
    return out


def _generate_into(dataset: str, out: Path, seed: int, size: str, difficulty: str, report: Progress) -> None:
    rs = rig_size(dataset, size, difficulty)
    world = build_world(seed, rs.span)
    views = rig_views(dataset, size, seed, difficulty)
    sequence = sequence_name(size, difficulty)
    if dataset in ("nerfds", "hypernerf"):
        _write_nerfies(dataset, out, world, views, report)
    else:
        _write_multiview(dataset, out, world, views, report, sequence)

    scene = _load(dataset, out, sequence)
    _check_loader(scene, {v.view: (v.camera, v.time) for v in views})
    _write_truth(scene, out, world, seed, size, difficulty, rs, report)


@dataclasses.dataclass(frozen=True)
class RigView:
    """One raw image the generator writes."""

    view: str  # the loader's View.name: nerfies item id / "<camera>/<frame:05d>"
    camera: Camera  # native camera (full lens model) in the generator's world
    time: float  # the dataset's time rule
    frame: int  # nerfies time_id / publisher frame number
    cam_index: int  # index of the fixed camera in the rig (multi-view), 0 or 1 (nerfds)


def rig_views(dataset: str, size: str = "small", seed: int = 0, difficulty: str = "standard") -> list[RigView]:
    """Every image of the dataset's rig with its native camera and time, in writing order."""
    _check_args(dataset, size, difficulty)
    rs = rig_size(dataset, size, difficulty)
    rng = np.random.default_rng([seed, DATASET_KEYS.index(dataset)])
    if dataset in ("nerfds", "hypernerf"):
        rig = nerfds_rig(rs, rng) if dataset == "nerfds" else hypernerf_rig(rs, rng)
        max_tid = max(rc.frame for rc in rig)
        return [RigView(rc.name, rc.camera, rc.frame / max_tid if max_tid > 0 else 0.0,  # time_id / max
                        rc.frame, 1 if rc.name.startswith("right") else 0) for rc in rig]
    cams = {"neu3d": neu3d_rig, "immersive": immersive_rig, "technicolor": technicolor_rig}[dataset](rs, rng)
    first = TECHNICOLOR_FIRST_FRAME if dataset == "technicolor" else 0
    n = rs.frames
    return [RigView(f"{cam.name}/{first + i:05d}", cam, i / n, first + i, k)  # t = i / n
            for k, cam in enumerate(cams) for i in range(n)]


# -- raw formats --------------------------------------------------------------------------
def _write_nerfies(dataset, out, world, views: list[RigView], report) -> None:
    for k, v in enumerate(views):
        rgb, _, _ = render(world, v.camera, v.time)
        formats.write_nerfies_image(out, v.view, rgb, v.camera)
        report("render", k + 1, len(views))
    if dataset == "nerfds":
        items = [(v.view, v.frame, v.cam_index) for v in views]
        train = [v.view for v in views if v.cam_index == 0]  # left camera
        val = [v.view for v in views if v.cam_index == 1]  # right camera
    else:
        items = [(v.view, v.frame, 0) for v in views]
        ids = [v.view for v in views]
        train, val = ids[0::4], ids[2::4]  # as the publisher's interp dataset.json
    points, _ = sparse_points(world)
    formats.write_nerfies_meta(out, items, train, val, points, near=0.3, far=12.0)


def _write_multiview(dataset, out, world, views: list[RigView], report, sequence) -> None:
    """Raw multi-view scene, then the toolkit's own ``prepare`` into ``<out>/prepared``."""
    cams: dict[int, Camera] = {}
    for v in views:
        cams.setdefault(v.cam_index, v.camera)
    by_cam: dict[int, list[RigView]] = {}
    for v in views:
        by_cam.setdefault(v.cam_index, []).append(v)
    done, bounds = 0, []
    for k, cam in cams.items():
        rays = camera_rays(cam)
        writer = formats.VideoWriter(out / f"{cam.name}.mp4", cam.width, cam.height) if dataset != "technicolor" else None
        depths = None
        for v in by_cam[k]:
            rgb, depth, _ = render(world, cam, v.time, rays)
            if writer is None:
                formats.write_png(out / formats.technicolor_image_name(v.frame, k), rgb)
            else:
                writer.write(rgb)
            if depths is None:
                depths = depth[depth > 0]
            done += 1
            report("render", done, len(views))
        if writer is not None:
            writer.close()
        bounds.append((float(np.percentile(depths, 0.1)) * 0.9, float(np.percentile(depths, 99.9)) * 1.1))
    cam_list = [cams[k] for k in sorted(cams)]
    if dataset == "neu3d":
        formats.write_poses_bounds(out, cam_list, bounds)
    elif dataset == "immersive":
        formats.write_models_json(out, cam_list)
    else:
        formats.write_technicolor_params(out, cam_list)
    frames = sorted({v.frame for v in views})
    # an SfM-like sparse cloud of the first frame (what COLMAP would give a real user)
    pts, cols = sparse_points(world, float(views[0].time))
    ply = out / "synthetic" / "sparse_points.ply"
    formats.write_points_ply(ply, pts, cols)
    _prepare(dataset, out, frames, report, sequence, ply)


def sparse_points(world: World, t: float = 0.0, n: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    """(points [M, 3], colours [M, 3] in [0, 1]): surface samples of the scene at time t."""
    g = build_geometry(world, np.array([t]), n, inset=0.0)
    return (g["means"] + g["d_xyz"][0]).astype(np.float64), g["colors"].astype(np.float64)


def _prepare(dataset: str, out: Path, frames: list[int], report, sequence: str, points: Path) -> None:
    from benchmark.datasets.prepare import prepare_sequence

    state = {"total": 0, "done": 0}

    def on_start(total):
        state["total"] = total

    def on_image():
        state["done"] += 1
        report("prepare", state["done"], state["total"])

    prepare_sequence(dataset, out, out / "prepared", sequence=sequence, frames=frames, points=points,
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


def _write_truth(scene, out: Path, world: World, seed: int, size: str, difficulty: str, rs, report) -> None:
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
    # silhouettes of the gaussians fitted on the training cameras only (see fit.py)
    train_cams = [v.camera for v in scene.train]
    insets, fit_report = calibrate_insets(world, scene.times, rs.gaussians, train_cams)
    geom = build_geometry(world, scene.times, rs.gaussians, inset=insets, footprint=pixel_footprint(train_cams))
    save_tabulated_geometry(syn / "geometry.npz", geom)
    report("geometry", 1, 1)
    manifest = {
        "generator_version": GENERATOR_VERSION,
        "dataset": scene.dataset,
        "sequence": scene.sequence,
        "seed": int(seed),
        "size": size,
        "difficulty": difficulty,
        "frames_per_camera": rs.frames,
        "motion_span": rs.span,
        "time_statistics": dataclasses.asdict(STANDARD_TIME[scene.dataset]) if difficulty == "standard" and size != "tiny" else None,
        "n_gaussians": len(geom["means"]),
        "times": [float(t) for t in scene.times],
        "objects": world.object_table(),
        "objects_of_interest": [o.name for o in interest],
        "instances": instances,
        "gt_masks": "gt_masks/{idx:05d}.png (objects of interest merged); gt_masks/<object>/{idx:05d}.png",
        "geometry": "geometry.npz",
        "geometry_fit": {"unit": "pixels of the training cameras (median depth / focal)",
                         "objects": fit_report},
    }
    write_manifest(out, manifest)
    # the text protocol's phrases (benchmark.protocol.text): "the <object>" per object of interest
    formats.write_json(out / "prompts_text.json", {scene.sequence: [f"the {o.name}" for o in interest]})
