"""Frame novelty: a frame that repeats a time-neighbour carries nothing new."""

import numpy as np
import pytest

from trase.frame_novelty import frame_novelty, novelty_summary


def test_a_repeated_frame_has_no_novelty_and_a_changing_one_has_its_smaller_step():
    rng = np.random.default_rng(0)
    a, b, c = (rng.random((40, 80, 3)).astype(np.float32) for _ in range(3))
    nov = frame_novelty([a, a, b, c], side=80)  # frame 1 repeats frame 0; frame 2 differs from both sides
    assert nov[0] == 0.0 and nov[1] == 0.0
    assert nov[2] == pytest.approx(min(np.abs(b - a).mean(), np.abs(c - b).mean()), rel=1e-5)
    assert nov[3] == pytest.approx(np.abs(c - b).mean(), rel=1e-5)  # the last frame has one neighbour
    s = novelty_summary(nov)
    assert s["frames"] == 4 and s["below_half"] == 0.5 and s["below_quarter"] == 0.5


def test_degenerate_input_gives_numbers_or_a_clear_error():
    assert frame_novelty([np.zeros((4, 4, 3))]).tolist() == [0.0]
    assert novelty_summary(np.zeros(0))["frames"] == 0
    nan = np.full((4, 4, 3), np.nan)
    assert np.isfinite(frame_novelty([nan, np.zeros((4, 4, 3))])).all()
    with pytest.raises(ValueError, match="frames of one sequence differ in size"):
        frame_novelty([np.zeros((4, 4, 3)), np.zeros((4, 6, 3))])
