"""The stages of a command method (benchmark.methods.command), after the benchmark's masks and
prompts:

    command-inputs  the method's input folder (benchmark.methods.command_io)  <- scene, masks, prompts
    command         the command run on it: its output folder and log          <- inputs, the method's settings
    evaluate        its masks as pred/*.png, scored under both metrics        <- command, ground truth

Each is cached like every stage: a rerun does not run the command again, and the input folder
is shared by every command method on the sequence. A command that cannot start, fails, outlives
its timeout or writes no usable masks stops the run with one line naming its log, kept at
``<cache>/command/<key>.failed.log``; its stage directory is removed, so nothing half-made is
reused or recorded.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import cv2
import numpy as np

from benchmark.cache import StageRecord
from benchmark.io import atomic_directory
from benchmark.pipeline.context import SequenceRun, jsonable
from benchmark.pipeline.prompts import load_prompts
from benchmark.pipeline.settings import key_config

LOG = "command.log"
OUTPUT = "output"


def inputs(ctx: SequenceRun) -> list[StageRecord]:
    from benchmark.methods.command_io import LAYOUT_VERSION, write_inputs

    masks_rec, prompts_rec = ctx.records["masks"], ctx.records["prompts"]
    cfg = {"layout": LAYOUT_VERSION}
    key = ctx.cache.key("command-inputs", cfg, {"scene": ctx.scene_key, "masks": masks_rec.key,
                                                "prompts": prompts_rec.key})

    def work(d: Path) -> dict:
        for stale in d.iterdir():  # a partial folder of a killed run: write it anew
            if stale.is_dir() and not stale.is_symlink():
                shutil.rmtree(stale)
            else:
                stale.unlink()
        bp, _ = load_prompts(prompts_rec)
        return write_inputs(ctx.scene, ctx.scene.dataset, masks_rec.path, bp, d)

    return [ctx.cache.run("command-inputs", key, work, cfg)]


def _cache_config(ctx: SequenceRun) -> dict:
    """What the command stage's key hashes: the method's settings (the TOML's content among
    them) without the preset, unless the command reads {preset}."""
    from benchmark.methods.command import uses_placeholder

    settings = ctx.settings.method
    cfg = {"method": key_config(settings)}
    if uses_placeholder(settings, "preset"):
        cfg["preset"] = settings.preset
    return cfg


def run(ctx: SequenceRun) -> list[StageRecord]:
    from benchmark.methods.command import CommandError, fill, workdir_of
    from benchmark.methods.command_io import CAMERAS, PROMPTS, SCENE_DIR, read_outputs
    from benchmark.methods.command_process import command_env, run_logged

    method, settings, scene = ctx.method, ctx.settings.method, ctx.scene
    inputs_rec = ctx.records["command-inputs"]
    cfg = _cache_config(ctx)
    key = ctx.cache.key("command", cfg, {"inputs": inputs_rec.key})
    final = ctx.cache.path("command", key).resolve()
    failed_log = final.with_name(key + ".failed.log")

    def work(d: Path) -> dict:
        d = d.resolve()  # the command runs in its own folder: every path it is given is absolute
        out = d / OUTPUT
        shutil.rmtree(out, ignore_errors=True)  # a killed run's masks are never read
        out.mkdir(parents=True)
        inp = inputs_rec.path.resolve()
        values = {"input": str(inp), "output": str(out), "scene": str(inp / SCENE_DIR),
                  "cameras": str(inp / CAMERAS), "prompts": str(inp / PROMPTS), "dataset": scene.dataset,
                  "sequence": scene.sequence, "preset": settings.preset,
                  "method_dir": str(Path(method.path).resolve().parent)}
        argv = [fill(a, values) for a in settings.command]
        env = command_env({k: fill(v, values) for k, v in settings.env.items()})
        cwd = workdir_of(method.path, settings)
        done = run_logged(argv, cwd, env, float(settings.timeout), d / LOG)
        try:
            if not done.ok:
                raise CommandError(done.problem(float(settings.timeout)))
            masks = read_outputs(out, scene, "its output folder")
        except CommandError as exc:
            with open(d / LOG, "a") as f:
                f.write(f"# failed: {exc}\n")
            os.replace(d / LOG, failed_log)
            shutil.rmtree(d, ignore_errors=True)
            raise CommandError(f"command method {method.name!r} on {scene.dataset}/{scene.sequence}: {exc} "
                               f"(log: {failed_log})") from None
        failed_log.unlink(missing_ok=True)
        return {"command": argv, "workdir": str(cwd), "exit_status": done.status, "seconds": round(done.seconds, 3),
                "timeout": float(settings.timeout), "log": str(final / LOG), "toml": str(Path(method.path).resolve()),
                "toml_sha256": settings.toml_sha256, "n_masks": len(masks)}

    return [ctx.cache.run("command", key, work, cfg)]


def evaluate(ctx: SequenceRun) -> list[StageRecord]:
    """The command's masks scored like any run's (benchmark.pipeline.evaluate's info, with no
    gaussians, clusters, click sets or oracle: the method's model is its own)."""
    from benchmark.methods.command_io import frame_names, read_outputs
    from benchmark.pipeline.evaluate import METRICS_KEY, read_ground_truths, score_predictions

    cmd_rec = ctx.records["command"]
    cfg = {"method": ctx.method.name, "kind": "command"}
    key = ctx.cache.key("evaluate", cfg | METRICS_KEY, {"command": cmd_rec.key, "gt": ctx.gt_key})

    def work(d: Path) -> dict:
        scene = ctx.scene
        preds = read_outputs(cmd_rec.path / OUTPUT, scene)
        names = frame_names(len(scene.test))
        with atomic_directory(d / "pred") as p:
            for n, m in zip(names, preds):
                cv2.imwrite(str(p / f"{n}.png"), m.astype(np.uint8) * 255)
        with atomic_directory(d / "command") as c:
            shutil.copyfile(cmd_rec.path / LOG, c / LOG)
        v1, official = score_predictions(names, preds, *read_ground_truths(scene.gt_masks))
        return jsonable({
            "v1": v1.to_dict(),
            "official": official.to_dict(),
            "selected": [], "click_clusters": None, "click_sets": None, "oracle": None,
            "n_gaussians": None, "n_clusters": None, "feature_space": None, "geometry_checksum": None,
            "storage": None,
        })

    return [ctx.cache.run("evaluate", key, work, cfg)]
