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
import dataclasses
import json
import os
import shutil
import statistics
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


# -- the worker: one reconstruction iteration, timed and profiled ---------------------------
def profile(sizes: list[tuple[int, int, int]], device: str, repeats: int, tf32: bool = False) -> dict:
    """perf gpu's reconstruction iteration at each size with whatever trase is importable:
    median wall time over ``repeats`` steps, then a profile of 3 steps. ``tf32``: matrix
    products in TF32 (a diagnostic; no preset uses it). The step is written out here, not
    imported from benchmark.perf.gpu: the harness must be the same for the checkout before and
    this one, so it lives outside both."""
    import torch

    torch.backends.cuda.matmul.allow_tf32 = tf32
    from benchmark.perf.raster import make_scene
    from trase.deformation import DeformMLP, deformed
    from trase.gaussians import GaussianModel
    from trase.losses import l1_loss, ssim
    from trase.reconstruct import ReconstructionConfig
    from trase.render import rasterize
    from trase.trainer import make_optimizers

    cuda = device == "cuda"
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    rows = []
    for n, w, h in sizes:
        sc, cam = make_scene(n, w, h, 0)
        g = GaussianModel.from_points(sc["means"].numpy(), sc["colors"].numpy(), sh_degree=3).to(device)
        g.active_sh_degree = 3
        # zero heads: offsets as small as a trained network's (the random initialisation's
        # ~0.1-0.5 scene units make every gaussian cover hundreds of tiles, and the steps change them)
        deform = DeformMLP.preset("paper").zero_heads().to(device)
        opt_g, opt_d = make_optimizers(g, deform, ReconstructionConfig.paper())
        gt = torch.rand(h, w, 3, device=device)
        bg = torch.zeros(3, device=device)
        backend = "auto" if cuda else "torch"

        def step():
            m, q, s = deformed(g, deform, 0.5)
            out = rasterize(m, q, s, g.opacities, cam, colors=g.sh_for_render(), sh_degree=3, background=bg,
                            backend=backend)
            loss = 0.8 * l1_loss(out.color, gt) + 0.2 * (1.0 - ssim(out.color, gt))
            loss.backward()
            opt_g.step()
            opt_d.step()
            opt_g.zero_grad(set_to_none=True)
            opt_d.zero_grad(set_to_none=True)

        for _ in range(3):
            step()
        sync()
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            step()
            sync()
            times.append(time.perf_counter() - t0)
        if cuda:
            torch.cuda.reset_peak_memory_stats()
            step()
            sync()
        rows.append({"gaussians": n, "width": w, "height": h, "median_ms": round(1e3 * statistics.median(times), 3),
                     "min_ms": round(1e3 * min(times), 3),
                     "peak_gpu_mib": round(torch.cuda.max_memory_allocated() / 2**20, 1) if cuda else None,
                     **_profiled(step, sync, cuda)})
        del g, deform, opt_g, opt_d
        if cuda:
            torch.cuda.empty_cache()
    import trase

    return {"device": torch.cuda.get_device_name() if cuda else "cpu", "repeats": repeats,
            "trase_from": str(Path(trase.__file__).parent), "tf32": tf32, "sizes": rows}


def _profiled(step, sync, cuda: bool) -> dict:
    """Three steps under torch's profiler -> the aten calls and kernel launches per step, and
    the 15 costliest operations (device time on a GPU, CPU time otherwise)."""
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
    with torch_profile(activities=activities) as prof:
        for _ in range(3):
            step()
        sync()
    events = prof.events()
    aten_top = [e for e in events if e.name.startswith("aten::")
                and (e.cpu_parent is None or not e.cpu_parent.name.startswith("aten::"))]
    launches = [e for e in events if e.name in ("cudaLaunchKernel", "cuLaunchKernel", "cudaLaunchKernelExC",
                                               "cuLaunchKernelEx")]
    key = "device_time_total" if cuda else "cpu_time_total"
    table = sorted(prof.key_averages(), key=lambda a: getattr(a, key, 0.0), reverse=True)
    top = [{"name": a.key[:80], "calls": a.count, "device_ms": round(getattr(a, "device_time_total", 0.0) / 3e3, 3),
            "cpu_ms": round(a.cpu_time_total / 3e3, 3)} for a in table[:15]]
    return {"aten_ops_per_step": len(aten_top) / 3, "kernel_launches_per_step": len(launches) / 3, "top_per_step": top}


# -- the worker: the default run's reconstruction, watched ---------------------------------
DIAG_VARIANTS = ("default", "torch-sh", "tf32", "cap", "lstsq")


def diagnose(seconds: float, variant: str, every: int = 100, until: int = 0,
             window: tuple[int, int] = (0, 0), near: float | None = None) -> dict:
    """The geometry stage of ``trase-bench run --method trase --dataset hypernerf`` (its
    resolved settings, on this machine's default device) for ``seconds``, with the model's
    state every ``every`` iterations: what grows or diverges, and when. Variants: ``torch-sh``
    evaluates SH in torch (the adapter before gsplat took it over), ``tf32`` runs the matrix
    products in TF32, ``cap`` caps the gaussians at two per pixel of a training image, ``lstsq``
    densifies by the statistic the cpu presets use. ``until``: stop after this iteration (the
    schedule is otherwise the run's); inside ``window`` (first, last iteration) every 10th
    iteration is recorded, and every iteration's loss. ``near``: the rasterizer's near plane while
    training (the run's ``geometry.train.near_plane`` when None). Each record also counts, over
    every training camera at its own time, the gaussians in its frustum nearer than 0.2 (the
    public rasterizer's cull), where a screen position moves as 1 / z^2 with depth; at the end
    the test PSNR and the geometry's label ceiling (the benchmark's ``ceiling`` stage, on the CPU)."""
    import tempfile

    import torch

    import trase.reconstruct as rec
    from benchmark.datasets import get_dataset, load_scene
    from benchmark.datasets.synthetic.cache import ensure_synthetic
    from benchmark.methods import get_method
    from benchmark.pipeline.settings import run_settings
    from trase.render_views import evaluate_psnr

    scene_dir = ensure_synthetic("hypernerf")
    scene = load_scene("hypernerf", scene_dir, gt_dir=scene_dir / "gt_masks")
    cam = scene.train[0].camera
    settings = run_settings(get_method("trase"), get_dataset("hypernerf"), "synthetic", {}, (cam.width, cam.height))
    cfg = _diag_config(settings.geometry.train, variant, until, near, cam)
    views = [(torch.as_tensor(c.w2c, dtype=torch.float32), 1.3 * c.width / (2 * c.fx), 1.3 * c.height / (2 * c.fy),
              float(c.time)) for c in (v.camera for v in scene.train)]
    torch.backends.cuda.matmul.allow_tf32 = variant == "tf32"
    if variant == "torch-sh":
        _use_torch_sh()
    rows: list[dict] = []
    losses: list[list] = []
    t0 = time.perf_counter()
    record = rec._record

    def watched(tr, it, step):
        record(tr, it, step)
        inside = window[0] <= it <= window[1]
        if inside:
            losses.append([it, round(float(step.loss), 5), round(float(step.camera.time), 4)])
        if it % (10 if inside else every) == 0:
            rows.append({"it": it, "s": round(time.perf_counter() - t0, 2), **_diag_row(tr, it, step, cfg, cam, views)})

    rec._record = watched
    with tempfile.TemporaryDirectory(prefix="gpu-diag-") as tmp:
        gaussians, deform = rec.reconstruct(scene.train, scene.points, scene.point_colors, cfg, Path(tmp) / "model",
                                            resume=False, progress=False, max_seconds=seconds)
        trained = round(time.perf_counter() - t0, 1)
        test_psnr = evaluate_psnr(gaussians, deform, scene.test, near=cfg.near_plane) if scene.test else None
        ceiling = _ceiling(Path(tmp), scene) if scene.truth is not None else None
    return {"variant": variant, "near_plane": cfg.near_plane, "config": dataclasses.asdict(cfg), "seconds": seconds,
            "trained_s": trained, "n_gaussians": int(gaussians.num_gaussians), "test_psnr": test_psnr,
            "ceiling": ceiling, "rows": rows, "window_losses": losses}


def _diag_config(cfg, variant: str, until: int, near: float | None, cam):
    """The run's reconstruction settings with the variant's change, the last iteration and the
    near plane asked for."""
    if variant == "cap":
        cfg = dataclasses.replace(cfg, max_gaussians=2 * cam.width * cam.height)
    if variant == "lstsq":
        cfg = dataclasses.replace(cfg, densify_statistic="lstsq")
    if until:
        cfg = dataclasses.replace(cfg, iterations=until)
    if near is not None:
        cfg = dataclasses.replace(cfg, near_plane=near)
    return cfg


def _use_torch_sh() -> None:
    """SH evaluated in torch before gsplat draws (the adapter before gsplat took it over)."""
    import trase.render.gsplat_backend as gb
    from trase.render.channels import gaussian_colors

    plain = gb.rasterize_gsplat

    def with_torch_sh(means, quats, scales, opacities, camera, colors, sh_degree, *rest):
        if colors is not None and colors.ndim == 3:
            colors, sh_degree = gaussian_colors(colors, sh_degree, means, camera), None
        return plain(means, quats, scales, opacities, camera, colors, sh_degree, *rest)

    gb.rasterize_gsplat = with_torch_sh


def _near_visible(step) -> int:
    """Gaussians this step drew (radius > 0) nearer than 0.2 to its camera."""
    import torch

    w = torch.as_tensor(step.camera.w2c, dtype=step.means.dtype, device=step.means.device)
    z = step.means.detach() @ w[2, :3] + w[2, 3]
    return int(((step.out.radii > 0) & (z < 0.2)).sum())


def _near_zone(tr, views: list, near_plane: float) -> dict:
    """Over every training camera at its time (``views``: (w2c, tan x, tan y, time)): the most
    gaussians in its frustum nearer than 0.2 (and of those, the most the run's plane still
    draws), the nearest in-frustum depth, and the time of the camera with the most."""
    from trase.deformation import deformed

    worst = {"near_zone_max": 0, "near_zone_time": None, "near_drawn_max": 0, "z_min": float("inf")}
    for w2c, tx, ty, t in views:
        m = deformed(tr.gaussians, tr.deformation(), t)[0]
        w = w2c.to(m.device)
        x = m @ w[:3, :3].T + w[:3, 3]
        z = x[:, 2]
        inside = (z > 1e-6) & (x[:, 0].abs() < tx * z) & (x[:, 1].abs() < ty * z)
        zone = int((inside & (z < 0.2)).sum())
        if zone > worst["near_zone_max"]:
            worst.update(near_zone_max=zone, near_zone_time=round(t, 4))
        worst["near_drawn_max"] = max(worst["near_drawn_max"], int((inside & (z < 0.2) & (z > near_plane)).sum()))
        if bool(inside.any()):
            worst["z_min"] = min(worst["z_min"], float(z[inside].min()))
    worst["z_min"] = round(worst["z_min"], 4)
    return worst


def _diag_row(tr, it: int, step, cfg, cam, views: list) -> dict:
    """The model's state after iteration ``it``: size, loss, scales, opacity, the network's
    offsets and gradients, what the step drew, and (past the warm-up) the near zone."""
    import torch

    from trase.losses import psnr_of_mse
    from trase.render_views import render_view

    with torch.no_grad():
        g, d = tr.gaussians, tr.deform
        s = g.scales.max(dim=1).values
        offsets = d(g.means.detach(), float(step.camera.time)) if it >= cfg.warm_up else None
        finite = all(bool(torch.isfinite(p).all()) for p in (g.means, g.sh_dc, g.sh_rest, g.log_scales, g.quats,
                                                              g.opacity_logits, *d.parameters()))
        mse = float(((step.out.color.clamp(0, 1) - step.gt) ** 2).mean())
        canonical = render_view(g, None, step.camera, step.out.color.new_zeros(3), "auto", with_deform=False)[0]
        return {
            "n": g.num_gaussians, "loss": round(float(step.loss), 5),
            "psnr": round(psnr_of_mse(mse), 2), "finite": finite,
            "scale_max": float(s.max()), "scale_p99": float(s.quantile(0.99)) if s.numel() < 16_000_000 else None,
            "large": int((s > 0.1 * tr.strategy.extent).sum()),
            "opacity_mean": round(float(g.opacities.mean()), 4),
            "d_xyz_max": None if offsets is None else float(offsets[0].abs().max()),
            "d_xyz_p99": None if offsets is None else float(offsets[0].abs().amax(dim=1).quantile(0.99)),
            "d_scale_max": None if offsets is None else float(offsets[2].max()),
            "deform_norm": round(float(sum(float(p.norm()) ** 2 for p in d.parameters()) ** 0.5), 3),
            "visible": int((step.out.radii > 0).sum()),
            "radius_max": int(step.out.radii.max()),
            "radius_over_quarter": int((step.out.radii > cam.width / 4).sum()),
            "d_scale_min": None if offsets is None else float(offsets[2].min()),
            "d_rot_max": None if offsets is None else float(offsets[1].abs().max()),
            "deform_grad": None if not step.use_deform else round(float(torch.sqrt(sum(
                (p.grad.double() ** 2).sum() for p in d.parameters() if p.grad is not None))), 6),
            "means_grad_max": None if g.means.grad is None else float(g.means.grad.abs().max()),
            "deform_lr": tr.opt_d.param_groups[0]["lr"],
            "time": round(float(step.camera.time), 4),
            "psnr_canonical": round(psnr_of_mse(float(((canonical.color.clamp(0, 1) - step.gt) ** 2).mean())), 2),
            "screen_grad_max": None if step.out.means2d.grad is None else float(
                step.out.means2d.grad.norm(dim=-1).max()),
            **(_near_zone(tr, views, cfg.near_plane) if it >= cfg.warm_up else {}),
            "near_visible": _near_visible(step),
        }


def _ceiling(model_dir: Path, scene) -> dict:
    """The saved model's label ceiling (the benchmark's ``ceiling`` stage, on the CPU)."""
    from benchmark.pipeline.context import load_geometry
    from benchmark.protocol.ceiling import label_ceiling
    from benchmark.scoring import read_mask

    g_cpu, d_cpu = load_geometry(model_dir)  # the saved model, on the CPU, as the ceiling stage loads it
    score, info = label_ceiling(g_cpu, d_cpu, scene, [read_mask(p) for p in scene.gt_masks])
    return {"miou": round(float(score.miou), 4), "object_alpha": info["object_alpha"], "objects": info["objects"]}


# -- the orchestrator ----------------------------------------------------------------------
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
                                    env={**os.environ, **(env or {})}).returncode
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
    background = [subprocess.Popen(cmd, cwd=REPO, env={**os.environ, **_py()}, stdout=open(chk.logs / f"{name}.log", "w"),
                                   stderr=subprocess.STDOUT)
                  for name, cmd in (("scene", [sys.executable, "-c", "from benchmark.datasets.synthetic.cache import "
                                               "ensure_synthetic; print(ensure_synthetic('hypernerf'))"]),
                                    ("precompile", [sys.executable, "-m", "trase.precompile"]))]
    if cuda:
        build_gsplat(chk, reuse, save)
    for p in background:
        p.wait(timeout=max(chk.left() - 30, 1))
    chk.result["steps"]["scene_and_kernels_s"] = round(time.monotonic() - chk.t0, 1)


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
    scene = subprocess.Popen([sys.executable, "-c", "from benchmark.datasets.synthetic.cache import ensure_synthetic; "
                              "print(ensure_synthetic('hypernerf'))"], cwd=REPO, env={**os.environ, **_py()})
    pre = subprocess.Popen([sys.executable, "-m", "trase.precompile"], cwd=REPO, env={**os.environ, **_py()})
    if chk.result["machine"]["gpu"]:
        build_gsplat(chk)
    scene.wait()
    pre.wait()
    procs = {}
    watch = ["--until", str(args.until), "--window", args.window, "--every", str(args.every)]
    for v in args.variants.split(","):
        log = open(chk.logs / f"diag_{v}.log", "w")
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
        log = open(chk.logs / f"diag_{label}.log", "w")
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
