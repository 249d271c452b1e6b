"""perf dnerf: fit on a D-NeRF scene as published, beside the published row; foreground IoU."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from benchmark.perf import dnerf

HOOK = Path(__file__).resolve().parents[2] / "data" / "dnerf" / "hook-tiny"


def test_published_rows_and_the_foreground_click():
    pub = dnerf.published()
    assert set(pub) == set(dnerf.SCENES)
    assert pub["hook"] == {"name": "Hook", "psnr": 37.42, "ssim": 0.9867, "lpips_vgg": 0.0144}
    alpha = np.zeros((9, 12))
    alpha[2:7, 4:9] = 1.0  # a 5x5 square centred at x 6, y 4
    assert dnerf.foreground_click(alpha) == (6, 4)  # the deepest interior pixel
    with pytest.raises(ValueError, match="outlines nothing"):
        dnerf.foreground_click(np.zeros((4, 4)))


@pytest.mark.slow
def test_the_suite_fits_a_scene_and_scores_the_object_against_alpha(tmp_path, monkeypatch):
    monkeypatch.setenv("TRASE_BENCH_CACHE", str(tmp_path / "cache"))
    scene = Path(shutil.copytree(HOOK, tmp_path / "hook"))  # named as the published scene
    from tests.trase.test_lpips import _weights

    weights = tmp_path / "lpips"
    weights.mkdir()
    _weights(weights)  # random weights under the names the suite looks for
    (weights / "vgg16.pth").rename(weights / "vgg16-397923af.pth")
    lines: list[str] = []
    out = dnerf.run(quick=True, echo=lines.append, out_dir=tmp_path / "out", scenes=[scene],
                    overrides=["capture.image_scale=1"], lpips_weights=str(weights))
    (row,) = out["rows"]
    assert row["published"]["psnr"] == 37.42 and np.isfinite(row["measures"]["test_psnr"])
    assert row["measures"]["test_lpips"] > 0
    fg = row["foreground_iou"]
    assert set(fg["per_view"]) == {"test/r_000", "test/r_010"} and 0 <= fg["worst"] <= fg["mean"] <= 1
    table = lines[-1]
    assert "| Hook |" in table and "37.42 / 0.9867 / 0.0144" in table
    assert f"{row['measures']['test_psnr'] - 37.42:+.2f}" in table
