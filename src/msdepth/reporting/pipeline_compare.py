"""The compare stage: every variant (mean over its seeds), baseline, optimum run and extra
evaluation set side by side, from the metrics tree, as ``compare.md`` and ``compare.json``."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable, Sequence

import pandas as pd

from msdepth.config.params import Params
from msdepth.evaluation.baselines import BASELINES, skipped_reason
from msdepth.evaluation.results import load_suite_metrics, load_training_summaries, load_unit_tables
from msdepth.evaluation.suites import no_rois
from msdepth.io import write_json, write_text
from msdepth.optimum.frames import matcher_runs, optimum_runs
from msdepth.optimum.selection import FOLDS, choose_weights, select_rows
from msdepth.pipeline.paths import (
    COMPARE_JSON,
    COMPARE_MD,
    METRICS,
    OPTIMUM,
    SUITE_NAMES,
    mean_path,
    optimum_run,
    set_metrics_dir,
    suite_dir,
    variant_runs,
)
from msdepth.reporting.comparison import (
    build_comparison,
    build_set_section,
    comparison_data,
    group_metrics,
    image_dependence,
    monocular_data,
    optimum_data,
    paired_statistics,
    seed_spread,
    set_roi_lines,
    variant_settings,
)
from msdepth.reporting.verdict import (
    OWN_BEST,
    Row,
    RowScope,
    display_names,
    headline_columns,
    network_rows,
    optimum_rows,
    settings_label,
    verdict_data,
    verdict_lines,
)
from msdepth.training.pairing import pairing_status


def _run_groups(
    params: Params, root: Path, suites: Sequence[str]
) -> tuple[dict[str, str], tuple[str, ...], dict[str, list[str]], list[str]]:
    """What is compared below ``root``: the baselines missing (with why), those built, the groups
    (each variant's runs over the seeds, each built baseline alone) and all their runs."""
    missing = {b: reason for b in BASELINES if (reason := skipped_reason(root, b, suites)) is not None}
    built = tuple(b for b in BASELINES if b not in missing)
    groups = {**variant_runs(params), **{b: [b] for b in built}}
    return missing, built, groups, [r for group in groups.values() for r in group]


def write_comparison(params: Params) -> None:
    """Write :data:`~msdepth.pipeline.paths.COMPARE_MD`, :data:`~msdepth.pipeline.paths.COMPARE_JSON`
    and each variant's mean over its seeds as a DVC metric (:func:`~msdepth.pipeline.paths.mean_path`)."""
    missing, built, groups, runs = _run_groups(params, METRICS, SUITE_NAMES)
    suites = load_suite_metrics(METRICS, runs)
    tables = load_unit_tables(METRICS, runs)
    # Without ROIs (an empty ROI index) only the full-image suite has numbers to compare.
    compared = ("full",) if all(no_rois(suites["roi"][r]) for r in runs) else ("full", "roi")
    pairing = pairing_status(groups, params.compare.reference, load_training_summaries(runs))
    stats = paired_statistics(
        {s: tables[s] for s in compared}, groups, params.compare, params.eval.caps, pairing
    )
    caps = [f"cap{c:g}" for c in params.eval.caps]
    comparison = comparison_data(
        group_metrics(suites, groups),
        list(params.variants),
        built,
        seeds=params.train.seeds,
        stats=stats,
        spread=seed_spread({s: suites[s] for s in compared}, groups, caps),
        dependence=image_dependence(suites, tables, groups, "prior", params.eval.caps[0]),
        groups=groups,
        missing_baselines=missing,
        optimum=_optimum_section(params, groups, compared),
        settings=variant_settings(params),
        monocular=monocular_data(suites["full"], load_training_summaries(runs), groups, caps[0]),
    )
    result, md = build_comparison(comparison)
    result["verdict"] = comparison_verdict(params, groups, compared, pairing)
    result["data_source"] = params.data.source  # whose frames the rows score: rendered or real
    md += "\n" + "\n".join(verdict_lines(result["verdict"]))
    for name in params.eval.extra_sets:
        result.setdefault("sets", {})[name], section = _compare_set(params, name, comparison.settings_label)
        md += "\n" + section
    write_json(COMPARE_JSON, result)
    write_text(COMPARE_MD, md)
    for variant, row in _mean_rows(result, params.variants, caps[0]).items():
        write_json(mean_path(variant), row)


def _optimum_section(params: Params, groups: dict[str, list[str]], compared: Sequence[str]) -> dict | None:
    """The optimum runs' and matchers' numbers, with the differences to the reference at the default
    weight and of the matchers (those see every frame), and each matcher without metrics with why.
    None where no optimum stage has written anything."""
    if not (suite_dir("full") / OPTIMUM).is_dir():
        return None
    matchers = matcher_runs(params)
    reasons = {k: skipped_reason(METRICS, r, compared) for k, r in matchers.items()}
    skipped = {k: why for k, why in reasons.items() if why is not None}
    matchers = {k: r for k, r in matchers.items() if k not in skipped}
    runs = {**optimum_runs(params, METRICS), **matchers}
    suites = load_suite_metrics(METRICS, list(runs.values()), compared)
    weight = f"{params.optimum.smoothness_weight:g}"
    default = {k: [r] for k, r in runs.items() if k in matchers or k.rsplit(" w", 1)[1] == weight}
    reference = {params.compare.reference: groups[params.compare.reference]}
    tables = load_unit_tables(
        METRICS, [*reference[params.compare.reference], *(r[0] for r in default.values())], compared
    )
    stats = paired_statistics(tables, {**reference, **default}, params.compare, params.eval.caps[:1])
    return optimum_data(suites, runs, stats, f"cap{params.eval.caps[0]:g}", skipped)


def comparison_verdict(
    params: Params,
    groups: dict[str, list[str]],
    compared: Sequence[str],
    pairing: dict[str, str | None] | None = None,
) -> dict:
    """compare.json's ``verdict`` (:func:`~msdepth.reporting.verdict.verdict_data`): the rows of the
    trained networks, the optimum at every weight and its own best, and each extra set's instruments
    (:func:`set_verdict_rows`), all computed by this pipeline."""
    cfg, cap = params.compare, params.eval.caps[0]
    variants = {v: groups[v] for v in params.variants}
    settings = settings_label(variant_settings(params), params.variants)
    rows = []
    if len(variants) > 1:
        tables = load_unit_tables(METRICS, [r for runs in variants.values() for r in runs], compared)
        rows += network_rows(tables, variants, cfg, cap, pairing=pairing, settings=settings)
        if (suite_dir("full") / OPTIMUM).is_dir():
            by_weight: dict[str, dict[str, str]] = {}
            for label, run in optimum_runs(params, METRICS).items():
                _, variant, weight = label.split(" ")  # "optimum <variant> w<weight>"
                by_weight.setdefault(weight, {})[variant] = run
            opt_tables = load_unit_tables(
                METRICS, [r for w in by_weight.values() for r in w.values()], compared
            )
            rows += optimum_rows(opt_tables, by_weight, cfg, cap, settings)
            rows += own_best_rows(opt_tables, by_weight, params, settings)
    for name in params.eval.extra_sets:
        rows += set_verdict_rows(params, name, pairing, settings)
    better, than = display_names(params.variants, cfg.reference)
    boxed = [n for n in params.eval.extra_sets if any(r.instrument.endswith(f" on {n} boxes") for r in rows)]
    own = [
        w
        for n in params.eval.extra_sets
        for w in (n, f"{n} boxes")
        if _has_row(rows, f"optimum {OWN_BEST} on {w}")
    ]
    columns = headline_columns(params.optimum.smoothness_weight, params.eval.extra_sets, boxed, own)
    return verdict_data(rows, cap, cfg.confidence, better, than, settings, columns)


def _has_row(rows: Sequence[Row], instrument: str) -> bool:
    return any(r.instrument == instrument for r in rows)


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


def _mean_rows(result: dict, variants: Sequence[str], cap: str) -> dict[str, dict[str, float]]:
    """Per variant its mean over seeds at ``cap`` from compare.json's ``result``: ``abs_rel``, ``a1``,
    with ROIs ``roi``, ``masks`` and each class's abs_rel; flat keys, one ``dvc metrics`` column each."""
    rows = {}
    for variant in variants:
        full = result["full"][cap][variant]
        row = {"abs_rel": full["abs_rel"], "a1": full["a1"]}
        roi = result.get("roi", {}).get(cap, {}).get(variant)
        if roi:  # {} without ROIs
            row["roi"] = roi["overall"]["abs_rel"]
            if (mask := result.get("roi_masks", {}).get(cap, {}).get(variant)) is not None:
                row["masks"] = mask["overall"]["abs_rel"]
            row.update({c: m["abs_rel"] for c, m in roi.get("by_class", {}).items()})
        rows[variant] = row
    return rows


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


def _set_instruments(params: Params, root: Path) -> tuple[dict[str, str], dict[str, str]]:
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


def _has_boxes(root: Path, runs: Sequence[str]) -> bool:
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
    instruments, _ = _set_instruments(params, root)
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
    if suite == "full" or _has_boxes(root, runs):
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
        if suite == "full" or _has_boxes(root, list(found.values())):
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
    if len(by_weight) < 2 or (suite == "roi" and not _has_boxes(root, runs)):
        return []
    tables = load_unit_tables(root, runs, list(dict.fromkeys(["full", suite])))
    return own_best_rows(tables, by_weight, params, settings, scope, [suite])


def _compare_set(params: Params, name: str, label: Callable[[str], str] = str) -> tuple[dict, str]:
    """An extra evaluation set's comparison, as the default frames' with the network-free
    instruments as groups of one run beside the baselines; ``label`` names a run's row."""
    root = set_metrics_dir(name)
    missing, built, groups, runs = _run_groups(params, root, ["full"])
    instruments, unrun = _set_instruments(params, root)
    groups.update({k: [run] for k, run in instruments.items()})
    runs += list(instruments.values())
    suites = load_suite_metrics(root, runs, ["full"])
    tables = load_unit_tables(root, runs, ["full"])
    caps = [f"cap{c:g}" for c in params.eval.caps]
    # The same trained networks as KITTI 2015's: paired as there (their summaries are the pipeline's).
    pairing = pairing_status(groups, params.compare.reference, load_training_summaries(runs))
    if _has_boxes(root, runs):  # the set's boxes, each a unit (data/index/set_rois/<set>.csv)
        suites.update(load_suite_metrics(root, runs, ["roi"]))
        tables.update(load_unit_tables(root, runs, ["roi"]))
    stats = paired_statistics(tables, groups, params.compare, params.eval.caps, pairing)
    merged = group_metrics(suites, groups)
    result, md = build_set_section(
        name,
        {"full": merged["full"]},
        list(params.variants),
        [*built, *instruments],
        stats,
        seed_spread({"full": suites["full"]}, groups, caps),
        params.train.seeds,
        missing_baselines=missing,
        label=label,
        unrun=unrun,
    )
    if "roi" not in merged:
        return result, md
    result["roi"] = merged["roi"]
    others = [*built, *instruments]
    lines = set_roi_lines(name, merged["roi"], [*params.variants, *others], stats, others, label)
    return result, md + "\n".join(lines) + "\n"
