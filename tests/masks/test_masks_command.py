"""``trase-bench masks`` end to end on a tiny fake synthetic scene (loader calls stubbed)."""

import json
from pathlib import Path

import cv2
import numpy as np
from mask_testutils import shapes_image

import masks
from benchmark.cli import main


class _View:
    def __init__(self, name, image_path):
        self.name, self.image_path = name, image_path


class _Scene:
    def __init__(self, root, train, manifest):
        self.root, self.train, self.dataset, self.sequence = root, train, "nerfds", "synthetic"
        from benchmark.datasets.truth import read_truth

        self.truth = read_truth(manifest) if manifest else None


def _fake_scene(tmp_path: Path, with_manifest=True):
    root = tmp_path / "scene"
    (root / "synthetic" / "instances").mkdir(parents=True)
    views, table = [], {}
    for i in range(2):
        img, ids = shapes_image(30, 40, seed=i, n_objects=3)
        p = root / f"left_{i:05d}.png"
        cv2.imwrite(str(p), img[..., ::-1])
        rel = f"instances/left_{i:05d}.png"
        cv2.imwrite(str(root / "synthetic" / rel), ids.astype(np.uint16))
        views.append(_View(f"left_{i:05d}", p))
        table[views[-1].name] = rel
    manifest = root / "synthetic" / "manifest.json"
    manifest.write_text(json.dumps({"instances": table}))
    return _Scene(root, views, manifest if with_manifest else None)


def test_masks_command_synthetic_and_classical(tmp_path, monkeypatch, capsys):
    import benchmark.datasets
    import benchmark.datasets.synthetic

    scene = _fake_scene(tmp_path)
    monkeypatch.setattr(benchmark.datasets.synthetic, "find_or_generate",
                        lambda d, s, r: (scene.root, "synthetic"))
    monkeypatch.setattr(benchmark.datasets, "load_scene", lambda *a, **k: scene)
    assert main(["masks", "--dataset", "nerfds", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "2 generated" in out
    files = sorted((scene.root / "masks" / "synthetic").glob("*.masks"))
    assert [f.name for f in files] == ["left_00000.masks", "left_00001.masks"]
    assert masks.load(files[0]).generator == "synthetic"
    assert main(["masks", "--dataset", "nerfds", "--no-progress"]) == 0  # the old spelling of --quiet
    done = capsys.readouterr()
    assert "0 generated, 2 already there" in done.out
    assert done.err == "trase-bench: --no-progress is now --quiet (the old spelling goes in the next version)\n"
    assert main(["masks", "--dataset", "nerfds", "--generator", "classical", "--quiet",
                 "--out", str(tmp_path / "c")]) == 0
    assert masks.load(tmp_path / "c" / "left_00001.masks").generator == "classical"
    # SAM without a checkpoint: one line, exit 1
    assert main(["masks", "--dataset", "nerfds", "--generator", "sam"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "checkpoint" in err and err.count("\n") == 1


def test_masks_command_synthetic_needs_manifest(tmp_path, monkeypatch, capsys):
    import benchmark.datasets
    import benchmark.datasets.synthetic

    scene = _fake_scene(tmp_path, with_manifest=False)
    monkeypatch.setattr(benchmark.datasets.synthetic, "find_or_generate",
                        lambda d, s, r: (scene.root, "real"))
    monkeypatch.setattr(benchmark.datasets, "load_scene", lambda *a, **k: scene)
    assert main(["masks", "--dataset", "nerfds", "--generator", "synthetic"]) == 1
    assert "needs a synthetic scene" in capsys.readouterr().err
