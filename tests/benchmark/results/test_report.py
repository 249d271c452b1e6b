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


def test_report_from_run_dir(tmp_path, capsys):
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
    assert main(["report", "--method", "trase", "--dataset", "hypernerf", "--sequence", "synthetic",
                 "--out", str(tmp_path)]) == 0
    page = (run / "report.html").read_text()
    assert "mIoU 1.0000" in page and page.count("data:image/png;base64") == 4
    assert f"Run {rec['run']['name']} (main; overrides: none). Protocol: geometry reconstruct" in page
    assert (run / "report" / "per_frame_iou.png").exists()
    assert main(["report", "--method", "x", "--dataset", "hypernerf", "--sequence", "s",
                 "--out", str(tmp_path)]) == 1
    assert "no main run of x" in capsys.readouterr().err
    assert main(["report", "--method", "trase", "--dataset", "hypernerf", "--sequence", "synthetic",
                 "--name", "nope", "--out", str(tmp_path)]) == 1
    assert "not a run directory" in capsys.readouterr().err


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
