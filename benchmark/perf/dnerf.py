"""``trase-bench perf dnerf --scene DIR [--scene DIR ...]``: ``trase-bench fit`` on D-NeRF scenes
as published (no preparation), measured beside the geometry's published figures.

Per scene: the fit at half size (``capture.image_scale=2``, scaled on the fly), black background
(Deformable-3DGS's protocol), the test split held out (``--holdout layout``), the validation
split measured and never trained on; then the object is selected in the middle training view
through ``trase-bench select``, by one click (the deepest interior pixel of its alpha) and by
its alpha as a mask prompt (``--mask``), and the selections' masks at the held-out views are
scored against their alpha (the exact ground truth of "the object" on D-NeRF). Printed: test
PSNR / SSIM and validation PSNR beside Deformable-3DGS's published test PSNR / SSIM / LPIPS
(benchmark/data/published/deformable3dgs_dnerf.csv: full resolution, 40k iterations on a GPU,
so a like-for-like row only under the same settings), the foreground IoU (mean and worst view,
each prompt) and the fit's stage times. Settings are compared on the validation views.

Scenes: ``--scene`` folders (the eight D-NeRF scenes keep their folder names: hook, mutant,
...), else every such folder under $TRASE_DNERF.
"""

from __future__ import annotations

import json
import os
import time
from importlib import resources
from pathlib import Path

import numpy as np

SCENES = ("hellwarrior", "mutant", "hook", "bouncingballs", "lego", "trex", "standup", "jumpingjacks")
QUICK_SET = ["geometry.train.iterations=60", "method.features.iterations=30"]


def published() -> dict[str, dict]:
    """scene -> {name, psnr, ssim, lpips_vgg} of Deformable-3DGS's Table 1 (package data)."""
    import csv

    path = resources.files("benchmark") / "data" / "published" / "deformable3dgs_dnerf.csv"
    with path.open() as f:
        return {r["scene"]: {"name": r["name"], **{k: float(r[k]) for k in ("psnr", "ssim", "lpips_vgg")}}
                for r in csv.DictReader(f)}


def default_scenes() -> list[Path]:
    root = os.environ.get("TRASE_DNERF")
    return [Path(root) / s for s in SCENES if (Path(root) / s).is_dir()] if root else []


def unavailable() -> str | None:
    if not default_scenes():
        return "no D-NeRF scenes: pass --scene DIR (or set TRASE_DNERF to the folder holding them)"
    return None


def foreground_click(alpha: np.ndarray) -> tuple[int, int]:
    """(x, y) of the deepest interior pixel of alpha >= 0.5 (the click on the object)."""
    import cv2

    m = (alpha >= 0.5).astype(np.uint8)
    if not m.any():
        raise ValueError("the view's alpha outlines nothing to click on")
    d = cv2.distanceTransform(m, cv2.DIST_L2, 3)
    y, x = np.unravel_index(int(np.argmax(d)), d.shape)
    return int(x), int(y)


def read_alpha(path: Path) -> np.ndarray:
    """[H, W] float alpha in [0, 1] of an RGBA image (8 or 16 bit)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.ndim != 3 or img.shape[2] != 4:
        raise ValueError(f"{path}: no alpha channel to score the foreground against")
    return img[:, :, 3].astype(np.float64) / (255.0 if img.dtype == np.uint8 else 65535.0)


def _alpha_ious(views: list[dict], masks: dict) -> dict:
    """{"per_view", "mean", "worst"}: IoU of each view's selection mask against its alpha >= 0.5."""
    ious = {}
    for t in views:
        gt = read_alpha(Path(t["image"])) >= 0.5
        pred = masks[t["name"]]
        union = int((gt | pred).sum())
        ious[t["name"]] = 1.0 if union == 0 else float((gt & pred).sum()) / union
    vals = list(ious.values())
    return {"per_view": ious, "mean": float(np.mean(vals)) if vals else None,
            "worst": float(np.min(vals)) if vals else None}


def foreground_iou(fit_dir: Path, echo=print) -> dict:
    """The object selected in the middle training view, scored against the alpha of every
    held-out view: by one click (its deepest interior pixel; the top-level keys) and by its
    alpha as a 2D mask prompt (``"mask"``: the clusters the object's silhouette covers, what a
    text prompt's Grounded-SAM mask would give)."""
    from benchmark.captures.select import select_clicks

    views = json.loads((fit_dir / "views.json").read_text())
    v = views["train"][len(views["train"]) // 2]
    x, y = foreground_click(read_alpha(Path(v["image"])))
    by_click = select_clicks(fit_dir, [f"{v['name']}:{x},{y}"], fit_dir / "selection")
    by_mask = select_clicks(fit_dir, [], fit_dir / "selection-mask", masks=[f"{v['name']}:{v['image']}"])
    return {"click": f"{v['name']}:{x},{y}", "clusters": by_click["clusters"],
            **_alpha_ious(views["test"], by_click["masks"]),
            "mask": {"prompt": f"{v['name']}:{v['image']}", "clusters": by_mask["clusters"],
                     **_alpha_ious(views["test"], by_mask["masks"])}}


def test_lpips(fit_dir: Path, scene_dir: Path, sets: list[str], lpips) -> float:
    """Mean LPIPS of the fitted model's renders of the held-out views (read as the fit read them)."""
    from benchmark.captures import CaptureOptions, load_capture
    from benchmark.config import merge, parse_overrides, typed
    from benchmark.pipeline.context import recorded_render_near
    from trase.checkpoint import load_model
    from trase.render_views import evaluate_images

    rec = json.loads((fit_dir / "fit.json").read_text())
    capture = merge(CaptureOptions(holdout="layout").to_dict(), parse_overrides(sets).get("capture", {}), "capture.")
    scene = load_capture(scene_dir, typed(CaptureOptions, capture, "capture"))
    g, d = load_model(fit_dir / "model")
    train = rec["config"]["geometry"]["train"]
    bg = (1.0, 1.0, 1.0) if train["white_background"] else None
    return evaluate_images(g, d, scene.test, bg, ssim_too=False, lpips=lpips,
                           near=recorded_render_near(rec["config"]))["lpips"]


def run(quick: bool = False, echo=print, out_dir: Path | None = None, scenes: list | None = None,
        image_scale: int = 2, overrides: list[str] | None = None, lpips_weights: str | None = None) -> dict:
    """``lpips_weights``: a folder with torchvision's ``vgg16-397923af.pth`` and the lpips
    package's ``vgg.pth`` (trase.lpips); without it LPIPS is not measured."""
    from benchmark.captures.fit import FitOptions, fit_capture

    lpips = None
    if lpips_weights:
        from trase.lpips import LPIPS

        lpips = LPIPS.from_files(Path(lpips_weights) / "vgg16-397923af.pth", Path(lpips_weights) / "vgg.pth")

    scenes = [Path(s) for s in (scenes or default_scenes())]
    if not scenes:
        raise ValueError(unavailable())
    out_dir = Path(out_dir or "perf-out") / "dnerf"
    pub = published()
    rows = []
    for scene in scenes:
        sets = [f"capture.image_scale={image_scale}", *(QUICK_SET if quick else []), *(overrides or [])]
        t0 = time.perf_counter()
        fit_json = fit_capture(FitOptions(scene, out_dir / scene.name, holdout="layout", overrides=sets,
                                          cache_dir=out_dir / ".cache", progress=False))
        seconds = time.perf_counter() - t0
        rec = json.loads(fit_json.read_text())
        fg = foreground_iou(fit_json.parent, echo)
        if lpips is not None:
            rec.setdefault("image_measures", {})["test_lpips"] = round(test_lpips(fit_json.parent, scene, sets, lpips), 4)
        row = {"scene": scene.name, "settings": sets, "measures": rec.get("image_measures", {}), "foreground_iou": fg, "fit_seconds": round(seconds, 1),
               "stage_seconds": {k: s.get("seconds") for k, s in rec["stages"].items()},
               "n_gaussians": rec["n_gaussians"], "published": pub.get(scene.name)}
        rows.append(row)
        echo(_line(row))
    echo("")
    echo(render_table(rows))
    return {"rows": rows}


def _line(row: dict) -> str:
    m, fg = row["measures"], row["foreground_iou"]
    return (f"{row['scene']}: test PSNR {m.get('test_psnr', float('nan')):.2f} dB, SSIM {m.get('test_ssim', float('nan')):.4f}"
            f"; validation PSNR {m.get('validation_psnr', float('nan')):.2f} dB; foreground IoU: one click {fg['mean']:.3f} "
            f"(worst {fg['worst']:.3f}), mask prompt {fg['mask']['mean']:.3f} (worst {fg['mask']['worst']:.3f}); "
            f"fit {row['fit_seconds']:.0f} s, {row['n_gaussians']} gaussians")


def render_table(rows: list[dict]) -> str:
    """The scenes beside Deformable-3DGS's published row (markdown)."""
    lines = [("| scene | test PSNR (dB) | test SSIM | test LPIPS (VGG) | validation PSNR | published PSNR / SSIM / "
              "LPIPS (VGG) | PSNR gap | foreground IoU, one click: mean / worst | foreground IoU, mask prompt: mean / worst "
              "| fit (s) |"), "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        m, p, fg = r["measures"], r["published"], r["foreground_iou"]
        ours = m.get("test_psnr")
        pub = f"{p['psnr']:.2f} / {p['ssim']:.4f} / {p['lpips_vgg']:.4f}" if p else "—"
        gap = f"{ours - p['psnr']:+.2f}" if p and ours is not None else "—"
        lp = f"{m['test_lpips']:.4f}" if m.get("test_lpips") is not None else "— (no weights)"
        lines.append(f"| {p['name'] if p else r['scene']} | {ours:.2f} | {m.get('test_ssim', float('nan')):.4f} | {lp} | "
                     f"{m.get('validation_psnr', float('nan')):.2f} | {pub} | {gap} | "
                     f"{fg['mean']:.3f} / {fg['worst']:.3f} | {fg['mask']['mean']:.3f} / {fg['mask']['worst']:.3f} | "
                     f"{r['fit_seconds']:.0f} |")
    return "\n".join(lines)
