"""How a capture is read: the ``capture`` section of ``trase-bench fit``'s config."""

from __future__ import annotations

import dataclasses
import re

from benchmark.datasets.errors import DatasetError

TIME_RULES = ("auto", "order", "static")


@dataclasses.dataclass(frozen=True)
class CaptureOptions:
    format: str = "auto"  # auto | nerfies | colmap | transforms
    # images at 1/s of the cameras' size: nerfies rgb/<s>x, COLMAP images_<s> (images/ for 1),
    # transforms <folder>_<s>; where the layout has no such copy, the finest one it has is scaled
    # on the fly (benchmark.captures.scaling); 0: the layout's default (nerfies 2, as the
    # benchmarks train on; COLMAP and transforms 1)
    image_scale: int = 0
    # the longest image side in pixels after image_scale (0: no limit): larger images are scaled
    # down on the fly (benchmark.captures.scaling)
    max_side: int = 0
    # auto: the layout's times (nerfies metadata.json; COLMAP times.json, else the frame order;
    # transforms each frame's "time", else the frame order); order: t = rank of the image name /
    # (n - 1); static: t = 0 for every view
    time: str = "auto"
    # none: every view trains; every:N: every N-th view in time order (the first included) is
    # held out to report reconstruction PSNR; layout: the layout's own test views
    # (dataset.json val_ids, transforms_test.json)
    holdout: str = "none"
    # COLMAP and transforms worlds are moved and scaled so the points' bulk (95% of them) sits in
    # the unit ball, the frame the deformation network's positional encoding expects (nerfies
    # captures carry their own scene.json for this). A similarity: images do not change.
    normalize: bool = True
    # initial points of a capture that ships none: "auto" carves them from the images' alpha
    # where the images have one (common.points_from_alpha), else random where the cameras look;
    # "random" always draws at random (the reader's only rule before the carving)
    initial_points: str = "auto"

    def __post_init__(self) -> None:
        if self.time not in TIME_RULES:
            raise DatasetError(f"--set capture.time={self.time}: choose {', '.join(TIME_RULES)}")
        if self.image_scale < 0:
            raise DatasetError(f"--set capture.image_scale={self.image_scale}: a whole number >= 1 (0: the layout's default)")
        if self.initial_points not in ("auto", "random"):
            raise DatasetError(f"--set capture.initial_points={self.initial_points}: choose auto or random")
        if self.max_side < 0:
            raise DatasetError(f"--set capture.max_side={self.max_side}: pixels >= 1 (0: no limit)")
        holdout_every(self.holdout)  # checks the rule

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def holdout_every(rule: str) -> int | None:
    """N of ``every:N``; None for ``none`` and ``layout``; an error for anything else."""
    if rule in ("none", "layout"):
        return None
    m = re.fullmatch(r"every:(\d+)", rule)
    if not m or int(m.group(1)) < 2:
        raise DatasetError(f"--holdout {rule}: choose none, layout or every:N with N >= 2")
    return int(m.group(1))
