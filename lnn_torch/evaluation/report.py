"""Report formatting, one place for every table the package and its benchmarks write: the cells
(percentages, times capped at a horizon, quartiles, numbers) and Markdown tables.

Pure functions of numbers and strings; nothing here knows a model, a scene or a section.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence


def pct(x: float, digits: int = 3, signed: bool = False) -> str:
    """A fraction as a percentage with ``digits`` significant digits (``0.0007`` -> ``0.07 %``;
    ``signed``: with its sign, ``+0.07 %``); ``n/a`` for NaN."""
    return "n/a" if x != x else f"{100 * x:{'+' if signed else ''}.{digits}g} %"


def number(x: float, fmt: str = ".4g") -> str:
    """A number in ``fmt``; ``n/a`` for NaN, ``inf``/``-inf`` as such."""
    if x != x:
        return "n/a"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return format(x, fmt)


def time_cell(t: float, cap: float) -> str:
    """A time in s; one at the horizon ``cap`` (never exceeded within it) reads ``≥ cap``."""
    return f"≥ {cap:g}" if t >= cap - 1e-9 else f"{t:.2f}"


def quartile_cell(d: dict, cap: float) -> str:
    """``median [q25, q75]`` of times (a dict with those keys, as ``metrics.quartiles`` gives);
    ``≥ cap (never exceeded)`` where all three are at the horizon ``cap``."""
    if d["q25"] >= cap - 1e-9:
        return f"≥ {cap:g} (never exceeded)"
    return f"{time_cell(d['median'], cap)} [{time_cell(d['q25'], cap)}, {time_cell(d['q75'], cap)}]"


def table_row(cells: Iterable[object]) -> str:
    """One Markdown table row: ``| a | b |`` of the cells as given (``str()`` of each, no escaping;
    an empty cell is ``| |``)."""
    return "|" + "".join(f" {c} |" if str(c) else " |" for c in cells)


def table_header(header: Sequence[object]) -> list[str]:
    """The two lines that open a Markdown table: the ``header`` cells and the ``|---|`` rule under them."""
    return [table_row(header), "|" + "---|" * len(header)]


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[object]], escape: bool = True) -> str:
    """A Markdown table: ``header`` cells, then each row's cells (``str()`` of each; with ``escape``, a
    ``|`` inside a cell is escaped, ``\\|``). Rows shorter than the header are padded with empty cells."""
    def line(cells):
        cells = [str(c).replace("|", "\\|") if escape else str(c) for c in cells]
        return table_row(cells + [""] * (len(header) - len(cells)))

    return "\n".join([*table_header(header), *(line(r) for r in rows)])


def scalar_rows(values: dict) -> list[str]:
    """``| name | value |`` rows of the scalars of ``values`` (one level of nested dicts; keys starting
    with ``_`` and booleans left out)."""
    rows = []
    for key, value in values.items():
        if key.startswith("_"):
            continue
        items = value.items() if isinstance(value, dict) else [(None, value)]
        for sub, v in items:
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                rows.append(table_row([key if sub is None else f"{key} ({sub})", f"{v:.4g}"]))
    return rows
