"""The five *-Mask benchmarks exactly as the paper defines them (supplementary, sec. 7-8).

One frozen ``DatasetSpec`` per benchmark: which sequences, how they split into train and test
views, at which resolution and over which frames, how times are normalised, and the per-dataset
defaults of the method (Np, M', filter threshold, warm-up, densify-until). Loaders and the
runner read these; nothing else in the toolkit hard-codes a dataset fact.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

from benchmark.datasets.errors import DatasetError

Format = Literal["nerfies", "neu3d", "immersive", "technicolor"]

MULTI_VIEW_FORMATS = ("neu3d", "immersive", "technicolor")


@dataclasses.dataclass(frozen=True)
class DatasetSpec:
    key: str  # registry key, also the folder name under the data root
    display_name: str  # "HyperNeRF-Mask": folder name of the Mask-Benchmark ground truth
    format: Format  # on-disk format of the publisher's raw data
    monocular: bool
    sequences: tuple[str, ...]  # the paper's sequences, in the paper's order
    split: str  # human-readable split rule (the loaders implement it)
    test_camera: str | None  # multi-view: name of the held-out camera; nerfies: None
    downscale: int  # native -> training resolution factor
    resolution: tuple[int, int] | None  # (W, H) at training resolution; None: per sequence
    frame_ranges: dict[str, tuple[int, int]] | None  # seq -> (first, last) inclusive, publisher numbering
    time_rule: str  # human-readable time normalisation (time_of / nerfies_time implement it)
    # the geometry every method segments: the public code's per-dataset reconstruction schedule
    warm_up: int  # reconstruction iterations before the deformation MLP is switched on
    densify_until: int  # last densification iteration
    aliases: dict[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)  # seq -> raw folder names
    notes: str = ""

    # -- sequences ------------------------------------------------------------------------
    def resolve_sequence(self, name: str) -> str:
        """The canonical sequence name for ``name`` or one of its raw folder aliases."""
        if name in self.sequences:
            return name
        for seq, names in self.aliases.items():
            if name in names:
                return seq
        raise DatasetError(
            f"{self.key}: unknown sequence {name!r}; valid: {', '.join(self.sequences)} "
            f"(a capture of your own: trase-bench fit --scene DIR)"
        )

    def folder_names(self, sequence: str) -> tuple[str, ...]:
        """Folder names a sequence may have on disk: canonical first, then publisher aliases."""
        seq = self.resolve_sequence(sequence)
        return (seq, *self.aliases.get(seq, ()))

    def frames(self, sequence: str) -> list[int]:
        """Publisher frame numbers of the benchmark's range (multi-view formats only)."""
        if self.frame_ranges is None:
            raise DatasetError(f"{self.key}: frames are listed by dataset.json, not by a range")
        first, last = self.frame_ranges[self.resolve_sequence(sequence)]
        return list(range(first, last + 1))

    # -- time ---------------------------------------------------------------------------
    def time_of(self, index: int, n: int) -> float:
        """Multi-view time rule: frame ``index`` (0..n-1 within the range) -> index / n."""
        if self.format == "nerfies":
            raise DatasetError(f"{self.key}: nerfies times come from time ids, use nerfies_time")
        if n <= 0 or not 0 <= index < n:
            raise DatasetError(f"{self.key}: frame index {index} outside 0..{n - 1}")
        return index / n

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["sequences"] = list(self.sequences)
        d["resolution"] = list(self.resolution) if self.resolution else None
        if self.frame_ranges is not None:
            d["frame_ranges"] = {k: list(v) for k, v in self.frame_ranges.items()}
        d["aliases"] = {k: list(v) for k, v in self.aliases.items()}
        return d


def nerfies_time(time_id: float, max_time_id: float) -> float:
    """Nerfies time rule: time_id / max over all items of dataset.json (max 0 -> 0)."""
    if max_time_id <= 0:
        return 0.0
    return float(time_id) / float(max_time_id)


_MONO = {"monocular": True}
_MULTI = {"monocular": False}
_NERFIES_TIME = "t = time_id / max(time_id) over all items of dataset.json (warp_id if time_id is missing)"
_MV_TIME = "frames of the range are indexed i = 0..n-1; t = i / n"

DATASETS: dict[str, DatasetSpec] = {
    "nerfds": DatasetSpec(
        key="nerfds",
        display_name="NeRF-DS-Mask",
        format="nerfies",
        sequences=("as_novel_view", "basin_novel_view", "cup_novel_view", "plate_novel_view",
                   "press_novel_view"),
        split="train: dataset.json train_ids (left camera); test: val_ids (right camera)",
        test_camera=None,
        downscale=2,
        resolution=None,
        frame_ranges=None,
        time_rule=_NERFIES_TIME,
        warm_up=3000,
        densify_until=15000,
        notes="images rgb/2x",
        **_MONO,
    ),
    "hypernerf": DatasetSpec(
        key="hypernerf",
        display_name="HyperNeRF-Mask",
        format="nerfies",
        sequences=("americano", "chickchicken", "cut-lemon1", "espresso", "hand1-dense-v2",
                   "keyboard", "oven-mitts", "slice-banana", "split-cookie", "torchocolate"),
        split="ids = dataset.json ids; train: ids[0::4]; test: ids[2::4] (interp protocol)",
        test_camera=None,
        downscale=2,
        resolution=None,
        frame_ranges=None,
        time_rule=_NERFIES_TIME,
        warm_up=1500,
        densify_until=9000,
        notes="images rgb/2x; publisher folders may sit under interp/ or misc/",
        **_MONO,
    ),
    "neu3d": DatasetSpec(
        key="neu3d",
        display_name="Neu3D-Mask",
        format="neu3d",
        sequences=("coffee_martini", "cook_spinach", "cut_roasted_beef", "flame_steak",
                   "sear_steak"),
        split="test: camera cam00; train: all other cameras; all frames of the range",
        test_camera="cam00",
        downscale=2,
        resolution=(1352, 1014),
        frame_ranges={s: (0, 299) for s in ("coffee_martini", "cook_spinach", "cut_roasted_beef",
                                            "flame_steak", "sear_steak")},
        time_rule=_MV_TIME + " (= frame / 300)",
        warm_up=3000,
        densify_until=8000,
        notes="coffee_martini has one unsynchronised camera (kept, as in the public code)",
        **_MULTI,
    ),
    "immersive": DatasetSpec(
        key="immersive",
        display_name="Immersive-Mask",
        format="immersive",
        sequences=("01_Welder", "02_Flames", "10_Alexa_1", "11_Alexa_2"),
        split="test: camera camera_0001; train: all other cameras; first 50 frames",
        test_camera="camera_0001",
        downscale=2,
        resolution=(1280, 960),
        frame_ranges={s: (0, 49) for s in ("01_Welder", "02_Flames", "10_Alexa_1", "11_Alexa_2")},
        time_rule=_MV_TIME,
        warm_up=1000,
        densify_until=3000,
        aliases={"10_Alexa_1": ("10_Alexa_Meade_Face_Paint_1",),
                 "11_Alexa_2": ("11_Alexa_Meade_Face_Paint_2",)},
        notes="fisheye videos undistorted to pinhole with the principal point at the centre",
        **_MULTI,
    ),
    "technicolor": DatasetSpec(
        key="technicolor",
        display_name="Technicolor-Mask",
        format="technicolor",
        sequences=("Birthday", "Fabien", "Painter", "Theater"),
        split="test: camera cam00 (first row of cameras_parameters.txt); train: the other 15",
        test_camera="cam00",
        downscale=2,
        resolution=(1024, 544),
        frame_ranges={"Birthday": (151, 200), "Fabien": (51, 100), "Painter": (100, 149),
                      "Theater": (51, 100)},
        time_rule=_MV_TIME,
        warm_up=3000,
        densify_until=5000,
        notes="publisher's undistorted PNGs; images shifted so the principal point is centred",
        **_MULTI,
    ),
}


def get_dataset(name: str) -> DatasetSpec:
    """The spec of benchmark ``name`` (registry key, case-insensitive, or display name)."""
    key = name.strip().lower()
    if key in DATASETS:
        return DATASETS[key]
    for spec in DATASETS.values():
        if spec.display_name.lower() == key:
            return spec
    raise DatasetError(f"unknown dataset {name!r}; valid: {', '.join(DATASETS)}")
