import json

import pytest

from benchmark.cli import main
from benchmark.leaderboard import build_tables, render, render_all
from benchmark.results import ResultsError, find_results, results_path, write_results


def _rec(method, dataset, sequence, miou, macc, variant="synthetic", seconds=10.0):
    return {
        "method": method, "dataset": dataset, "sequence": sequence, "variant": variant,
        "metrics": {"miou": miou, "macc": macc, "pooled_iou": miou, "metric_version": "v1/bin1",
                    "n_frames": 3},
        "stages": {"features": {"seconds": seconds}},
    }


def _write(root, rec):
    write_results(results_path(root, rec["method"], rec["dataset"], rec["sequence"]), rec)


def test_synthetic_table_best_in_bold_and_no_published_rows(tmp_path):
    _write(tmp_path, _rec("trase", "hypernerf", "synthetic", 0.9, 0.99))
    _write(tmp_path, _rec("cgc", "hypernerf", "synthetic", 0.7, 0.995))
    recs = find_results(tmp_path)
    tables = build_tables(recs, "synthetic")
    main_t = tables[0]
    assert [r[0] for r in main_t.rows] == ["cgc", "trase"]
    md = render(main_t, "markdown")
    assert "**0.9000**" in md and "**0.9950**" in md
    assert "published" not in render_all(recs, "markdown", variants=("synthetic",))
    assert build_tables(recs, "real", published=False) == []


def test_real_average_only_when_every_sequence_ran(tmp_path):
    _write(tmp_path, _rec("trase", "nerfds", "as_novel_view", 0.8, 0.9, variant="real"))
    recs = find_results(tmp_path)
    t = build_tables(recs, "real")[0]
    row = dict((r[0], r[1]) for r in t.rows)
    nerfds = t.groups.index("NeRF-DS-Mask")
    assert row["trase"][2 * nerfds] is None  # 1 of 5 sequences: no average
    assert row["trase (published)"][2 * nerfds] == pytest.approx(0.8773, abs=1e-3)
    assert any("1/5 sequences" in n for n in t.notes)
    for seq in ("basin_novel_view", "cup_novel_view", "plate_novel_view", "press_novel_view"):
        _write(tmp_path, _rec("trase", "nerfds", seq, 0.6, 0.9, variant="real"))
    t = build_tables(find_results(tmp_path), "real")[0]
    row = dict((r[0], r[1]) for r in t.rows)
    assert row["trase"][2 * nerfds] == pytest.approx((0.8 + 4 * 0.6) / 5)


def test_formats_render(tmp_path):
    _write(tmp_path, _rec("trase", "neu3d", "synthetic", 0.5, 0.6))
    recs = find_results(tmp_path)
    for fmt in ("markdown", "latex", "csv", "html"):
        out = render_all(recs, fmt, variants=("synthetic",))
        assert "0.5000" in out or "0.5" in out
    assert "\\textbf{0.5000}" in render_all(recs, "latex", variants=("synthetic",))


def test_corrupt_results_file_is_named(tmp_path):
    p = tmp_path / "x" / "results.json"
    p.parent.mkdir()
    p.write_text(json.dumps({"schema": "trase-bench/results/1", "method": "m"}))
    with pytest.raises(ResultsError, match="results.json: results file lacks key 'dataset'"):
        find_results(tmp_path)


def test_cli_leaderboard(tmp_path, capsys):
    _write(tmp_path, _rec("trase", "hypernerf", "synthetic", 0.9, 0.99))
    assert main(["leaderboard", "--results", str(tmp_path), "--variant", "synthetic"]) == 0
    out = capsys.readouterr().out
    assert "HyperNeRF-Mask" in out and "trase" in out
    assert main(["leaderboard", "--results", str(tmp_path / "none")]) == 1
