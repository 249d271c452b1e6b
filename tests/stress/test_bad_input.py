"""The bad-input catalogue (tests/stress/catalogue.py) as tests.

Every case: a valid input (synthetic scene in one of the five formats, mask file, checkpoint,
results file) is copied, one file is corrupted, and the entry point that reads it is run.
It must fail as a user error: exit code 1 and exactly one stderr line ``error: ...`` (CLI) or
an exception with ``user_facing = True`` (library function), the message naming the
corrupted file and saying what is wrong (``fragment``), and leave no partial output.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from .bad_input_harness import (
    MULTIVIEW,
    build_pristine,
    copy_input,
    run_case,
    run_target,
)
from .catalogue import CASES, TARGETS

RUN_TARGETS = ("hypernerf", "nerfds", "hypernerf-named")
STATS = {"corruptions_caught": 0}


# whole runs on corrupted copies of every format: part of `make test-all`
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> dict[str, Path]:
    return build_pristine(tmp_path_factory.mktemp("bad_input"))


def test_catalogue_is_large_and_well_formed():
    ids = [c.id for c in CASES]
    assert len(ids) == len(set(ids)) and len(CASES) >= 30
    assert all(c.fragment for c in CASES), "every case states what the error must say"
    assert {c.target.split("-")[0] for c in CASES} >= {"hypernerf", "nerfds", "neu3d", "immersive", "technicolor",
                                                       "masks", "checkpoint", "results"}
    assert {c.target for c in CASES} <= set(TARGETS)


def _leftovers(out: Path | None, before: set[Path]) -> list[str]:
    """Files under ``out`` that a failed run must not leave: results, manifests, temporaries,
    finished-looking stage directories without a stage record."""
    if out is None or not out.exists():
        return []
    bad = []
    for p in out.rglob("*"):
        if p in before:
            continue
        name = p.name
        if p.is_file() and (name in ("results.json", "prepared.json") or ".tmp" in name):
            bad.append(str(p))
    cache = out / ".cache"
    if cache.is_dir():
        for stage in cache.iterdir():
            for d in stage.iterdir():
                if d.is_dir() and not d.name.endswith(".partial") and not (d / "_stage.json").is_file():
                    bad.append(str(d))
    return bad


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_corruption_gives_one_line_error(case, pristine, tmp_path, capsys):
    before: set[Path] = set()
    rc, err, path, out = run_case(case, pristine, tmp_path)
    if out is not None and case.file.startswith("@out/"):
        before = {path}  # the user's own (damaged) file stays as it was
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 1, f"{case.id}: exit code {rc}, stderr {err!r}"
    assert len(lines) == 1 and lines[0].startswith("error: "), f"{case.id}: not one error line: {err!r}"
    msg = lines[0]
    assert str(path) in msg, f"{case.id}: message does not name {path}: {msg}"
    assert case.fragment.lower() in msg.lower(), f"{case.id}: expected {case.fragment!r} in {msg}"
    assert "Traceback" not in err
    assert not _leftovers(out, before), f"{case.id}: partial output left: {_leftovers(out, before)}"
    STATS["corruptions_caught"] += 1


@pytest.mark.parametrize("target", sorted({c.target for c in CASES}))
def test_pristine_inputs_are_valid(target, pristine, tmp_path):
    """The uncorrupted input passes the same entry point, so each failure above is caused by
    its corruption. (Nerfies scenes: the loader the run uses, not the whole run.)"""
    root = copy_input(pristine[target.split("-")[0]], tmp_path, target)
    if target in RUN_TARGETS:
        from benchmark.datasets import load_scene
        from benchmark.datasets.images import read_image

        scene = load_scene(target.split("-")[0], root)
        assert scene.train and scene.test
        for v in scene.test:
            assert read_image(v.image_path).size
        return
    rc, err, out = run_target(target, root, tmp_path)
    assert rc == 0, err
    if target in MULTIVIEW:
        manifest = json.loads((out / "prepared.json").read_text())
        assert manifest["n_images"] > 0
