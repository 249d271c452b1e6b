"""Two training processes side by side, their idle OpenMP threads spinning or asleep.

    python scripts/measure_idle_threads.py [--seconds 20] [--threads 2] [--repeats 2]

Each process trains an MLP over 15k points (the shape of a CPU reconstruction step's
deformation network) with ``--threads`` torch threads for ``--seconds``; both run at once,
first with the OpenMP default (idle threads spin a while before sleeping), then with
``OMP_WAIT_POLICY=PASSIVE`` (they sleep at once), ``--repeats`` times alternating. Prints
each process's milliseconds per step and CPU seconds. Why it matters: local sweeps with several
workers (``benchmark.sweep.idle_threads_sleep``) and any runs side by side on a small machine.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

WORKER = r"""
import sys, time, torch
torch.set_num_threads(int(sys.argv[1])); torch.manual_seed(0)
layers = []
for _ in range(4):
    layers += [torch.nn.Linear(128, 128), torch.nn.ReLU()]
net = torch.nn.Sequential(*layers, torch.nn.Linear(128, 10))
x = torch.randn(15000, 128)  # [N, 128]
opt = torch.optim.Adam(net.parameters(), 1e-3)
t0, c0, n = time.perf_counter(), time.process_time(), 0
while time.perf_counter() - t0 < float(sys.argv[2]):
    loss = net(x).square().mean(); opt.zero_grad(); loss.backward(); opt.step(); n += 1
print(f"{1000 * (time.perf_counter() - t0) / n:.1f} {time.process_time() - c0:.1f}")
"""


def pair(policy: str | None, threads: int, seconds: float) -> list[tuple[float, float]]:
    env = dict(os.environ)
    env.pop("OMP_WAIT_POLICY", None)
    if policy:
        env["OMP_WAIT_POLICY"] = policy
    procs = [subprocess.Popen([sys.executable, "-c", WORKER, str(threads), str(seconds)], env=env,
                              stdout=subprocess.PIPE, text=True) for _ in range(2)]
    out = [p.communicate()[0].split() for p in procs]
    return [(float(ms), float(cpu)) for ms, cpu in out]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args()
    print(f"{os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}, {a.threads} torch threads per process, "
          f"{a.seconds:.0f} s per pair")
    for r in range(a.repeats):
        for policy in (None, "PASSIVE"):
            res = pair(policy, a.threads, a.seconds)
            name = policy or "default"
            print(f"  {time.strftime('%H:%M:%S')} {name:8s} ms/step " + ", ".join(f"{ms:.1f}" for ms, _ in res)
                  + "; CPU s " + ", ".join(f"{cpu:.1f}" for _, cpu in res))


if __name__ == "__main__":
    main()
