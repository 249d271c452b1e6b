"""A stage's torch thread count holds whatever numba does inside it (trase.threads)."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# a fresh process, where numba's thread pool has not started yet: its start sets the OpenMP
# thread count torch reads, and the first parallel kernel of a stage used to start it
CODE = """
import numba, numpy as np, torch
from numba import njit, prange
from trase.threads import torch_threads

@njit(parallel=True)
def twice(x):
    out = np.empty_like(x)
    for i in prange(x.size):
        out[i] = 2 * x[i]
    return out

with torch_threads(1):
    twice(np.arange(100_000.0))
    print(torch.get_num_threads())
"""


def test_the_first_parallel_numba_kernel_keeps_the_stages_torch_threads():
    env_threads = {"NUMBA_NUM_THREADS": "2", "OMP_NUM_THREADS": "2"}
    out = subprocess.run([sys.executable, "-c", CODE], cwd=ROOT, env={**os.environ, **env_threads},
                         capture_output=True, text=True, check=True, timeout=120).stdout.split()
    assert out == ["1"]
