"""Each loss's own best: the optimum at the smoothness weight each variant chooses on the other fold
of frames (:mod:`msdepth.optimum.selection`), added as a run and scored as the verdict's rows."""

from __future__ import annotations

import dataclasses
from typing import Sequence

import pandas as pd

from msdepth.analysis.verdict import OWN_BEST, Row, RowScope, optimum_rows
from msdepth.config.params import Params
from msdepth.optimum.selection import FOLDS, choose_weights, select_rows


def own_best_tables(
    tables: dict[str, dict[str, pd.DataFrame]], by_weight: dict[str, dict[str, str]], cap: float
) -> tuple[dict[str, str], dict[str, dict[int, float]]]:
    """Adds to ``tables`` (``{suite: {run: table}}``) each variant's optimum at its own best weight
    (:mod:`msdepth.optimum.selection`: two folds of frames, each scored at the weight with the lowest
    full-frame abs_rel at ``cap`` on the other), as the run ``<its runs' folder>/own_best``.

    ``by_weight``: ``{"w<weight>": {variant: run}}``. Returns ``{variant: its own-best run}`` and
    ``{variant: {fold: chosen weight}}``; empty where the weights were scored on different frames
    (``optimum.sweep_frames`` > 0), only one weight ran, or there are fewer frames than folds (a
    one-frame set has no other frames to choose on).
    """
    variants = {v for runs in by_weight.values() for v in runs}
    found, chosen, added = {}, {}, {}
    for variant in sorted(variants):
        runs = {float(w[1:]): r[variant] for w, r in by_weight.items() if variant in r}
        full = {w: tables["full"][r] for w, r in runs.items()}
        headline = {w: t[t["cap"] == cap] for w, t in full.items()}
        names = {frozenset(t["frame"]) for t in headline.values()}
        if len(runs) < 2 or len(names) != 1 or len(next(iter(names))) < FOLDS:
            return {}, {}  # ``tables`` untouched: the rows are added only once every variant has them
        frames, chosen[variant] = choose_weights(headline)
        run = found[variant] = f"{next(iter(runs.values())).rsplit('/', 1)[0]}/own_best"
        added[("full", run)] = select_rows(full, frames, "frame")
        if "roi" in tables:
            added[("roi", run)] = select_rows({w: tables["roi"][r] for w, r in runs.items()}, frames, "image")
    for (suite, run), table in added.items():
        tables[suite][run] = table
    return found, chosen


def own_best_rows(
    tables: dict[str, dict[str, pd.DataFrame]],
    by_weight: dict[str, dict[str, str]],
    params: Params,
    settings: str,
    scope: RowScope | None = None,
    suites: Sequence[str] = (),
) -> list[Row]:
    """The verdict's rows of the optimum at each variant's own best weight (:func:`own_best_tables`),
    named ``optimum own best``; each row's method names the weights chosen per fold. ``suites``: the
    suites that get rows (default: every one of ``tables``; the weights are chosen on ``full``)."""
    runs, chosen = own_best_tables(tables, by_weight, params.eval.caps[0])
    if not runs:
        return []
    scored = {suite: tables[suite] for suite in (suites or tables)}
    rows = optimum_rows(
        scored, {OWN_BEST: runs}, params.compare, params.eval.caps[0], settings, scope or RowScope()
    )
    picked = "; ".join(
        f"{v}: " + ", ".join(f"w{w:g}" for _, w in sorted(folds.items())) for v, folds in chosen.items()
    )
    note = f"; each fold of frames at the weight best on the other fold ({picked})"
    return [dataclasses.replace(row, method=row.method + note) for row in rows]
