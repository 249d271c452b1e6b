"""Golden results of ``trase-bench run`` on the tiny synthetic scenes: one recording, compared bit
for bit on every machine (portable numerics, benchmark.numerics), so every behaviour-preserving
commit is checked on whatever machine runs the tests.

    python -m tests.benchmark.golden_pipeline --write     # re-record (only for an intended change)
    python -m tests.benchmark.golden_pipeline --confirm   # add this machine to those that reproduced it
    python -m tests.benchmark.golden_pipeline --numerics native --json out.json   # measure natively

Each case is one run (method, dataset, --set values); what is compared: the scores (v1,
official, oracle, ceiling, click sets), the robot user's clicks and curve, the clusters chosen, the model's size and the checksums
of the predicted masks and of the geometry. The recording lists the machines (CPU model,
x86-64 levels) that gave it. Native mode is checked within a tolerance: golden_portable.py.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

GOLDEN = Path(__file__).with_name("golden") / "pipeline.json"

# The recording's click rule, pinned: the default became "feature" after the cases were first
# recorded. With "feature" the first case's click sets 1 and 4 choose other clusters on these
# 40-step features (0.555 -> 0.092); the other cases choose the same.
RECORDED_CLICK_RULE = "method.prompts.click_rule=weight"
FAST_GT = ["geometry.source=ground-truth", "method.features.iterations=40", "method.features.n_pixels=400",
           RECORDED_CLICK_RULE]
CASES = {
    "trase-hypernerf-gt": ("trase", "hypernerf", FAST_GT),
    # the binary correspondence, which the cpu preset's tiny-image rule replaces on this scene
    "trase-hypernerf-gt-binary": ("trase", "hypernerf", [*FAST_GT, "method.features.objective_params.correspondence=binary"]),
    "cgc-hypernerf-gt": ("cgc", "hypernerf", FAST_GT),
    "opengaussian-hypernerf-gt": ("opengaussian", "hypernerf", FAST_GT),
    "trase-nerfds-gt": ("trase", "nerfds", FAST_GT),
    "trase-hypernerf-reconstruct": ("trase", "hypernerf", [
        "geometry.train.iterations=60", "method.features.iterations=40", "method.features.n_pixels=400",
        RECORDED_CLICK_RULE]),
}


def machine() -> dict:
    """This machine as a recording lists it: its CPU and instruction sets, where the kernels of
    its native mode would go, and the pinning of portable mode it ran (benchmark.numerics;
    entries without one ran the first)."""
    from llvmlite import binding

    from benchmark import numerics

    d = numerics.describe("native")
    return {"cpu_model": d["cpu_model"], "x86_levels": d["x86_levels"], "host_cpu": binding.get_host_cpu_name(),
            "avx512": bool(d["avx512"]), "libc": d["libc"], "pinning": numerics.PINNING}


def recording() -> dict:
    """The recording: {"numerics", "cases", "machines"}."""
    return json.loads(GOLDEN.read_text())


def picked(r: dict) -> dict:
    """The compared part of a results record."""
    cs = r.get("click_sets") or {}
    return {
        "miou": r["metrics"]["miou"], "macc": r["metrics"]["macc"],
        "official_miou": r["metrics"]["official"]["miou"],
        "oracle_miou": (r.get("oracle") or {}).get("miou"),
        "ceiling_miou": (r.get("ceiling") or {}).get("miou"),
        "click_sets": [s["miou"] for s in cs.get("sets", [])],
        "corrective": corrective_picked(r.get("corrective")),
        "n_gaussians": r["n_gaussians"], "n_clusters": r["n_clusters"],
        "selected_clusters": r["selected_clusters"], "click_clusters": r["click_clusters"],
        "test_psnr": r["stages"]["geometry"]["info"].get("test_psnr"),
        "pred_checksum": r["checksums"]["pred"], "geometry_checksum": r["geometry_checksum"],
    }


def corrective_picked(c: dict | None) -> dict | None:
    """The compared part of the robot user's record: its clicks and the score after each."""
    if c is None:
        return None
    return {"corrections": [[k["view_index"], k["u"], k["v"], k.get("positive", True)] for k in c["corrections"]],
            "curve": [p["miou"] for p in c["curve"]], "noc@85": c["noc@85"], "noc@90": c["noc@90"]}


def measure(work: Path, cases=CASES, numerics_mode: str = "portable") -> dict:
    """Run every case on freshly generated tiny scenes under ``work`` -> {case: picked results}."""
    from benchmark.cli import main
    from benchmark.datasets.synthetic import generate
    from benchmark.results import load_results

    data = work / "data"
    out = {}
    for case, (method, dataset, sets) in cases.items():
        scene = data / dataset / "synthetic"
        if not scene.exists():
            generate(dataset, scene, seed=0, size="tiny")
        runs = work / "runs" / case
        args = ["run", "--method", method, "--dataset", dataset, "--sequence", "synthetic", "--data-root",
                str(data), "--runs", str(runs), "--quiet"]
        for s in [*sets, f"machine.numerics={numerics_mode}"]:
            args += ["--set", s]
        if main(args) != 0:
            raise RuntimeError(f"golden case {case}: trase-bench run failed")
        (path,) = runs.glob(f"{method}/{dataset}/synthetic/*/results.json")
        out[case] = picked(load_results(path))
    return out


def main(argv=None) -> int:
    import tempfile

    from benchmark import numerics

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help=f"record into {GOLDEN} (replaces the recording)")
    ap.add_argument("--confirm", action="store_true", help="add this machine to the recording's machines "
                    "(only when it reproduces every case bit for bit)")
    ap.add_argument("--numerics", choices=numerics.MODES, default=numerics.DEFAULT)
    ap.add_argument("--cases", nargs="+", choices=list(CASES), help="measure only these (default: all)")
    ap.add_argument("--json", type=Path, help="write the measurement here (what the test compares)")
    args = ap.parse_args(argv)
    if args.cases and (args.write or args.confirm):
        raise SystemExit("--write and --confirm measure every case")
    numerics.apply(args.numerics)  # before measure() loads numpy, torch and numba, as trase-bench does
    cases = {c: CASES[c] for c in args.cases} if args.cases else CASES
    with tempfile.TemporaryDirectory() as tmp:
        results = measure(Path(tmp), cases, numerics_mode=args.numerics)
    record = {"numerics": args.numerics, "cases": results, "machines": [machine()]}
    if args.write or args.confirm:
        if args.numerics != "portable":
            raise SystemExit("the recording holds portable numerics only")
        if args.confirm:
            golden = recording()
            if golden["cases"] != results:
                raise SystemExit("this machine does not reproduce the recording: not confirmed")
            record["machines"] = [m for m in golden["machines"] if m != machine()] + [machine()]
        GOLDEN.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    text = json.dumps(record, indent=1, sort_keys=True) + "\n"
    if args.json:
        args.json.write_text(text)
    elif not (args.write or args.confirm):
        print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
