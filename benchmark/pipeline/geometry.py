"""Stage ``geometry``: the frozen gaussians and deformation every method segments
(reconstructed with Deformable-3DGS, the synthetic scene's truth, or an imported model)."""

from __future__ import annotations

import shutil
from pathlib import Path

from benchmark.cache import StageRecord
from benchmark.config import ConfigError
from benchmark.pipeline.context import SequenceRun, load_geometry, synthetic_truth
from benchmark.pipeline.settings import key_config

SOURCES = ("reconstruct", "ground-truth", "import")


def geometry_key_inputs(ctx: SequenceRun) -> dict:
    """The inputs a geometry key hashes besides its settings: the scene, and the resolution
    schedules' code version where either is on (its older results are not reused, the
    others' keys stay as they were)."""
    inputs = {"scene": ctx.scene_key}
    train = ctx.settings.geometry.train
    if train.resolution_schedule != "off" or train.primitive_schedule != "off":
        from trase.resolution_schedule import SCHEDULE_VERSION

        inputs["resolution_schedule_version"] = str(SCHEDULE_VERSION)
    return inputs


def run(ctx: SequenceRun) -> list[StageRecord]:
    geometry, scene = ctx.settings.geometry, ctx.scene
    keyed = key_config(geometry)
    key = ctx.cache.key("geometry", keyed, geometry_key_inputs(ctx))

    def work(d: Path) -> dict:
        from trase.devices import peak_memory_mib, reset_peak_memory, resolve_device
        from trase.reconstruct import reconstruct
        from trase.render_views import evaluate_images

        src = geometry.source
        device = resolve_device(geometry.train.device) if src == "reconstruct" else "cpu"
        reset_peak_memory(device)
        if src == "ground-truth":
            shutil.copyfile(synthetic_truth(scene).geometry_path, d / "geometry.npz")
        elif src == "import":
            if not geometry.model_dir:
                raise ConfigError("geometry.source=import needs --set geometry.model_dir=PATH")
            shutil.copytree(geometry.model_dir, d / "model", dirs_exist_ok=True)
        elif src == "reconstruct":
            reconstruct(scene.train, scene.points, scene.point_colors, geometry.train, d / "model",
                        resume=True, progress=ctx.progress)
        else:
            raise ConfigError(f"--set geometry.source={src}: choose {', '.join(SOURCES)}")
        gaussians, deformation = load_geometry(d)
        # the held-out views composited over the background the reconstruction trained on, at
        # the near plane their cameras carry (benchmark.pipeline.context.render_near)
        bg = (1.0, 1.0, 1.0) if geometry.train.white_background else None
        info = {"source": src, "n_gaussians": int(gaussians.num_gaussians), "test_psnr": None,
                "motion": "dynamic" if deformation is not None else "static (plain 3DGS, no deformation network)"}
        if src == "reconstruct":
            from trase.convergence import STOP_FILE, read_summary

            stopping = read_summary(d / "model" / STOP_FILE)  # stop_interval > 0: the checks, where it stopped
            if stopping is not None:
                info["stopping"] = stopping
        static = getattr(deformation, "static", None)  # trase.static_gaussians: rows that skip the network
        if static is not None:
            info["static_gaussians"] = int(static.sum())
        for split, views in (("test", scene.test), ("validation", scene.validation)):
            if views:
                m = evaluate_images(gaussians, deformation, views, bg)
                info.update({f"{split}_psnr": round(m["psnr"], 3), f"{split}_ssim": round(m["ssim"], 4)})
        peak = peak_memory_mib(device)
        return {**info, **({"peak_gpu_mib": peak} if peak is not None else {})}

    return [ctx.cache.run("geometry", key, work, keyed)]
