import importlib.util
from pathlib import Path

import numpy as np
import torch

from tests.trase.test_prompts_segment import _semi_transparent_front

_spec = importlib.util.spec_from_file_location("click_rules", Path(__file__).parents[2] / "scripts" / "click_rules.py")
click_rules = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(click_rules)


def test_every_rule_resolves_every_click():
    """The semi-transparent sheet before a wall: weight picks the wall, front at a share below the
    sheet's picks the sheet; a click off the image chooses nothing under every rule."""
    gm, labels, cam = _semi_transparent_front()
    with torch.no_grad():
        gm.opacity_logits[: int((labels == 0).sum())] = -2.0  # the sheet holds ~0.42 of the weight
    feats = np.eye(4, dtype=np.float32)[labels]
    out = click_rules.resolve(gm, None, labels, feats, [cam], [(0, 16.0, 12.0), (0, -5.0, 3.0)])
    assert list(out) == ["feature", "weight", "depth", "front 0.20", "front 0.25", "front 0.33", "front 0.40"]
    assert out["weight"] == [1, -1] and out["feature"] == [1, -1]
    assert out["front 0.25"] == [0, -1] and out["front 0.40"] == [0, -1]
