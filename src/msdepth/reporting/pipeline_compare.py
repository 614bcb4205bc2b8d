"""The compare stage: every variant (mean over its seeds), baseline, optimum run and extra
evaluation set side by side, from the metrics tree, as ``compare.md`` and ``compare.json``."""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Sequence

from msdepth.analysis.comparison import comparison_data, mean_rows, optimum_data, variant_settings
from msdepth.analysis.own_best import own_best_rows
from msdepth.analysis.runs import (
    group_metrics,
    image_dependence,
    monocular_data,
    paired_statistics,
    seed_spread,
)
from msdepth.analysis.sets import has_boxes, set_instruments, set_verdict_rows
from msdepth.analysis.verdict import (
    OWN_BEST,
    Row,
    display_names,
    headline_columns,
    network_rows,
    optimum_rows,
    settings_label,
    verdict_data,
)
from msdepth.config.params import Params
from msdepth.evaluation.baselines import BASELINES, skipped_reason
from msdepth.evaluation.results import load_suite_metrics, load_training_summaries, load_unit_tables
from msdepth.evaluation.suites import no_rois
from msdepth.io import write_json, write_text
from msdepth.optimum.frames import matcher_runs, optimum_runs
from msdepth.pipeline.paths import (
    COMPARE_JSON,
    COMPARE_MD,
    METRICS,
    OPTIMUM,
    SUITE_NAMES,
    mean_path,
    set_metrics_dir,
    suite_dir,
    variant_runs,
)
from msdepth.reporting.comparison import build_comparison, build_set_section, set_roi_lines
from msdepth.reporting.verdict import verdict_lines
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
    for variant, row in mean_rows(result, params.variants, caps[0]).items():
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
    """compare.json's ``verdict`` (:func:`~msdepth.analysis.verdict.verdict_data`): the rows of the
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


def _compare_set(params: Params, name: str, label: Callable[[str], str] = str) -> tuple[dict, str]:
    """An extra evaluation set's comparison, as the default frames' with the network-free
    instruments as groups of one run beside the baselines; ``label`` names a run's row."""
    root = set_metrics_dir(name)
    missing, built, groups, runs = _run_groups(params, root, ["full"])
    instruments, unrun = set_instruments(params, root)
    groups.update({k: [run] for k, run in instruments.items()})
    runs += list(instruments.values())
    suites = load_suite_metrics(root, runs, ["full"])
    tables = load_unit_tables(root, runs, ["full"])
    caps = [f"cap{c:g}" for c in params.eval.caps]
    # The same trained networks as KITTI 2015's: paired as there (their summaries are the pipeline's).
    pairing = pairing_status(groups, params.compare.reference, load_training_summaries(runs))
    if has_boxes(root, runs):  # the set's boxes, each a unit (data/index/set_rois/<set>.csv)
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
