"""The prompts part of a run's report (benchmark.results.report): the clicks drawn on the frames
they were made in, the score after each click of the robot user (benchmark.pipeline.corrective),
and every click set's clicks and score."""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from benchmark.results.report_images import (
    MAX_FRAMES_SHOWN,
    img_tag,
    overlay,
    png,
    read_rgb,
    score_plot,
)
from benchmark.scoring import read_mask

PALETTE = [(255, 200, 0), (0, 220, 255), (255, 80, 200), (120, 255, 120), (255, 140, 60)]  # other click sets


def _by_frame(record: dict) -> dict[int, list[tuple[dict, object, int]]]:
    """Per test frame: (click, its label, its kind) of the clicks made in it; kind 0 a first
    click of the run (label: the cluster it chose), -1 a corrective one kept, -2 one undone
    (label: its number among the clicks spent, the curve's x), j >= 1 click set j's first click."""
    prompts = record.get("prompts") or {}
    first = prompts.get("clicks", [])
    corrections = (record.get("corrective") or {}).get("corrections", [])
    chosen = record.get("click_clusters") or [None] * (len(first) + len(corrections))
    by_frame: dict[int, list] = {}
    for c, k in zip(first, chosen):
        by_frame.setdefault(int(c["view_index"]), []).append((c, k, 0))
    for n, c in enumerate(corrections, start=len(first) + 1):  # "n": the click's number among those spent
        by_frame.setdefault(int(c["view_index"]), []).append((c, c.get("n", n), -1))
    for c in (record.get("corrective") or {}).get("undone", []):
        by_frame.setdefault(int(c["view_index"]), []).append((c, c.get("n"), -2))
    for j, cs in enumerate(prompts.get("alternatives", []), start=1):
        for c in cs:
            by_frame.setdefault(int(c["view_index"]), []).append((c, None, j))
    return by_frame


def _draw(img: np.ndarray, c: dict, label, kind: int, scale: int) -> None:
    import cv2

    pt = (int(c["u"] * scale), int(c["v"] * scale))
    font = (cv2.FONT_HERSHEY_SIMPLEX, 0.35 * scale)
    if kind == 0:
        cv2.circle(img, pt, 3 * scale, (255, 255, 255), max(1, scale // 2))
        cv2.putText(img, "none" if label is None or label < 0 else str(label), (pt[0] + 3 * scale, pt[1]),
                    *font, (255, 255, 255), 1)
    elif kind == -2:  # undone: a grey cross, numbered
        cv2.drawMarker(img, pt, (160, 160, 160), cv2.MARKER_TILTED_CROSS, 5 * scale, max(1, scale // 2))
        cv2.putText(img, "" if label is None else str(label), (pt[0] + 3 * scale, pt[1]), *font, (160, 160, 160), 1)
    elif kind < 0:  # corrective: green ring positive, red ring negative, numbered in click order
        colour = (60, 255, 60) if c.get("positive", True) else (255, 60, 60)
        cv2.circle(img, pt, 3 * scale, colour, max(1, scale // 2))
        cv2.putText(img, f"{'+' if c.get('positive', True) else '-'}{label}", (pt[0] + 3 * scale, pt[1]),
                    *font, colour, 1)
    else:
        cv2.circle(img, pt, max(1, scale), PALETTE[(kind - 1) % len(PALETTE)], -1)


def click_tiles(record: dict, frames: list[dict]) -> list[str]:
    """One image per prompted frame: the run's first clicks (white rings, labelled with the
    cluster each chose), its corrective clicks (green +n / red -n rings, n the click's number)
    and the other click sets' first clicks (small dots, one colour per set)."""
    import cv2

    by_frame = _by_frame(record)
    tiles = []
    for i in sorted(by_frame)[:MAX_FRAMES_SHOWN]:
        if not 0 <= i < len(frames):
            continue
        f = frames[i]
        gt = read_mask(f["gt"])
        img = np.ascontiguousarray(overlay(read_rgb(Path(f["image"]), gt.shape), np.zeros_like(gt), gt))
        scale = max(1, 320 // max(gt.shape))
        img = cv2.resize(img, (gt.shape[1] * scale, gt.shape[0] * scale), interpolation=cv2.INTER_NEAREST)
        for c, label, kind in sorted(by_frame[i], key=lambda x: -x[2]):  # the run's own clicks on top
            _draw(img, c, label, kind, scale)
        own = sum(1 for x in by_frame[i] if x[2] in (0, -1))
        caption = f"frame {f['frame']}: {own} click(s) of the run"
        tiles.append(f"<figure>{img_tag(png(img), caption)}<figcaption>{html.escape(caption)}</figcaption></figure>")
    return tiles


def clicks_plot(corrective: dict) -> bytes:
    """The official mIoU and mAcc over the test frames against the number of clicks, the
    targets of NoC@85 and NoC@90 dashed."""
    curve = corrective["curve"]
    n = [p["clicks"] for p in curve]
    series = [("mIoU", [p["miou"] for p in curve], "o", 4, 1.0), ("mAcc", [p["macc"] for p in curve], ".", 3, 0.7)]
    return score_plot(n, series, "clicks", (5, 2.6), "lower right", hlines=(0.85, 0.90),
                      xticks=range(n[0], corrective["first_clicks"] + corrective["budget"] + 1))


def _corrective_text(record: dict) -> str:
    c = record.get("corrective")
    if not c:
        return "<p>The run's score is its first clicks' (no corrective clicks).</p>"
    curve = c["curve"]
    polarity = "" if c.get("negatives") else " The method takes no negative clicks: positive corrections only."
    undone = len(c.get("undone", []))
    text = (f"The robot user clicked {len(curve) - 1} more time(s) after the {c['first_clicks']} first click(s), "
            f"undoing {undone} that made its click and check frames worse or changed nothing "
            f"(budget {c['budget']}, stopping once every click frame reached IoU {c.get('target', '?')}): mIoU "
            f"{curve[0]['miou']:.4f} after the first clicks, {curve[-1]['miou']:.4f} after {curve[-1]['clicks']}; "
            f"NoC@85 {c['noc@85']}, NoC@90 {c['noc@90']}.{polarity}")
    return f"<p>{html.escape(text)}</p>{img_tag(clicks_plot(c), 'mIoU against clicks')}"


def prompts_section(record: dict) -> str:
    """The report's prompts section: the clicks on their frames, the corrective clicks' curve,
    every click set's clicks and score."""
    return f"""<h2>Prompts</h2><p>White rings: the run's first clicks, labelled with the cluster each chose;
green / red rings: its corrective clicks, positive / negative, numbered as the plot counts clicks; grey crosses:
corrective clicks it undid (they made its click and check frames worse or changed nothing); dots: the other click
sets (the same objects elsewhere in their first frames). Ground truth in blue.</p>
{''.join(click_tiles(record, record.get("frames", [])))}
{_corrective_text(record)}
<table><tr><th>click set</th><th>clicks (frame (u,v))</th><th>corrective clicks</th><th>cluster per click</th>
<th>chosen</th><th>mIoU</th></tr>
{click_set_rows(record)}</table>"""


def click_set_rows(record: dict) -> str:
    """One table row per click set: its first and corrective clicks, clusters and mIoU."""
    sets = (record.get("click_sets") or {}).get("sets", [])
    rows = []
    for e in sets:
        clicks = ", ".join(f"f{c[0]} ({c[1]:.0f},{c[2]:.0f})" for c in e.get("clicks", []))
        fixes = ", ".join(f"{'+' if c.get('positive', True) else '-'}f{c['view_index']} ({c['u']:.0f},{c['v']:.0f})"
                          for c in e.get("corrections", [])) or "—"
        rows.append(f"<tr><td>{e['set']}{' (run)' if e['set'] == 0 else ''}</td><td>{html.escape(clicks)}</td>"
                    f"<td>{html.escape(fixes)}</td>"
                    f"<td>{html.escape(str(e.get('click_clusters', '—')))}</td>"
                    f"<td>{html.escape(str(e.get('selected', '—')))}</td><td>{e['miou']:.4f}</td></tr>")
    return "".join(rows)


