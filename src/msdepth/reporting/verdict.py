"""The verdict's renderers: compare.md's verdict section and the README's summary table and
sentences, each formatting the one table of :func:`msdepth.analysis.verdict.verdict_table`."""

from __future__ import annotations

from typing import Mapping, Sequence

from msdepth.analysis.verdict import (
    FULL_FRAME,
    MIN_UNITS,
    Column,
    Row,
    columns_of,
    rows_of,
    verdict_table,
)
from msdepth.reporting.comparison import markdown_table

VERDICT_FIGURE = "verdict.png"  # below plots/figures: the figures stage draws it (figures.verdict_figure)


def signed(x: float, decimals: int = 3) -> str:
    """``x`` with its sign, the minus as U+2212 (as the results page writes numbers)."""
    return f"{x:+.{decimals}f}".replace("-", "\u2212")


VERDICT_TITLE = "The verdict per surface class"


def interval_cell(r: Row, decimals: int = 3) -> str:
    """A row's difference and interval as a table cell (``*``: it excludes 0).

    Example:
        >>> interval_cell(Row("x", "car", -0.036, -0.068, -0.002, 66, "m", "network"))
        '−0.036 [−0.068, −0.002] *'
    """
    if not r.has_interval:
        return f"{signed(r.diff, decimals)} (no interval)"
    star = " *" if r.excludes_zero else ""
    return f"{signed(r.diff, decimals)} [{signed(r.low, decimals)}, {signed(r.high, decimals)}]{star}"


def units_text(r: Row) -> str:
    """What a row's n counts, short: ``66 ROIs × 3 seed pairs``, ``5 eigen frames``."""
    unit = r.unit or ("images" if r.cls == FULL_FRAME else "ROIs")
    if r.kind == "network":
        pairs = "seed pairs" if r.method.startswith("paired") else "seeds a side"
        return f"{r.n} {unit} × {r.seeds} {pairs}"
    return f"{r.n} {unit}"


def summary_lines(data: Mapping) -> list[str]:
    """The summary table as Markdown (compare.md and the README): each cell's interval and n."""
    columns = columns_of(data)
    rows = [
        [cls, *("–" if r is None else f"{interval_cell(r)}, n = {units_text(r)}" for r in cells)]
        for cls, cells in verdict_table(rows_of(data), columns, data["classes"])
    ]
    return markdown_table(["class", *(c.header for c in columns)], rows).split("\n")


def _filled_columns(data: Mapping) -> list[tuple[Column, dict[str, Row]]]:
    """Each summary column that has rows, with its ``{class: row}``."""
    table = verdict_table(rows_of(data), columns_of(data), data["classes"])
    out = [
        (c, {cls: cells[i] for cls, cells in table if cells[i] is not None})
        for i, c in enumerate(columns_of(data))
    ]
    return [(c, cells) for c, cells in out if cells]


def on_places(data: Mapping, places: Sequence[str]) -> dict:
    """``data`` (compare.json's ``verdict``) with only the summary columns of the rows made on
    ``places`` (an extra set's name, or ``<set> boxes``: instruments named ``... on <place>``), and
    only the classes they fill, in ``data``'s order then the rows'. Nothing is pooled: each column is
    one place's.

    Example:
        >>> from msdepth.analysis.verdict import verdict_data
        >>> rows = [Row("optimum w10", "car", -0.02, -0.03, -0.01, 91, "m", "optimum"),
        ...         Row("optimum w10 on kitti2012", "reflective", 0.01, None, None, 2, "m", "optimum")]
        >>> cols = [Column("rendered", "optimum", "optimum w10"),
        ...         Column("k12", "optimum", "optimum w10 on kitti2012")]
        >>> real = on_places(verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM", columns=cols), ["kitti2012"])
        >>> list(real["headline"]), real["classes"]
        (['k12'], ['reflective'])
    """
    headline = {h: c for h, c in data["headline"].items() if any(c[1].endswith(f" on {p}") for p in places)}
    instruments = {c[1] for c in headline.values()}
    filled = [r["class"] for r in data["rows"] if r["instrument"] in instruments]
    classes = [c for c in dict.fromkeys([*data["classes"], *filled]) if c in filled]
    return {**data, "headline": headline, "classes": classes}


def answer_sentence(data: Mapping) -> str:
    """The summary table in one sentence: per column, on how many surface classes the variant's
    error is lower and where its interval excludes 0 (with the paired t's agreement).

    Example:
        >>> from msdepth.analysis.verdict import verdict_data
        >>> rows = [Row("stereo networks", "car", -0.02, -0.03, -0.01, 91, "m", "network", -0.05, 0.01)]
        >>> print(answer_sentence(verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM")))
        stereo networks: lower on 1 of 1 surface class; its interval excludes 0 on car (the paired t
        over seeds includes 0).
    """
    parts = []
    for column, cells in _filled_columns(data):
        lower = [c for c, r in cells.items() if r.diff < 0]
        noun = "class" if len(cells) == 1 else "classes"
        text = f"{column.header}: lower on {len(lower)} of {len(cells)} surface {noun}"
        excluding = [c for c, r in cells.items() if r.excludes_zero]
        if excluding:
            text += f"; its interval excludes 0 on {', '.join(c + _t_words(cells[c]) for c in excluding)}"
            higher = [c for c in excluding if cells[c].diff > 0]
            text += f" (higher on {', '.join(higher)})" if higher else ""
        else:
            text += "; no interval excludes 0"
        parts.append(text)
    return "; ".join(parts) + "." if parts else "No instrument compares two variants here."


def sign_caveat(data: Mapping) -> str:
    """One sentence naming the classes whose sign depends on the instrument (the summary table's
    columns disagree) or on the optimum's smoothness weight (its rows ``optimum w<W>`` disagree);
    "" where every sign agrees.

    Example:
        >>> from msdepth.analysis.verdict import verdict_data
        >>> rows = [Row("optimum w3", "car", -0.02, -0.03, -0.01, 91, "m", "optimum"),
        ...         Row("optimum w30", "car", 0.01, 0.0, 0.02, 91, "m", "optimum"),
        ...         Row("stereo networks", "car", -0.01, -0.03, 0.01, 91, "m", "network")]
        >>> sign_caveat(verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM"))
        "The sign depends on the optimum's smoothness weight on car."
    """
    table = verdict_table(rows_of(data), columns_of(data), data["classes"])
    by_instrument = [cls for cls, cells in table if len({c.diff < 0 for c in cells if c is not None}) > 1]
    weights: dict[str, set[bool]] = {}
    for r in rows_of(data):
        if r.kind == "optimum" and r.instrument.startswith("optimum w") and " " not in r.instrument[9:]:
            weights.setdefault(r.cls, set()).add(r.diff < 0)
    by_weight = [cls for cls in data["classes"] if len(weights.get(cls, ())) > 1]
    parts = []
    if by_instrument:
        parts.append(f"on the instrument on {', '.join(by_instrument)}")
    if by_weight:
        parts.append(f"on the optimum's smoothness weight on {', '.join(by_weight)}")
    return f"The sign depends {'; and '.join(parts)}." if parts else ""


def short_answer(data: Mapping) -> str:
    """:func:`answer_sentence` in a line: per column, on how many classes the variant's error is
    lower and on how many its interval excludes 0.

    Example:
        >>> from msdepth.analysis.verdict import verdict_data
        >>> rows = [Row("stereo networks", "car", -0.02, -0.03, -0.01, 91, "m", "network")]
        >>> short_answer(verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM"))
        "MS-SSIM's abs_rel against SSIM's: stereo networks lower on 1 of 1 class, 1 interval excluding 0."
    """
    parts = []
    for column, cells in _filled_columns(data):
        lower, excluding = (
            sum(r.diff < 0 for r in cells.values()),
            sum(r.excludes_zero for r in cells.values()),
        )
        noun = "class" if len(cells) == 1 else "classes"
        intervals = "no interval" if not excluding else f"{excluding} interval{'s' * (excluding > 1)}"
        parts.append(f"{column.header} lower on {lower} of {len(cells)} {noun}, {intervals} excluding 0")
    if not parts:
        return "No instrument compares two variants here."
    return f"{data['variant']}'s abs_rel against {data['reference']}'s: {'; '.join(parts)}."


def _t_words(r: Row) -> str:
    """`` (the paired t over seeds agrees)`` or ``... includes 0)`` where the row has a paired t."""
    if r.t_low is None:
        return ""
    return (
        " (the paired t over seeds agrees)" if r.t_excludes_zero else " (the paired t over seeds includes 0)"
    )


def verdict_lines(data: Mapping | None) -> list[str]:
    """compare.md's verdict section from :func:`verdict_data`'s dict: the summary table
    (:func:`summary_lines`), what a row is, one line per row, then the sentences."""
    if not data or not data["rows"]:
        return [f"# {VERDICT_TITLE}", "", "No instrument compares two variants here.", ""]
    level = f"{data['confidence'] * 100:g} %"
    lines = [
        f"# {VERDICT_TITLE}",
        "",
        f"{data['variant']} − {data['reference']} in abs_rel (cap {data['cap'][3:]} m; negative: "
        f"{data['variant']}'s error is lower), each instrument's {level} interval; `*`: it excludes 0. "
        f"Settings: `{data.get('settings') or 'not recorded'}`.",
        "",
        *summary_lines(data),
        "",
        answer_sentence(data),
        "",
        "Networks trained with the same seed are pairs (same initial weights and batches): their rows "
        "resample seed pairs with the units and give the paired t over seeds beside the bootstrap. "
        "n: the units (images, ROIs, frames or seed pairs); ROIs are resampled with their "
        f"frame, so the frames are their independent units; with fewer than {MIN_UNITS} independent "
        "units a row has no interval (src/msdepth/analysis/verdict.py). "
        "The figure: `plots/figures/verdict.png`.",
        "",
        "| class | instrument | difference | paired t | n | method |",
        "|---|---|---|---|---|---|",
    ]
    rows = rows_of(data)
    for cls in data["classes"]:
        for r in (r for r in rows if r.cls == cls):
            t = f"[{signed(r.t_low)}, {signed(r.t_high)}]" if r.t_low is not None else "–"
            lines.append(
                f"| {cls} | {r.instrument} | {interval_cell(r)} | {t} | {units_text(r)} | {r.method} |"
            )
    return [*lines, "", *[f"- {data['sentences'][c]}" for c in data["classes"]], ""]
