"""What the figures pages share: the formats and their names, the data file's schema, how a
figure is written (mean ± std), and the marks of cells whose runs came from another instruction
set than the rest (benchmark.results.figures, benchmark.results.figures_methods)."""

from __future__ import annotations

from benchmark.errors import UserError

FORMATS = ("nerfds", "hypernerf", "neu3d", "immersive", "technicolor")
GEOMETRIES = ("reconstruct", "ground-truth")
NAMES = {"nerfds": "NeRF-DS", "hypernerf": "HyperNeRF", "neu3d": "Neu3D", "immersive": "Immersive",
         "technicolor": "Technicolor"}
SCHEMA = "trase-bench/figures/1"
SINGLE_CLICK_NOTE = ("° runs of the first clicks alone (made before the corrective protocol, or with "
                     "`prompts.corrections=0`): their mIoU is the single-click score.")


def ms(st: dict | None, digits: int = 3) -> str:
    if not st:
        return "—"
    s = f"{st['mean']:.{digits}f}"
    return s + (f" ± {st['std']:.{digits}f}" if st.get("std") is not None else "")


def mean_std(values: list[float], digits: int = 2) -> str:
    import numpy as np

    if not values:
        return "—"
    v = np.asarray(values, float)
    return f"{v.mean():.{digits}f}" + (f" ± {v.std(ddof=1):.{digits}f}" if v.size > 1 else "")


def check_schema(data: dict) -> None:
    if data.get("schema") != SCHEMA:
        raise UserError(f"figures data: schema {data.get('schema')!r}, expected {SCHEMA}")


def machine_line(data: dict) -> str:
    """Where the figures were measured: cores, processor, the instruction sets of the runs."""
    m = data["machine"]
    isa = m.get("instruction_sets") or []
    line = f"{m.get('cpus', '?')} CPU cores, {m.get('processor', '?')}"
    if len(isa) == 1:
        line += f"; {isa[0]}"
    elif isa:
        line += f"; runs from {len(isa)} instruction sets: " + " / ".join(isa)
    return line


MARKS = ("†", "‡", "§", "¶")


def row_isa(row: dict, data: dict) -> tuple[str, ...]:
    """The instruction sets of a row's runs (its file's for rows written before rows kept them)."""
    return tuple(row.get("instruction_sets") or data["machine"].get("instruction_sets") or ())


def by_share(rows: list[dict], key) -> list:
    """The rows' values of ``key(row)``, most cells first; on a tie the earlier measured first
    (rows without a date are the oldest), so a re-measurement never unmarks what it is merged into."""
    first = {}
    for r in rows:
        k = key(r)
        first[k] = min(first.get(k, r.get("date") or ""), r.get("date") or "")
    count = lambda k: sum(key(r) == k for r in rows)
    return sorted(first, key=lambda k: (-count(k), first[k]))


def marks_for(others: list, symbols: tuple[str, ...]) -> dict:
    """A mark per value in ``others``: the symbols in turn, doubled once they run out."""
    return {k: symbols[i % len(symbols)] * (1 + i // len(symbols)) for i, k in enumerate(others)}


def isas_by_share(rows: list[dict], data: dict) -> list[tuple[str, ...]]:
    """The rows' instruction sets, most cells first (``by_share``)."""
    return by_share(rows, lambda r: row_isa(r, data))


def isa_marks(rows: list[dict], data: dict) -> dict[tuple[str, ...], str]:
    """A mark per instruction set other than the main one (``isas_by_share``): cells of merged
    re-measurements (``figures --update``) say that their runs came from another machine."""
    return marks_for(isas_by_share(rows, data)[1:], MARKS)


def isa_note(rows: list[dict], data: dict, marks: dict) -> list[str]:
    """A line per mark: the instruction set and dates of the marked cells' runs (their code's
    commits are in the data file)."""
    if not marks:
        return []
    name = lambda isa: " / ".join(isa) or "unrecorded"
    main = isas_by_share(rows, data)[0]
    out = []
    for isa, mark in marks.items():
        mine = [r for r in rows if row_isa(r, data) == isa]
        dates = sorted({r["date"] for r in mine if r.get("date")})
        out.append(f"{mark} runs computed with {name(isa)}"
                   + (f", on {', '.join(dates)}" if dates else "") + f"; the unmarked cells' with {name(main)}.")
    return out
