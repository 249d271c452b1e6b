"""perf dnerf: fit on a D-NeRF scene as published, beside the published row; foreground IoU."""

import json
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
    assert set(fg["mask"]["per_view"]) == set(fg["per_view"]) and 0 <= fg["mask"]["worst"] <= fg["mask"]["mean"] <= 1
    assert fg["mask"]["prompt"].startswith(fg["click"].split(":")[0] + ":")  # the clicked view's alpha
    table = lines[-1]
    assert "| Hook |" in table and "37.42 / 0.9867 / 0.0144" in table
    assert f"{row['measures']['test_psnr'] - 37.42:+.2f}" in table


@pytest.mark.slow
def test_perf_skip_measures_each_skip_on_a_dnerf_scene(tmp_path, monkeypatch):
    """perf skip --scene: full, static and converged fits of the scene, its own table and plot."""
    from benchmark.perf import skip

    monkeypatch.setenv("TRASE_BENCH_CACHE", str(tmp_path / "cache"))
    scene = Path(shutil.copytree(HOOK, tmp_path / "hook"))
    lines: list[str] = []
    out = skip.run(quick=True, echo=lines.append, datasets=[], scenes=[scene], overrides=["capture.image_scale=1"],
                   out_dir=tmp_path / "out")
    assert not out["failed"], out["runs"]
    full, _, converged, *_ = out["runs"]
    assert [r["variant"] for r in out["runs"]] == ["full", "static", "converged", "resolution", "resolution+primitives", "primitives"]
    assert {r["dataset"] for r in out["runs"]} == {"dnerf/hook"}
    assert full["stopping"] == {} and set(converged["stopping"]) == {"geometry", "features"}
    assert {s: st["cap"] for s, st in converged["stopping"].items()} == {"geometry": 60, "features": 30}
    for r in out["runs"]:
        assert np.isfinite(r["measures"]["test_psnr"]) and 0 <= r["foreground_worst"] <= r["foreground_iou"] <= 1
        assert 0 <= r["foreground_mask_worst"] <= r["foreground_mask_iou"] <= 1
        assert r["seconds"]["geometry"] > 0 and r["gaussians"] > 0
    assert full["static_gaussians"] == 0
    # each variant trained its own geometry (the static threshold and the stopping are keyed)
    keys = {v: json.loads((tmp_path / "out" / "skip-dnerf" / "hook" / v / "fit.json").read_text())["stages"]["geometry"]["key"]
            for v in ("full", "static", "converged", "resolution", "resolution+primitives", "primitives")}
    assert len(set(keys.values())) == 6, keys
    text = "\n".join(lines)
    assert text.startswith("skips on and off, dnerf/hook, trase, settings")  # the scene only, no format
    assert "foreground IoU, mask prompt" in text and "dnerf/hook" in text and "geometry s vs full" in text
    assert (tmp_path / "out" / "skip-dnerf-hook.png").stat().st_size > 1000
    told = (tmp_path / "out" / "skip-runs.jsonl").read_text().splitlines()  # a line per fit, as each ended
    assert len(told) == 6 and "[3/6] dnerf/hook converged: " in text and "foreground IoU" in text
    assert "[5/6] dnerf/hook resolution+primitives: " in text and "[6/6] dnerf/hook primitives: " in text


def test_capture_settings_reach_the_scenes_only():
    from benchmark.perf.skip import for_runs

    assert for_runs(["capture.image_scale=2", "geometry.train.iterations=60", " capture.max_side=400"]) == [
        "geometry.train.iterations=60"]


def test_perf_dataset_none_measures_only_the_scenes(tmp_path, monkeypatch, capsys):
    """`perf skip --scene DIR --dataset none`: the skip suite without the built-in formats."""
    import benchmark.commands.perf as perf_command
    from benchmark.cli import main

    seen = {}

    def fake_skip(quick, echo, datasets=None, scenes=None, out_dir=None):
        seen.update(datasets=datasets, scenes=scenes)
        return {}

    monkeypatch.setattr(perf_command, "get_suite", lambda name: fake_skip)
    assert main(["perf", "skip", "--scene", str(HOOK), "--dataset", "none", "--out-dir", str(tmp_path)]) == 0
    assert seen == {"datasets": [], "scenes": [str(HOOK)]}
    assert main(["perf", "skip", "--dataset", "none"]) != 0  # no scene: nothing to measure
    assert "--dataset none measures only the --scene folders" in capsys.readouterr().err
