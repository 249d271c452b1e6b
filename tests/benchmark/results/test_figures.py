"""The figures page (docs/figures.md) comes from docs/figures.json through one renderer."""

from pathlib import Path

import pytest

from benchmark.errors import UserError
from benchmark.results.figures import (
    BEGIN,
    END,
    SCHEMA,
    page_block,
    read_figures,
    render_block,
    replace_block,
    run_instruction_sets,
)

ROOT = Path(__file__).resolve().parents[3]


def _data():
    st = lambda m, s: {"mean": m, "std": s, "n": 3}
    summary = {"seeds": [0, 1, 2], "miou": st(0.9, 0.01), "oracle": st(0.91, 0.01), "ceiling": st(0.92, 0.0),
               "click_sets_median": st(0.88, 0.02), "click_sets_worst": st(0.5, 0.1),
               "miou_at_1": st(0.6, 0.2), "noc85": st(3.0, 0.0), "noc90": st(4.0, 1.0),
               "agreement": {"pixel_ari": 0.95, "gaussian_ari": None, "pairs": []}}
    return {"schema": SCHEMA, "commit": "abc1234", "date": "2026-11-24", "machine": {"cpus": 2, "processor": "x86_64"},
            "rows": [{"format": "hypernerf", "geometry": "reconstruct", "summary": summary,
                      "test_psnr": [27.0, 27.2, 26.8], "seconds": [200.0, 210.0, 190.0]}]}


def test_block_renders_mean_and_spread_and_replaces_only_itself():
    block = render_block(_data())
    assert "| HyperNeRF | reconstructed | 27.00 ± 0.20 | 0.920 ± 0.000 | 0.910 ± 0.010 | **0.900 ± 0.010** |" in block
    assert "| 0.600 ± 0.200 | 3.0 ± 0.0 / 4.0 ± 1.0 | 0.880 ± 0.020 / 0.500 ± 0.100 | 0.950 | 3 |" in block
    assert "abc1234" not in block and "Measured on 2026-11-24" in block and "°" not in block  # the commit: data only
    single = _data()
    for k in ("miou_at_1", "noc85", "noc90"):  # a row of runs of the first clicks alone
        del single["rows"][0]["summary"][k]
    block1 = render_block(single)
    assert "**0.900 ± 0.010**° | — | — / — |" in block1 and block1.rstrip().endswith("the single-click score.")
    text = f"intro\n{BEGIN}\nold\n{END}\nrest\n"
    new = replace_block(text, block)
    assert new.startswith("intro\n") and new.endswith(f"{END}\nrest\n") and page_block(new) == block
    with pytest.raises(UserError, match="exactly one figures block"):
        replace_block("no markers", block)
    with pytest.raises(UserError, match="schema"):
        render_block({"schema": "x"})


def test_block_names_the_instruction_sets_its_runs_were_computed_with():
    # they change a reconstruction's bits and so the figures (docs/determinism.md)
    avx512 = {"machine": {"torch_cpu_capability": "AVX512", "numba_cpu": "znver5"}}
    avx2 = {"machine": {"torch_cpu_capability": "AVX2", "numba_cpu": "znver3"}}
    assert run_instruction_sets([avx512, avx512]) == ["torch AVX512, numba znver5"]
    first = {"config": {"machine": {"numerics": "portable"}}, "machine": {"torch_cpu_capability": "AVX2", "numba_cpu": "x86-64-v3",
                                                         "numerics": {"mode": "portable"}}}
    second = {"config": first["config"], "machine": dict(first["machine"], numerics={"pinning": 2})}
    assert run_instruction_sets([first, second]) == ["torch AVX2, numba x86-64-v3",
                                                     "torch AVX2, numba x86-64-v3, pinning 2"]
    assert run_instruction_sets([avx512, avx2, {}]) == ["torch AVX2, numba znver3", "torch AVX512, numba znver5",
                                                         "unrecorded"]
    data = _data()
    data["machine"]["instruction_sets"] = ["torch AVX512, numba znver5"]
    assert "(2 CPU cores, x86_64; torch AVX512, numba znver5)" in render_block(data)
    data["machine"]["instruction_sets"] = run_instruction_sets([avx512, avx2])
    assert "runs from 2 instruction sets: torch AVX2, numba znver3 / torch AVX512, numba znver5)" in render_block(data)
    del data["machine"]["instruction_sets"]  # a data file written before the field: as before
    assert "(2 CPU cores, x86_64), `trase-bench figures`" in render_block(data)


def test_figures_page_is_the_rendering_of_its_data_file():
    readme = (ROOT / "docs" / "figures.md").read_text()
    data = read_figures(ROOT / "docs" / "figures.json")
    assert page_block(readme) == render_block(data), \
        "docs/figures.md figures block differs from docs/figures.json: run `trase-bench figures --collect-only --write-page`"


def _methods_data():
    data = _data()
    base = data["rows"][0]
    st = lambda m, s: {"mean": m, "std": s, "n": 3}
    rows = []
    for method, miou, seeds in (("trase", 0.9, [0, 1, 2]), ("cgc", 0.7, [0]), ("saga", 0.8, [0, 1, 2])):
        for fmt in ("hypernerf", "neu3d"):
            summary = dict(base["summary"], seeds=seeds, miou=st(miou, 0.01 if len(seeds) > 1 else None))
            rows.append(dict(base, method=method, format=fmt, summary=summary))
    rows.append(dict(rows[0], geometry="ground-truth"))
    data["rows"] = rows
    return data


def test_methods_block_puts_the_measured_beside_the_published_and_orders_both():
    from benchmark.results.figures import METHODS_BEGIN, METHODS_END, page_markers
    from benchmark.results.figures_methods import render_methods_block

    block = render_methods_block(_methods_data())
    assert "| method | HyperNeRF | Neu3D |" in block  # only the formats measured
    assert "| trase | 0.900 ± 0.010 | 0.900 ± 0.010 |" in block
    assert "| cgc | 0.700 (1) | 0.700 (1) |" in block  # a seed count where fewer than three
    gt = block.split("**Ground-truth geometry**")[1].split("**Published**")[0]
    assert "| trase | 0.900 ± 0.010 | — |" in gt and "| cgc | — | — |" in gt
    # the paper's Table 1 averages (package data), measured methods first, then the others
    pub = block.split("**Published**")[1].split("**Order**")[0]
    assert "| trase | 0.866 | 0.902 |" in pub and "| saga | 0.766 | 0.694 |" in pub and "| dgd |" in pub
    assert pub.index("| cgc |") < pub.index("| dgd |")
    assert "| HyperNeRF | trase > saga > cgc | — | trase > cgc > saga |" in block
    # the block's markers tell the page apart from trase's figures page
    assert page_markers(f"{METHODS_BEGIN}\nx\n{METHODS_END}")[1] is render_methods_block
    assert page_markers(f"{BEGIN}\nx\n{END}")[1] is render_block
    # trase's figures block ignores the other methods' rows
    assert "0.700" not in render_block(_methods_data())


def test_competitors_page_methods_table_is_the_rendering_of_its_data_file():
    from benchmark.results.figures import METHODS_BEGIN, METHODS_END
    from benchmark.results.figures_methods import render_methods_block

    page = (ROOT / "docs" / "competitors.md").read_text()
    data = read_figures(ROOT / "docs" / "methods-figures.json")
    assert page_block(page, markers=(METHODS_BEGIN, METHODS_END)) == render_methods_block(data), \
        ("docs/competitors.md methods table differs from docs/methods-figures.json: run `trase-bench figures "
         "--collect-only --method ... --data docs/methods-figures.json --write-page docs/competitors.md`")


def test_methods_block_gives_each_methods_feature_stage_on_the_default_scene():
    from benchmark.results.figures_methods import render_methods_block

    data = _methods_data()
    assert "Feature stage" not in render_methods_block(data)  # data files from before these fields
    for r in data["rows"]:
        if r["method"] == "saga" and r["format"] == "hypernerf":
            r.update(features_seconds=[300.0, 100.0, 200.0], features_per_step=[0.1, 0.2, 0.3])
        if r["method"] == "trase" and r["format"] == "neu3d":  # not the default scene: not shown
            r.update(features_seconds=[50.0], features_per_step=[0.02])
    block = render_methods_block(data)
    part = block.split("**Feature stage on the default scene**")[1]
    assert "| saga | 200 | 200 | — | — |" in part  # medians: seconds, ms per step
    assert "| trase |" not in part and "| cgc |" not in part


def test_methods_block_leaves_the_code_commits_to_the_data_file():
    from benchmark.results.figures_methods import render_methods_block

    data = _methods_data()
    data["run_commits"] = ["abc1234", "unrecorded"]
    head = render_methods_block(data).splitlines()[0]
    assert head.startswith(f"Summarised on {data['date']}") and "abc1234" not in head
    assert "each run's code commit is in the data file" in head


def test_a_results_record_names_its_code_commit():
    import subprocess

    from benchmark.results.record import code_commit, package_versions

    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                          check=False)
    if head.returncode != 0:
        pytest.skip("not a git checkout: the commit is 'unknown' here")
    assert package_versions()["trase-bench commit"] == code_commit()
    assert code_commit().split("+")[0] == head.stdout.strip()


def _remeasured(data):
    """A re-measurement of cgc on HyperNeRF and of opengaussian (new) from another machine."""
    new = _methods_data()
    avx2 = ["torch AVX2, numba znver3"]
    rows = []
    for r in new["rows"]:
        if r["method"] == "cgc" and r["format"] == "hypernerf" and r["geometry"] == "reconstruct":
            rows.append(dict(r, summary=dict(r["summary"], miou={"mean": 0.5, "std": 0.02, "n": 3},
                                             seeds=[0, 1, 2]),
                             instruction_sets=avx2, run_commits=["def5678"], date="2026-11-28"))
    rows.append(dict(rows[0], method="opengaussian"))
    return dict(new, commit="def5678", date="2026-11-28", rows=rows,
                machine={"cpus": 2, "processor": "x86_64", "instruction_sets": avx2}, run_commits=["def5678"])


def test_an_update_replaces_only_its_cells_and_marks_those_from_another_machine():
    from benchmark.results.figures import merge
    from benchmark.results.figures_methods import render_methods_block

    old = _methods_data()
    old["machine"]["instruction_sets"] = ["torch AVX512, numba znver5"]
    old["run_commits"] = ["abc1234"]
    data = merge(old, _remeasured(old))
    keys = [(r["method"], r["format"], r["geometry"]) for r in data["rows"]]
    assert len(keys) == len(set(keys)) == len(old["rows"]) + 1  # one replaced in place, one added
    assert keys.index(("cgc", "hypernerf", "reconstruct")) == 2
    assert data["run_commits"] == ["abc1234", "def5678"]
    assert data["machine"]["instruction_sets"] == ["torch AVX2, numba znver3", "torch AVX512, numba znver5"]
    block = render_methods_block(data)
    assert "| cgc | 0.500 ± 0.020† | 0.700 (1) |" in block  # the re-measured cell, marked
    assert "| opengaussian | 0.500 ± 0.020† | — |" in block
    assert "| trase | 0.900 ± 0.010 | 0.900 ± 0.010 |" in block  # kept, unmarked
    assert ("† runs computed with torch AVX2, numba znver3, on 2026-11-28; "
            "the unmarked cells' with torch AVX512, numba znver5.") in block
    assert "runs from 2 instruction sets" in block.splitlines()[0]
    # one machine: no marks, as before
    same = _remeasured(old)
    for r in same["rows"]:
        r["instruction_sets"] = ["torch AVX512, numba znver5"]
    assert "†" not in render_methods_block(merge(old, same))


def test_figures_update_merges_into_its_data_file_and_needs_one(tmp_path, monkeypatch, capsys):
    import json

    from benchmark.cli import main
    from benchmark.results import figures

    old = _methods_data()
    old["machine"]["instruction_sets"] = ["torch AVX512, numba znver5"]
    monkeypatch.setattr(figures, "collect", lambda *a, **k: _remeasured(old))
    path = tmp_path / "methods-figures.json"
    args = ["figures", "--collect-only", "--runs", str(tmp_path), "--method", "cgc", "--method", "opengaussian",
            "--data", str(path), "--update"]
    assert main(args) != 0
    assert "does not exist" in capsys.readouterr().err and not path.exists()
    path.write_text(json.dumps(old))
    assert main(args) == 0
    data = read_figures(path)
    assert len(data["rows"]) == len(old["rows"]) + 1 and "0.500 ± 0.020†" in capsys.readouterr().out


def test_figures_of_one_other_method_print_its_rows(tmp_path, monkeypatch, capsys):
    """`figures --method saga` alone prints saga's rows (trase's block would show none of them)."""
    from benchmark.cli import main
    from benchmark.results import figures

    data = _methods_data()
    data["rows"] = [r for r in data["rows"] if r["method"] == "saga"]
    monkeypatch.setattr(figures, "collect", lambda *a, **k: data)
    assert main(["figures", "--collect-only", "--runs", str(tmp_path), "--method", "saga",
                 "--data", str(tmp_path / "saga.json")]) == 0
    assert "| saga |" in capsys.readouterr().out


def test_trases_figures_block_marks_its_cells_from_another_machine_too():
    from benchmark.results.figures import merge

    old = _data()
    old["machine"]["instruction_sets"] = ["torch AVX512, numba znver5"]
    old["rows"] += [dict(old["rows"][0], format="neu3d"), dict(old["rows"][0], format="technicolor")]
    new = _data()
    new["rows"][0].update(instruction_sets=["torch AVX2, numba znver3"], run_commits=["def5678"], date="2026-11-28")
    block = render_block(merge(old, new))
    assert "| HyperNeRF | reconstructed | 27.00 ± 0.20 | 0.920 ± 0.000 | 0.910 ± 0.010 | **0.900 ± 0.010**† |" in block
    assert "| Neu3D | reconstructed | 27.00 ± 0.20 | 0.920 ± 0.000 | 0.910 ± 0.010 | **0.900 ± 0.010** |" in block
    assert block.endswith("the unmarked cells' with torch AVX512, numba znver5.\n")
    # a tie (one cell of each): the earlier measurement stays unmarked, the re-measured cell is marked
    tie = merge(dict(old, rows=old["rows"][:1] + [dict(old["rows"][0], format="neu3d")]), new)
    assert "| HyperNeRF | reconstructed | 27.00 ± 0.20 | 0.920 ± 0.000 | 0.910 ± 0.010 | **0.900 ± 0.010**† |" in render_block(tie)


def test_methods_block_gives_the_clicks_of_the_methods_measured_under_the_corrective_protocol():
    from benchmark.results.figures_methods import render_methods_block

    data = _methods_data()
    for r in data["rows"]:  # rows of the first clicks alone
        r["summary"] = {k: v for k, v in r["summary"].items() if k not in ("miou_at_1", "noc85", "noc90")}
    assert "**Clicks" not in render_methods_block(data)
    st = lambda m, s: {"mean": m, "std": s, "n": 3}
    for r in data["rows"]:
        if r["method"] == "saga" and r["format"] == "hypernerf":
            r["summary"] |= {"miou_at_1": st(0.4, 0.1), "noc85": st(5.0, 1.0), "noc90": st(7.0, 0.0)}
    block = render_methods_block(data)
    part = block.split("**Clicks, reconstructed geometry**")[1].split("**")[0]
    assert "| saga | 0.400 ± 0.100; 5.0 ± 1.0 / 7.0 ± 0.0 |" in part and "| trase |" not in part
    assert "0.766" in block and "°" in block.split("**Clicks")[0]  # the other cells: first clicks alone


def test_blocks_are_written_together_or_not_at_all(tmp_path):
    from benchmark.results.figures import write_blocks

    page = tmp_path / "page.md"
    page.write_text("a\n<!-- A:BEGIN -->\nold\n<!-- A:END -->\nb\n<!-- B:BEGIN -->\nold\n")  # B has no end
    a, b = ("<!-- A:BEGIN -->", "<!-- A:END -->"), ("<!-- B:BEGIN -->", "<!-- B:END -->")
    with pytest.raises(UserError, match="exactly one figures block"):
        write_blocks(page, [(a, "new\n"), (b, "new\n")])
    assert "old\n<!-- A:END -->" in page.read_text()  # the first block was not written alone
    write_blocks(page, [(a, "new\n")])
    assert page.read_text().startswith("a\n<!-- A:BEGIN -->\nnew\n<!-- A:END -->\nb\n")
