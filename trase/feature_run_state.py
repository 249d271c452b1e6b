"""The feature loop's running state: its checkpoint file and its progress bar. Beside the
loop (``trase.features``) so it holds only training, as ``trase.training_log`` is beside the
reconstruction's.

``step`` below is the loop's step (its numpy ``rng`` and torch ``gen`` streams), ``criterion``
its stopping criterion (its ``plateau``, ``trase.convergence.Plateau``) or None.
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path

import torch


class FeatureCheckpoint:
    """The feature loop's state in one file: features, Adam's moments, the next step, both
    random streams, the history and the training seconds so far. Saved atomically every
    ``every_s`` seconds; a file for other features (count or width) is not resumed from."""

    def __init__(self, path: Path, every_s: float) -> None:
        self.path, self.every_s = path, float(every_s)
        self.last = time.perf_counter()

    def load(self, feats: torch.nn.Parameter, opt, step,
             criterion=None) -> tuple[int, list[dict], float]:
        """Restore into ``feats``/``opt``/``step``'s generators (and the criterion's checks) ->
        (next step, history, seconds)."""
        if not self.path.is_file():
            return 0, [], 0.0
        state = torch.load(self.path, map_location="cpu", weights_only=False)
        if tuple(state["features"].shape) != tuple(feats.shape):
            return 0, [], 0.0
        with torch.no_grad():
            feats.copy_(state["features"].to(feats.device))
        opt.load_state_dict(state["optimizer"])
        step.rng.bit_generator.state = state["rng"]
        step.gen.set_state(state["gen"])
        if criterion is not None:
            criterion.plateau.restore(state.get("plateau"))
        return int(state["step"]), list(state["history"]), float(state["seconds"])

    def maybe_save(self, feats, opt, step, next_step: int, history: list[dict], seconds: float,
                   criterion=None) -> None:
        if time.perf_counter() - self.last < self.every_s:
            return
        from trase.io import atomic_torch_save

        atomic_torch_save({"features": feats.detach().cpu(), "optimizer": opt.state_dict(), "step": next_step,
                           "rng": step.rng.bit_generator.state, "gen": step.gen.get_state(),
                           "history": history, "seconds": seconds,
                           **({"plateau": criterion.plateau.state()} if criterion is not None else {})}, self.path)
        self.last = time.perf_counter()

    def remove(self) -> None:
        self.path.unlink(missing_ok=True)


@contextlib.contextmanager
def feature_progress(enabled: bool, total: int, start: int = 0):
    """A rich progress bar over a feature loop's ``total`` steps, ``start`` of them done (a
    resumed loop) -> advance(loss), loss a 0-d tensor read only where the bar is shown; nothing
    where not ``enabled``."""
    if not enabled:
        yield lambda loss: None
        return
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    bar = Progress(TextColumn("features"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                   TextColumn("loss {task.fields[loss]:.4f}"), TimeRemainingColumn(), transient=True)
    task = bar.add_task("features", total=total, completed=start, loss=0.0)
    with bar:
        yield lambda loss: bar.update(task, advance=1, loss=float(loss.detach()))


__all__ = ["FeatureCheckpoint", "feature_progress"]
