"""Side-by-side comparison of every run (loss variants and baselines) over the three suites."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Sequence

import pandas as pd

from .config import CompareConfig
from .errors import DataError
from .evaluate import GRADIENTS
from .metrics import HIGHER_IS_BETTER, METRICS
from .stats import paired_bootstrap, paired_table

SUITES = ("full", "roi", "gradients")


def _load_runs(metrics_dir: str | os.PathLike, suites: Sequence[str], runs: Sequence[str], suffix: str, read, what: str) -> dict:
    """``{suite: {run: read(metrics_dir/<suite>/<run><suffix>)}}``, naming any missing file."""
    out: dict[str, dict] = {}
    for suite in suites:
        out[suite] = {}
        for run in runs:
            path = Path(metrics_dir) / suite / f"{run}{suffix}"
            if not path.exists():
                raise DataError(f"{path}: missing {what} of run {run!r} (suite {suite})")
            out[suite][run] = read(path)
    return out


def load_suite_metrics(metrics_dir: str | os.PathLike, runs: Sequence[str]) -> dict[str, dict[str, dict]]:
    """``{suite: {run: metrics}}`` from ``metrics_dir/<suite>/<run>.json``."""
    return _load_runs(metrics_dir, SUITES, runs, ".json", lambda p: json.loads(p.read_text()), "metrics")


# Per-unit tables of the suites that are compared statistically, and the column pairing units.
UNIT_KEYS = {"full": ["frame"], "roi": ["roi"]}


def load_unit_tables(metrics_dir: str | os.PathLike, runs: Sequence[str]) -> dict[str, dict[str, pd.DataFrame]]:
    """``{suite: {run: per-image or per-ROI table}}`` from ``metrics_dir/<suite>/<run>.csv``."""
    return _load_runs(metrics_dir, list(UNIT_KEYS), runs, ".csv",
                      lambda p: pd.read_csv(p, dtype={"frame": str, "image": str}), "per-unit metrics")


def paired_statistics(
    tables: dict[str, dict[str, pd.DataFrame]], runs: Sequence[str], cfg: CompareConfig, caps: Sequence[float]
) -> dict:
    """``{suite: {capN: {run: {metric: PairedDifference dict}}}}`` of every run against ``cfg.reference``."""
    stats: dict = {"reference": cfg.reference, "confidence": cfg.confidence, "bootstrap_samples": cfg.bootstrap_samples}
    for suite, keys in UNIT_KEYS.items():
        stats[suite] = {}
        for cap in caps:
            ref = tables[suite][cfg.reference]
            ref = ref[ref["cap"] == cap]
            block: dict = {}
            for run in runs:
                if run == cfg.reference:
                    continue
                table = tables[suite][run]
                table = table[table["cap"] == cap]
                block[run] = {}
                for metric in METRICS:
                    values, reference = paired_table(table, ref, keys, metric, f"{suite} {run} vs {cfg.reference}, cap {cap:g}")
                    block[run][metric] = paired_bootstrap(
                        values, reference, cfg.bootstrap_samples, cfg.confidence, cfg.seed
                    ).as_dict()
            stats[suite][f"cap{cap:g}"] = block
    return stats


def _ci_rows(block: dict) -> list[list[str]]:
    """One row per run: ``mean [low, high]`` per metric, ``*`` where the interval excludes 0."""
    rows = []
    for run, metrics in block.items():
        cells = []
        for m in METRICS:
            d = metrics[m]
            cells.append(f"{d['mean']:+.4f} [{d['low']:+.4f}, {d['high']:+.4f}]{' *' if d['excludes_zero'] else ''}")
        rows.append([run, *cells])
    return rows


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


def build_comparison(
    suites: dict[str, dict[str, dict]],
    variants: Sequence[str],
    baselines: Sequence[str],
    stats: dict | None = None,
) -> tuple[dict, str]:
    """The comparison as JSON-ready dict and as Markdown (best variant per column in bold).

    With ``stats`` (from :func:`paired_statistics`), each full-image and ROI table is followed
    by the paired differences to the reference run with their bootstrap intervals.
    """
    runs = [*variants, *baselines]
    caps = [k for k in suites["full"][runs[0]] if k.startswith("cap")]
    result: dict = {"variants": list(variants), "baselines": list(baselines), "full": {}, "roi": {}, "gradients": {}}
    md = ["# Comparison of loss variants", "",
          f"Variants: {', '.join(variants)}. Baselines (image-blind, from training GT): {', '.join(baselines) or 'none'}.",
          "Errors: lower is better; a1–a3: higher is better. Best variant per column in **bold**.", ""]
    if stats is not None:
        result["statistics"] = stats
        md += [f"Differences are `run − {stats['reference']}` (mean over images or ROIs) with a paired "
               f"bootstrap {stats['confidence']:.0%} interval ({stats['bootstrap_samples']} resamples); "
               "`*`: the interval excludes 0. One training run per variant: the intervals cover the "
               "choice of images, not training noise.", ""]

    def ci_table(suite: str, cap: str, unit: str) -> list[str]:
        if stats is None:
            return []
        block = stats[suite][cap]
        n = next(iter(next(iter(block.values())).values()))["n"] if block else 0
        return [f"Difference to {stats['reference']} ({n} paired {unit}):", "",
                _table(["run", *METRICS], _ci_rows(block)), ""]

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
        md += ci_table("full", cap, "images")
        roi = {r: result["roi"][cap][r]["overall"] for r in runs}
        md += [f"## ROI, cap {cap[3:]} m (mean over {roi[runs[0]]['count']} ROIs)", "", _table(["run", *METRICS], metric_rows(roi)), ""]
        md += ci_table("roi", cap, "ROIs")
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
