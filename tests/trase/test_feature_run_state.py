"""The feature loops' progress bar (trase.feature_run_state.feature_progress): a resumed loop's
bar starts where it stopped, the loss is read only where the bar is shown."""

import pytest
import rich.progress
import torch

from trase.feature_run_state import feature_progress


class _Unread(torch.Tensor):
    """A loss whose value must not be read (a host-device transfer on a GPU)."""

    def detach(self):
        raise AssertionError("the loss was read with the bar off")


def test_off_it_reads_nothing_and_shows_nothing(capsys):
    with feature_progress(False, 10) as advance:
        for _ in range(3):
            advance(torch.zeros(()).as_subclass(_Unread))
    assert capsys.readouterr().out == ""


def test_on_it_starts_at_the_resumed_step_and_counts_each_step(monkeypatch):
    added, updates = [], []
    real_add, real_update = rich.progress.Progress.add_task, rich.progress.Progress.update
    monkeypatch.setattr(rich.progress.Progress, "add_task",
                        lambda self, *a, **k: added.append(k) or real_add(self, *a, **k))
    monkeypatch.setattr(rich.progress.Progress, "update",
                        lambda self, task, **k: updates.append(k) or real_update(self, task, **k))
    with feature_progress(True, 10, start=4) as advance:
        for v in (0.5, 0.25):
            advance(torch.tensor(v))
    assert added[0]["total"] == 10 and added[0]["completed"] == 4
    assert [u["advance"] for u in updates] == [1, 1] and [u["loss"] for u in updates] == [0.5, 0.25]


def test_an_error_in_the_loop_stops_the_bar_and_reaches_the_caller():
    with pytest.raises(ValueError, match="non-finite"), feature_progress(True, 5) as advance:
        advance(torch.tensor(1.0))
        raise ValueError("non-finite")
