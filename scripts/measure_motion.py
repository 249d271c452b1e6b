"""How much of a reconstruction moves, checkpoint by checkpoint: when its motion is learned.

    python scripts/measure_motion.py MODEL_DIR [MODEL_DIR ...] [--times 50] [--above 0.05 0.1 0.2]

MODEL_DIR: a reconstruction's model folder (``<stage cache>/geometry/<key>/model`` or a fit's
``model``), with ``deform/iteration_N`` checkpoints (the cpu preset keeps 2000 and 4000). For
each checkpoint, the deformation network's motion of every gaussian over ``--times`` times
evenly spread over [0, 1] (``trase.static_gaussians.motion``, in the capture's units: the
extent given as 1), and how many gaussians move more than each ``--above`` value. Why: static
gaussians are measured from iteration 1600 on; a scene whose movers have not learned their
motion by then loses them (docs/skip.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model_dirs", nargs="+", type=Path)
    ap.add_argument("--times", type=int, default=50, help="times over [0, 1] the motion is measured at")
    ap.add_argument("--above", type=float, nargs="+", default=[0.05, 0.1, 0.2])
    args = ap.parse_args(argv)

    from trase.checkpoint import available_iterations, load_model
    from trase.static_gaussians import PartlyStaticDeformation, motion

    times = [float(t) for t in np.linspace(0.0, 1.0, args.times)]
    print("model | iteration | gaussians | max motion | " + " | ".join(f"> {a:g}" for a in args.above))
    for d in args.model_dirs:
        its = available_iterations(d)
        if not its:
            print(f"{d}: no checkpoint (point_cloud/iteration_N)", file=sys.stderr)
            return 2
        for it in its:
            g, deform = load_model(d, it)
            if deform is None:
                print(f"{d}: iteration {it} has no deformation network (a motionless capture)", file=sys.stderr)
                return 2
            net = deform.net if isinstance(deform, PartlyStaticDeformation) else deform
            mv, _ = motion(net, g.means.detach(), g.scales.detach(), times, 1.0)
            counts = " | ".join(str(int((mv > a).sum())) for a in args.above)
            print(f"{d} | {it} | {g.num_gaussians} | {float(mv.max()):.3f} | {counts}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
