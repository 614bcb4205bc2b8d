"""Side-by-side comparison of every run (loss variants and baselines) over the three suites."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Sequence

from .errors import DataError
from .evaluate import GRADIENTS
from .metrics import HIGHER_IS_BETTER, METRICS

SUITES = ("full", "roi", "gradients")


def load_suite_metrics(metrics_dir: str | os.PathLike, runs: Sequence[str]) -> dict[str, dict[str, dict]]:
    """``{suite: {run: metrics}}`` from ``metrics_dir/<suite>/<run>.json``."""
    out: dict[str, dict[str, dict]] = {}
    for suite in SUITES:
        out[suite] = {}
        for run in runs:
            path = Path(metrics_dir) / suite / f"{run}.json"
            if not path.exists():
                raise DataError(f"{path}: missing metrics of run {run!r} (suite {suite})")
            out[suite][run] = json.loads(path.read_text())
    return out


def _fmt(v: float | None) -> str:
    return "–" if v is None else f"{v:.4f}"


def _table(header: Sequence[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _best(values: dict[str, float], metric: str) -> str | None:
    if not values:
        return None
    pick = max if metric in HIGHER_IS_BETTER else min
    return pick(values, key=values.get)


def build_comparison(suites: dict[str, dict[str, dict]], variants: Sequence[str], baselines: Sequence[str]) -> tuple[dict, str]:
    """The comparison as JSON-ready dict and as Markdown (best variant per column in bold)."""
    runs = [*variants, *baselines]
    caps = [k for k in suites["full"][runs[0]] if k.startswith("cap")]
    result: dict = {"variants": list(variants), "baselines": list(baselines), "full": {}, "roi": {}, "gradients": {}}
    md = ["# Comparison of loss variants", "",
          f"Variants: {', '.join(variants)}. Baselines (image-blind, from training GT): {', '.join(baselines) or 'none'}.",
          "Errors: lower is better; a1–a3: higher is better. Best variant per column in **bold**.", ""]
    for cap in caps:
        result["full"][cap] = {r: suites["full"][r][cap] for r in runs}
        result["roi"][cap] = {r: suites["roi"][r][cap] for r in runs}
        result["gradients"][cap] = {r: suites["gradients"][r][cap] for r in runs}

        def metric_rows(block: dict[str, dict]) -> list[list[str]]:
            best = {m: _best({v: block[v][m] for v in variants}, m) for m in METRICS}
            rows = []
            for r in runs:
                cells = [f"**{_fmt(block[r][m])}**" if best[m] == r else _fmt(block[r][m]) for m in METRICS]
                rows.append([r, *cells])
            return rows

        md += [f"## Full image, cap {cap[3:]} m", "", _table(["run", *METRICS], metric_rows(result["full"][cap])), ""]
        roi = {r: result["roi"][cap][r]["overall"] for r in runs}
        md += [f"## ROI, cap {cap[3:]} m (mean over {roi[runs[0]]['count']} ROIs)", "", _table(["run", *METRICS], metric_rows(roi)), ""]
        classes = sorted({c for r in runs for c in result["roi"][cap][r]["by_class"]})
        rows = [[r, *[_fmt(result["roi"][cap][r]["by_class"].get(c, {}).get("abs_rel")) for c in classes]] for r in runs]
        md += [f"### ROI abs rel per class, cap {cap[3:]} m", "", _table(["run", *classes], rows), ""]
        grad = result["gradients"][cap]
        header = ["run", *[f"pred {g}" for g in GRADIENTS], *[f"|pred−GT| {g}" for g in GRADIENTS]]
        rows = []
        for r in runs:
            dense = grad[r]["dense_gt"]["overall"]
            rows.append([r, *[_fmt(grad[r]["overall"][f"pred_{g}"]) for g in GRADIENTS],
                         *[_fmt(dense.get(f"error_{g}")) for g in GRADIENTS]])
        gt_row = grad[runs[0]]["dense_gt"]["overall"]
        rows.append(["GT (dense ROIs)", *[_fmt(gt_row.get(f"gt_{g}")) for g in GRADIENTS], "", "", ""])
        md += [f"## Gradient consistency on ROIs, cap {cap[3:]} m (mean |derivative| of depth, m/px)", "",
               _table(header, rows), ""]
    return result, "\n".join(md) + "\n"
