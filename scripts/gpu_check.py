"""The GPU path's whole check in one command, for a GPU machine available for a few minutes.

    python3 scripts/gpu_check.py all --out DIR [--before TREE] [--budget SECONDS] [--tiny]

In order, each step under its own time limit and written to DIR/gpu_check.json as soon as it
ends (a step cut short keeps what the earlier ones measured):

1. the machine (GPU, torch, CUDA, numba, gsplat versions); gsplat's CUDA sources compiled for
   this GPU only (TORCH_CUDA_ARCH_LIST from its compute capability, MAX_JOBS = its cores),
   while the CPU makes the built-in scene and compiles the numba kernels beside it;
2. the CUDA tests (tests/trase/render/test_cuda_backends.py, tests/trase/test_cuda_training.py);
3. one reconstruction iteration (perf gpu's step: deformation network, render, L1 + D-SSIM,
   backward, both Adam steps) at a launch-bound size (5k gaussians, 160x120) and at the
   paper's (100k, 960x536), timed and profiled (kernel launches and operators per step, the
   operators with the most GPU time), with the code of ``--before TREE`` (an older checkout)
   and of this tree, one after the other on the same GPU (and this tree's with TF32 matrix
   products at the large size, a diagnostic);
4. ``trase-bench run --method trase --dataset hypernerf`` with the defaults (on a GPU: the
   paper preset), in the time left but 100 s: its results, per-stage seconds, peak GPU
   memory and the gaussian count over the reconstruction (its train log);
5. ``trase-bench perf gpu --quick`` with each tree, as time allows.

``--tiny`` checks the script itself on a CPU: tiny sizes, the torch rasterizer for the
profile, and a few iterations of the run (its figures mean nothing). ``profile`` is the
step-3 worker, run with PYTHONPATH set to the tree under test.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tarfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the check's modules beside it

from gpu_check_steps import (
    CUDA_TESTS,
    REPO,
    SIZES,
    TINY_RUN,
    TINY_SIZES,
    Check,
    _cli,
    _collect_diag,
    _default_run,
    _pack,
    _profile,
    _py,
    _run_figures,
    _scene_kernels_and_gsplat,
    _start,
    build_gsplat,
    machine,
    run_progress,
)
from gpu_check_workers import DIAG_VARIANTS, diagnose, profile


def run_all(args) -> int:
    out, chk, cuda = _start(args)
    sizes = TINY_SIZES if args.tiny else SIZES
    size_arg = ",".join(f"{n}x{w}x{h}" for n, w, h in sizes)

    # 1. the scene and the numba kernels on the CPU, beside gsplat's build
    _scene_kernels_and_gsplat(chk, cuda)

    # 2. the CUDA tests
    chk.sh("cuda_tests", [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rs", *CUDA_TESTS],
           min(150, chk.left() - 60), _py())

    # 3. a reconstruction iteration, before and after (and after with TF32 matrix products, to
    # see how much of the large step is the network's FP32 products)
    device = "cuda" if cuda else "cpu"
    trees = ([("before", Path(args.before).resolve())] if args.before else []) + [("after", REPO)]
    variants = [(label, tree, size_arg, []) for label, tree in trees]
    variants.append(("after_tf32", REPO, ",".join(f"{n}x{w}x{h}" for n, w, h in sizes[-1:]), ["--tf32"]))
    for label, tree, sz, flags in variants:
        js = out / "logs" / f"profile_{label}.json"
        rec = chk.sh(f"profile_{label}", [sys.executable, str(REPO / "scripts" / "gpu_check.py"), "profile",
                                          "--sizes", sz, "--device", device, "--json", str(js),
                                          "--repeats", "3" if args.tiny else "10", *flags],
                     min(120, chk.left() - 60), _py(tree))
        if js.is_file():
            rec["profile"] = json.loads(js.read_text())
            chk.save()

    # 4. the default run, keeping time for perf gpu after it
    runs = out / "runs"
    extra = TINY_RUN if args.tiny else []
    rec = chk.sh("run_hypernerf", _default_run(runs, *extra), chk.left() - (100 if cuda else 15), _py())
    rec["results"] = _run_figures(runs)
    chk.save()

    # 5. perf gpu (reconstruction iteration and feature steps at 100k gaussians) with each tree
    if cuda:
        for label, tree in trees:
            if chk.left() < 40:
                break
            js = out / "logs" / f"perf_gpu_{label}.json"
            rec = chk.sh(f"perf_gpu_{label}", _cli("perf", "gpu", "--quick", "--json", str(js)),
                         min(90, chk.left() - 10), _py(tree))
            if js.is_file():
                rec["perf"] = json.loads(js.read_text())
                chk.save()
    _pack(out, runs)
    print(json.dumps({k: v.get("rc") if isinstance(v, dict) else v for k, v in chk.result["steps"].items()}), flush=True)
    return 0


def diagnose_all(args) -> int:
    """gsplat built (beside the scene and the numba kernels), then each variant of ``diagnose``
    in its own process, all at once on the GPU (their quality over iterations is the figure;
    their speeds share the GPU and mean little); one JSON."""
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    n_var = len(args.variants.split(","))
    chk = Check(out, args.seconds * (n_var if args.sequential else 1) + 200)
    chk.result["machine"] = machine()
    chk.save()
    scene = subprocess.Popen([sys.executable, "-c", ("from benchmark.datasets.synthetic.cache import ensure_synthetic; "
                                                     "print(ensure_synthetic('hypernerf'))")], cwd=REPO,
                             env={**os.environ, **_py()})
    pre = subprocess.Popen([sys.executable, "-m", "trase.precompile"], cwd=REPO, env={**os.environ, **_py()})
    if chk.result["machine"]["gpu"]:
        build_gsplat(chk)
    scene.wait()
    pre.wait()
    procs = {}
    watch = ["--until", str(args.until), "--window", args.window, "--every", str(args.every)]
    for v in args.variants.split(","):
        log = open(chk.logs / f"diag_{v}.log", "w")  # noqa: SIM115 - open while the child writes to it
        procs[v] = subprocess.Popen([sys.executable, str(REPO / "scripts" / "gpu_check.py"), "diagnose", "--seconds",
                                     str(args.seconds), "--variant", v, "--json", str(out / f"diag_{v}.json"), *watch],
                                    cwd=REPO, env={**os.environ, **_py()}, stdout=log, stderr=subprocess.STDOUT)
        if args.sequential:
            _collect_diag(chk, out, v, procs.pop(v), args.seconds)
    for v, p in procs.items():
        _collect_diag(chk, out, v, p, args.seconds)
    shutil.rmtree(chk.logs)
    return 0


def watch_all(args) -> int:
    """The check for one short GPU run: gsplat built (beside the scene and the numba kernels), each
    watched variant of the default run's reconstruction one after the other, alone on the GPU
    (``diagnose``: the model's state every ``--every`` iterations, the test PSNR and label
    ceiling where it stops), sharing what the budget leaves after the time kept for the CUDA
    tests (unless skipped) and, last, a reconstruction iteration timed and profiled
    (``profile``) at both sizes. Variants are ``NAME[@NEAR]`` (NEAR: the near plane)."""
    out, chk, cuda = _start(args)
    _scene_kernels_and_gsplat(chk, cuda, args.reuse_build, args.save_build)
    specs = [s.partition("@") for s in args.variants.split(",") if s]
    tests = cuda and not args.skip_tests
    if cuda and args.profile_first:  # the iteration's time first, in FP32 and in TF32
        _profile(chk, out, "profile", [], min(60, chk.left() - 10))
        _profile(chk, out, "profile_tf32", ["--tf32"], min(60, chk.left() - 10))
    perf_reserve = ((0 if args.profile_first else args.profile_seconds) + (args.tests_limit if tests else 0)) if cuda else 0
    for i, (variant, _, near) in enumerate(specs):
        label = variant + (f"_near{near}" if near else "")  # file names: letters, digits, . _ -
        # each variant's training time: an equal share of what is left, less its start and its end
        # (imports, the scene, test PSNR, the ceiling on the CPU): ~``args.overhead`` seconds
        share = (chk.left() - perf_reserve) / (len(specs) - i) - args.overhead
        if share < 20:
            chk.result["steps"][f"diag_{label}"] = {"rc": "skipped: no time left"}
            continue
        js = out / f"diag_{label}.json"
        cmd = [sys.executable, str(REPO / "scripts" / "gpu_check.py"), "diagnose", "--seconds", f"{share:.0f}",
               "--variant", variant, "--json", str(js), "--until", str(args.until), "--every", str(args.every),
               *(["--near", near] if near else [])]
        print(f"[{time.monotonic() - chk.t0:6.1f} s] diag {label}: {share:.0f} s of training", flush=True)
        log = open(chk.logs / f"diag_{label}.log", "w")  # noqa: SIM115 - open while the child writes to it
        p = subprocess.Popen(cmd, cwd=REPO, env={**os.environ, **_py()}, stdout=log, stderr=subprocess.STDOUT)
        _collect_diag(chk, out, label, p, share + args.overhead - 5 if cuda else share + 120)
    if tests:  # after the watched runs, in the time kept for them
        chk.sh("cuda_tests", [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rs", *CUDA_TESTS],
               min(args.tests_limit, chk.left() - 10), _py())
    if cuda and not args.profile_first and chk.left() > 25:  # where an iteration's time goes, launch-bound and at 100k
        _profile(chk, out, "profile", [], chk.left() - 5)
    with tarfile.open(out / "logs.tar.gz", "w:gz") as tar:  # the whole logs in one file that travels
        tar.add(chk.logs, arcname="logs")
    shutil.rmtree(chk.logs)
    print(json.dumps({k: v.get("rc") if isinstance(v, dict) else v for k, v in chk.result["steps"].items()}), flush=True)
    return 0


def paper_run(args) -> int:
    """``trase-bench run --method trase --dataset hypernerf`` (the paper preset on a GPU) over as
    many calls as it needs: each call builds what is missing (gsplat, the scene, the numba
    kernels: seconds once built), then continues the run in ``--runs`` (a folder kept between
    calls: the stage cache resumes a cut stage from its last checkpoint) until the budget, and
    writes what the run has so far: its results where it finished, else how far each stage got."""
    out, chk, cuda = _start(args)
    runs = Path(args.runs).resolve()
    chk.result["runs"] = str(runs)
    chk.result["resumed"] = runs.is_dir()
    _scene_kernels_and_gsplat(chk, cuda)
    extra = TINY_RUN if args.tiny else []
    sets = [x for kv in args.set for x in ("--set", kv)]
    rec = chk.sh("run_hypernerf", _default_run(runs, *extra, *sets), chk.left() - 10, _py())
    rec["progress"] = run_progress(runs)
    rec["results"] = _run_figures(runs)
    chk.save()
    for i, more in enumerate(args.rerun_with if rec["rc"] == 0 else []):
        # the same run with other settings of its last stages: the finished stages are reused
        extra_sets = [x for kv in more.split(",") if kv for x in ("--set", kv)]
        again = chk.sh(f"rerun_{i}", _default_run(runs, *extra, *sets, *extra_sets), chk.left() - 10, _py())
        again["settings"] = more
        again["results"] = _run_figures(runs, more)
        chk.save()
    logs = sorted(runs.glob(".cache/geometry/*/model/train_log.csv"), key=lambda p: p.stat().st_mtime)
    if logs:  # the reconstruction's, finished or cut (a .partial folder)
        shutil.copyfile(logs[-1], out / "train_log.csv")
    shutil.rmtree(chk.logs)
    print(json.dumps({"rc": rec["rc"], "progress": rec["progress"]}), flush=True)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("all", help="the whole check")
    a.add_argument("--out", required=True)
    a.add_argument("--before", default=None, help="an older checkout to time beside this one")
    a.add_argument("--budget", type=float, default=520.0, help="seconds for everything")
    a.add_argument("--tiny", action="store_true", help="check the script on a CPU (figures mean nothing)")
    p = sub.add_parser("profile", help="(worker) time and profile a reconstruction iteration")
    p.add_argument("--sizes", required=True, help="NxWxH,...")
    p.add_argument("--device", default="cuda")
    p.add_argument("--repeats", type=int, default=10)
    p.add_argument("--json", required=True)
    p.add_argument("--tf32", action="store_true", help="TF32 matrix products (a diagnostic)")
    d = sub.add_parser("diagnose", help="(worker) the default run's reconstruction, watched")
    d.add_argument("--seconds", type=float, required=True)
    d.add_argument("--variant", choices=DIAG_VARIANTS, default="default")
    d.add_argument("--json", required=True)
    d.add_argument("--near", type=float, default=None, help="the near plane while training (default: the run's)")
    w = sub.add_parser("watch", help="CUDA tests and watched variants one after the other, for one short GPU run")
    w.add_argument("--out", required=True)
    w.add_argument("--budget", type=float, default=540.0, help="seconds for everything")
    w.add_argument("--variants", default="cap@0.01,cap@0.2", help="NAME[@NEAR],...")
    w.add_argument("--overhead", type=float, default=35.0, help="seconds a variant spends outside training")
    w.add_argument("--tests-limit", type=float, default=90.0, help="seconds kept for the CUDA tests")
    w.add_argument("--skip-tests", action="store_true")
    w.add_argument("--profile-seconds", type=float, default=40.0, help="kept for the profile at the end")
    w.add_argument("--profile-first", action="store_true", help="profile first, in FP32 and TF32, then the variants")
    w.add_argument("--reuse-build", default=None, help="a tar.gz of an earlier GPU run's gsplat build (--save-build)")
    w.add_argument("--save-build", default=None, help="write this run's gsplat build here as a tar.gz")
    r = sub.add_parser("paper-run", help="the default run on the GPU, continued over calls until it ends")
    r.add_argument("--out", required=True)
    r.add_argument("--runs", required=True, help="the run's folder, kept between calls (it resumes there)")
    r.add_argument("--budget", type=float, default=580.0, help="seconds for this call")
    r.add_argument("--set", action="append", default=[], help="KEY=VALUE for the run (repeatable)")
    r.add_argument("--rerun-with", action="append", default=[],
                   help="KEY=VALUE,...: once the run has ended, the same run with these settings too (repeatable)")
    r.add_argument("--tiny", action="store_true", help="check the script on a CPU (figures mean nothing)")
    dg = sub.add_parser("diagnose-all", help="diagnose's variants side by side on one GPU")
    dg.add_argument("--out", required=True)
    dg.add_argument("--seconds", type=float, default=150.0, help="seconds per variant")
    dg.add_argument("--variants", default="default,torch-sh,cap")
    dg.add_argument("--sequential", action="store_true", help="one variant after the other, each alone on the GPU")
    for q in (d, dg, w):
        q.add_argument("--until", type=int, default=0, help="stop after this iteration")
        q.add_argument("--window", default="0,0", help="FIRST,LAST: iterations watched every 10, every loss kept")
        q.add_argument("--every", type=int, default=100)
    args = ap.parse_args(argv)
    if args.cmd == "all":
        return run_all(args)
    if args.cmd == "diagnose":
        window = tuple(int(x) for x in args.window.split(","))
        Path(args.json).write_text(json.dumps(diagnose(args.seconds, args.variant, args.every, args.until, window,
                                                       args.near), indent=1))
        return 0
    if args.cmd == "diagnose-all":
        return diagnose_all(args)
    if args.cmd == "watch":
        return watch_all(args)
    if args.cmd == "paper-run":
        return paper_run(args)
    sizes = [tuple(int(x) for x in s.split("x")) for s in args.sizes.split(",")]
    Path(args.json).write_text(json.dumps(profile(sizes, args.device, args.repeats, args.tf32), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
