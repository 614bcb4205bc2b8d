"""The statistics over runs and seeds: each variant against the reference (paired by seed where the
runs are pairs), the metrics averaged over a variant's runs, their spread over seeds, whether a
difference may be marked, whether a run uses the image, and the monocular runs' scale and pose."""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from msdepth.config.params import CompareConfig
from msdepth.errors import DataError
from msdepth.evaluation.metrics import METRICS
from msdepth.stats import paired_table, seed_bootstrap

# A difference is marked only when its interval covers training noise: at least this many seeds
# of every trained run it involves (with fewer, the seed draws cannot show seed-to-seed spread).
MIN_SEEDS_FOR_MARKS = 3
# Image-blind: predictions varying across images less than this fraction of the GT's variation
# (a constant or the per-pixel prior score exactly 0; networks that follow the scene ~1).
IMAGE_BLIND_BELOW = 0.25


# Per-unit tables of the suites that are compared statistically, and the column pairing units.
UNIT_KEYS = {"full": ["frame"], "roi": ["roi"]}
# The column grouping a suite's units into independent clusters: a frame's ROIs share its scene,
# its rendering and each network's view of it, so the bootstrap draws frames with all their ROIs.
CLUSTER_KEYS = {"roi": "image"}


def unit_clusters(suite: str, anchor: pd.DataFrame) -> np.ndarray | None:
    """Each unit's cluster label in ``anchor``'s order; None where the units are independent (images)."""
    key = CLUSTER_KEYS.get(suite)
    return None if key is None else anchor[key].astype(str).to_numpy()


def _unit_matrix(
    tables: dict[str, pd.DataFrame],
    runs: Sequence[str],
    anchor: pd.DataFrame,
    keys: list[str],
    metric: str,
    what: str,
) -> np.ndarray:
    """(runs, units): ``metric`` of every run, its units aligned on ``keys`` to ``anchor``'s order."""
    return np.stack([paired_table(anchor, tables[r], keys, metric, f"{what} ({r})")[1] for r in runs])


def paired_statistics(
    tables: dict[str, dict[str, pd.DataFrame]],
    groups: dict[str, Sequence[str]],
    cfg: CompareConfig,
    caps: Sequence[float],
    pairing: Mapping[str, str | None] | None = None,
) -> dict:
    """``{suite: {capN: {group: {metric: PairedDifference dict}}}}`` of every group (variant -> its
    runs) against ``cfg.reference`` (:func:`msdepth.stats.seed_bootstrap`); ``pairing``: the groups
    whose seed pairs are drawn jointly (None: paired; absent: nothing is)."""
    others = [g for g in groups if g != cfg.reference]
    pairing = dict(pairing) if pairing is not None else dict.fromkeys(others, "pairing not checked")
    stats: dict = {
        "reference": cfg.reference,
        "confidence": cfg.confidence,
        "bootstrap_samples": cfg.bootstrap_samples,
        "pairing": {g: pairing.get(g, "pairing not checked") for g in others},
    }
    for suite in tables:
        keys = UNIT_KEYS[suite]
        stats[suite] = {}
        for cap in caps:
            cap_tables = {run: t[t["cap"] == cap] for run, t in tables[suite].items()}
            anchor = cap_tables[groups[cfg.reference][0]]
            clusters = unit_clusters(suite, anchor)

            ref_what = f"{suite} {cfg.reference}, cap {cap:g}"
            reference = {
                m: _unit_matrix(cap_tables, groups[cfg.reference], anchor, keys, m, ref_what) for m in METRICS
            }
            block: dict = {}
            for name in others:
                what = f"{suite} {name} vs {cfg.reference}, cap {cap:g}"
                paired = stats["pairing"][name] is None
                block[name] = {
                    m: seed_bootstrap(
                        _unit_matrix(cap_tables, groups[name], anchor, keys, m, what),
                        reference[m],
                        cfg.bootstrap_samples,
                        cfg.confidence,
                        cfg.seed,
                        paired=paired,
                        clusters=clusters,
                    ).as_dict()
                    for m in METRICS
                }
            stats[suite][f"cap{cap:g}"] = block
    return stats


def _mean_over_runs(trees: Sequence[dict]) -> dict:
    """The runs' metric JSONs (same layout) averaged leaf by leaf; counts and labels must agree."""
    first = trees[0]
    if isinstance(first, dict):
        keys = set(first)
        if any(set(t) != keys for t in trees):
            raise DataError(f"cannot average runs whose metrics have different entries: {sorted(keys)}")
        return {k: _mean_over_runs([t[k] for t in trees]) for k in first}
    if first is None or isinstance(first, (str, bool)) or (isinstance(first, int) and len(set(trees)) == 1):
        if len(set(map(repr, trees))) != 1:
            raise DataError(
                f"runs disagree on a value that cannot be averaged: {sorted(set(map(repr, trees)))}"
            )
        return first
    return float(np.mean(trees))


def group_metrics(
    suites: dict[str, dict[str, dict]], groups: dict[str, Sequence[str]]
) -> dict[str, dict[str, dict]]:
    """``{suite: {group: metrics averaged over the group's runs}}``."""
    return {
        suite: {g: _mean_over_runs([runs_metrics[r] for r in runs]) for g, runs in groups.items()}
        for suite, runs_metrics in suites.items()
    }


def seed_spread(
    suites: dict[str, dict[str, dict]], groups: dict[str, Sequence[str]], caps: Sequence[str]
) -> dict:
    """``{suite: {capN: {variant: {metric: {mean, sd, runs}}}}}`` over each variant's seeds (full
    image and all ROIs, those in ``suites``); ``sd``: the sample sd, None for one seed."""
    out: dict = {}
    picks = {"full": lambda m, cap: m[cap], "roi": lambda m, cap: m[cap]["overall"]}
    for suite, pick in picks.items():
        if suite not in suites:
            continue
        out[suite] = {}
        for cap in caps:
            out[suite][cap] = {}
            for g, runs in groups.items():
                values = {metric: [pick(suites[suite][r], cap)[metric] for r in runs] for metric in METRICS}
                out[suite][cap][g] = {
                    metric: {
                        "mean": float(np.mean(v)),
                        "sd": float(np.std(v, ddof=1)) if len(v) > 1 else None,
                        "runs": dict(zip(runs, map(float, v), strict=True)),
                    }
                    for metric, v in values.items()
                }
    return out


def marks_allowed(difference: dict, baseline: bool) -> bool:
    """Whether ``difference`` may be marked: enough seeds of every trained run in it (not a baseline's)."""
    seeds = [difference["reference_seeds"]] + ([] if baseline else [difference["seeds"]])
    return min(seeds) >= MIN_SEEDS_FOR_MARKS


def image_dependence(
    suites: dict[str, dict[str, dict]],
    tables: dict[str, dict[str, pd.DataFrame]],
    groups: dict[str, Sequence[str]],
    prior: str,
    cap: float,
) -> dict[str, dict]:
    """Per run: its ``variation_ratio`` (full-image suite), the correlation of its per-image abs_rel
    with the image-blind ``prior``'s, and ``image_blind`` (ratio below :data:`IMAGE_BLIND_BELOW`)."""
    full = {r: t[t["cap"] == cap] for r, t in tables["full"].items()}
    out: dict = {}
    for runs in groups.values():
        for run in runs:
            ratio = suites["full"][run].get("image_dependence", {}).get("variation_ratio")
            if ratio is not None and not np.isfinite(ratio):
                ratio = None  # NaN: no pixel has GT in enough frames (e.g. fewer than 3 frames)
            corr = None
            if prior in full and run != prior:
                errors, prior_errors = paired_table(
                    full[run], full[prior], ["frame"], "abs_rel", f"full {run} vs {prior}"
                )
                if len(errors) > 2 and np.std(errors) > 0 and np.std(prior_errors) > 0:
                    corr = float(np.corrcoef(errors, prior_errors)[0, 1])
            out[run] = {
                "variation_ratio": ratio,
                "prior_correlation": corr,
                "image_blind": ratio is not None and bool(ratio < IMAGE_BLIND_BELOW),
            }
    return out


def monocular_data(
    full: dict[str, dict], training: dict[str, dict], groups: dict[str, Sequence[str]], cap: str
) -> dict[str, dict] | None:
    """Per variant trained monocularly (with ``median_scaling``): its scale ratios' median and spread
    at ``cap`` and its pose ATE, means over its runs; None when no variant is."""
    out = {}
    for group, runs in groups.items():
        scaling = [full[r][cap].get("median_scaling") for r in runs if r in full]
        if not scaling or any(s is None for s in scaling):
            continue
        entry = {
            "runs": len(runs),
            "scale_ratio": float(np.mean([s["ratio_median"] for s in scaling])),
            "scale_spread": float(np.mean([s["ratio_std_over_median"] for s in scaling])),
        }
        poses = [training.get(r, {}).get("pose") for r in runs]
        if all(p is not None for p in poses):
            entry["pose_ate"] = float(np.mean([p["ate_mean"] for p in poses]))
            entry["pose_ate_std"] = float(np.mean([p["ate_std"] for p in poses]))
        out[group] = entry
    return out or None
