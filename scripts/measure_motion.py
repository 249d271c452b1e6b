"""How much of a reconstruction moves, checkpoint by checkpoint: when its motion is learned.

    python scripts/measure_motion.py MODEL_DIR [MODEL_DIR ...] [--times 50] [--above 0.05 0.1 0.2]
        [--dataset hypernerf --scene SCENE_DIR [--scene ...]]

MODEL_DIR: a reconstruction's model folder (``<stage cache>/geometry/<key>/model`` or a fit's
``model``), with ``deform/iteration_N`` checkpoints (the cpu preset keeps 2000 and 4000). For
each checkpoint, the deformation network's motion of every gaussian over ``--times`` times
evenly spread over [0, 1] (``trase.static_gaussians.motion``, in the capture's units: the
extent given as 1), and how many gaussians move more than each ``--above`` value. Why: static
gaussians are measured from iteration 1600 on; a scene whose movers have not learned their
motion by then loses them (docs/notes/skip.md). With ``--scene`` (one per MODEL_DIR, read as
``--dataset``): the PSNR of each training view rendered at its time (black background, as the
cpu preset trains), its median, the worst and the times of the three worst: a motion not yet
learned shows as a few times much worse than the rest; the time gap is
``trase.static_gaussians.time_gap`` over all of them (what ``static_time_gap`` compares, there
over a check's times only).
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
    ap.add_argument("--scene", type=Path, action="append", default=[],
                    help="the scene each MODEL_DIR was trained on (in order): training-view PSNR per checkpoint")
    ap.add_argument("--dataset", default="hypernerf", help="the scenes' format (a trase-bench dataset name)")
    args = ap.parse_args(argv)
    if args.scene and len(args.scene) != len(args.model_dirs):
        print(f"--scene given {len(args.scene)} times for {len(args.model_dirs)} model folders", file=sys.stderr)
        return 2

    from trase.checkpoint import available_iterations, load_model
    from trase.static_gaussians import PartlyStaticDeformation, motion, time_gap

    times = [float(t) for t in np.linspace(0.0, 1.0, args.times)]
    views_head = " | training views: median PSNR | worst | worst times | time gap" if args.scene else ""
    print("model | iteration | gaussians | max motion | " + " | ".join(f"> {a:g}" for a in args.above) + views_head)
    for i, d in enumerate(args.model_dirs):
        views = training_views(args.dataset, args.scene[i]) if args.scene else None
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
            row = f"{d} | {it} | {g.num_gaussians} | {float(mv.max()):.3f} | {counts}"
            if views is not None:
                ps, ts = view_psnrs(g, deform, views)
                worst = np.argsort(ps)[:3]
                row += (f" | {np.median(ps):.2f} dB | {ps.min():.2f} dB | "
                        + ", ".join(f"t={ts[k]:.2f}" for k in worst)
                        + f" | {time_gap(ps.tolist(), ts.tolist()):.2f} dB")
            print(row)
    return 0


def training_views(dataset: str, scene_dir: Path) -> list:
    from benchmark.datasets.loader import load_scene

    return load_scene(dataset, scene_dir).train


def view_psnrs(gaussians, deformation, views) -> tuple[np.ndarray, np.ndarray]:
    """Each training view's PSNR (dB) at its time (black background), and the times -> ([V], [V])."""
    import torch

    from trase.render_views import evaluate_images

    with torch.no_grad():
        ps = evaluate_images(gaussians, deformation, views, ssim_too=False)["per_view_psnr"]
    return np.array(ps), np.array([float(v.camera.time) for v in views])


if __name__ == "__main__":
    sys.exit(main())
