"""The numeric environment of a process: which instruction set each library's kernels use.

A float result depends on the code that computed it. numba compiles for the processor it runs
on; torch (ATen), MKL, oneDNN, numpy, OpenBLAS and OpenCV each pick kernels by the processor
when they load. Two x86-64 machines therefore round differently, and a reconstruction turns a
last-bit difference into other gaussians, clusters and clicks (docs/determinism.md). Two modes:

* ``portable`` (the default): every one of them pinned to one named baseline, x86-64-v3 (the
  Haswell level: AVX2, FMA, BMI2), which every x86-64 machine of the last decade has. The same
  config gives the same bits on any such machine (same library versions, same libm).
* ``native``: each library picks the fastest code of this processor (AVX-512 where it has it):
  faster where that helps; the bits are this machine kind's.

The environment has to be in place before the libraries load, so the command line sets it first
(``apply``), from ``--set machine.numerics=MODE`` (or ``$TRASE_NUMERICS``); a run checks the
process it computes in (``check``) and records it (``describe``). This module imports nothing
heavy: it must run before numpy, torch and numba are imported.
"""

from __future__ import annotations

import contextlib
import functools
import os
import platform
import sys

from benchmark.errors import UserError

MODES = ("portable", "native")
DEFAULT = "portable"
ENV_MODE = "TRASE_NUMERICS"
BASELINE = "x86-64-v3"
# The version of what portable mode pins: 1 asked MKL for its AVX2 branch, 2 for its COMPATIBLE one,
# 3 moved the deformation network's products to OpenBLAS. It enters the stages' cache keys and the
# protocol label, so the bits of two pinnings never mix.
PINNING = 3


def pinning_name(pinning: int) -> str:
    """"pinning N" for portable bits from the second pinning on; "" for the first, whose labels,
    groups and pages never named one (so its results keep their names)."""
    return f"pinning {pinning}" if pinning > 1 else ""

# What x86-64-v3 requires, in LLVM's feature names (llvmlite reports the host's in them).
BASELINE_FEATURES = ("avx", "avx2", "bmi", "bmi2", "cx16", "f16c", "fma", "lzcnt", "movbe", "popcnt", "sahf",
                     "sse3", "sse4.1", "sse4.2", "ssse3", "xsave")

# The environment of portable mode, read by each library when it loads:
PORTABLE_ENV = {
    # numba: code for the baseline CPU with exactly its features (numba otherwise adds the host's
    # features to a named CPU, AVX-512 included); no Intel SVML (its entry points dispatch by CPU)
    "NUMBA_CPU_NAME": BASELINE,
    "NUMBA_CPU_FEATURES": ",".join(f"+{f}" for f in BASELINE_FEATURES),
    "NUMBA_DISABLE_INTEL_SVML": "1",
    # torch's ATen kernels (vectorised loops, Sleef) at AVX2 instead of AVX-512
    "ATEN_CPU_CAPABILITY": "avx2",
    # MKL's conditional numerical reproducibility: the COMPATIBLE branch (one SSE2 code path), strict
    # (bits independent of the arrays' alignment). MKL honours its other named branches (AVX2 ...)
    # on Intel processors only and takes its AUTO branch elsewhere: AVX2 gave AMD and Intel
    # machines other products (pinning 1)
    "MKL_CBWR": "COMPATIBLE,STRICT",
    # oneDNN (torch's mkldnn ops) capped at AVX2; both spellings (old and new releases)
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    "DNNL_MAX_CPU_ISA": "AVX2",
    # numpy's dispatched loops (exp, log, sort ...) above x86-64-v3 switched off
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
    # OpenBLAS (numpy's and scipy's) with its Haswell kernels
    "OPENBLAS_CORETYPE": "Haswell",
    # the deformation network's products through OpenBLAS (trase.blas_linear): its Haswell kernels
    # run on every vendor, about 2x the rate of MKL's COMPATIBLE branch on the network's shapes
    "TRASE_PRODUCTS": "openblas",
    # OpenCV's dispatched AVX-512 code switched off (its own feature names, comma-separated)
    "OPENCV_CPU_DISABLE": "AVX512F,AVX512-SKX",
}


class NumericsError(UserError):
    """A numeric mode this process or machine cannot give; the message is one line."""


def mode_from_sets(items) -> str | None:
    """The mode of a ``machine.numerics=MODE`` among ``key=value`` settings, if any."""
    modes = [v.split("=", 1)[1].strip() for v in items if "=" in v and v.split("=", 1)[0].strip() == "machine.numerics"]
    return modes[-1] if modes else None


def mode_from_argv(argv: list[str]) -> str | None:
    """The mode of ``--set machine.numerics=MODE`` (or ``--set=...``) in a command line, if any."""
    sets = [argv[i + 1] for i, a in enumerate(argv[:-1]) if a == "--set"]
    return mode_from_sets(sets + [a.split("=", 1)[1] for a in argv if a.startswith("--set=")])


def requested_mode(argv: list[str] | None = None) -> str:
    """The command line's mode, else ``$TRASE_NUMERICS``, else the default."""
    mode = mode_from_argv(list(sys.argv[1:] if argv is None else argv)) or os.environ.get(ENV_MODE) or DEFAULT
    if mode not in MODES:
        raise NumericsError(f"machine.numerics={mode}: choose {' or '.join(MODES)}")
    return mode


def wanted_env(mode: str) -> dict[str, str | None]:
    """The variables ``mode`` sets (None: unset, so each library chooses for itself)."""
    if mode == "portable":
        return dict(PORTABLE_ENV)
    return dict.fromkeys(PORTABLE_ENV)


def apply(mode: str) -> None:
    """Put ``mode``'s environment in place for this process (where its libraries are not loaded
    yet) and the processes it starts. A machine that cannot give portable mode (another
    architecture, or an x86-64 processor below the baseline) keeps its own environment; ``check``
    says why when a run needs the mode."""
    if mode == "portable" and missing_features() != []:
        return
    os.environ[ENV_MODE] = mode
    for key, value in wanted_env(mode).items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


@contextlib.contextmanager
def environment(mode: str):
    """``mode``'s environment for the processes started inside (a sweep's workers), the
    previous one back afterwards."""
    keys = [ENV_MODE, *PORTABLE_ENV]
    before = {k: os.environ.get(k) for k in keys}
    apply(mode)
    try:
        yield
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@functools.cache
def host_features() -> frozenset[str] | None:
    """The host's instruction-set features in LLVM's names (None off x86-64)."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return None
    from llvmlite import binding  # pure ctypes: loads none of the libraries pinned here

    return frozenset(k for k, on in binding.get_host_cpu_features().items() if on)


def missing_features() -> list[str] | None:
    """The baseline's features this processor lacks ([] where it has them all); None off x86-64."""
    host = host_features()
    return None if host is None else [f for f in BASELINE_FEATURES if f not in host]


def check(mode: str) -> None:
    """Raise NumericsError unless this process computes in ``mode``: the machine can give it, the
    environment is ``mode``'s, and the libraries already loaded read that environment."""
    missing = missing_features()
    if mode == "portable" and missing is None:
        raise NumericsError(f"portable numerics pin x86-64 code ({BASELINE}); this machine is {platform.machine()}: "
                            "run with --set machine.numerics=native (its figures hold on this machine kind)")
    if mode == "portable" and missing:
        raise NumericsError(f"portable numerics need {BASELINE}; this processor lacks {', '.join(missing)}: run with "
                            "--set machine.numerics=native (its figures hold on this machine kind)")
    wrong = {k: os.environ.get(k) for k, v in wanted_env(mode).items() if os.environ.get(k) != v}
    live = live_mismatch(mode)
    if wrong or live:
        what = live or f"environment {', '.join(f'{k}={v}' for k, v in wrong.items())}"
        raise NumericsError(f"machine.numerics={mode}, but this process computes otherwise ({what}): start it "
                            f"through trase-bench (which sets the environment before the libraries load), or "
                            f"set {ENV_MODE}={mode} and call benchmark.numerics.apply first")


def live_mismatch(mode: str) -> str:
    """What a loaded library does that ``mode`` does not ('' when all agree)."""
    out = []
    if "numba" in sys.modules:
        import numba

        name, features = numba.config.CPU_NAME, numba.config.CPU_FEATURES
        want = (PORTABLE_ENV["NUMBA_CPU_NAME"], PORTABLE_ENV["NUMBA_CPU_FEATURES"]) if mode == "portable" else (None, None)
        if (name, features) != want:
            out.append(f"numba compiles for {name or 'the host CPU'}")
    if "torch" in sys.modules:
        import torch

        capability = torch.backends.cpu.get_cpu_capability()
        if (capability != "AVX2") if mode == "portable" else (_has_avx512() and capability != "AVX512"):
            out.append(f"torch's kernels at {capability}")
    if "numpy" in sys.modules:
        from numpy._core._multiarray_umath import __cpu_features__

        if mode == "portable" and __cpu_features__.get("X86_V4"):
            out.append("numpy dispatches x86-64-v4 loops")
    if "trase.blas_linear" in sys.modules:
        from trase import blas_linear

        want = PORTABLE_ENV["TRASE_PRODUCTS"] if mode == "portable" else "torch"
        if blas_linear.engine() != want:
            out.append(f"the deformation network's products through {blas_linear.engine()}")
    return "; ".join(out)


def _has_avx512() -> bool:
    host = host_features() or set()
    return {"avx512f", "avx512bw", "avx512vl", "avx512dq"} <= host


def cpu_model() -> str:
    """The processor's model name (/proc/cpuinfo on Linux)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def x86_levels(host: set[str] | None) -> list[str]:
    """The x86-64 micro-architecture levels the host reaches (v2, v3, v4)."""
    if host is None:
        return []
    v2 = {"cx16", "popcnt", "sahf", "sse3", "sse4.1", "sse4.2", "ssse3"}
    v4 = {"avx512f", "avx512bw", "avx512cd", "avx512dq", "avx512vl"}
    levels = [("x86-64-v2", v2), (BASELINE, set(BASELINE_FEATURES)), ("x86-64-v4", set(BASELINE_FEATURES) | v4)]
    return [name for name, need in levels if need <= host]


def describe(mode: str) -> dict:
    """What a results file records of the numerics: the mode, its environment and the machine
    (model, x86-64 levels, the AVX-512 features it has, its C library)."""
    host = host_features()
    out = {"mode": mode, "baseline": BASELINE if mode == "portable" else "native",
           "cpu_model": cpu_model(), "x86_levels": x86_levels(host),
           "avx512": sorted(f for f in (host or ()) if f.startswith("avx512")),
           "libc": "-".join(platform.libc_ver()) or "unknown"}
    if mode == "portable":
        out["env"] = dict(PORTABLE_ENV)
        out["pinning"] = PINNING
    return out


def kernels() -> dict:
    """What the loaded libraries compute with: torch's kernel level and numba's target CPU."""
    out = {}
    if "torch" in sys.modules:
        import torch

        out["torch_cpu_capability"] = torch.backends.cpu.get_cpu_capability()
    if "numba" in sys.modules:
        import numba
        from llvmlite import binding

        out["numba_cpu"] = numba.config.CPU_NAME or binding.get_host_cpu_name()
    if "trase.blas_linear" in sys.modules:
        from trase import blas_linear

        out["products"] = blas_linear.engine()
    return out


__all__ = [
    "BASELINE",
    "DEFAULT",
    "MODES",
    "PINNING",
    "PORTABLE_ENV",
    "NumericsError",
    "apply",
    "check",
    "describe",
    "environment",
    "kernels",
    "missing_features",
    "mode_from_argv",
    "mode_from_sets",
    "pinning_name",
    "requested_mode",
    "wanted_env",
]
