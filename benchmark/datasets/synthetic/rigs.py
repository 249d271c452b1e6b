"""Camera rigs like the real datasets', at native resolution with each format's lens model.

* nerfds: a stereo pair moving together along a slow arc; left = train, right = test.
* hypernerf: one hand-held-like moving camera (interp split by the registry).
* neu3d: ~18 fixed, roughly forward-facing cameras on a gentle arc, pinhole, centred
  principal point (LLFF stores only H, W, focal).
* immersive: fixed equidistant-fisheye cameras on a spherical cap (a dome looking outwards).
* technicolor: a 4x4 planar array of parallel pinhole cameras, off-centre principal point.

Sizes: ``small`` keeps the loader's training resolution <= 160 px wide; ``medium`` is for
benchmarks; ``tiny`` is for unit tests (few frames, whatever the difficulty).

Difficulty: ``standard`` scenes follow the real benchmarks' statistics in time (see
``STANDARD_TIME``); ``hard`` scenes are the generator's earlier scenes, kept for stress runs:
every object's whole path (the pillar and the cube cross the room) squeezed into 10-60 frames,
4-25x fewer than the benchmarks have, so objects move 4-30x further per frame than in any of them.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from trase.camera import Camera, intrinsics, look_at

DATASET_KEYS = ("nerfds", "hypernerf", "neu3d", "immersive", "technicolor")
SIZE_NAMES = ("tiny", "small", "medium")
DIFFICULTIES = ("standard", "hard")


@dataclasses.dataclass(frozen=True)
class RigSize:
    width: int  # native image width (the loader trains at width / 2)
    height: int
    frames: int  # time steps (per camera)
    cameras: int  # fixed cameras (multi-view) / moving cameras (nerfies)
    gaussians: int  # budget of ground-truth gaussians
    span: float = 1.0  # part of the objects' motion the sequence covers (world.build_world)


# the ``hard`` scenes: the generator's scenes up to version 2, unchanged
HARD_SIZES: dict[str, dict[str, RigSize]] = {
    "nerfds": {
        "tiny": RigSize(128, 96, 6, 2, 4000),
        "small": RigSize(320, 240, 24, 2, 24000),
        "medium": RigSize(640, 480, 80, 2, 60000),
    },
    "hypernerf": {
        "tiny": RigSize(128, 96, 12, 1, 4000),
        "small": RigSize(320, 240, 60, 1, 24000),
        "medium": RigSize(640, 480, 160, 1, 60000),
    },
    "neu3d": {
        "tiny": RigSize(96, 72, 3, 18, 4000),
        "small": RigSize(256, 192, 12, 18, 24000),
        "medium": RigSize(512, 384, 30, 18, 60000),
    },
    "immersive": {
        "tiny": RigSize(96, 72, 3, 10, 4000),
        "small": RigSize(256, 192, 12, 10, 24000),
        "medium": RigSize(512, 384, 30, 12, 60000),
    },
    "technicolor": {
        "tiny": RigSize(128, 68, 3, 16, 4000),
        "small": RigSize(320, 176, 10, 16, 24000),
        "medium": RigSize(640, 352, 25, 16, 60000),
    },
}


@dataclasses.dataclass(frozen=True)
class TimeStatistics:
    """How a benchmark samples time, where the figure comes from, and what the scene uses."""

    benchmark_frames: int  # frames per sequence (per camera) in the real benchmark
    fps: float  # capture frame rate
    source: str
    frames: int = 0  # frames the standard scene has (0: benchmark_frames)
    why: str = ""  # why ``frames`` differs from ``benchmark_frames``

    def __post_init__(self) -> None:
        if self.frames == 0:
            object.__setattr__(self, "frames", self.benchmark_frames)


# Frames per sequence of the real benchmarks (per camera). Object motion per frame is the
# other half: in the world's units (metres), the fastest object of the hard scenes (the cube)
# travels 6.4 m over the sequence and the pillar 5.4 m; the standard scenes cover the part of
# that motion (``span``) at which the fastest object moves at most MAX_MOTION_PER_FRAME per
# frame, i.e. 0.9 m/s at 30 fps: a quick hand or arm, a walking person. That speed is an
# estimate from the benchmarks' content (people cooking, welding, turning; hands moving objects
# on a table); the datasets publish no motion statistics.
STANDARD_TIME: dict[str, TimeStatistics] = {
    "nerfds": TimeStatistics(150, 30.0, "NeRF-DS (Yan et al. 2023): stereo rig, left camera trains and right "
                             "camera tests; a few hundred frames per camera (approximate: no release "
                             "file was checked here), the lower end taken"),
    "hypernerf": TimeStatistics(200, 15.0, "HyperNeRF interp captures (Park et al. 2021): a few hundred frames "
                                "(approximate: no release file was checked here); the Mask benchmark trains "
                                "on every 4th and tests on every 4th from the third"),
    "neu3d": TimeStatistics(300, 30.0, "Neu3D (Li et al. 2022; the paper's supplementary): 300 frames at 30 fps, "
                            "18-21 cameras", frames=100,
                            why="18 cameras x 300 frames is 5400 ray-cast images (~20 min to generate on 2 "
                                "cores) and 5100 training views; 100 frames (3.3 s) keep the motion per frame"),
    "immersive": TimeStatistics(50, 30.0, "Immersive-Mask (the paper's supplementary): the first 50 frames at "
                                "30 fps of a 46-camera fisheye dome"),
    "technicolor": TimeStatistics(50, 30.0, "Technicolor-Mask (the paper's supplementary): 50 frames per scene "
                                  "(e.g. Birthday 151-200) of a 4x4 array at 30 fps"),
}
FASTEST_PATH_M = 6.4  # the cube's path over the hard sequence (world.py)
MAX_MOTION_PER_FRAME = 0.03  # metres per frame for the fastest object (0.9 m/s at 30 fps)


def standard_span(frames: int) -> float:
    """Part of the motion a standard sequence of ``frames`` frames covers."""
    return min(1.0, frames * MAX_MOTION_PER_FRAME / FASTEST_PATH_M)


def _standard(dataset: str) -> dict[str, RigSize]:
    n = STANDARD_TIME[dataset].frames
    hard = HARD_SIZES[dataset]
    return {
        "tiny": hard["tiny"],  # unit-test scenes: few frames, the whole motion
        "small": dataclasses.replace(hard["small"], frames=n, span=standard_span(n)),
        "medium": dataclasses.replace(hard["medium"], frames=n, span=standard_span(n)),
    }


STANDARD_SIZES: dict[str, dict[str, RigSize]] = {ds: _standard(ds) for ds in DATASET_KEYS}
SIZES = STANDARD_SIZES  # the default difficulty
_TABLES = {"standard": STANDARD_SIZES, "hard": HARD_SIZES}


def rig_size(dataset: str, size: str = "small", difficulty: str = "standard") -> RigSize:
    return _TABLES[difficulty][dataset][size]


TARGET = np.array([0.0, 0.3, 0.45])  # where the rigs look


@dataclasses.dataclass(frozen=True)
class RigCamera:
    """One image of the rig: its raw name, native camera (full lens, world pose), frame index."""

    name: str  # raw item id (nerfies) / camera name (multi-view)
    camera: Camera
    frame: int


def _nerfies_lens(rng: np.random.Generator) -> dict:
    # small, like the publishers' phones: the loader drops it (< ~0.5 px at 2x)
    return {
        "radial": (-0.010 + rng.uniform(-0.002, 0.002), 0.002, 0.0),
        "tangential": (2e-4, -1e-4),
    }


def nerfds_rig(size: RigSize, rng: np.random.Generator) -> list[RigCamera]:
    """Left/right stereo pair on a slow arc; item ids left_XXXXX / right_XXXXX, time_id = XXXXX."""
    W, H, n = size.width, size.height, size.frames
    f = 0.95 * W
    lens = _nerfies_lens(rng)
    out: list[RigCamera] = []
    for side, dx in (("left", -0.06), ("right", 0.06)):
        for i in range(n):
            a = i / max(n - 1, 1)
            ang = -0.35 + 0.7 * a
            eye = np.array([3.1 * math.sin(ang), -3.1 * math.cos(ang) + 0.3, 1.25 + 0.1 * math.sin(3 * a)])
            w2c = look_at(eye, TARGET)
            # the pair shares orientation; the right camera sits 12 cm to the right
            R = w2c[:3, :3]
            eye_s = eye + R[0] * dx
            w2c_s = np.eye(4)
            w2c_s[:3, :3] = R
            w2c_s[:3, 3] = -R @ eye_s
            cam = Camera(intrinsics(f, f, W / 2 + 1.5, H / 2 - 1.0), w2c_s, W, H,
                         name=f"{side}_{i:05d}", **lens)
            out.append(RigCamera(f"{side}_{i:05d}", cam, i))
    return out


def hypernerf_rig(size: RigSize, rng: np.random.Generator) -> list[RigCamera]:
    """One moving camera (hand-held wobble around an arc); item ids XXXXXX, time_id = index."""
    W, H, n = size.width, size.height, size.frames
    f = 0.9 * W
    lens = _nerfies_lens(rng)
    out = []
    for i in range(n):
        a = i / max(n - 1, 1)
        ang = 0.45 * math.sin(2 * math.pi * a * 0.75)
        eye = np.array([3.0 * math.sin(ang), -3.0 * math.cos(ang) + 0.3, 1.2 + 0.25 * math.sin(2 * math.pi * a)])
        eye = eye + 0.02 * np.array([math.sin(17 * a), math.cos(13 * a), math.sin(11 * a)])
        cam = Camera(intrinsics(f, f, W / 2 - 1.0, H / 2 + 0.5), look_at(eye, TARGET), W, H,
                     name=f"{i:06d}", **lens)
        out.append(RigCamera(f"{i:06d}", cam, i))
    return out


def neu3d_names(n: int) -> list[str]:
    """cam00.. with one number skipped (cam03), as real Neu3D folders lack some cameras, so
    "row i = i-th video in sorted order" is exercised."""
    nums = [k for k in range(n + 1) if k != 3][:n]
    return [f"cam{k:02d}" for k in nums]


def neu3d_rig(size: RigSize, rng: np.random.Generator) -> list[Camera]:
    """Fixed forward-facing cameras on a gentle arc (cam00 in the middle, the test camera)."""
    W, H = size.width, size.height
    f = 0.85 * W
    names = neu3d_names(size.cameras)
    cams = []
    n = len(names)
    cols = math.ceil(n / 2)
    for k, name in enumerate(names):
        if k == 0:
            u, v = 0.0, 0.0
        else:
            j = k - 1
            u = ((j % cols) / max(cols - 1, 1)) * 2 - 1
            v = -0.5 if j < cols else 0.5
        eye = np.array([0.75 * u, -3.2 + 0.15 * u * u, 1.15 + 0.25 * v])
        tgt = TARGET + np.array([0.15 * u, 0.0, 0.0])
        cams.append(Camera(intrinsics(f, f, W / 2, H / 2), look_at(eye, tgt), W, H, name=name))
    return cams


def immersive_rig(size: RigSize, rng: np.random.Generator) -> list[Camera]:
    """Equidistant-fisheye cameras on a dome (sphere cap of radius 0.45 m) looking outwards."""
    W, H = size.width, size.height
    f = W / 2 / 0.85  # 0.85 rad (49 deg) to the left/right image border
    centre = np.array([0.0, -2.7, 1.0])
    cams = []
    n = size.cameras
    for k in range(n):
        if k == 0:
            az, el = 0.0, 0.0
        else:
            ring = 0.22 if k <= 6 else 0.40
            m = 6 if k <= 6 else max(n - 7, 1)
            j = (k - 1) if k <= 6 else (k - 7)
            phi = 2 * math.pi * j / m + (0.0 if k <= 6 else 0.5)
            az, el = ring * math.cos(phi), ring * 0.7 * math.sin(phi)
        d = np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])
        eye = centre + 0.45 * d
        cam = Camera(intrinsics(f, f, W / 2 + 0.7, H / 2 - 0.4), look_at(eye, eye + d), W, H,
                     name=f"camera_{k + 1:04d}", radial=(0.02, -0.004, 0.0), fisheye=True)
        cams.append(cam)
    return cams


def technicolor_rig(size: RigSize, rng: np.random.Generator) -> list[Camera]:
    """4x4 planar array of parallel cameras, 8 cm apart, row-major; camera 0 is the test one."""
    W, H = size.width, size.height
    f = 0.9 * W
    base = look_at(np.array([0.0, -3.3, 1.1]), TARGET)
    R = base[:3, :3]
    centre = -R.T @ base[:3, 3]
    cams = []
    for k in range(16):
        r, c = divmod(k, 4)
        eye = centre + R[0] * (c - 1.5) * 0.08 + R[1] * (r - 1.5) * 0.08
        w2c = np.eye(4)
        w2c[:3, :3] = R
        w2c[:3, 3] = -R @ eye
        cx = W / 2 + 6.0 + 0.5 * c
        cy = H / 2 - 3.0 + 0.5 * r
        cams.append(Camera(intrinsics(f, f, cx, cy), w2c, W, H, name=f"cam{k:02d}"))
    return cams
