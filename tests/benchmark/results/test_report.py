import cv2
import numpy as np

from benchmark.cli import main
from benchmark.results import write_results
from benchmark.results.report import overlay
from tests.benchmark.results.helpers import record


def test_overlay_colours():
    img = np.zeros((1, 3, 3), np.uint8)
    pred = np.array([[True, True, False]])
    gt = np.array([[True, False, True]])
    ov = overlay(img, pred, gt)
    assert ov[0, 0, 1] > ov[0, 0, 0]  # true positive: green
    assert ov[0, 1, 0] > ov[0, 1, 1]  # false positive: red
    assert ov[0, 2, 2] > ov[0, 2, 0]  # miss: blue


def _finished_run(tmp_path):
    """A main run of trase on hypernerf/synthetic under ``tmp_path`` (the folder of runs), with
    three frames: (its directory, its record)."""
    rec = record("trase", "hypernerf", "synthetic", 1.0, 1.0)
    run = tmp_path / "trase" / "hypernerf" / "synthetic" / rec["run"]["name"]
    (run / "pred").mkdir(parents=True)
    frames = []
    for i in range(3):
        name = f"{i:05d}"
        img, gt = tmp_path / f"img{i}.png", tmp_path / f"gt{i}.png"
        cv2.imwrite(str(img), np.full((8, 10, 3), 100, np.uint8))
        m = np.zeros((8, 10), np.uint8)
        m[2:6, 2:6] = 255
        cv2.imwrite(str(gt), m)
        cv2.imwrite(str(run / "pred" / f"{name}.png"), m)
        frames.append({"frame": name, "image": str(img), "gt": str(gt), "pred": f"pred/{name}.png"})
    write_results(run / "results.json", rec | {
        "per_frame": [{"frame": f["frame"], "iou": 1.0, "acc": 1.0} for f in frames],
        "frames": frames, "stages": {"masks": {"seconds": 1.5, "peak_rss_mb": 100}},
    })
    return run, rec


def test_report_from_run_dir(tmp_path, capsys):
    run, rec = _finished_run(tmp_path)
    assert main(["report", "--method", "trase", "--dataset", "hypernerf", "--sequence", "synthetic",
                 "--runs", str(tmp_path)]) == 0
    page = (run / "report.html").read_text()
    assert "mIoU 1.0000" in page and page.count("data:image/png;base64") == 4
    assert f"Run {rec['run']['name']} (main; overrides: none). Protocol: geometry reconstruct" in page
    assert (run / "report" / "per_frame_iou.png").exists()
    assert main(["report", "--method", "x", "--dataset", "hypernerf", "--sequence", "s",
                 "--runs", str(tmp_path)]) == 1
    assert "no main run of x" in capsys.readouterr().err
    assert main(["report", "--method", "trase", "--dataset", "hypernerf", "--sequence", "synthetic",
                 "--name", "nope", "--runs", str(tmp_path)]) == 1
    assert "not a run directory" in capsys.readouterr().err


def test_report_of_one_run_folder(tmp_path, capsys):
    run, rec = _finished_run(tmp_path)
    assert main(["report", "--run", str(run)]) == 0
    assert capsys.readouterr().out == f"wrote {run / 'report.html'}\n"
    assert "mIoU 1.0000" in (run / "report.html").read_text()
    (run / "report.html").unlink()
    assert main(["report", "--run", str(run / "results.json")]) == 0  # as leaderboard --run takes it
    assert (run / "report.html").is_file()
    # one way to name the run at a time, and a folder that is no run: one line each
    assert main(["report", "--run", str(run), "--method", "trase", "--name", rec["run"]["name"]]) == 2
    assert "--run names the run; leave out --method, --name" in capsys.readouterr().err
    assert main(["report", "--run", str(run), "--runs", str(tmp_path)]) == 2
    assert "leave out --runs" in capsys.readouterr().err
    assert main(["report", "--method", "trase", "--dataset", "hypernerf"]) == 2
    assert "--run DIR, or --method, --dataset and --sequence (missing --sequence)" in capsys.readouterr().err
    assert main(["report", "--run", str(tmp_path)]) == 1
    assert "not a run directory" in capsys.readouterr().err


def test_report_old_spelling_of_runs_still_works(tmp_path, capsys):
    _finished_run(tmp_path)
    seq = ["--method", "trase", "--dataset", "hypernerf", "--sequence", "synthetic"]
    assert main(["report", *seq, "--out", str(tmp_path)]) == 0
    assert capsys.readouterr().err == \
        "trase-bench: --out is now --runs (the old spelling goes in the next version)\n"
    assert main(["report", *seq, "--runs", str(tmp_path)]) == 0
    assert capsys.readouterr().err == ""


def test_ceiling_notes_name_holes_movers_and_the_frames_they_touch():
    from benchmark.results.report import _ceiling_objects_notes

    c = {"miou": 0.8, "objects": {"ball": {"holes": 0.1}, "ring": {"holes": None}},
         "movers": {"pillar": {"holes": 0.98}},
         "mover_frames": {"frames": 57, "miou": 0.705, "other_frames": 93, "other_miou": 0.855}}
    notes = _ceiling_objects_notes(c)
    assert notes[0] == "Share of each object's pixels the geometry leaves out (holes): ball 10%."
    assert notes[1] == "Moving objects not of interest, holes: pillar 98%."
    assert "57 test frames" in notes[2] and "0.7050" in notes[2] and "other 93, 0.8550" in notes[2]
    assert _ceiling_objects_notes({"miou": 0.8}) == []  # an older ceiling record: nothing to say
    assert _ceiling_objects_notes({"objects": {"ring": {"holes": None}}}) == []  # no pixels measured
    assert len(_ceiling_objects_notes(c | {"mover_frames": {"frames": 0}})) == 2  # no frame touched
