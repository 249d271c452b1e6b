"""trase's numba kernels compiled in another process while a synthetic scene is generated.

A first run on a fresh checkout pays both: generating the scene (~35-45 s on 2 cores, numpy
and the rasterizer's forward) and compiling the kernels on first use (~35 s, inside the
geometry and feature stages). The two are independent, so the runner and ``trase-bench synth``
start ``python -m trase.precompile`` beside the generation and wait for it before going on.
Numba writes its cache atomically; a kernel the main process needs before the other process
has cached it is compiled in both, with the same result. Nothing a run reports depends on it.
``TRASE_PRECOMPILE=0`` turns it off (the test suite does).
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator

ENV = "TRASE_PRECOMPILE"
WAIT_S = 600.0  # the other process never holds a run back longer than this


def enabled() -> bool:
    return os.environ.get(ENV, "1").strip().lower() not in ("0", "false", "no", "off")


@contextlib.contextmanager
def kernels_compiled_meanwhile(echo=None) -> Iterator[None]:
    """Compile the kernels in another process while the body runs; wait for it afterwards.

    If the body fails the other process is stopped. If it fails, one line says so and the
    kernels compile on first use, as without it.
    """
    say = echo or (lambda msg: print(msg, file=sys.stderr))
    if not enabled():
        yield
        return
    t0 = time.perf_counter()
    # its messages go to a file, not a pipe: nobody reads a pipe while the body runs, and a
    # full one would stop the other process
    with tempfile.TemporaryFile(mode="w+") as err_file:
        try:
            proc = subprocess.Popen([sys.executable, "-m", "trase.precompile", "--quiet"],
                                    stdout=subprocess.DEVNULL, stderr=err_file, text=True)
        except OSError as exc:
            say(f"trase-bench: could not start the kernel compilation beside the scene's generation ({exc}); "
                "kernels compile on first use")
            yield
            return
        ok = False
        try:
            yield
            ok = True
        finally:
            if not ok:
                proc.kill()
                proc.wait()
        if proc.poll() is None:
            say("trase-bench: waiting for the numba kernels compiling alongside "
                f"({time.perf_counter() - t0:.0f} s so far)")
        try:
            proc.wait(timeout=WAIT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            say(f"trase-bench: the kernel compilation alongside took over {WAIT_S:.0f} s and was stopped; "
                "kernels compile on first use")
            return
        err_file.seek(0)
        err = err_file.read()
    if proc.returncode != 0:
        last = err.strip().splitlines()[-1:] or ["no message"]
        say(f"trase-bench: the kernel compilation alongside failed (exit {proc.returncode}: {last[0]}); "
            "kernels compile on first use")
