"""Rank the settings of a selection grid: one row per (method, run name), one column per format,
the official mIoU of each run, the mean over the formats, best first per method.

    python3 scripts/selection_table.py RUNS_DIR [--method M ...]

RUNS_DIR holds runs made on the selection scenes (e.g. seed-1 scenes under --data-root, one
--name per setting, as docs/notes/cpu-constants.md describes); a row lacking a format is ranked
after the complete ones and marked.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

FORMATS = ("nerfds", "hypernerf", "neu3d", "immersive", "technicolor")


def table(runs_dir: Path, methods: list[str] | None = None) -> str:
    cells: dict[tuple[str, str], dict[str, float]] = defaultdict(dict)
    for f in sorted(runs_dir.glob("*/*/*/*/results.json")):
        r = json.loads(f.read_text())
        if methods and r["method"] not in methods:
            continue
        cells[(r["method"], r["run"]["name"])][r["dataset"]] = float(r["metrics"]["official"]["miou"])
    lines = ["| method | setting | " + " | ".join(FORMATS) + " | mean |", "|---|---|" + "---|" * (len(FORMATS) + 1)]
    for method in sorted({m for m, _ in cells}):
        rows = [(name, d) for (m, name), d in cells.items() if m == method]
        rows.sort(key=lambda nd: (len(nd[1]) < len(FORMATS), -sum(nd[1].values()) / max(len(nd[1]), 1)))
        for name, d in rows:
            mean = sum(d.values()) / len(d)
            mark = "" if len(d) == len(FORMATS) else f" ({len(d)} of {len(FORMATS)})"
            lines.append(f"| {method} | {name} | " + " | ".join(f"{d[f]:.3f}" if f in d else "—" for f in FORMATS)
                         + f" | {mean:.3f}{mark} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs_dir", type=Path)
    ap.add_argument("--method", action="append")
    args = ap.parse_args()
    print(table(args.runs_dir, args.method))


if __name__ == "__main__":
    main()
