"""The GPU check's steps (scripts/gpu_check.py): its state file, the child processes' environment,
gsplat's build, the machine, the built-in scene and kernels, and the figures gathered from a
run's folder."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tarfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CUDA_TESTS = ["tests/trase/render/test_cuda_backends.py", "tests/trase/test_cuda_training.py"]
SIZES = [(5_000, 160, 120), (100_000, 960, 536)]
TINY_SIZES = [(500, 64, 48)]
TINY_RUN = ["--sequence", "synthetic-tiny", "--set", "preset=paper", "--set", "geometry.train.iterations=40",
            "--set", "geometry.train.warm_up=20", "--set", "geometry.train.densify_from=5",
            "--set", "geometry.train.densify_until=30", "--set", "geometry.train.densify_interval=10",
            "--set", "method.features.iterations=20", "--set", "prompts.click_sets=1"]


# -- the check's state and its child processes ------------------------------------------
class Check:
    """The check's state: DIR/gpu_check.json rewritten after every step, logs under DIR/logs."""

    def __init__(self, out: Path, budget: float) -> None:
        self.out, self.t0, self.budget = out, time.monotonic(), budget
        self.logs = out / "logs"
        self.logs.mkdir(parents=True, exist_ok=True)
        self.result: dict = {"started": time.strftime("%Y-%m-%d %H:%M:%S"), "steps": {}}

    def left(self) -> float:
        return self.budget - (time.monotonic() - self.t0)

    def save(self) -> None:
        self.result["elapsed_s"] = round(time.monotonic() - self.t0, 1)
        (self.out / "gpu_check.json").write_text(json.dumps(self.result, indent=1, default=str))

    def sh(self, name: str, cmd: list[str], timeout: float, env: dict | None = None) -> dict:
        """Run ``cmd`` (output to logs/NAME.log) under ``timeout``; its rc and seconds."""
        log = self.logs / f"{name}.log"
        t = time.monotonic()
        print(f"[{time.monotonic() - self.t0:6.1f} s] {name}: {' '.join(cmd)[:160]} (limit {timeout:.0f} s)", flush=True)
        with open(log, "w") as f:
            try:
                rc = subprocess.run(cmd, cwd=REPO, stdout=f, stderr=subprocess.STDOUT, timeout=max(timeout, 1),
                                    env={**os.environ, **(env or {})}, check=False).returncode
            except subprocess.TimeoutExpired:
                rc = "timeout"
        rec = {"rc": rc, "seconds": round(time.monotonic() - t, 1), "log_tail": log.read_text()[-1500:]}
        print(f"[{time.monotonic() - self.t0:6.1f} s] {name}: rc {rc} in {rec['seconds']} s", flush=True)
        self.result["steps"][name] = rec
        self.save()
        return rec


def _py(tree: Path | None = None) -> dict:
    """The environment a child python needs to import ``tree``'s packages (this repo's by default)."""
    path = [str(tree or REPO)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    return {"PYTHONPATH": os.pathsep.join(path), "PYTHONUNBUFFERED": "1"}


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "benchmark.cli", *args]


def _default_run(runs: Path, *args: str) -> list[str]:
    """The default run's command (``make demo``'s: TRASE on the built-in HyperNeRF-format scene)."""
    return _cli("run", "--method", "trase", "--dataset", "hypernerf", "--runs", str(runs), *args)


EXTENSIONS_DIR = "/tmp/trase-torch-extensions"  # torch's JIT builds (gsplat's), at a path the check knows


def build_gsplat(chk, reuse: str | None = None, save: str | None = None) -> dict:
    """gsplat's CUDA extension, ready in this process's environment. ``reuse``: a tar.gz of an
    earlier GPU run's build folder (same image, GPU and gsplat), unpacked first with its files'
    times, and gsplat's sources dated back so that ninja finds every object newer than its
    inputs and compiles nothing (~90 s of a GPU run otherwise); where anything differs ninja
    compiles as before, so a stale archive costs the build's time, not a wrong extension.
    ``save``: where to write this run's build folder as such an archive."""
    import importlib.util

    import torch

    # for this GPU only, on every core; set in this process's environment too: every child that
    # imports gsplat must see the same flags, or torch's JIT loader takes the build as stale and
    # compiles it again, for every architecture (the likely cause of the ~110 s three diagnose
    # processes spent before their first iteration in one check)
    major, minor = torch.cuda.get_device_capability()
    env = {"TORCH_CUDA_ARCH_LIST": f"{major}.{minor}", "MAX_JOBS": str(os.cpu_count() or 8),
           "TORCH_EXTENSIONS_DIR": EXTENSIONS_DIR}
    os.environ.update(env)
    reused = False
    if reuse and Path(reuse).is_file():
        Path(EXTENSIONS_DIR).mkdir(parents=True, exist_ok=True)
        with tarfile.open(reuse) as tar:
            tar.extractall(EXTENSIONS_DIR, filter="tar")
        spec = importlib.util.find_spec("gsplat")
        old = time.mktime((2001, 1, 1, 0, 0, 0, 0, 0, -1))
        for p in (Path(spec.origin).parent.rglob("*") if spec is not None and spec.origin else ()):
            os.utime(p, (old, old))
        reused = True
    rec = chk.sh("build_gsplat", [sys.executable, "-c", "import torch, gsplat.cuda._backend as b; print(b._C)"],
                 min(240, chk.left()), env)
    rec["reused_archive"] = reused
    if save and rec["rc"] == 0:
        with tarfile.open(save, "w:gz") as tar:
            tar.add(EXTENSIONS_DIR, arcname=".")
        rec["saved_archive_mib"] = round(Path(save).stat().st_size / 2**20, 1)
    chk.save()
    return rec


def machine() -> dict:
    import torch

    info = {"python": sys.version.split()[0], "torch": torch.__version__, "cuda": torch.version.cuda,
            "gpu": torch.cuda.get_device_name() if torch.cuda.is_available() else None, "cpus": os.cpu_count()}
    for mod in ("numba", "gsplat"):
        try:
            info[mod] = __import__(mod).__version__
        except Exception as exc:  # noqa: BLE001 - a missing package is a fact to report
            info[mod] = f"missing ({type(exc).__name__})"
    return info


def _start(args):
    """(DIR emptied, its Check, whether torch sees a GPU) for an orchestrator writing to ``args.out``."""
    out = Path(args.out).resolve()
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    chk = Check(out, args.budget)
    chk.result["machine"] = machine()
    chk.save()
    return out, chk, chk.result["machine"]["gpu"] is not None


def _scene_kernels_and_gsplat(chk, cuda: bool, reuse: str | None = None, save: str | None = None) -> None:
    """The built-in scene made and the numba kernels compiled on the CPU, beside gsplat's build."""
    make_scene = ("from benchmark.datasets.synthetic.cache import ensure_synthetic; "
                  "print(ensure_synthetic('hypernerf'))")
    jobs = (("scene", [sys.executable, "-c", make_scene]), ("precompile", [sys.executable, "-m", "trase.precompile"]))
    background = [subprocess.Popen(cmd, cwd=REPO, env={**os.environ, **_py()},
                                   stdout=open(chk.logs / f"{name}.log", "w"),  # noqa: SIM115 - the child's log
                                   stderr=subprocess.STDOUT)
                  for name, cmd in jobs]
    if cuda:
        build_gsplat(chk, reuse, save)
    for p in background:
        p.wait(timeout=max(chk.left() - 30, 1))
    chk.result["steps"]["scene_and_kernels_s"] = round(time.monotonic() - chk.t0, 1)


def run_progress(runs: Path) -> dict:
    """How far each stage of the cache in ``runs`` got: done, or cut (its latest checkpoint
    iteration where it has one)."""
    found: dict = {}
    for d in sorted((runs / ".cache").glob("*/*")):
        if not d.is_dir():
            continue
        stage, cut = d.parent.name, d.name.endswith(".partial")
        entry = {"state": "cut" if cut else "done"}
        if stage == "geometry" and (d / "model").is_dir():
            its = [int(p.parent.name.split("_")[-1]) for p in (d / "model").glob("point_cloud/iteration_*/point_cloud.ply")]
            entry["checkpoint"] = max(its, default=None)
        found.setdefault(stage, []).append(entry)
    return found


def _profile(chk, out: Path, label: str, flags: list[str], limit: float) -> None:
    """The ``profile`` worker at both sizes on the GPU, its figures into the check's JSON."""
    js = out / "logs" / f"{label}.json"
    rec = chk.sh(label, [sys.executable, str(REPO / "scripts" / "gpu_check.py"), "profile", "--sizes",
                         ",".join(f"{n}x{w}x{h}" for n, w, h in SIZES), "--device", "cuda", "--json", str(js), *flags],
                 limit, _py())
    if js.is_file():
        rec["profile"] = json.loads(js.read_text())
        chk.save()


def _collect_diag(chk, out: Path, v: str, p, seconds: float) -> None:
    """Wait for variant ``v``'s worker and put its figures into the check's JSON."""
    try:
        rc = p.wait(timeout=max(seconds + 90, 1))
    except subprocess.TimeoutExpired:
        p.kill()
        rc = "timeout"
    js = out / f"diag_{v}.json"
    chk.result["steps"][f"diag_{v}"] = {"rc": rc, "log_tail": (chk.logs / f"diag_{v}.log").read_text()[-1500:],
                                       **({"diag": json.loads(js.read_text())} if js.is_file() else {})}
    js.unlink(missing_ok=True)
    chk.save()


def _run_figures(runs: Path, settings: str = "") -> dict:
    """The run's figures from its results.json (the newest one, or the newest made with the
    ``--set`` overrides ``settings``, KEY=VALUE,...), and its reconstruction's train log in brief."""
    found = sorted(runs.glob("trase/hypernerf/*/*/results.json"), key=lambda p: p.stat().st_mtime)
    wanted = [kv for kv in settings.split(",") if kv]
    found = [p for p in found if all(kv in json.loads(p.read_text())["run"]["overrides"] for kv in wanted)]
    fig: dict = {}
    if found:
        res = json.loads(found[-1].read_text())
        fig["results"] = res
    logs = sorted(runs.glob(".cache/geometry/*/model/train_log.csv"))
    if logs:
        lines = logs[-1].read_text().splitlines()
        fig["train_log_every_500"] = [lines[0]] + [ln for ln in lines[1:] if int(ln.split(",")[0]) % 500 == 0]
        fig["train_log_last"] = lines[-1]
    return fig


def _pack(out: Path, runs: Path) -> None:
    """logs/ and the run's files (its cache's logs, not its models) in one archive; the bulky
    parts left out so the archive travels."""
    with tarfile.open(out / "logs.tar.gz", "w:gz") as tar:
        tar.add(out / "logs", arcname="logs")
        for p in sorted(runs.rglob("*")):
            if p.is_file() and p.suffix in (".json", ".csv", ".txt", ".log", ".md") and p.stat().st_size < 4_000_000:
                tar.add(p, arcname=str(Path("runs") / p.relative_to(runs)))
    for p in sorted(runs.glob(".cache/geometry/*/model/train_log.csv"))[-1:]:
        shutil.copyfile(p, out / "train_log.csv")
    shutil.rmtree(out / "logs")
    shutil.rmtree(runs, ignore_errors=True)


__all__ = ["CUDA_TESTS", "EXTENSIONS_DIR", "REPO", "SIZES", "TINY_RUN", "TINY_SIZES", "Check", "build_gsplat",
           "machine", "run_progress"]
