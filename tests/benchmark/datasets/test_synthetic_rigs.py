"""The synthetic rigs' sizes and difficulty: the hard variant keeps the earlier scenes, the standard
one follows the benchmarks' frame counts, and a slower span keeps the layout."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from benchmark.datasets.synthetic import (
    DATASET_KEYS,
    SyntheticError,
    build_world,
    generate,
    parse_sequence_name,
    sequence_name,
)
from benchmark.datasets.synthetic.rigs import MAX_MOTION_PER_FRAME, STANDARD_TIME, rig_size, standard_span

SIZE = "tiny"


def test_hard_scenes_are_the_earlier_scenes_and_standard_ones_follow_the_benchmarks():
    # the hard variant keeps the sizes of generator version 2 (regression values)
    assert [rig_size(d, "small", "hard").frames for d in DATASET_KEYS] == [24, 60, 12, 12, 10]
    assert all(rig_size(d, "small", "hard").span == 1.0 for d in DATASET_KEYS)
    for d in DATASET_KEYS:
        std = rig_size(d, "small")
        assert std.frames == STANDARD_TIME[d].frames and STANDARD_TIME[d].source
        assert (std.width, std.height, std.cameras) == (rig_size(d, "small", "hard").width,
                                                         rig_size(d, "small", "hard").height,
                                                         rig_size(d, "small", "hard").cameras)
        # the fastest object (the cube) moves at most MAX_MOTION_PER_FRAME per frame
        world = build_world(0, std.span)
        path = [world.centre("cube", i / std.frames) for i in range(std.frames)]
        step = max(np.linalg.norm(b - a) for a, b in itertools.pairwise(path))
        assert step <= MAX_MOTION_PER_FRAME * 1.6, (d, step)  # the cube's height also bobs
    assert rig_size("immersive", "small").frames == 50 and standard_span(50) < 0.3
    assert standard_span(10**6) == 1.0



def test_span_slows_the_motion_down_without_changing_the_layout():
    full, slow = build_world(3), build_world(3, 0.25)
    for name in ("ball", "ring", "blob", "pillar", "cube", "crate"):
        for t in (0.0, 0.4, 1.0):
            R1, c1, S1 = full.by_name(name).pose(0.25 * t)
            R2, c2, S2 = slow.by_name(name).pose(t)
            np.testing.assert_allclose(R1, R2) and np.testing.assert_allclose(c1, c2)
            np.testing.assert_allclose(S1, S2)
    with pytest.raises(ValueError, match="span"):
        build_world(0, 0.0)



def test_sequence_names_carry_size_and_difficulty():
    assert sequence_name("small") == "synthetic" and sequence_name("medium", "hard") == "synthetic-medium-hard"
    assert parse_sequence_name("synthetic-hard") == ("small", "hard")
    assert parse_sequence_name("synthetic-tiny") == ("tiny", "standard")
    assert parse_sequence_name("americano") is None
    with pytest.raises(SyntheticError, match="unknown difficulty"):
        generate("hypernerf", Path("/nonexistent-never-written"), size=SIZE, difficulty="easy")
