"""Performance suites for ``trase-bench perf SUITE``. A suite is a module with
``run(quick: bool, echo) -> dict`` (JSON-ready, figures measured in this run); register it with
one line in ``SUITES``: name, "module:function", one-line description. A suite that needs what a
machine may lack (a GPU) also has ``unavailable() -> str | None``: ``trase-bench perf`` with no
suite named skips it with that reason."""

from __future__ import annotations

import os
import platform
import sys
from collections.abc import Callable

from lazyspecs import Registry

SUITES = Registry("perf suite")
SUITES.add("raster", "benchmark.perf.raster:run",
           "Gaussian rasterizer: numba vs torch reference, forward/backward.")
SUITES.add("knn", "benchmark.perf.knn:run",
           "K=16 smoothing neighbours: cKDTree (as trase) vs all-core, chunked, sklearn; + smoothing step.")
SUITES.add("cluster", "benchmark.perf.cluster:run",
           "Feature clustering: HDBSCAN 2/10/25% vs DBSCAN, KMeans, PCA and fixed-sample variants (ARI).")
SUITES.add("features", "benchmark.perf.features:run",
           "Feature step: whole step on the synthetic scene (rasterizer vs fast path, R/F/X/O), fused vs dense objective, render grid.")
SUITES.add("reconstruct", "benchmark.perf.reconstruct:run",
           "Test PSNR vs wall-clock time of the CPU reconstruction (synthetic HyperNeRF), old and new CPU preset.")
SUITES.add("gpu", "benchmark.perf.gpu:run",
           "One reconstruction iteration and one feature step at the paper's settings on a CUDA GPU; fast path vs rasterizing.")
SUITES.add("pipeline", "benchmark.perf.pipeline:run",
           "Per-stage time and peak memory of the runner per synthetic dataset, 2 sizes; exponents.")
SUITES.add("determinism", "benchmark.perf.determinism:run",
           "A fixed seed under other thread counts and numeric modes (fresh processes): bit-identical or by how much "
           "not, and the seconds each stage took.")
SUITES.add("captures", "benchmark.perf.captures:run",
           "trase-bench fit on the built-in scene written as nerfies / COLMAP / transforms captures: click IoU, stage times.")
SUITES.add("viewer", "benchmark.perf.viewer:run",
           "The web viewer's frame rate at 320x240 and 640x480 per render mode, and click-selection latency.")
SUITES.add("dnerf", "benchmark.perf.dnerf:run",
           "trase-bench fit on D-NeRF scenes as published (--scene): test/validation PSNR, SSIM beside Deformable-3DGS's, foreground IoU.")
SUITES.add("methods", "benchmark.perf.methods:run",
           "Every method's feature stage on one scene, a fresh process each: ms per step, stage time, peak memory.")
SUITES.add("skip", "benchmark.perf.skip:run",
           "Skipping what a scene does not need (static gaussians, stages stopped when converged, resolution and "
           "primitive schedules), on and off per "
           "format: stage seconds, PSNR, ceiling, mIoU; a PNG per format with the Pareto front.")
SUITES.add("frames", "benchmark.perf.frames:run",
           "How much new content each frame of a monocular sequence carries (built-in formats, D-NeRF --scene): "
           "the share of frames far below the median novelty.")
SUITES.add("network", "benchmark.perf.network:run",
           "The deformation network's training step: ms and GFLOP/s against one of its matrix products alone.")
SUITES.add("pareto", "benchmark.perf.pareto:run",
           "mIoU vs features+fit+evaluate time over a settings grid for one scene; PNG with the Pareto front.")


def get_suite(name: str) -> Callable:
    return SUITES.load(name)


def machine_info() -> dict:
    """Where the figures were measured: what a results file records (benchmark.results:
    platform, cores, instruction sets), plus the CPU model, load and library versions."""
    import numba
    import numpy
    import torch

    from benchmark.results import machine_info as results_machine

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return results_machine() | {
        "cpu": cpu,
        "python": sys.version.split()[0],
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "numba": numba.__version__,
        "numba_threads": numba.config.NUMBA_NUM_THREADS,
        "numpy": numpy.__version__,
        "load_average_start": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }
