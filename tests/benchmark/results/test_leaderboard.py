import json

import pytest

from benchmark.cli import main
from benchmark.results import ResultsError, write_results
from benchmark.results.leaderboard import build_tables
from benchmark.results.leaderboard_render import render, render_all
from benchmark.results.runs import RunError, find_runs, one_config_per_row, select_runs
from tests.benchmark.results.helpers import config, record, write


def _main_runs(root):
    return one_config_per_row(select_runs(find_runs(root)))


def test_synthetic_table_best_in_bold_and_no_published_rows(tmp_path):
    write(tmp_path, record("trase", "hypernerf", "synthetic", 0.9, 0.99))
    write(tmp_path, record("cgc", "hypernerf", "synthetic", 0.7, 0.995))
    recs = _main_runs(tmp_path)
    tables = build_tables(recs, "synthetic")
    main_t = tables[0]
    assert [r[0] for r in main_t.rows] == ["cgc [a]", "trase [a]"]  # one protocol, one marker
    md = render(main_t, "markdown")
    assert "**0.9000**" in md and "**0.9950**" in md
    assert "[a] geometry reconstruct (cpu preset); features cpu; masks synthetic" in md
    assert "(published)" not in render_all(recs, "markdown", variants=("synthetic",))
    assert build_tables(recs, "real", published=False) == []


def test_ablation_variants_and_reruns_stay_out_of_the_main_table(tmp_path):
    # the reported case: a main run, then ablation variants into the same --out
    write(tmp_path, record("trase", "nerfds", "synthetic", 0.1221, 0.9))
    for k, miou in (("K=0", 0.1221), ("K=16", 0.6368), ("K=32", 0.1069)):
        rec = record("trase", "nerfds", "synthetic", miou, 0.9, cfg=config(knn=k), study="smoothing",
                     overrides=[f"method.features.knn={k[2:]}"], name=k)
        write(tmp_path, rec, under="ablations/smoothing")
    write(tmp_path, record("trase", "nerfds", "synthetic", 0.5, 0.9, cfg=config(filter_threshold=0.5),
                           overrides=["method.filter_threshold=0.5"]))
    runs = find_runs(tmp_path)
    assert sorted(r["run"]["kind"] for r in runs) == ["ablation"] * 3 + ["main", "run"]
    t = build_tables(_main_runs(tmp_path), "synthetic")
    assert t[0].rows[0][1][:2] == [0.1221, 0.9] and t[1].rows[0][1][:2] == [0.1221, 0.9]
    # asked for: the variants enter, and their different configs are refused, named
    with pytest.raises(RunError, match="4 runs with different configs"):
        one_config_per_row(select_runs(runs, ("main", "ablation")))


def test_a_set_that_restates_the_defaults_is_still_the_main_run():
    from benchmark.results.runs import run_info

    assert run_info("c1", ["method.features.knn=16"], defaults=True)["kind"] == "main"
    assert run_info("c1", [], defaults=False)["kind"] == "run"
    assert run_info("c1", ["x=1"], study="smoothing", variant="K=0", defaults=True)["kind"] == "ablation"


def test_two_configs_for_one_row_are_refused_unless_chosen(tmp_path, capsys):
    a = write(tmp_path, record("trase", "hypernerf", "synthetic", 0.7, 0.9))
    b = write(tmp_path, record("trase", "hypernerf", "synthetic", 0.8, 0.9, cfg=config(preset="paper")))
    with pytest.raises(RunError, match=r"trase on hypernerf/synthetic: 2 runs with different configs.*--run"):
        _main_runs(tmp_path)
    assert main(["leaderboard", "--runs", str(tmp_path), "--variant", "synthetic"]) == 1
    assert "choose one with --run" in capsys.readouterr().err
    assert main(["leaderboard", "--run", str(b), "--variant", "synthetic"]) == 0
    out = capsys.readouterr().out
    assert "0.8000" in out and "0.7000" not in out and "geometry reconstruct (paper preset)" in out
    # the same config twice (a named rerun of the defaults): one cell, the newest
    rec = record("trase", "hypernerf", "synthetic", 0.7, 0.9, name="again")
    rec["created"] = "2099-01-01T00:00:00+00:00"
    write(tmp_path, rec)
    kept = one_config_per_row([r for r in find_runs(tmp_path) if r["config_hash"] == rec["config_hash"]])
    assert len(kept) == 1 and kept[0]["run"]["name"] == "again"
    assert a.exists()
    # the same config on another scene of the same name (a synthetic scene of another seed)
    other = record("trase", "hypernerf", "synthetic", 0.9, 0.9, name="seed1") | {"checksums": {"gt": "other"}}
    write(tmp_path, other)
    with pytest.raises(RunError, match="different scenes"):
        one_config_per_row([r for r in find_runs(tmp_path) if r["config_hash"] == rec["config_hash"]])


def test_official_metric_with_v1_beside_where_it_differs(tmp_path):
    write(tmp_path, record("trase", "hypernerf", "synthetic", 0.6, 0.9, v1=(0.75, 0.9)))
    md = render_all(_main_runs(tmp_path), "markdown", variants=("synthetic",))
    assert "0.6000** (v1 0.7500)" in md  # official in the cell, v1 beside it
    assert "0.9000**" in md and "0.9000** (v1" not in md  # mAcc: the same, nothing beside
    assert "official metric" in md
    csv = render_all(_main_runs(tmp_path), "csv", variants=("synthetic",))
    assert "HyperNeRF-Mask_miou_v1" in csv and "0.75" in csv


def test_real_average_only_when_every_sequence_ran(tmp_path):
    write(tmp_path, record("trase", "nerfds", "as_novel_view", 0.8, 0.9, variant="real"))
    t = build_tables(_main_runs(tmp_path), "real")[0]
    row = {r[0]: r[1] for r in t.rows}
    nerfds = t.groups.index("NeRF-DS-Mask")
    assert row["trase [a]"][2 * nerfds] is None  # 1 of 5 sequences: no average
    assert row["trase (published)"][2 * nerfds] == pytest.approx(0.8773, abs=1e-3)
    assert any("1/5 sequences" in n for n in t.notes)
    for seq in ("basin_novel_view", "cup_novel_view", "plate_novel_view", "press_novel_view"):
        write(tmp_path, record("trase", "nerfds", seq, 0.6, 0.9, variant="real"))
    t = build_tables(_main_runs(tmp_path), "real")[0]
    row = {r[0]: r[1] for r in t.rows}
    assert row["trase [a]"][2 * nerfds] == pytest.approx((0.8 + 4 * 0.6) / 5)


def test_formats_render(tmp_path):
    write(tmp_path, record("trase", "neu3d", "synthetic", 0.5, 0.6))
    recs = _main_runs(tmp_path)
    for fmt in ("markdown", "latex", "csv", "html"):
        out = render_all(recs, fmt, variants=("synthetic",))
        assert "0.5000" in out or "0.5" in out
    latex = render_all(recs, "latex", variants=("synthetic",))
    assert "\\textbf{0.5000}" in latex and "trase [a]" in latex and "[a] scene" not in latex
    assert "[a] geometry reconstruct" in latex  # the protocol footnote under the table


def test_corrupt_and_legacy_results_files(tmp_path, capsys):
    p = tmp_path / "x" / "results.json"
    p.parent.mkdir()
    p.write_text(json.dumps({"schema": "trase-bench/results/3", "method": "m"}))
    with pytest.raises(ResultsError, match="results.json: results file lacks key 'dataset'"):
        find_runs(tmp_path)
    for old in ("1", "2"):
        p.write_text(json.dumps({"schema": f"trase-bench/results/{old}", "method": "m"}))
        notes = []
        assert find_runs(tmp_path, warn=notes.append) == []
        assert "written by an older version" in notes[0]
        with pytest.raises(ResultsError, match="older version"):
            write_results(tmp_path / "y.json", {"schema": f"trase-bench/results/{old}"})
    bad = record("trase", "nerfds", "synthetic", 0.5, 0.5)
    bad["run"]["seed"] = -1
    with pytest.raises(ResultsError, match="seed"):
        write_results(tmp_path / "z.json", bad)


def test_seeds_of_one_config_are_one_row_with_mean_and_spread(tmp_path):
    for s, miou in ((0, 0.80), (1, 0.90), (2, 0.85)):
        write(tmp_path, record("trase", "hypernerf", "synthetic", miou, 0.99, seed=s))
    write(tmp_path, record("cgc", "hypernerf", "synthetic", 0.84, 0.98, cfg=config(knn=0)))
    recs = _main_runs(tmp_path)
    names = {r["run"]["seed"]: r["run"]["name"] for r in recs if r["method"] == "trase"}
    group = recs[-1]["run"]["group"][:8]
    assert names == {0: f"c{group}", 1: f"c{group}-s1", 2: f"c{group}-s2"}  # side by side
    assert sorted(r["run"]["seed"] for r in recs if r["method"] == "trase") == [0, 1, 2]
    t = build_tables(recs, "synthetic")[0]
    rows = {r.label.split(" ")[0]: r for r in t.rows}
    assert rows["trase"].cells[0] == pytest.approx(0.85) and rows["trase"].seeds == 3
    assert rows["trase"].spread[0] == pytest.approx(0.05)  # sample std of 0.80, 0.90, 0.85
    assert rows["cgc"].seeds == 1 and rows["cgc"].spread[0] is None
    md = render(t, "markdown")
    assert "**0.8500** ± 0.0500" in md and "| seeds |" in md
    assert "≈0.8400" in md  # 0.01 below the best, within its spread of 0.05
    assert "0.9900** ± 0.0000" in md and "≈0.9800" not in md  # mAcc: no spread, a real gap
    csv = render(t, "csv")
    assert "HyperNeRF-Mask_miou_std" in csv and ",3," in csv
    # per-sequence table: the same mean and spread
    seq = build_tables(recs, "synthetic")[1]
    assert {r.label.split(" ")[0]: r.seeds for r in seq.rows} == {"cgc": 1, "trase": 3}
    for fmt in ("latex", "html"):
        assert "0.0500" in render(t, fmt)


def test_a_rerun_of_one_seed_keeps_the_newest_and_other_configs_are_still_refused(tmp_path):
    write(tmp_path, record("trase", "nerfds", "synthetic", 0.5, 0.9, seed=1))
    again = record("trase", "nerfds", "synthetic", 0.6, 0.9, seed=1, name="again")
    again["created"] = "2099-01-01T00:00:00+00:00"
    write(tmp_path, again)
    kept = _main_runs(tmp_path)
    assert len(kept) == 1 and kept[0]["run"]["name"] == "again"
    write(tmp_path, record("trase", "nerfds", "synthetic", 0.7, 0.9, seed=2, cfg=config(knn=0)))
    with pytest.raises(RunError, match="different configs"):
        _main_runs(tmp_path)


def test_cli_leaderboard_and_runs(tmp_path, capsys):
    write(tmp_path, record("trase", "hypernerf", "synthetic", 0.9, 0.99))
    write(tmp_path, record("trase", "hypernerf", "synthetic", 0.5, 0.99, cfg=config(knn=0), study="smoothing",
                           name="K=0"), under="ablations/smoothing")
    assert main(["leaderboard", "--runs", str(tmp_path), "--variant", "synthetic"]) == 0
    out = capsys.readouterr().out
    assert "HyperNeRF-Mask" in out and "trase [a]" in out and "0.5000" not in out
    assert main(["leaderboard", "--runs", str(tmp_path), "--kind", "ablation", "--variant", "synthetic"]) == 0
    assert "0.5000" in capsys.readouterr().out
    assert main(["runs", "--runs", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "ablation smoothing/v" in out and "main" in out and "[a] geometry reconstruct" in out
    assert main(["leaderboard", "--runs", str(tmp_path / "none")]) == 1


def test_a_gpu_run_names_its_device_in_the_protocol(tmp_path):
    from benchmark.results.runs import protocol, protocol_label

    cpu = config()
    gpu = config(preset="paper", features={"device": "cuda"})
    gpu["geometry"]["train"] = {"device": "cuda"}
    assert "on cuda" not in protocol_label(protocol({"config": cpu}))
    cpu["geometry"]["train"] = {"device": "cpu"}
    assert "on cpu" not in protocol_label(protocol({"config": cpu}))  # the CPU is the default, unnamed
    label = protocol_label(protocol({"config": gpu}))
    assert "geometry reconstruct (paper preset, on cuda); features paper, on cuda" in label
    write(tmp_path, record("trase", "hypernerf", "synthetic", 0.8, 0.9, cfg=gpu))
    md = render(build_tables(_main_runs(tmp_path), "synthetic")[0], "markdown")
    assert "(paper preset, on cuda)" in md


def test_a_front_click_rule_names_its_share_in_the_protocol():
    from benchmark.results.runs import protocol, protocol_label

    assert "click weight;" in protocol_label(protocol({"config": config()}))
    front = config(prompts={"click_rule": "front", "front_share": 0.4})
    assert "click front 0.4;" in protocol_label(protocol({"config": front}))


def test_portable_and_native_numerics_are_labelled_and_never_share_a_row(tmp_path):
    from benchmark.results.runs import protocol, protocol_label

    portable = config() | {"machine": {"numerics": "portable"}}
    native = config()  # records without a machine section computed natively
    assert "numerics portable x86-64-v3" in protocol_label(protocol({"config": portable}))
    assert "numerics native;" in protocol_label(protocol({"config": native}))
    write(tmp_path, record("trase", "hypernerf", "synthetic", 0.8, 0.9, cfg=portable))
    write(tmp_path, record("trase", "hypernerf", "synthetic", 0.7, 0.9, cfg=native, overrides=["machine.numerics=native"]))
    groups = {r["run"]["group"] for r in find_runs(tmp_path)}
    assert len(groups) == 2  # two configs: two rows wherever both are shown, never one mean
    rec = json.loads(next(tmp_path.rglob("results.json")).read_text())
    assert rec["machine"]["numerics"]["mode"] in ("portable", "native") and rec["machine"]["numerics"]["cpu_model"]


def test_portable_runs_name_their_pinning_and_two_pinnings_never_share_a_mean(tmp_path):
    from benchmark.numerics import PINNING
    from benchmark.results.runs import group, protocol, protocol_label

    portable = config() | {"machine": {"numerics": "portable"}}
    first = {"numerics": {"mode": "portable"}}  # a record of the first pinning: no pinning recorded
    now = {"numerics": {"mode": "portable", "pinning": PINNING}}
    assert PINNING > 1
    assert "numerics portable x86-64-v3;" in protocol_label(protocol({"config": portable, "machine": first}))
    label = f"numerics portable x86-64-v3 pinning {PINNING};"
    assert label in protocol_label(protocol({"config": portable, "machine": now}))
    assert label in protocol_label(protocol({"config": portable}))  # not written yet: this process's
    old = record("trase", "hypernerf", "synthetic", 0.8, 0.9, cfg=portable, seed=0) | {"machine": first}
    new = record("trase", "hypernerf", "synthetic", 0.7, 0.9, cfg=portable, seed=1)
    write(tmp_path, old)
    write(tmp_path, new)
    runs = find_runs(tmp_path)
    assert len({group(r) for r in runs}) == 2
    with pytest.raises(RunError, match="different configs"):
        one_config_per_row(runs)


def _corrective(miou_at_1: float, noc85: int, noc90: int) -> dict:
    return {"first_clicks": 2, "budget": 6, "negatives": True, "corrections": [], "undone": [],
            "curve": [{"clicks": 2, "miou": miou_at_1, "macc": 0.9}], "noc@85": noc85, "noc@90": noc90}


def test_runs_of_the_corrective_protocol_get_a_clicks_table_where_fewer_clicks_are_best(tmp_path):
    a = record("trase", "hypernerf", "synthetic", 0.9, 0.99) | {"corrective": _corrective(0.12, 3, 9)}
    b = record("cgc", "hypernerf", "synthetic", 0.8, 0.98) | {"corrective": _corrective(0.50, 5, 7)}
    write(tmp_path, a)
    write(tmp_path, b)
    write(tmp_path, record("saga", "hypernerf", "synthetic", 0.7, 0.97))  # first clicks alone: no row
    tables = build_tables(_main_runs(tmp_path), "synthetic")
    clicks = [t for t in tables if t.columns == ("mIoU@1", "NoC@85", "NoC@90")]
    assert [t.title.split(" (")[0] for t in clicks] == ["Clicks", "HyperNeRF-Mask clicks per sequence"]
    assert [r.label.split(" ")[0] for r in clicks[0].rows] == ["cgc", "trase"]
    assert clicks[0].best() == [0.5, 3.0, 7.0]  # mIoU@1 the most, clicks the fewest
    md = render(clicks[0], "markdown")
    assert "| method | HyperNeRF-Mask mIoU@1 | HyperNeRF-Mask NoC@85 | HyperNeRF-Mask NoC@90 |" in md
    assert "**3.00**" in md and "**0.5000**" in md and "s/seq" not in md
    assert "<th rowspan=2>s/seq</th>" not in render(clicks[0], "html")
    assert "seconds_per_sequence" not in render(clicks[0], "csv")
    assert "s/seq" in render(tables[0], "markdown") and "<th rowspan=2>s/seq</th>" in render(tables[0], "html")


def test_within_the_spread_of_the_best_counts_both_ways():
    from benchmark.results.leaderboard import within_spread

    assert within_spread(0.80, 0.82, [0.05]) and not within_spread(0.70, 0.82, [0.05])
    assert within_spread(4.2, 4.0, [0.5]) and not within_spread(7.0, 4.0, [0.1])  # clicks: the least is best


def test_the_default_leaderboard_names_methods_it_leaves_out(tmp_path, capsys):
    """A plugin run with --set (kind run) beside another method's main run: the default
    tables show the main run and say which method they leave out and how to show it."""
    write(tmp_path, record("trase", "hypernerf", "synthetic", 0.9, 0.99))
    write(tmp_path, record("colour-kmeans", "hypernerf", "synthetic", 0.3, 0.9, cfg=config(filter_threshold=0.5),
                           overrides=["geometry.source=ground-truth"]))
    assert main(["leaderboard", "--runs", str(tmp_path), "--variant", "synthetic"]) == 0
    out, err = capsys.readouterr()
    assert "trase" in out and "colour-kmeans" not in out
    assert "note: not shown, every run made with --set (kind run): colour-kmeans; --kind run shows them" in err
    assert main(["leaderboard", "--runs", str(tmp_path), "--variant", "synthetic", "--kind", "run"]) == 0
    assert "colour-kmeans" in capsys.readouterr().out


def test_the_protocol_label_names_the_robot_users_budget_target_and_check_frames():
    from benchmark.results.runs import corrective_protocol

    cfg = {"prompts": {"corrections": 3, "correction_target": 0.9, "correction_check_frames": 2}}
    assert corrective_protocol(cfg, {"negatives": True}) == ", corrective 3/object to IoU 0.9 watching 2 check frames"
    cfg["prompts"]["correction_undone_radius"] = 2.0
    assert corrective_protocol(cfg, {"negatives": True}) == (
        ", corrective 3/object to IoU 0.9 watching 2 check frames retrying 2 px from undone clicks")
    cfg["prompts"]["correction_region_tries"] = 2
    assert corrective_protocol(cfg, {"negatives": True}).endswith("retrying 2 px from undone clicks, 2 tries per region")
    del cfg["prompts"]["correction_region_tries"]
    del cfg["prompts"]["correction_undone_radius"]
    cfg["prompts"]["correction_check_frames"] = 0  # the click frames alone
    assert corrective_protocol(cfg, {"negatives": False}) == ", corrective 3/object to IoU 0.9, positive only"
    assert corrective_protocol({"prompts": {"corrections": 0}}, None) == ""
