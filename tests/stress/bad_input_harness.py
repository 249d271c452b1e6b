"""Builds the valid inputs of the bad-input catalogue and runs one corrupted case.

Kept apart from the test module so the catalogue can be explored from a shell:
``python -c "from tests.stress.bad_input_harness import explore; explore()"``.
"""

from __future__ import annotations

import contextlib
import io
import shutil
from pathlib import Path

import numpy as np

from .catalogue import Case

FAST = ["geometry.source=ground-truth", "method.features.iterations=40", "method.features.n_pixels=400"]
MULTIVIEW = {  # dataset -> (registry sequence to prepare as, publisher frame span of the tiny scene)
    "neu3d": ("coffee_martini", "0-1"),
    "immersive": ("01_Welder", "0-1"),
    "technicolor": ("Birthday", "1-2"),
}


def _generate(dataset: str, out: Path) -> Path:
    from benchmark.datasets.synthetic import generate

    return generate(dataset, out, seed=0, size="tiny")


def build_pristine(base: Path) -> dict[str, Path]:
    """target -> a valid input of that kind (never modified; cases work on copies)."""
    import cv2
    import torch

    import masks as masklib
    from benchmark.results import write_results
    from trase.checkpoint import save_model
    from trase.deformation import DeformMLP
    from trase.gaussians import GaussianModel

    out: dict[str, Path] = {}
    for ds in ("hypernerf", "nerfds"):
        out[ds] = _generate(ds, base / "src" / ds / "synthetic")
    for ds in MULTIVIEW:
        out[ds] = _generate(ds, base / "src" / ds / "synthetic-tiny")

    gt = base / "src" / "gt"
    (gt / "gt").mkdir(parents=True)
    (gt / "pred").mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(gt / "gt" / f"{i:05d}.png"), (rng.random((12, 16)) < 0.4).astype(np.uint8) * 255)
        m = rng.random((12, 16)) < 0.4
        if i == 2:
            np.save(gt / "pred" / f"{i:05d}.npy", m)
        else:
            cv2.imwrite(str(gt / "pred" / f"{i:05d}.png"), m.astype(np.uint8) * 255)
    out["gt"] = gt

    md = base / "src" / "masks"
    md.mkdir(parents=True)
    ms = masklib.MaskSet.from_masks(rng.random((4, 12, 16)) < 0.3, generator="test")
    masklib.save(md / "view.masks", ms)
    masklib.save_official(md / "official.pt", ms)
    out["masks"] = md

    ck = base / "src" / "checkpoint"
    n = 20
    g = GaussianModel(torch.randn(n, 3), torch.full((n, 3), -2.0), torch.randn(n, 4),
                      torch.zeros(n), torch.rand(n, 1, 3))
    save_model(ck, g, DeformMLP(D=2, W=16), iteration=7)
    out["checkpoint"] = ck

    geo = base / "src" / "geometry"
    geo.mkdir(parents=True)
    shutil.copyfile(out["hypernerf"] / "synthetic" / "geometry.npz", geo / "geometry.npz")
    out["geometry"] = geo

    res = base / "src" / "results"
    from tests.benchmark.results.helpers import record

    write_results(res / "m" / "hypernerf" / "s" / "main" / "results.json",
                  record("m", "hypernerf", "s", 0.5, 0.9, name="main"))
    out["results"] = res
    return out


def _cli(argv: list[str]) -> tuple[int, str]:
    from benchmark.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = main(argv)
    return rc, err.getvalue()


def output_dir(target: str, work: Path) -> Path | None:
    if target in ("hypernerf", "nerfds", "hypernerf-named"):
        return work / "out"
    if target in MULTIVIEW:
        return work / "prepared"
    return None


def run_target(target: str, root: Path, work: Path) -> tuple[int, str, Path | None]:
    """Run the entry point of ``target`` on the input at ``root``.

    -> (exit code: 0 ok / 1 user error, stderr text or the exception message, output dir)."""
    if target in ("hypernerf", "nerfds", "hypernerf-named"):
        out = output_dir(target, work)
        dataset = target.split("-")[0]
        argv = ["run", "--method", "trase", "--dataset", dataset, "--sequence", root.name,
                "--data-root", str(root.parent.parent), "--runs", str(out), "--quiet"]
        for s in FAST:
            argv += ["--set", s]
        rc, err = _cli(argv)
        return rc, err, out
    if target in MULTIVIEW:
        seq, span = MULTIVIEW[target]
        out = output_dir(target, work)
        rc, err = _cli(["prepare", target, str(root), str(out), "--sequence", seq, "--frames", span])
        return rc, err, out
    if target == "gt":
        rc, err = _cli(["score", str(root / "pred"), str(root / "gt")])
        return rc, err, None
    if target == "results":
        rc, err = _cli(["leaderboard", "--runs", str(root), "--no-published"])
        return rc, err, None
    from benchmark.errors import is_user_error

    try:
        if target == "masks":
            import masks as masklib

            for name in ("view.masks", "official.pt"):
                masklib.load(root / name)
        elif target == "checkpoint":
            from trase.checkpoint import load_model

            load_model(root)
        elif target == "geometry":
            from trase.checkpoint import load_tabulated_geometry

            load_tabulated_geometry(root / "geometry.npz")
        else:
            raise KeyError(target)
    except Exception as exc:
        if not is_user_error(exc):
            raise
        return 1, f"error: {exc}\n", None
    return 0, "", None


def copy_input(pristine: Path, work: Path, target: str) -> Path:
    """A private copy of the pristine input, laid out as its entry point expects."""
    if target in ("hypernerf", "nerfds"):
        dst = work / "data" / target / "synthetic"
    elif target == "hypernerf-named":  # a paper sequence name: never the synthetic default
        dst = work / "data" / "hypernerf" / "americano"
    else:
        dst = work / "input" / pristine.name
    shutil.copytree(pristine, dst)
    return dst


def run_case(case: Case, pristine: dict[str, Path], work: Path) -> tuple[int, str, Path, Path | None]:
    """Copy, corrupt, run. -> (rc, stderr, corrupted path, output dir)."""
    root = copy_input(pristine[case.target.split("-")[0]], work, case.target)
    if case.file.startswith("@out/"):
        path = output_dir(case.target, work) / case.file[len("@out/"):]
        path.parent.mkdir(parents=True, exist_ok=True)
    else:
        path = root / case.file if case.file != "." else root
    case.apply(path)
    rc, err, out = run_target(case.target, root, work)
    return rc, err, path, out


def explore(base: Path | None = None, only: tuple[str, ...] = ()) -> None:
    """Print every case's outcome (for writing the expected fragments)."""
    import tempfile

    from .catalogue import CASES

    base = Path(tempfile.mkdtemp()) if base is None else base
    pristine = build_pristine(base)
    for i, case in enumerate(CASES):
        if only and case.id not in only:
            continue
        work = base / f"case{i}"
        work.mkdir()
        try:
            rc, err, _path, _out = run_case(case, pristine, work)
            print(f"{case.id:28s} rc={rc} {err.strip()!r}")
        except Exception as exc:  # noqa: BLE001
            print(f"{case.id:28s} CRASH {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
