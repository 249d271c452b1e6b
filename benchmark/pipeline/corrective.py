"""The corrective protocol in a run's evaluation (benchmark.protocol.corrective): the robot
user's clicks for one method and one set of first clicks, the score over every test frame
after each click, and the clicks needed to reach an IoU (NoC@85, NoC@90).

A method that selects clusters renders each selection once (a click that changes nothing costs
a selection, not a render); any other method segments again for each click count.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from benchmark.protocol.corrective import check_frames, clicks_to_reach, corrective_clicks
from benchmark.scoring import score_masks

NOC_TARGETS = (0.85, 0.90)  # NoC@85, NoC@90: the interactive-segmentation standard's two


class Predictor:
    """A method's masks for a list of clicks, at some or all test views. A method that selects
    clusters renders each (views, clusters) pair once; renders of every test view are kept only
    when asked (``remember``: the click sets' final selections), so that a long sequence's curve
    does not hold a render per click."""

    def __init__(self, method, fitted, scene, prompts) -> None:
        self.method, self.fitted, self.scene, self.prompts = method, fitted, scene, prompts
        self.by_clusters = getattr(method, "selects_clusters", False) and fitted.gaussians is not None
        self.rendered: dict[tuple, list[np.ndarray]] = {}

    def masks(self, clicks, views: list[int] | None = None,
              remember: bool = True) -> tuple[list[np.ndarray], list[int] | None, list[int] | None]:
        """(masks bool [H, W] of the test views ``views`` (None: all, in order), the clusters
        selected, the cluster of each click; both None for a method that does not select
        clusters)."""
        from benchmark.methods import click_selection

        test = self.scene.test if views is None else [self.scene.test[i] for i in views]
        scene = self.scene if views is None else dataclasses.replace(
            self.scene, test=test, gt_masks=[self.scene.gt_masks[i] for i in views] if self.scene.gt_masks else [])
        prompts = dataclasses.replace(self.prompts, clicks=list(clicks), alternatives=[])
        if not self.by_clusters:
            return self._checked(self.method.segment(self.fitted, scene, prompts), test), None, None
        selected, per_click = click_selection(self.method, self.fitted, scene, prompts)
        key = (None if views is None else tuple(views), tuple(selected))
        masks = self.rendered.get(key)
        if masks is None:
            masks = self._checked(self.method.render_selection(self.fitted, scene, list(selected)), test)
            if remember or views is not None:
                self.rendered[key] = masks
        return masks, list(selected), list(per_click)

    def _checked(self, masks: list, views: list) -> list[np.ndarray]:
        """The method's masks, one bool [H, W] per view at the view's size, or a MethodError."""
        from benchmark.methods import MethodError

        if len(masks) != len(views):
            raise MethodError(f"{self.method.name} gave {len(masks)} masks for {len(views)} test views")
        for m, v in zip(masks, views):
            if np.shape(m) != (v.camera.height, v.camera.width):
                raise MethodError(f"{self.method.name} gave a {np.shape(m)} mask for test view {v.name} "
                                  f"({v.camera.height} x {v.camera.width})")
        return [np.asarray(m, dtype=bool) for m in masks]


@dataclasses.dataclass
class Corrected:
    """One set of first clicks after the robot user."""

    clicks: list  # trase.prompts.Click: the first clicks, then the corrective ones kept
    spent: list  # (Click, kept) per corrective click in order: the undone ones too
    n_first: int
    budget: int  # the most corrective clicks it could have made
    negatives: bool  # whether it could click negatively (the method's negative_clicks)
    check_frames: list = dataclasses.field(default_factory=list)  # test view indices the robot watched

    def kept_after(self, j: int) -> list:
        """The clicks in force after the first ``j`` corrective clicks."""
        return self.clicks[: self.n_first + sum(kept for _, kept in self.spent[:j])]


def correct(predictor: Predictor, first: list, gts: list[np.ndarray], protocol) -> Corrected:
    """The robot user from ``first`` (benchmark.protocol.corrective) with ``protocol``'s budget
    per first click, target and check frames; the click and check frames' ground truth is the
    only truth it reads."""
    from benchmark.methods import takes_negative_clicks

    negatives = takes_negative_clicks(predictor.method)
    clicked = sorted({c.view_index for c in first})
    checks = check_frames(len(gts), clicked, int(protocol.correction_check_frames))
    frames = sorted({*clicked, *checks})
    budget = int(protocol.corrections) * len(first)

    def predict(clicks) -> dict[int, np.ndarray]:
        return dict(zip(frames, predictor.masks(clicks, frames)[0]))

    robot = corrective_clicks(list(first), predict, {i: gts[i] for i in frames}, budget,
                              float(protocol.correction_target), negatives, float(protocol.correction_min_gain),
                              float(protocol.correction_undone_radius), int(protocol.correction_region_tries))
    return Corrected(robot.clicks, robot.spent, len(first), budget, negatives, checks)


def score_curve(predictor: Predictor, run: Corrected, names: list[str], stored: list[np.ndarray]) -> tuple[dict, tuple]:
    """The official mIoU and mAcc over every test frame after the first clicks and after each
    corrective click spent (an undone one leaves the score), with ``stored`` the ground truths as
    stored (as the official metric reads them), and NoC@85 / NoC@90 from it: a sequence that
    never reaches a target counts its first clicks + budget + 1; after the robot user stopped
    the score stays. -> (that summary, the final clicks' (masks, clusters selected, cluster per
    click)), the final clicks segmented last so that the method's stats are theirs."""
    by_kept: dict[int, dict] = {}  # clicks in force -> their scores
    for j in range(len(run.spent) + 1):
        n = len(run.kept_after(j))
        if n not in by_kept and n != len(run.clicks):
            preds = predictor.masks(run.kept_after(j), remember=False)[0]
            s = score_masks(dict(zip(names, preds)), dict(zip(names, stored)), "official")
            by_kept[n] = {"miou": s.miou, "macc": s.macc}
    final = predictor.masks(run.clicks)  # last: the method's stats are the final clicks'
    s = score_masks(dict(zip(names, final[0])), dict(zip(names, stored)), "official")
    by_kept[len(run.clicks)] = {"miou": s.miou, "macc": s.macc}
    points = [{"clicks": run.n_first + j, **by_kept[len(run.kept_after(j))],
               **({"undone": True} if j and not run.spent[j - 1][1] else {})} for j in range(len(run.spent) + 1)]
    mious = [p["miou"] for p in points]
    mious += [mious[-1]] * (run.budget + 1 - len(mious))  # no more clicks: the score stays
    noc = {f"noc@{round(t * 100)}": clicks_to_reach(mious, run.n_first, t, run.budget) for t in NOC_TARGETS}
    numbered = [click_dicts([c])[0] | {"n": run.n_first + j + 1} for j, (c, _) in enumerate(run.spent)]
    summary = {"first_clicks": run.n_first, "budget": run.budget, "negatives": run.negatives,
               "check_frames": [predictor.scene.test[i].name for i in run.check_frames],
               "corrections": [d for d, (_, kept) in zip(numbered, run.spent) if kept],
               "undone": [d for d, (_, kept) in zip(numbered, run.spent) if not kept], "curve": points, **noc}
    return summary, final


def click_dicts(clicks) -> list[dict]:
    """Clicks as the results hold them (the prompts file's form)."""
    from benchmark.protocol.prompts import click_dict

    return [click_dict(c) for c in clicks]


__all__ = ["NOC_TARGETS", "Corrected", "Predictor", "click_dicts", "correct", "score_curve"]
