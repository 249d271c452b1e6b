"""``trase-bench perf``: the suite registry, the command, and the JSON it writes (tiny settings)."""

import json

import pytest

from benchmark.cli import main
from benchmark.perf import SUITES, get_suite


def test_raster_suite_runs_and_writes_json(tmp_path, monkeypatch, capsys):
    from benchmark.perf import raster

    monkeypatch.setattr(raster, "QUICK", [(150, 32, 24, 4, True)])
    out = tmp_path / "perf.json"
    assert main(["perf", "raster", "--quick", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "speed-up numba/torch" in text and "max |output diff|" in text
    d = json.loads(out.read_text())
    assert d["machine"]["cpu_count"] >= 1 and d["machine"]["numba"]
    row = d["suites"]["raster"]["settings"][0]
    assert row["gaussians"] == 150 and row["channels"] == 7
    assert row["max_abs_output_diff"] < 1e-4 and row["max_grad_rel_diff"] < 1e-3
    for backend in ("numba", "torch"):
        assert row[backend]["total_s"]["median"] > 0 and len(row[backend]["forward_s"]["all"]) >= 2


def test_threads_option_sets_and_records_thread_count(tmp_path, monkeypatch):
    import numba
    import torch

    from benchmark.perf import raster

    monkeypatch.setattr(raster, "QUICK", [(50, 16, 16, 2, False)])
    before = (torch.get_num_threads(), numba.get_num_threads())
    out = tmp_path / "perf.json"
    try:
        assert main(["perf", "raster", "--quick", "--threads", "1", "--json", str(out)]) == 0
        assert torch.get_num_threads() == 1 and numba.get_num_threads() == 1
    finally:
        torch.set_num_threads(before[0])
        numba.set_num_threads(before[1])
    assert json.loads(out.read_text())["threads"] == 1


def test_registry_entries_resolve():
    for name in SUITES.names():
        assert callable(get_suite(name))


def test_reconstruct_suite_reports_psnr_per_checkpoint_for_every_preset(monkeypatch, capsys):
    from benchmark.perf import reconstruct

    monkeypatch.setattr(reconstruct, "QUICK", {"size": "tiny", "budget_s": 60.0, "iterations": 10, "interval": 5})
    out = reconstruct.run(quick=True, echo=print)
    assert [r["preset"] for r in out["runs"]] == ["cpu-v1", "cpu-v2", "cpu-v3", "cpu"]
    for r in out["runs"]:
        assert [c["iteration"] for c in r["curve"]] == [5, 10]
        for c in r["curve"]:
            assert 0 < c["seconds"] <= r["wall_s"] + 1 and 5.0 < c["psnr"] < 60.0 and c["gaussians"] > 0
        assert r["final"] == r["curve"][-1]
        assert r["finished"] and r["iterations_planned"] == 10
        # the runner's settings for this scene (the tiny scene trains at full resolution)
        assert r["train_config"]["image_downscale"] == 1.0 and r["train_config"]["deform_preset"] == "small"
    old, v2, v3, new = (r["train_config"] for r in out["runs"])
    assert old["torch_threads"] == 1 and v2["torch_threads"] == v3["torch_threads"] == new["torch_threads"] == 2
    assert (v2["warm_up"], v3["warm_up"]) == (300, 600)  # the same schedule, stretched
    assert (v3["min_opacity"], new["min_opacity"]) == (0.005, 0.1)  # faint gaussians pruned
    printed = capsys.readouterr().out
    assert "test PSNR" in printed and "s/it deforming" in printed


def test_reconstruct_suite_trains_equal_settings_once(monkeypatch, capsys):
    """On a multi-view rig cpu-v2 and cpu-v3 are the same settings: reported, trained once."""
    from benchmark.perf import reconstruct

    monkeypatch.setattr(reconstruct, "QUICK", {"size": "tiny", "budget_s": 60.0, "iterations": 4, "interval": 4})
    out = reconstruct.run(quick=True, echo=print, dataset="technicolor")
    by = {r["preset"]: r for r in out["runs"]}
    assert list(by) == ["cpu-v1", "cpu-v2", "cpu-v3", "cpu"]
    assert by["cpu-v3"]["same_as"] == "cpu-v2" and "curve" not in by["cpu-v3"]
    assert by["cpu-v3"]["runner_config"] == by["cpu-v2"]["runner_config"]
    assert all("curve" in by[p] for p in ("cpu-v1", "cpu-v2", "cpu"))
    assert by["cpu"]["iterations_planned"] == 4 and by["cpu"]["runner_config"]["iterations"] == 4000
    assert "cpu-v3   = cpu-v2" in capsys.readouterr().out


@pytest.mark.slow
def test_captures_suite_fits_every_layout_with_both_mask_sources(tmp_path):
    from benchmark.perf import captures

    out = captures.run(quick=True, echo=lambda *_: None, out_dir=tmp_path)
    assert set(out["layouts"]) == {f"{a}/{b}" for a in ("nerfies", "colmap", "transforms") for b in ("classical", "files")}
    for name, r in out["layouts"].items():
        assert set(r["iou_per_object"]) == {str(i) for i in out["scene"]["objects"]}
        assert 0.0 <= r["iou_all_objects"] <= 1.0 and 0.0 <= r["geometry_ceiling"]["all"] <= 1.0
        assert r["stages"]["geometry"]["reused"] == name.endswith("/files")  # one reconstruction per layout
    assert any("ignored 2 image(s)" in n for n in out["layouts"]["nerfies/classical"]["notices"])


@pytest.mark.slow
def test_viewer_suite_times_every_mode_at_both_sizes_and_a_click(tmp_path):
    from benchmark.perf import viewer

    out = viewer.run(quick=True, echo=lambda *_: None, out_dir=tmp_path)
    assert set(out["sizes"]) == {"320x240", "640x480"}
    for per_mode in out["sizes"].values():
        assert set(per_mode) == set(viewer.MODES)
        assert all(m["fps"] > 0 and len(m["render_s"]["all"]) == out["frames_per_setting"] for m in per_mode.values())
    assert out["click"]["clicks"] == len(out["click"]["latency_s"]["all"]) > 0


def test_dataset_option_reaches_suites_that_take_one_and_is_refused_elsewhere(monkeypatch, capsys):
    from benchmark.commands import perf as perf_command

    seen = []

    def fake_reconstruct(quick, echo, dataset="hypernerf"):
        seen.append(dataset)
        return {}

    real = perf_command.get_suite
    monkeypatch.setattr(perf_command, "get_suite", lambda n: fake_reconstruct if n == "reconstruct" else real(n))
    assert main(["perf", "reconstruct", "--quick", "--dataset", "Technicolor"]) == 0
    assert seen == ["technicolor"]
    assert main(["perf", "raster", "--quick", "--dataset", "technicolor"]) == 2
    assert "none of raster takes a dataset" in capsys.readouterr().err
    assert main(["perf", "reconstruct", "--dataset", "nope"]) == 1
    assert "unknown dataset 'nope'" in capsys.readouterr().err
    assert seen == ["technicolor"]


def test_gpu_suite_without_a_gpu_is_a_one_line_error(capsys):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU: the suite runs (tests/trase/render/test_cuda_backends.py)")
    assert main(["perf", "gpu", "--quick"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err and "torch sees no CUDA GPU" in err[-1]
