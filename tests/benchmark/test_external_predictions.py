"""``trase-bench evaluate``: predicted masks made outside the benchmark become runs of kind
external, which ``runs``, ``leaderboard`` and ``report`` show like any run, and which hold the
numbers ``trase-bench score`` gives on the same masks.

The data: every NeRF-DS sequence as a tiny real-format scene (6 test views of 16x12, ground
truth 0/255), and predictions written as the public code's render.py writes them (RGB 0/255 at
``<sequence>/test/ours_<iteration>/pred_masks/<idx:05d>.png``): the ground truth shifted by one
pixel, one frame missing in cup_novel_view, an older iteration and a stray file in as_novel_view.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from benchmark.cli import main
from benchmark.datasets import DATASETS, load_scene
from benchmark.results.runs import EXTERNAL_PROTOCOL
from tests.benchmark.datasets.fixture_writers import write_nerfies

SEQUENCES = DATASETS["nerfds"].sequences
MISSING = ("cup_novel_view", "00002")


def _write_masks(out: Path, gt_masks: list[Path], shift: int = 1) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for i, g in enumerate(gt_masks):
        m = np.roll(cv2.imread(str(g), cv2.IMREAD_GRAYSCALE), shift, axis=1)
        cv2.imwrite(str(out / f"{i:05d}.png"), np.repeat(m[..., None], 3, axis=2))  # RGB, as render.py saves


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """(data root, predictions folder in the public code's layout) for all of NeRF-DS."""
    root = tmp_path_factory.mktemp("external")
    data, preds = root / "data", root / "output" / "nerfds"
    for seq in SEQUENCES:
        scene = load_scene("nerfds", write_nerfies(data / "nerfds" / seq, two_cameras=True))
        _write_masks(preds / seq / "test" / "ours_30000" / "pred_masks", scene.gt_masks)
    older = preds / "as_novel_view" / "test" / "ours_7000" / "pred_masks"
    _write_masks(older, load_scene("nerfds", data / "nerfds" / "as_novel_view").gt_masks, shift=5)
    (preds / "as_novel_view" / "test" / "ours_30000" / "pred_masks" / "notes.txt").write_text("stray")
    (preds / MISSING[0] / "test" / "ours_30000" / "pred_masks" / f"{MISSING[1]}.png").unlink()
    return data, preds


def _evaluate(bench, runs: Path, *extra: str, name: str = "ext", predictions: Path | None = None) -> int:
    data, preds = bench
    return main(["evaluate", "--predictions", str(predictions or preds), "--dataset", "nerfds", "--name", name,
                 "--data-root", str(data), "--runs", str(runs), *extra])


@pytest.fixture(scope="module")
def evaluated(bench, tmp_path_factory) -> dict[str, dict]:
    """The runs written by one evaluate of the public layout: sequence -> results record."""
    runs = tmp_path_factory.mktemp("runs")
    assert _evaluate(bench, runs) == 0
    found = {}
    for p in sorted(runs.glob("ext/nerfds/*/*/results.json")):
        rec = json.loads(p.read_text())
        found[rec["sequence"]] = rec | {"_dir": p.parent}
    return found


def test_every_sequence_becomes_an_external_run(evaluated):
    from benchmark.results.fields import FIELDS

    assert sorted(evaluated) == sorted(SEQUENCES)
    for seq, rec in evaluated.items():
        assert set(rec) - {"_dir"} <= set(FIELDS)  # every field documented (docs/reference/results-file.md)
        assert rec["run"]["kind"] == "external" and rec["method"] == "ext" and rec["variant"] == "real"
        assert rec["run"]["name"] == rec["_dir"].name == f"e{rec['config_hash'][:8]}"
        ext = rec["external"]
        assert (ext["layout"], ext["iteration_dir"]) == ("trase", "ours_30000")
        assert ext["metric_versions"] == {"v1": "v1/bin2", "official": "official/script1"}
        assert rec["metrics"]["metric_version"] == "v1/bin2"
        assert rec["metrics"]["official"]["metric_version"] == "official/script1"
        assert Path(ext["masks_dir"]).parts[-4:] == (seq, "test", "ours_30000", "pred_masks")
    # the highest iteration is read, the others listed; files that are no masks are listed, not read
    as_ = evaluated["as_novel_view"]["external"]
    assert as_["other_iteration_dirs"] == ["ours_7000"] and as_["ignored"] == ["notes.txt"]


def test_checksums_of_the_prediction_files(evaluated):
    for rec in evaluated.values():
        files = rec["external"]["files"]
        source = Path(rec["external"]["masks_dir"])
        assert files == {name: hashlib.sha256((source / name).read_bytes()).hexdigest() for name in files}
        # the run keeps the same bytes
        assert files == {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in (rec["_dir"] / "pred").iterdir()}
        assert len(rec["checksums"]["pred"]) == 16 and len(rec["checksums"]["gt"]) == 16


def test_missing_frames_are_listed(evaluated):
    seq, frame = MISSING
    rec = evaluated[seq]
    assert rec["external"]["missing"] == [frame]
    assert rec["metrics"]["missing"] == [frame] and rec["metrics"]["official"]["missing"] == [frame]
    assert rec["metrics"]["n_frames"] == 6 and rec["metrics"]["official"]["n_frames"] == 5  # v1: empty; official: skipped
    assert [f["pred"] for f in rec["frames"]][2] is None
    assert all(not r["external"]["missing"] for s, r in evaluated.items() if s != seq)


@pytest.mark.parametrize("metric", ["v1", "official"])
def test_score_on_the_same_masks_gives_the_recorded_numbers(evaluated, metric, capsys):
    for rec in evaluated.values():
        ext = rec["external"]
        assert main(["score", ext["masks_dir"], ext["gt_dir"], "--metric", metric, "--json"]) == 0
        scored = json.loads(capsys.readouterr().out)
        recorded = rec["metrics"] if metric == "v1" else rec["metrics"]["official"]
        per_frame = rec["per_frame"] if metric == "v1" else rec["per_frame_official"]
        for key in ("miou", "macc", "pooled_iou", "missing", "n_frames", "metric_version"):
            assert scored[key] == recorded[key], (rec["sequence"], key)
        assert scored["per_frame"] == per_frame
        # and the copy in the run scores the same
        assert main(["score", str(rec["_dir"] / "pred"), ext["gt_dir"], "--metric", metric, "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["miou"] == recorded["miou"]


def test_runs_leaderboard_and_report_show_them_with_the_footnote(evaluated, capsys):
    runs = next(iter(evaluated.values()))["_dir"].parents[3]
    assert main(["runs", "--runs", str(runs), "--kind", "external"]) == 0
    out = capsys.readouterr().out
    listed = [line for line in out.splitlines() if " external " in line and "/ext/nerfds/" in line]
    assert len(listed) == len(SEQUENCES) and f"[a] {EXTERNAL_PROTOCOL}" in out
    assert main(["leaderboard", "--runs", str(runs), "--variant", "real"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| ext [a]")]
    assert len(rows) == 2  # the main table and NeRF-DS per sequence
    official = [r["metrics"]["official"] for r in evaluated.values()]
    mean = np.mean([o["miou"] for o in official])
    assert rows[0].split(" | ")[1].startswith(f"{mean:.4f}")  # every sequence evaluated: the dataset's average
    assert rows[0].rstrip(" |").endswith("—")  # no time: not measured here
    assert f"- [a] {EXTERNAL_PROTOCOL}; metric official/script1" in out
    assert "trase (published)" in out
    run = evaluated[MISSING[0]]["_dir"]
    assert main(["report", "--run", str(run)]) == 0
    page = (run / "report.html").read_text()
    assert f"Protocol: {EXTERNAL_PROTOCOL}; metric official/script1" in page
    assert "No prediction for 1 test frame(s) (00002)" in page and "<h2>Prompts</h2>" not in page
    assert main(["report", "--method", "ext", "--dataset", "nerfds", "--sequence", "as_novel_view",
                 "--runs", str(runs)]) == 0
    capsys.readouterr()
    assert main(["render", "--run", str(run)]) == 1
    assert "external predictions (trase-bench evaluate) come without a model" in capsys.readouterr().err


def test_the_flat_layout_gives_the_same_runs(bench, evaluated, tmp_path, capsys):
    flat = tmp_path / "flat"
    for seq in SEQUENCES:
        shutil.copytree(Path(evaluated[seq]["external"]["masks_dir"]), flat / seq)
    for layout in ("flat", "auto"):
        runs = tmp_path / f"runs-{layout}"
        assert _evaluate(bench, runs, "--layout", layout, predictions=flat) == 0
        for seq, rec in evaluated.items():
            (path,) = (runs / "ext" / "nerfds" / seq).glob("*/results.json")
            got = json.loads(path.read_text())
            assert got["external"]["layout"] == "flat" and got["external"]["iteration_dir"] is None
            assert got["metrics"] == rec["metrics"] and got["run"]["name"] == rec["run"]["name"]
    assert capsys.readouterr().out.count("-> ") == 2 * len(SEQUENCES)


def test_a_second_evaluate_of_the_same_masks_is_the_same_run_and_other_masks_another(bench, tmp_path, capsys):
    runs = tmp_path / "runs"
    assert _evaluate(bench, runs, "--sequence", "press_novel_view") == 0
    assert _evaluate(bench, runs, "--sequence", "press_novel_view") == 0
    assert len(list(runs.glob("ext/nerfds/press_novel_view/*/results.json"))) == 1
    other = tmp_path / "other"
    shutil.copytree(bench[1] / "press_novel_view", other / "press_novel_view")
    mask = other / "press_novel_view" / "test" / "ours_30000" / "pred_masks" / "00000.png"
    cv2.imwrite(str(mask), np.zeros((12, 16, 3), np.uint8))
    assert _evaluate(bench, runs, predictions=other) == 0
    assert len(list(runs.glob("ext/nerfds/press_novel_view/*/results.json"))) == 2
    capsys.readouterr()
    assert main(["leaderboard", "--runs", str(runs), "--variant", "real"]) == 1
    assert "2 runs with different configs" in capsys.readouterr().err


def test_sequences_without_predictions_are_listed(bench, tmp_path, capsys):
    part = tmp_path / "part"
    for seq in SEQUENCES[:-1]:
        shutil.copytree(bench[1] / seq, part / seq)
    runs = tmp_path / "runs"
    assert _evaluate(bench, runs, predictions=part) == 0
    err = capsys.readouterr().err
    assert f"not evaluated: {SEQUENCES[-1]} (no nerfds average for ext" in err
    assert main(["leaderboard", "--runs", str(runs), "--variant", "real"]) == 0
    assert f"ext on nerfds: {len(SEQUENCES) - 1}/{len(SEQUENCES)} sequences run, no average" in capsys.readouterr().out


def _error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1, err
    return err


def _flat_copy(bench, tmp_path, seqs=("as_novel_view",)) -> Path:
    flat = tmp_path / "flat"
    for seq in seqs:
        shutil.copytree(bench[1] / seq / "test" / "ours_30000" / "pred_masks", flat / seq)
    return flat


def test_a_wrong_layout_is_one_line_naming_the_folder(bench, tmp_path, capsys):
    runs = tmp_path / "runs"
    flat = _flat_copy(bench, tmp_path)
    assert _evaluate(bench, runs, "--layout", "trase", predictions=flat) == 1
    err = _error(capsys)
    assert f"{flat / 'as_novel_view'}: no test/ folder (layout trase" in err and "use --layout flat" in err
    assert _evaluate(bench, runs, "--layout", "flat", "--sequence", "as_novel_view") == 1
    err = _error(capsys)
    assert f"{bench[1] / 'as_novel_view'}: no mask files (layout flat" in err and "--layout trase" in err
    # one sequence's model folder given in place of the folder above it
    assert _evaluate(bench, runs, predictions=bench[1] / "as_novel_view") == 1
    assert f"{bench[1] / 'as_novel_view'}: holds a model folder of the public code" in _error(capsys)
    assert not runs.exists()


@pytest.mark.parametrize("case", ["empty", "absent", "dataset", "sequence", "name", "mixed", "not-there",
                                  "no-masks"])
def test_bad_input_is_one_line_naming_the_folder_and_writes_nothing(bench, tmp_path, capsys, case):
    runs, preds = tmp_path / "runs", tmp_path / "preds"
    preds.mkdir()
    args, name, expect = [], "ext", None
    if case == "empty":
        expect = f"{preds}: no sequence folders"
    elif case == "absent":
        preds = tmp_path / "nowhere"
        expect = f"{preds}: predictions folder not found"
    elif case == "dataset":
        main_args = ["evaluate", "--predictions", str(preds), "--dataset", "nerfies", "--name", "ext",
                     "--runs", str(runs)]
        assert main(main_args) == 1
        assert f"{preds}: cannot evaluate for --dataset 'nerfies': unknown dataset" in _error(capsys)
        assert not runs.exists()
        return
    elif case == "sequence":
        (preds / "cookie").mkdir()
        expect = f"{preds / 'cookie'}: not a sequence of nerfds"
    elif case == "name":
        name, expect = "trase", "--name 'trase' is a method of this benchmark"
    elif case == "mixed":
        preds = _flat_copy(bench, tmp_path)
        shutil.copytree(preds / "as_novel_view", preds / "synthetic")
        expect = f"{preds}: predictions for real (as_novel_view) and synthetic (synthetic) sequences"
    elif case == "not-there":
        preds = _flat_copy(bench, tmp_path)
        args, expect = ["--sequence", "cup_novel_view"], f"{preds}: no predictions for nerfds/cup_novel_view"
    elif case == "no-masks":
        (preds / "as_novel_view" / "test" / "ours_30000").mkdir(parents=True)
        expect = f"{preds / 'as_novel_view' / 'test'}: no <iteration dir>/pred_masks/ folder"
    assert _evaluate(bench, runs, *args, name=name, predictions=preds) == 1
    assert expect in _error(capsys)
    assert not runs.exists()


@pytest.mark.parametrize("problem", ["extra frame", "wrong size"])
def test_one_bad_sequence_leaves_no_run_of_any(bench, tmp_path, capsys, problem):
    preds = tmp_path / "preds"
    shutil.copytree(bench[1], preds)
    masks = preds / "plate_novel_view" / "test" / "ours_30000" / "pred_masks"
    bad = masks / ("00099.png" if problem == "extra frame" else "00001.png")
    cv2.imwrite(str(bad), np.zeros((6, 8, 3) if problem == "wrong size" else (12, 16, 3), np.uint8))
    runs = tmp_path / "runs"
    assert _evaluate(bench, runs, predictions=preds) == 1
    err = _error(capsys)
    assert str(bad) in err
    assert ("no ground-truth frame named '00099'" if problem == "extra frame" else "differs from ground truth") in err
    assert not list(runs.rglob("results.json"))


@pytest.mark.slow
def test_a_run_s_own_masks_through_evaluate_give_its_numbers(tiny_run, tmp_path, capsys):
    """A tiny trase run's predicted masks, laid out as the public code writes them, evaluated as
    an external method: the same scores as the run, and both rows in the synthetic leaderboard."""
    rec = json.loads((tiny_run / "results.json").read_text())
    masks = tmp_path / "output" / "synthetic" / "test" / "ours_40" / "pred_masks"
    shutil.copytree(tiny_run / "pred", masks)
    runs = tmp_path / "runs"
    data_root = Path(rec["scene_dir"]).parents[1]
    assert main(["evaluate", "--predictions", str(tmp_path / "output"), "--dataset", "hypernerf", "--name",
                 "trase-replay", "--data-root", str(data_root), "--runs", str(runs)]) == 0
    (path,) = runs.glob("trase-replay/hypernerf/synthetic/*/results.json")
    got = json.loads(path.read_text())
    assert got["variant"] == "synthetic" and got["synthetic_scene"] == rec["synthetic_scene"]
    assert got["checksums"] == rec["checksums"]  # the same ground truth, the same mask bytes
    for key in ("miou", "macc", "pooled_iou"):
        assert got["metrics"][key] == rec["metrics"][key]
    for key in ("miou", "macc", "pooled_iou"):  # both read the ground truth as stored
        assert got["metrics"]["official"][key] == rec["metrics"]["official"][key]
    # and so does `score` on the run's masks
    capsys.readouterr()
    assert main(["score", str(tiny_run / "pred"), got["external"]["gt_dir"], "--metric", "official", "--json"]) == 0
    assert got["metrics"]["official"]["macc"] == json.loads(capsys.readouterr().out)["macc"]
    assert main(["leaderboard", "--run", str(tiny_run), "--run", str(path.parent), "--variant", "synthetic"]) == 0
    out = capsys.readouterr().out
    assert "| trase [a] |" in out and "| trase-replay [b] |" in out
    assert f"- [b] {EXTERNAL_PROTOCOL}; scene synthetic" in out


def test_a_sequence_without_ground_truth_is_one_line_and_writes_nothing(bench, tmp_path, capsys):
    data = tmp_path / "data"
    write_nerfies(data / "nerfds" / "as_novel_view", two_cameras=True, gt=False)
    runs = tmp_path / "runs"
    assert main(["evaluate", "--predictions", str(bench[1]), "--dataset", "nerfds", "--name", "ext",
                 "--sequence", "as_novel_view", "--data-root", str(data), "--runs", str(runs)]) == 1
    err = _error(capsys)
    assert f"{data / 'nerfds' / 'as_novel_view'}: no ground-truth masks for nerfds/as_novel_view" in err
    assert str(bench[1] / "as_novel_view") in err and not runs.exists()
