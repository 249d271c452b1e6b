"""Stopping a training stage once it has converged: a criterion measured on views held out of
the stage's training (never test views), checked every ``interval`` steps, and a stop once the
best value has not improved by ``min_delta`` for ``patience`` checks in a row, no earlier than
``floor`` and never past the schedule's own end (the cap).

Why a plateau of a held-out criterion: the training loss of one random view per step is too noisy
to read a plateau from, and a held-out view says whether the model still improves where it was
not fitted; why a patience: one check without gain happens on the way up (densification, an
opacity reset).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Sequence
from pathlib import Path

STOP_FILE = "stopped.json"  # where a reconstruction records its checks and where it stopped


@dataclasses.dataclass
class StopRule:
    """When a stage stops. ``interval`` 0: never (the full schedule)."""

    interval: int = 0  # steps between checks; 0 = off
    patience: int = 2  # checks in a row without a gain of min_delta before stopping
    min_delta: float = 0.0  # the smallest gain that counts, in the criterion's units
    floor: int = 0  # no stop before this step
    higher_is_better: bool = True  # PSNR: higher; a loss: lower
    # min_delta as a fraction of |the first check's value|: a loss's own scale (a loss may
    # cross zero, so not of the best value)
    relative: bool = False

    def __post_init__(self) -> None:
        if self.interval < 0 or self.patience < 1 or self.min_delta < 0 or self.floor < 0:
            raise ValueError(f"stopping rule: interval must be >= 0, patience >= 1, min_delta >= 0 and floor >= 0, "
                             f"got {self.interval}, {self.patience}, {self.min_delta}, {self.floor}")

    @property
    def enabled(self) -> bool:
        return self.interval > 0

    def can_stop_before(self, cap: int, first_check: int) -> bool:
        """Whether a stop can come before ``cap`` when the first check is at ``first_check``:
        the first check sets the baseline, a stop needs ``patience`` more, from ``floor`` on.
        Where it cannot, holding views out for the criterion would cost for nothing."""
        if not self.enabled:
            return False
        earliest = max(first_check + self.patience * self.interval, -(-self.floor // self.interval) * self.interval)
        return earliest < cap


@dataclasses.dataclass
class Plateau:
    """The checks of one stage so far and whether it should stop (``observe``)."""

    rule: StopRule
    checks: list[tuple[int, float]] = dataclasses.field(default_factory=list)  # (step, value)
    best: float | None = None
    since_best: int = 0  # checks since the last gain of min_delta
    stopped_at: int | None = None

    def due(self, step: int) -> bool:
        """A check is due after ``step`` (1-based count of steps done)."""
        return self.rule.enabled and step % self.rule.interval == 0

    def observe(self, step: int, value: float, cap: int | None = None) -> bool:
        """Record the criterion after ``step`` steps -> True when the stage should stop here
        (never at ``cap``, the schedule's end: that is no stop). A gain is a rise (a fall for a
        loss) of at least ``min_delta`` and above zero. A non-finite value (a broken render, or a
        perfect one's infinite PSNR) is recorded but neither a gain nor a check without one."""
        value = float(value)
        self.checks.append((int(step), value))
        if not math.isfinite(value):
            return False
        sign = 1.0 if self.rule.higher_is_better else -1.0
        finite = [v for _, v in self.checks if math.isfinite(v)]
        scale = abs(finite[0]) if self.rule.relative else 1.0  # relative: of the first finite check
        gain = None if self.best is None else sign * (value - self.best)
        if gain is None or (gain > 0 and gain >= self.rule.min_delta * scale):
            self.best, self.since_best = value, 0
        else:
            self.since_best += 1
        if self.since_best >= self.rule.patience and step >= self.rule.floor and (cap is None or step < cap):
            self.stopped_at = int(step)
            return True
        return False

    def summary(self, criterion: str, cap: int, held_out: Sequence[str]) -> dict:
        """What results record: the criterion, the rule, every check, where it stopped (None:
        it ran to the cap)."""
        return {"criterion": criterion, "rule": dataclasses.asdict(self.rule), "cap": int(cap),
                "stopped_at": self.stopped_at, "best": self.best,
                "checks": [[s, round(v, 6)] for s, v in self.checks], "held_out": list(held_out)}

    def state(self) -> dict:
        """The checks so far, for a resumed run (``restore``)."""
        return {"checks": [list(c) for c in self.checks], "best": self.best, "since_best": self.since_best,
                "stopped_at": self.stopped_at}

    def restore(self, state: dict | None) -> None:
        if state:
            self.checks = [(int(s), float(v)) for s, v in state.get("checks", [])]
            self.best, self.since_best = state.get("best"), int(state.get("since_best", 0))
            self.stopped_at = state.get("stopped_at")


def view_name(view) -> str:
    """A view's name (its image file where it has none)."""
    name = getattr(view, "name", None)
    return str(name) if name else str(view.image_path)


def held_out_indices(views: Sequence, every: int) -> list[int]:
    """The indices of the views held out: every ``every``-th in time order (then by name),
    starting from the middle of the first block so neither end of the sequence is lost;
    ``every`` < 2 or fewer than 2 * every views: none."""
    if every < 2 or len(views) < 2 * every:
        return []
    order = sorted(range(len(views)), key=lambda i: (float(views[i].camera.time), view_name(views[i])))
    return sorted(order[every // 2::every])


def none_held_out(cap: int, why: str) -> dict:
    """The summary of a stage that held nothing out (so ran its whole schedule), and why."""
    return {"criterion": None, "stopped_at": None, "cap": int(cap), "held_out": [], "why": why}


def write_summary(path: os.PathLike | str, summary: dict) -> None:
    """The summary as JSON, written whole or not at all."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(summary, indent=1))
    os.replace(tmp, path)


def read_summary(path: os.PathLike | str) -> dict | None:
    """A summary written by ``write_summary``; None when there is none."""
    path = Path(path)
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None


__all__ = ["STOP_FILE", "Plateau", "StopRule", "held_out_indices", "none_held_out", "read_summary", "view_name",
           "write_summary"]
