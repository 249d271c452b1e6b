"""The README's one results table: this version's TRASE on each format's built-in synthetic
scene (from the figures data) beside the paper's published TRASE on the real benchmark. The two
are different data and not one comparison: the table says which is which."""

from __future__ import annotations

from benchmark.results.figures_format import NAMES, isa_marks, isa_note, row_isa

SUMMARY_BEGIN = "<!-- SUMMARY:BEGIN (trase-bench figures --write-page README.md; do not edit by hand) -->"
SUMMARY_END = "<!-- SUMMARY:END -->"


def _cell(row: dict | None, key: str) -> str:
    if row is None or not row["summary"].get(key):
        return "—"
    m = row["summary"][key]
    return f"{m['mean']:.3f} ± {m['std']:.3f}"


def published_miou() -> dict[str, float]:
    """The paper's average mIoU of TRASE per benchmark (its Table 1)."""
    from benchmark.results.leaderboard import published_frame

    df = published_frame()
    avg = df[(df["method"] == "trase") & (df["sequence"] == "_average")]
    return {str(r.dataset): float(r.miou) for r in avg.itertuples()}


def render_summary_block(data: dict) -> str:
    """The table from a figures file (``docs/figures.json``) and the published numbers; rows whose
    runs came from other instruction sets than most are marked as on the figures page."""
    rows = {r["format"]: r for r in data["rows"] if r.get("method", "trase") == "trase" and r["geometry"] == "reconstruct"}
    marks = isa_marks(list(rows.values()), data) if rows else {}
    published = published_miou()
    lines = ["| format | built-in scene: mIoU | its oracle | seeds | real benchmark: published mIoU |",
             "|---|---|---|---|---|"]
    for key, name in NAMES.items():
        row, pub = rows.get(key), published.get(key)
        seeds = len(row["summary"]["seeds"]) if row else "—"
        mark = marks.get(row_isa(row, data), "") if row else ""
        lines.append(f"| {name} | {_cell(row, 'miou')}{mark} | {_cell(row, 'oracle')} | {seeds} "
                     f"| {'—' if pub is None else f'{pub:.3f}'} |")
    note = isa_note(list(rows.values()), data, marks)
    return "\n".join(lines + ([""] + note if note else [])) + "\n"


__all__ = ["SUMMARY_BEGIN", "SUMMARY_END", "published_miou", "render_summary_block"]
