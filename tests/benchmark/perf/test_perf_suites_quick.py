"""Every perf suite end to end with ``--quick`` through the CLI, into one JSON file."""

import json

import pytest

from benchmark.cli import main
from benchmark.perf import SUITES


@pytest.mark.slow
def test_all_suites_quick(tmp_path, monkeypatch, capsys):
    from benchmark.perf import raster

    monkeypatch.setenv("TRASE_BENCH_CACHE", str(tmp_path / "cache"))  # synthetic scenes generated here
    monkeypatch.delenv("TRASE_DNERF", raising=False)  # perf dnerf has its own test (test_dnerf_suite.py)
    monkeypatch.setattr(raster, "QUICK", [(150, 32, 24, 4, True)])  # raster's own test covers its sizes
    out = tmp_path / "perf.json"
    assert main(["perf", "--quick", "--json", str(out)]) == 0  # no suite named: all this machine can run
    text = capsys.readouterr().out
    d = json.loads(out.read_text())
    s = d["suites"]
    assert set(s) == set(SUITES.names()) and d["machine"]["cpu_count"] >= 1
    import torch

    if not torch.cuda.is_available():
        assert s["gpu"] == {"skipped": "torch sees no CUDA GPU here"}
    assert s["dnerf"]["skipped"].startswith("no D-NeRF scenes: pass --scene DIR")
    _check_kernel_suites(s)
    _check_run_suites(s, text)
    _check_skip_suite(s["skip"], text, tmp_path)
    _check_pareto_and_determinism(s, text, tmp_path)


def _check_kernel_suites(s: dict) -> None:
    """knn, cluster, features: each fast path agrees with its reference."""
    knn = s["knn"]["sizes"][0]["methods"]
    for m in knn.values():
        assert m["seconds"]["median"] > 0 and m["equal_up_to_ties"] == 1.0
    assert "versions" in s["knn"] and s["knn"]["sizes"][0]["smoothing_step_seconds"]["median"] > 0

    cl = s["cluster"]["sizes"][0]
    ref = cl["configs"][cl["reference"]]
    assert ref["ari_vs_reference"] == pytest.approx(1.0)
    ran = [c for c in cl["configs"].values() if "skipped" not in c]
    assert len(ran) >= 8 and all(-1 <= c["ari_vs_known"] <= 1 for c in ran)
    assert any("skipped" in c for c in cl["configs"].values())  # 25% of 8000 > the quick cap of 1500

    ft = s["features"]
    real = ft["whole_step_real_scale"]["threads"]["1"]
    assert real["loss_abs_diff"] < 1e-5 and ft["whole_step_real_scale"]["feature_max_abs_diff"] < 1e-5
    assert real["ceiling_free_objective"] >= real["ratio_bound"] > 0
    assert ft["operators"]["bytes_per_view"] > 0
    for o in ft["objective_alone"]:  # the soft C's fused kernels against its dense form
        soft = o["jaccard_vs_reference"]
        assert soft["stats_equal"] and soft["loss_abs_diff"] < 1e-4 and soft["grad_max_rel_diff"] < 1e-4
    step = ft["steps"][0]
    assert step["max_abs_rendered_diff"] < 1e-4 and step["loss_abs_diff"] < 1e-4
    assert step["fastpath_render_s"]["median"] > 0 and step["rasterizer_render_s"]["median"] > 0



def _check_run_suites(s: dict, text: str) -> None:
    """pipeline, methods: whole runs and per-method processes."""
    pl = s["pipeline"]
    assert not pl["failed"], pl["runs"]
    stages = pl["runs"][0]["stages"]
    assert {"masks", "geometry", "fit", "prompts", "evaluate"} <= set(stages)

    me = s["methods"]  # one fresh process per method
    assert not me["failed"] and [r["method"] for r in me["methods"]] == ["trase"]
    r = me["methods"][0]
    assert r["per_step_seconds"] > 0 and r["peak_rss_mb"] >= r["baseline_rss_mb"] > 0
    assert r["preset_steps"] > 100 and r["stage_seconds_at_preset_steps"] > 100 * r["per_step_seconds"]
    assert "ms/step" in text



def _check_skip_suite(sk: dict, text: str, tmp_path) -> None:
    """static gaussians on and off, stages that stop when converged, the schedules."""
    assert not sk["failed"] and [r["variant"] for r in sk["runs"]] == ["full", "static", "converged", "resolution", "resolution+primitives",
                                                                       "primitives"]
    full, static, converged, resolution, primitives, primitives_alone = sk["runs"]
    assert full["stopping"] == {}  # full: no stopping
    assert {s: st["cap"] for s, st in converged["stopping"].items()} == {"geometry": 60, "features": 20}
    assert all(st["stopped_at"] is None or 10 <= st["stopped_at"] < st["cap"] for st in converged["stopping"].values())
    assert (tmp_path / "skip-neu3d.png").stat().st_size > 1000 and "Pareto front" in text
    assert full["static_gaussians"] == 0 and full["gaussians"] > 0 and static["gaussians"] > 0
    for r in (full, static):  # the ceiling split into the frames with motion and the others
        assert 0 <= r["ceiling_moving_frames"] <= 1 and 0 <= r["ceiling_other_frames"] <= 1
    assert full["seconds"]["geometry"] > 0 and static["seconds"]["geometry"] > 0 and "geometry s vs full" in text
    # each run was told as it ended: a line printed and a line in the runs file (an interrupted suite keeps them)
    told = [json.loads(line) for line in (tmp_path / "skip-runs.jsonl").read_text().splitlines()]
    assert [r["variant"] for r in told] == [r["variant"] for r in sk["runs"]] and told[0]["miou"] == full["miou"]
    assert "[1/6] neu3d full: " in text and "[6/6] neu3d primitives: " in text
    assert resolution["seconds"]["geometry"] > 0 and primitives["gaussians"] > 0 and primitives_alone["gaussians"] > 0
    from benchmark.perf.skip import tables

    assert tables(told) in text  # the runs file gives back the table the suite printed


def _check_pareto_and_determinism(s: dict, text: str, tmp_path) -> None:
    _, net = s["network"]["cases"]  # the deformation network's step against one of its products
    assert net["step_gflops_per_s"] > 0 and 0 < net["share_of_product_rate"]

    pa = s["pareto"]
    assert not pa["failed"] and len(pa["runs"]) == 2 and pa["pareto_front"]
    assert (tmp_path / "pareto.png").stat().st_size > 1000  # next to the --json file
    assert "Pareto" in text and "ARI vs known" in text

    det = s["determinism"]["variants"]
    base = det["portable (default)"]
    assert base["geometry"]["identical"] and base["features"]["identical"] and base["numerics"] == "portable"
    # the claim of tests/trase/test_thread_determinism.py, here through whole fresh processes
    assert det["numba 1 thread"]["geometry"]["identical"] and det["numba 1 thread"]["features"]["identical"]
    assert set(det) == {"portable (default)", "numba 1 thread", "torch 1 thread", "torch 2 threads", "native"}
    assert det["native"]["numerics"] == "native" and base["geometry_s"] > 0 and base["features_s"] > 0
    assert "numeric modes" in SUITES.entry("determinism").help
