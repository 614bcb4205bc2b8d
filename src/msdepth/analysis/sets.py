"""Each extra evaluation set's verdict rows: the networks, the SGM cost starts and the optimum at
each of ``optimum.set_weights`` and at each loss's own best, over the set's frames and its boxes."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Sequence

from msdepth.analysis.own_best import own_best_rows
from msdepth.analysis.verdict import Row, RowScope, network_rows, optimum_rows
from msdepth.config.params import Params
from msdepth.evaluation.baselines import skipped_reason
from msdepth.evaluation.results import load_suite_metrics, load_unit_tables
from msdepth.evaluation.suites import no_rois
from msdepth.optimum.frames import matcher_runs
from msdepth.pipeline.paths import OPTIMUM, optimum_run, set_metrics_dir, suite_dir, variant_runs


def _set_optimum_run(root: Path, variant: str, weight: float) -> str:
    """The run of ``variant``'s optimum at ``weight`` below ``root``, found by value (dvc.yaml writes a
    weight as params.yaml spells it); the name the value gives where there is none."""
    for path in sorted((suite_dir("full", root) / OPTIMUM / variant).glob("w*.json")):
        try:
            if float(path.stem[1:]) == weight:
                return optimum_run(variant, path.stem[1:])
        except ValueError:
            continue
    return optimum_run(variant, f"{weight}")


def set_instruments(params: Params, root: Path) -> tuple[dict[str, str], dict[str, str]]:
    """An extra set's network-free instruments below ``root``: ``{label: run}`` of those with metrics
    (``SGM (<variant> cost)``, ``SGBM``, ``optimum <variant> w<weight>``) and ``{label: why}`` of the
    others; neither where none has written anything."""
    if not (suite_dir("full", root) / OPTIMUM).is_dir():
        return {}, {}
    runs = dict(matcher_runs(params))
    for w in params.optimum.set_weights:
        runs |= {f"{OPTIMUM} {v} w{w:g}": _set_optimum_run(root, v, w) for v in params.variants}
    reasons = {label: skipped_reason(root, run, ["full"]) for label, run in runs.items()}
    found = {label: run for label, run in runs.items() if reasons[label] is None}
    return found, {label: why for label, why in reasons.items() if why is not None}


def has_boxes(root: Path, runs: Sequence[str]) -> bool:
    """Whether every run of ``runs`` has scored an extra set's boxes (its ROI suite below ``root``)."""
    if not runs or any(skipped_reason(root, r, ["roi"]) is not None for r in runs):
        return False
    return not any(no_rois(s) for s in load_suite_metrics(root, runs, ["roi"])["roi"].values())


def set_verdict_rows(
    params: Params, name: str, pairing: dict[str, str | None] | None = None, settings: str = ""
) -> list[Row]:
    """The verdict's rows of extra set ``name``: the networks, SGM cost starts and the optimum at each
    of ``optimum.set_weights``, over the frames (whole frame, exact classes: ``<instrument> on
    <set>``) and over the boxes (``<instrument> on <set> boxes``); [] with fewer than two variants."""
    if len(params.variants) < 2:
        return []
    root = set_metrics_dir(name)
    variants = {v: variant_runs(params)[v] for v in params.variants}
    instruments, _ = set_instruments(params, root)
    rows = []
    for suite, where in (("full", name), ("roi", f"{name} boxes")):
        unit = where if suite == "roi" else f"{name} frames"
        scope = RowScope(whole_frame=suite == "full", unit=unit, keep_few=True)
        found = _set_suite_rows(params, root, suite, scope, variants, instruments, pairing, settings)
        rows += [dataclasses.replace(r, instrument=f"{r.instrument} on {where}") for r in found]
    return rows


def _set_suite_rows(
    params: Params,
    root: Path,
    suite: str,
    scope: RowScope,
    variants: dict[str, list[str]],
    instruments: dict[str, str],
    pairing: dict[str, str | None] | None,
    settings: str,
) -> list[Row]:
    """:func:`set_verdict_rows`' rows of one suite (``full``, or ``roi`` where the runs scored boxes)."""
    cfg, cap = params.compare, params.eval.caps[0]
    rows = []
    runs = [r for group in variants.values() for r in group]
    if suite == "full" or has_boxes(root, runs):
        tables = load_unit_tables(root, runs, [suite])
        rows += network_rows(tables, variants, cfg, cap, pairing=pairing, settings=settings, scope=scope)
    weights = [f"w{w:g}" for w in params.optimum.set_weights]
    for instrument, label, pattern in (
        *(("optimum", weight, f"{OPTIMUM} {{}} {weight}") for weight in weights),
        ("SGM", "cost start", "SGM ({} cost)"),
    ):
        found = {
            v: instruments[pattern.format(v)] for v in params.variants if pattern.format(v) in instruments
        }
        if cfg.reference not in found or len(found) < 2:
            continue
        if suite == "full" or has_boxes(root, list(found.values())):
            tables = load_unit_tables(root, list(found.values()), [suite])
            rows += optimum_rows(tables, {label: found}, cfg, cap, settings, scope, instrument)
    return rows + _set_own_best_rows(params, root, suite, scope, instruments, settings)


def _set_own_best_rows(
    params: Params, root: Path, suite: str, scope: RowScope, instruments: dict[str, str], settings: str
) -> list[Row]:
    """:func:`own_best_rows` on an extra set: each variant's weight chosen from ``optimum.set_weights``
    on the other fold of the set's frames (full-frame abs_rel), then scored on ``suite``. [] with
    fewer than two weights or a variant missing one."""
    by_weight = {}
    for w in params.optimum.set_weights:
        labels = {v: f"{OPTIMUM} {v} w{w:g}" for v in params.variants}
        if any(label not in instruments for label in labels.values()):
            return []
        by_weight[f"w{w:g}"] = {v: instruments[label] for v, label in labels.items()}
    runs = [r for found in by_weight.values() for r in found.values()]
    if len(by_weight) < 2 or (suite == "roi" and not has_boxes(root, runs)):
        return []
    tables = load_unit_tables(root, runs, list(dict.fromkeys(["full", suite])))
    return own_best_rows(tables, by_weight, params, settings, scope, [suite])
