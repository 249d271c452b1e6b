"""Stage ``geometry``: the frozen gaussians and deformation every method segments
(reconstructed with Deformable-3DGS, the synthetic scene's truth, or an imported model)."""

from __future__ import annotations

import shutil
from pathlib import Path

from benchmark.cache import StageRecord
from benchmark.config import ConfigError, typed
from benchmark.pipeline.context import SequenceRun, load_geometry, synthetic_truth

SOURCES = ("reconstruct", "ground-truth", "import")


def run(ctx: SequenceRun) -> list[StageRecord]:
    gcfg, scene = ctx.cfg["geometry"], ctx.scene
    key = ctx.cache.key("geometry", gcfg, {"scene": ctx.scene_key})

    def work(d: Path) -> dict:
        from trase.reconstruct import ReconstructionConfig, evaluate_psnr, reconstruct

        src = gcfg["source"]
        if src == "ground-truth":
            shutil.copyfile(synthetic_truth(scene).geometry_path, d / "geometry.npz")
        elif src == "import":
            if not gcfg.get("model_dir"):
                raise ConfigError("geometry.source=import needs --set geometry.model_dir=PATH")
            shutil.copytree(gcfg["model_dir"], d / "model", dirs_exist_ok=True)
        elif src == "reconstruct":
            rcfg = typed(ReconstructionConfig, gcfg["train"], "geometry.train")
            reconstruct(scene.train, scene.points, scene.point_colors, rcfg, d / "model",
                        resume=True, progress=ctx.progress)
        else:
            raise ConfigError(f"--set geometry.source={src}: choose {', '.join(SOURCES)}")
        gaussians, deformation = load_geometry(d)
        psnr = evaluate_psnr(gaussians, deformation, scene.test) if scene.test else None
        return {"source": src, "n_gaussians": int(gaussians.num_gaussians),
                "test_psnr": None if psnr is None else round(float(psnr), 3)}

    return [ctx.cache.run("geometry", key, work, gcfg)]
