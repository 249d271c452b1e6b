"""Per-sequence report: one self-contained HTML page (images embedded) plus its PNGs.

Built only from a run directory, so it can be made long after the run and on another
machine. Layout of a run directory (written by the runner):

    results.json                 metrics, per-frame values, stages, config (benchmark.results.record)
    pred/<frame>.png             predicted masks (0/255)
    clusters/<frame>.png         optional: test view rendered with one colour per cluster
The test images and ground-truth masks are found through ``results["frames"]``.
"""

from __future__ import annotations

import base64
import html
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmark.errors import UserError
from benchmark.io import atomic_write_bytes, atomic_write_text
from benchmark.results.record import load_results
from benchmark.results.report_clicks import prompts_section
from benchmark.results.report_images import (
    MAX_FRAMES_SHOWN,
    img_tag,
    overlay,
    png,
    read_rgb,
    score_plot,
)
from benchmark.results.runs import protocol, protocol_label
from benchmark.scoring import read_mask


def _iou_plot(record: dict) -> bytes:
    frames = record.get("per_frame", [])
    iou = [np.nan if f["iou"] is None else f["iou"] for f in frames]
    acc = [f["acc"] for f in frames]
    return score_plot(range(len(frames)), [("IoU", iou, "o", 3, 1.0), ("accuracy", acc, ".", 3, 0.7)],
                      "test frame", (7, 2.6), "lower left")


def _fmt(x) -> str:
    """A score with four decimals on the report page; "n/a" where there is none."""
    return "n/a" if x is None else f"{x:.4f}"


def _ceiling_objects_notes(c: dict) -> list[str]:
    """The ceiling's per-object holes, the movers' (occluders not of interest) and the
    ceiling's IoU in the frames they touch an object, as sentences; [] where absent."""
    def holes(objs: dict) -> str:
        return ", ".join(f"{name} {100 * o['holes']:.0f}%" for name, o in objs.items() if o.get("holes") is not None)

    out = []
    if holes(c.get("objects") or {}):
        out.append(f"Share of each object's pixels the geometry leaves out (holes): {holes(c['objects'])}.")
    if holes(c.get("movers") or {}):
        out.append(f"Moving objects not of interest, holes: {holes(c['movers'])}.")
    mf = c.get("mover_frames") or {}
    if mf.get("frames"):
        out.append(f"In the {mf['frames']} test frames where one of them touches an object of interest the "
                   f"ceiling's IoU is {_fmt(mf.get('miou'))}; in the other {mf.get('other_frames')}, "
                   f"{_fmt(mf.get('other_miou'))}.")
    return out


def _model_line(record: dict) -> str:
    """The model's size, or what stands for it where the benchmark never saw the model."""
    if record.get("n_gaussians") is None:
        return "The method's model is its own: the benchmark saw only its predicted masks."
    return (f"{record['n_gaussians']} gaussians; model {(record.get('storage') or {}).get('total_mib', 0):.1f} MiB "
            "(gaussians, features and deformation, float32).")


def _seed_section(record: dict, run_dir: Path) -> str:
    """The other seeds of this config beside this run (its sequence directory), with the
    clustering agreement between them."""
    from benchmark.results.runs import find_runs, seed_siblings
    from benchmark.results.stability import format_summary, seed_summary

    try:
        candidates = find_runs(run_dir.parent, warn=lambda m: None)
    except UserError as exc:  # a broken sibling must not stop this run's report
        return f"<p>Other seeds not read: {html.escape(str(exc))}</p>"
    sibs = seed_siblings(record, candidates)
    if len(sibs) < 2:
        return "<p>One seed of this config (run others with <code>--seeds N</code>).</p>"
    fmt = lambda x: "—" if x is None else f"{x:.4f}"
    rows = "".join(
        f"<tr><td>{r['run']['seed']}</td><td>{html.escape(r['run']['name'])}</td>"
        f"<td>{fmt(r['metrics']['official']['miou'])}</td><td>{fmt((r.get('oracle') or {}).get('miou'))}</td>"
        f"<td>{fmt((r.get('ceiling') or {}).get('miou'))}</td><td>{r.get('n_clusters', '—')}</td>"
        f"<td>{html.escape(str(r.get('selected_clusters')))}</td></tr>" for r in sibs)
    summary = format_summary(seed_summary(sibs))
    return (f"<p>{html.escape(summary)} (ARI: adjusted Rand index of the clusterings, per pixel of the "
            "shown test views and, with one geometry, per gaussian; 1 = the same partition)</p>"
            "<table><tr><th>seed</th><th>run</th><th>mIoU</th><th>oracle</th><th>ceiling</th><th>clusters</th>"
            f"<th>chosen</th></tr>{rows}</table>")


def _clip(run_dir: Path, render_clip: Callable[[Path], bytes] | None) -> tuple[str, str]:
    """(html, note): the animated WebP ``render_clip(run_dir)`` makes of the run's selection, or
    why there is none."""
    if render_clip is None:
        return "", "No clip: this report was made without a renderer."
    try:
        data = render_clip(run_dir)
    except Exception as exc:  # the report stands without its clip, and says why
        if not getattr(exc, "user_facing", False):
            raise
        return "", f"No clip: {exc}"
    atomic_write_bytes(run_dir / "report" / "clip.webp", data)
    tag = f'<img alt="clip" src="data:image/webp;base64,{base64.b64encode(data).decode()}">'
    return tag, ""


def _frame_tiles(record: dict, run_dir: Path) -> tuple[list[str], int]:
    """(HTML figures of the shown test frames: overlay and clusters, count of missing images);
    each overlay also written to ``report/overlay_<frame>.png``."""
    frames = record.get("frames", [])
    step = max(1, len(frames) // MAX_FRAMES_SHOWN)
    per_frame = {f["frame"]: f for f in record.get("per_frame", [])}
    tiles, missing_images = [], 0
    for f in frames[::step][:MAX_FRAMES_SHOWN]:
        gt = read_mask(f["gt"])
        pred_path = run_dir / f["pred"] if f.get("pred") else None  # None: an external run's missing frame
        pred = read_mask(pred_path) if pred_path is not None and pred_path.exists() else np.zeros_like(gt)
        if not Path(f["image"]).exists():
            missing_images += 1
        data = png(overlay(read_rgb(Path(f["image"]), gt.shape), pred, gt))
        atomic_write_bytes(run_dir / "report" / f"overlay_{f['frame']}.png", data)
        iou = per_frame.get(f["frame"], {}).get("iou")
        caption = f"{f['frame']}  IoU {'n/a' if iou is None else f'{iou:.3f}'}"
        cluster_png = run_dir / "clusters" / f"{f['frame']}.png"
        extra = img_tag(cluster_png.read_bytes(), "clusters") if cluster_png.exists() else ""
        tiles.append(f"<figure>{img_tag(data, caption)}{extra}<figcaption>{html.escape(caption)}"
                     "</figcaption></figure>")
    return tiles, missing_images


def _external_notes(record: dict) -> list[str]:
    """Where an external run's masks came from and what was missing, as sentences; [] for a
    run of the benchmark's own."""
    ext = record.get("external")
    if not ext:
        return []
    where = f"{ext['layout']} layout" + (f", {ext['iteration_dir']}" if ext.get("iteration_dir") else "")
    out = [(f"Predictions made outside the benchmark: {len(ext['files'])} mask file(s) read from "
            f"{ext['masks_dir']} ({where}), their checksums in results.json.")]
    if ext.get("missing"):
        out.append(f"No prediction for {len(ext['missing'])} test frame(s) ({', '.join(ext['missing'])}): v1 scores "
                   "them as empty, the official metric skips them.")
    if ext.get("extra"):
        out.append(f"Ignored by the official metric (no ground-truth file of that name): {', '.join(ext['extra'])}.")
    return out


def _notes(record: dict, missing_images: int) -> list[str]:
    """What to read beside the score: missing images, the oracle, the geometry's ceiling, an
    external run's source."""
    notes = _external_notes(record)
    if missing_images:
        notes.append(f"{missing_images} test image(s) not found: grey backdrop shown.")
    if record.get("oracle"):
        o = record["oracle"]
        notes.append(f"Oracle cluster selection (upper bound, not the method's score): "
                     f"mIoU {_fmt(o.get('miou'))}, mAcc {_fmt(o.get('macc'))}.")
    if record.get("ceiling"):
        c = record["ceiling"]
        notes.append(f"Geometry ceiling (every gaussian labelled from the training views' instance maps, "
                     f"same rendering rule; what this geometry allows): mIoU {_fmt(c.get('miou'))}.")
        notes += _ceiling_objects_notes(c)
    return notes


def _is_external(record: dict) -> bool:
    return (record.get("run") or {}).get("kind") == "external"


def _clip_section(record: dict, run_dir: Path, render_clip: Callable[[Path], bytes] | None) -> str:
    """The clip of the run's selection; none for external predictions (no model to render)."""
    if _is_external(record):
        return ""
    clip, clip_note = _clip(run_dir, render_clip)
    return f"""<h2>Clip</h2><p>The selected objects tinted over the test views in time order
(<code>trase-bench render --run {html.escape(str(run_dir))} --mode selection --selected</code>).
{html.escape(clip_note)}</p>{clip}"""


def _method_sections(record: dict, run_dir: Path) -> str:
    """Prompts, seeds and stages of a run of the benchmark's own; none for external predictions,
    whose prompts and stages were their maker's."""
    if _is_external(record):
        return ""
    stage_rows = "".join(
        f"<tr><td>{html.escape(name)}</td><td>{s.get('seconds', 0):.1f}</td>"
        f"<td>{s.get('peak_rss_mb', 0):.0f}</td><td>{'cached' if s.get('skipped') else 'run'}</td></tr>"
        for name, s in record.get("stages", {}).items()
    )
    return f"""{prompts_section(record)}
<h2>Seeds</h2>{_seed_section(record, run_dir)}
<h2>Stages</h2><table><tr><th>stage</th><th>seconds</th><th>peak RSS MiB</th><th></th></tr>{stage_rows}</table>
<p>{_model_line(record)}</p>"""


def make_report(run_dir: str | Path, render_clip: Callable[[Path], bytes] | None = None) -> Path:
    """Write ``report.html`` and ``report/*.png`` into ``run_dir``; returns the HTML path.
    ``render_clip``: run folder -> an animated WebP of its selection over its test views
    (benchmark.scene.render.selection_clip; the renderer sits above this module)."""
    run_dir = Path(run_dir)
    record = load_results(run_dir / "results.json")
    tiles, missing_images = _frame_tiles(record, run_dir)
    plot = _iou_plot(record)
    atomic_write_bytes(run_dir / "report" / "per_frame_iou.png", plot)
    m = record["metrics"]
    official = m.get("official", {})
    title = f"{record['method']} on {record['dataset']} / {record['sequence']} ({record['variant']} data)"
    run = record.get("run") or {}
    overrides = " ".join(f"--set {o}" for o in run.get("overrides", [])) or "none"
    run_line = (f"Run {run.get('name', '?')} ({run.get('kind', '?')}; overrides: {overrides}). "
                f"Protocol: {protocol_label(protocol(record))}.")
    notes = _notes(record, missing_images)
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}figure{{display:inline-block;margin:4px}}
figure img{{display:block;max-width:260px}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 8px}}
pre{{background:#f6f6f6;padding:8px;overflow:auto;font-size:12px}}</style></head><body>
<h1>{html.escape(title)}</h1>
<p><b>mIoU {_fmt(official.get('miou', m['miou']))}</b> &middot; mAcc {_fmt(official.get('macc', m['macc']))}
(metric {html.escape(official.get('metric_version', m['metric_version']))}, the public script's rules)
&middot; v1: mIoU {_fmt(m['miou'])}, mAcc {_fmt(m['macc'])}, pooled IoU {_fmt(m['pooled_iou'])}
&middot; {m['n_frames']} test frames</p>
<p>{html.escape(run_line)}</p>
<p>{' '.join(html.escape(n) for n in notes)}</p>
{_clip_section(record, run_dir, render_clip)}
<h2>Test views</h2><p>green: correct object pixels, red: false positives, blue: missed.</p>
{''.join(tiles)}
<h2>Per-frame scores</h2>{img_tag(plot, 'per-frame IoU')}
{_method_sections(record, run_dir)}
<h2>Config</h2><pre>{html.escape(json.dumps(record.get('config', {}), indent=2))}</pre>
<h2>Versions</h2><pre>{html.escape(json.dumps(record.get('versions', {}), indent=2))}</pre>
</body></html>
"""
    out = run_dir / "report.html"
    atomic_write_text(out, page)
    return out
