"""Stage ``evaluate``: predicted masks at every test view (pred/*.png), both metric versions,
the oracle, every click set's score, cluster pictures; cached like the other stages, so a
rerun of a finished config renders nothing."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from benchmark.cache import StageRecord
from benchmark.io import atomic_directory
from benchmark.pipeline.context import SequenceRun, jsonable
from benchmark.pipeline.prompts import PROMPTS_FILE, load_prompts
from benchmark.scoring import metric_version, read_mask, read_official_ground_truth, score_masks
from trase.io import atomic_write_text

OUTPUT_DIRS = ("pred", "clusters", "command")  # copied into the run's directory, where the stage has them
N_SHOWN = 8  # test views rendered with cluster colours (and cluster id maps for benchmark.results.stability)


def render_clusters(fitted, camera) -> np.ndarray:
    """A view rendered with one colour per cluster -> uint8 [H, W, 3] (trase.visualize)."""
    from trase.edit import EditableModel
    from trase.visualize import Painter

    model = EditableModel(fitted.gaussians, fitted.deformation, fitted.labels, fitted.keep)
    return Painter(model).render(camera, "clusters")


def _click_list(clicks) -> list[list[float]]:
    return [[c.view_index, round(c.u, 1), round(c.v, 1)] for c in clicks]


def score_click_sets(predictor, prompts, gts: list[np.ndarray], names: list[str], first: dict,
                     protocol) -> dict | None:
    """Official mIoU of every click set (benchmark.protocol.prompts), each after the robot user
    where the protocol corrects (benchmark.pipeline.corrective) -> per set (its first clicks,
    its corrections, the cluster each click chose, the clusters chosen, mIoU) and median /
    worst / best; None with a single set. Set 0 is the run's own: ``first`` (its entry, already
    scored); a set choosing clusters already rendered reuses their masks (``predictor``)."""
    from benchmark.pipeline.corrective import click_dicts, correct

    sets = prompts.click_sets()
    if len(sets) < 2:
        return None
    out = [first]
    for j, p in enumerate(sets[1:], start=1):
        entry: dict = {"set": j, "clicks": _click_list(p.clicks)}
        clicks = list(p.clicks)
        if protocol.corrections > 0:
            run = correct(predictor, clicks, gts, protocol)
            clicks = run.clicks
            entry["corrections"] = click_dicts(clicks[run.n_first:])
        preds, selected, per_click = predictor.masks(clicks)
        if selected is not None:
            entry |= {"click_clusters": per_click, "selected": selected}
        entry["miou"] = score_masks(dict(zip(names, preds)), dict(zip(names, gts)), "official").miou
        out.append(entry)
    scores = np.array([e["miou"] for e in out], dtype=float)
    return {"n": len(out), "median": float(np.median(scores)), "worst": float(scores.min()),
            "best": float(scores.max()), "sets": out,
            "note": "official mIoU per click set; set 0 gives the run's score"}


# in every evaluate stage's key: a stage scored by older rules of a metric is not reused
METRICS_KEY = {"metrics": [metric_version("v1"), metric_version("official")]}


def read_ground_truths(gt_paths: list[Path]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The test frames' ground truths, each read once -> (binarised bool [H, W], as stored). The
    official metric reads them as stored, as the public script does (its accuracy compares a
    0/1 prediction with the stored values; its IoU equals the binarised one's)."""
    return [read_mask(p) for p in gt_paths], [read_official_ground_truth(p) for p in gt_paths]


def score_predictions(names: list[str], preds: list, gts: list[np.ndarray], stored: list[np.ndarray]):
    """Masks [H, W] bool of the test frames ``names`` against their ground truths
    (``read_ground_truths``) -> (v1 scores, official scores)."""
    by_name = dict(zip(names, preds))
    return score_masks(by_name, dict(zip(names, gts)), "v1"), score_masks(by_name, dict(zip(names, stored)), "official")


def segment_prompts(method, fitted, scene, prompts, protocol, gts: list[np.ndarray], stored: list[np.ndarray],
                    names: list[str]):
    """The run's masks at every test view under the prompt protocol -> (predictor, masks,
    clusters selected, cluster per click, the corrective summary or None). The first clicks
    alone where the protocol does not correct (``prompts.corrections`` 0)."""
    from benchmark.pipeline.corrective import Predictor, correct, score_curve

    predictor = Predictor(method, fitted, scene, prompts)
    if protocol.corrections == 0:
        preds = method.segment(fitted, scene, prompts)
        selected = list(fitted.stats.get("selected_clusters", []))
        if predictor.by_clusters:  # the other click sets reuse these masks
            predictor.rendered[(None, tuple(selected))] = preds
        return predictor, preds, selected, fitted.stats.get("click_clusters"), None
    run = correct(predictor, list(prompts.clicks), gts, protocol)
    summary, (preds, selected, per_click) = score_curve(predictor, run, names, stored)
    summary["target"] = float(protocol.correction_target)
    if selected is None:  # a method that does not select clusters records its own
        selected, per_click = list(fitted.stats.get("selected_clusters", [])), fitted.stats.get("click_clusters")
    return predictor, preds, selected, per_click, summary


def evaluate(method, fitted, scene, prompts, directory: Path, protocol) -> dict:
    """Predicted masks for every test view under the prompt ``protocol`` (the run's
    PromptProtocol) -> ``directory``/pred/*.png and clusters/, and the scores (v1 and official,
    as dicts), the corrective clicks and curve, oracle, scores of the other click sets, model
    facts."""
    import cv2

    from benchmark.results.stability import geometry_checksum, save_cluster_maps
    from trase.checkpoint import model_storage

    names = [f"{i:05d}" for i in range(len(scene.test))]
    gts, stored = read_ground_truths(scene.gt_masks)
    text = None
    if protocol.source == "text":
        from benchmark.pipeline.text_prompts import segment_text

        preds, selected, text = segment_text(method, fitted, scene, protocol)
        predictor, per_click, corrective = None, None, None
    else:
        predictor, preds, selected, per_click, corrective = segment_prompts(method, fitted, scene, prompts, protocol,
                                                                            gts, stored, names)
    if len(preds) != len(scene.test):
        raise RuntimeError(f"{method.name}.segment returned {len(preds)} masks for {len(scene.test)} test views")
    v1, official = score_predictions(names, preds, gts, stored)
    with atomic_directory(directory / "pred") as d:
        for n, m in zip(names, preds):
            cv2.imwrite(str(d / f"{n}.png"), m.astype(np.uint8) * 255)
    shown = names[:: max(1, len(names) // N_SHOWN)][:N_SHOWN]
    with atomic_directory(directory / "clusters") as d:
        for n in shown:
            rgb = render_clusters(fitted, scene.test[names.index(n)].camera)
            cv2.imwrite(str(d / f"{n}.png"), rgb[..., ::-1])
        if fitted.gaussians is not None:  # for agreement between seeds (benchmark.results.stability)
            save_cluster_maps(d, fitted, {n: scene.test[names.index(n)].camera for n in shown})
    first = {"set": 0, "clicks": _click_list(prompts.clicks), "miou": official.miou}
    if corrective is not None:
        first["corrections"] = corrective["corrections"]
        # the run's clicks as a prompts file: the first ones, then the robot user's
        atomic_write_text(directory / PROMPTS_FILE, json.dumps(
            prompts.to_dict() | {k: corrective[k] for k in ("corrections", "undone")}, indent=1))
    if per_click is not None:
        first |= {"click_clusters": list(per_click), "selected": selected}
    out = {
        "v1": v1.to_dict(),
        "official": official.to_dict(),
        "selected": selected,
        "click_clusters": per_click,
        "corrective": corrective,
        "text": text,
        "click_sets": score_click_sets(predictor, prompts, gts, names, first, protocol) if predictor else None,
        "oracle": None,
        "n_gaussians": int(fitted.features.shape[0]),
        "n_clusters": int(fitted.stats.get("n_clusters", 0)),
        "feature_space": fitted.stats.get("feature_space"),
        # the model itself (gaussians + features + deformation, float32), as the paper's storage
        "geometry_checksum": geometry_checksum(fitted.gaussians) if fitted.gaussians is not None else None,
        "storage": model_storage(fitted.gaussians, fitted.deformation, int(fitted.features.shape[1]))
        if fitted.gaussians is not None else None,
    }
    bound = method.segment_oracle(fitted, scene, gts)
    if bound is not None:
        opreds, oclusters = bound
        oracle = score_masks(dict(zip(names, opreds)), dict(zip(names, gts)), "v1").to_dict()
        out["oracle"] = {k: oracle[k] for k in ("miou", "macc", "pooled_iou")} | {
            "clusters": [int(c) for c in oclusters],
            "note": "upper bound: clusters chosen with the ground truth; not the method's score"}
    return jsonable(out)


def prompt_key(protocol, scene=None) -> dict:
    """The prompt protocol's part of the evaluate stage's key: the text protocol's settings where
    it reads text, else the corrective one's (every setting that changes the robot's clicks; the
    retry settings only where they act, so runs without them keep their keys); none for the first
    clicks alone, so single-click stages keep their keys."""
    from benchmark.protocol.corrective import PROTOCOL_VERSION

    if protocol.source == "text":
        from benchmark.pipeline.text_prompts import text_key

        return text_key(protocol, scene)
    if protocol.corrections == 0:
        return {}
    radius, tries = float(protocol.correction_undone_radius), int(protocol.correction_region_tries)
    retry = {"undone_radius": radius, **({"region_tries": tries} if tries else {})} if radius else {}
    return {"corrective": {"version": PROTOCOL_VERSION, "corrections": int(protocol.corrections),
                           "target": float(protocol.correction_target),
                           "check_frames": int(protocol.correction_check_frames),
                           **({"min_gain": float(protocol.correction_min_gain)} if protocol.correction_min_gain else {}),
                           **retry}}


def run(ctx: SequenceRun) -> list[StageRecord]:
    from benchmark.methods import FittedModel

    fit_rec, prompts_rec = ctx.records["fit"], ctx.records["prompts"]
    protocol = ctx.settings.prompts
    key = ctx.cache.key("evaluate", {"method": ctx.method.name, **METRICS_KEY, **prompt_key(protocol, ctx.scene)},
                        {"fit": fit_rec.key, "prompts": prompts_rec.key, "gt": ctx.gt_key})

    def work(d: Path) -> dict:
        from trase.memoised_deformation import memoised

        gaussians, deformation = ctx.geometry
        # every test view is rendered many times over (click sets, oracle, pictures): offsets once per time
        deformation = memoised(deformation, gaussians.means) if gaussians is not None else deformation
        fitted = FittedModel.load(fit_rec.path, gaussians, deformation, ctx.method.settings_class())
        prompts, _ = load_prompts(prompts_rec)
        return evaluate(ctx.method, fitted, ctx.scene, prompts, d, protocol)

    return [ctx.cache.run("evaluate", key, work, {"method": ctx.method.name})]


def copy_outputs(rec: StageRecord, run_dir: Path) -> None:
    """The evaluation's pictures and predicted masks into the run's directory (each directory
    replaced whole, never half-written), and its prompts.json: the first clicks and the robot
    user's."""
    import shutil

    if (rec.path / PROMPTS_FILE).is_file():  # the corrective protocol's clicks
        atomic_write_text(run_dir / PROMPTS_FILE, (rec.path / PROMPTS_FILE).read_text())
    for name in OUTPUT_DIRS:
        if not (rec.path / name).is_dir():  # clusters: not of a command method; command: only of one
            continue
        with atomic_directory(run_dir / name) as d:
            shutil.copytree(rec.path / name, d, dirs_exist_ok=True)
