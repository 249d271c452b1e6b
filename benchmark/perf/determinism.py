"""What a fixed seed gives under other numeric modes and thread counts: the same stages in fresh
processes, compared with the default (portable numerics, the presets' threads).

Each variant runs in a fresh process (the numeric mode is chosen before torch and numba load):
the runner's geometry training for a few hundred iterations on the synthetic HyperNeRF-format
scene, then feature training on that scene's ground-truth geometry. Variants:

* ``numba 1 thread``: the rasterizer's and the fast path's parallel loops on one thread;
* ``torch 1 thread`` / ``torch 2 threads``: torch's intra-op threads for both stages (the cpu
  preset fixes them in the config: 2 for the geometry, 1 for the features);
* ``native``: each library's kernels for this processor (``machine.numerics=native``), what
  every run computed before the numeric modes; on an AVX-512 machine, another vector width.

Printed per variant: whether the gaussians and the features are bit-identical to the
baseline's, the largest difference, the test PSNR and the seconds each stage took (numba's
compilation included where its cache holds no kernels of that mode yet: run the suite twice to
compare speed). What a
difference does downstream (clusters, clicks, mIoU) is a whole run's business: see
docs/determinism.md.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

# name -> (numeric mode, extra environment)
VARIANTS: dict[str, tuple[str, dict[str, str]]] = {
    "portable (default)": ("portable", {}),
    "numba 1 thread": ("portable", {"NUMBA_NUM_THREADS": "1"}),
    "torch 1 thread": ("portable", {"TRASE_PERF_TORCH_THREADS": "1"}),  # geometry: the cpu preset has 2
    "torch 2 threads": ("portable", {"TRASE_PERF_TORCH_THREADS": "2"}),  # features: the cpu preset has 1
    "native": ("native", {}),
}
QUICK = {"size": "tiny", "iterations": 60, "feature_steps": 30}
FULL = {"size": "small", "iterations": 400, "feature_steps": 300}


def child(out: str, size: str, iterations: int, feature_steps: int) -> None:
    """One variant (in its own process): geometry and features -> ``out``.npz + .json."""
    import numpy as np

    from benchmark.datasets import get_dataset, load_scene
    from benchmark.datasets.synthetic import ensure_synthetic
    from benchmark.perf.reconstruct import runner_train_config
    from trase.checkpoint import load_tabulated_geometry
    from trase.features import FeatureConfig, train_features
    from trase.reconstruct import ReconstructionConfig, reconstruct
    from trase.render_views import evaluate_psnr

    spec = get_dataset("hypernerf")
    scene_dir = ensure_synthetic("hypernerf", size=size)
    scene = load_scene("hypernerf", scene_dir)
    cam = scene.test[0].camera
    train = runner_train_config("hypernerf", (cam.width, cam.height))
    threads = os.environ.get("TRASE_PERF_TORCH_THREADS")
    train |= {"iterations": iterations, "checkpoint_interval": iterations}
    if threads:
        train["torch_threads"] = int(threads)
    work = Path(out + "_work")
    t0 = time.perf_counter()
    g, deform = reconstruct(scene.train, scene.points, scene.point_colors, ReconstructionConfig(**train), work,
                            resume=False, progress=False)
    geometry_s = time.perf_counter() - t0
    psnr = evaluate_psnr(g, deform, scene.test)

    import masks as masklib

    gt_g, gt_deform, _ = load_tabulated_geometry(scene.truth.geometry_path)
    from masks.generators import make_generator

    gen = make_generator("synthetic", seed=0)
    mask_dir = work / "masks"
    masklib.generate_scene_masks(scene.train, gen, mask_dir, progress=False,
                                 instance_maps=scene.truth.instance_maps)
    from benchmark.methods.trase_presets import trase_settings

    fcfg = trase_settings("cpu", spec.key).features  # the features `run` trains under the cpu preset
    fcfg = FeatureConfig(**(fcfg.to_dict() | {"iterations": feature_steps, "device": "cpu"}
                            | ({"torch_threads": int(threads)} if threads else {})))
    t0 = time.perf_counter()
    res = train_features(gt_g, gt_deform, scene.train, lambda v: masklib.load(masklib.mask_path(mask_dir, v.name)),
                         fcfg, cache_dir=work / "pixel_weights", progress=False)
    np.savez(out + ".npz", means=g.means.detach().numpy(), opacity=g.opacity_logits.detach().numpy(),
             features=res.features.detach().numpy())
    Path(out + ".json").write_text(json.dumps({"psnr": psnr, "gaussians": int(g.num_gaussians),
                                               "geometry_s": geometry_s, "features_s": time.perf_counter() - t0}))


def run(quick: bool, echo: Callable[[str], None]) -> dict:
    import numpy as np

    s = QUICK if quick else FULL
    echo(f"  synthetic HyperNeRF ({s['size']}): {s['iterations']} geometry iterations, {s['feature_steps']} feature "
         "steps on ground-truth geometry; each variant in a fresh process")
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, (mode, env) in VARIANTS.items():
            out = str(Path(tmp) / "".join(c if c.isalnum() else "_" for c in name))
            code = (f"from benchmark import numerics; numerics.apply({mode!r}); "
                    "from benchmark.perf.determinism import child; "
                    f"child({out!r}, {s['size']!r}, {s['iterations']}, {s['feature_steps']})")
            proc = subprocess.run([sys.executable, "-c", code], env={**os.environ, **env},
                                  capture_output=True, text=True, check=False)
            if proc.returncode:
                raise RuntimeError(f"determinism variant {name!r} failed:\n{proc.stderr[-2000:]}")
            arrays = dict(np.load(out + ".npz"))
            info = json.loads(Path(out + ".json").read_text())
            results[name] = (arrays, info)
    base, base_info = results["portable (default)"]
    rows = {}
    echo(f"  {'variant':<20} {'gaussians':>9} {'PSNR':>7} {'geometry s':>10} {'features s':>10}  geometry"
         "                    features")
    for name, (arrays, info) in results.items():
        row = {"numerics": VARIANTS[name][0], "env": VARIANTS[name][1], **info}
        for part, keys in (("geometry", ("means", "opacity")), ("features", ("features",))):
            same_shape = all(arrays[k].shape == base[k].shape for k in keys)
            identical = same_shape and all(np.array_equal(arrays[k], base[k]) for k in keys)
            diff = max(float(np.abs(arrays[k] - base[k]).max()) for k in keys) if same_shape else None
            row[part] = {"identical": identical, "max_abs_diff": diff}
        rows[name] = row
        echo(f"  {name:<20} {info['gaussians']:>9} {info['psnr']:7.3f} {info['geometry_s']:10.1f} "
             f"{info['features_s']:10.1f}  {_show(row['geometry']):<27} {_show(row['features'])}")
    return {"settings": s, "variants": rows, "baseline_psnr": base_info["psnr"]}


def _show(part: dict) -> str:
    if part["identical"]:
        return "identical"
    if part["max_abs_diff"] is None:
        return "differs (other gaussian count)"
    return f"differs (max {part['max_abs_diff']:.1e})"
