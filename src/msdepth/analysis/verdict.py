"""The verdict as data: per surface class, MS-SSIM − SSIM abs_rel as every instrument measures it.

A :class:`Row` is one instrument's ``variant − reference`` (``compare.reference``) abs_rel on one
class (the full frame, then each ROI class in :data:`CLASS_ORDER`) with its interval; negative: the
variant's error is lower. The kinds (:data:`KINDS`): ``network``, the trained stereo networks
(bootstrap over units and seed pairs, the paired t beside it), and ``optimum``, the losses' own
optimum (one deterministic run per variant and weight, bootstrap over units). Both also run on each
extra evaluation set (``<instrument> on <set>``), where a set of fewer than :data:`MIN_UNITS`
frames keeps its rows without an interval; elsewhere such rows are left out.

:func:`verdict_table` is the one layout of rows per class and :class:`Column`; compare.md, the
README, compare.json's ``summary`` and ``verdict.png`` all format it
(:mod:`msdepth.reporting.verdict`, :mod:`msdepth.reporting.figures`). A new instrument in the
summary table is its rows plus one :class:`Column` in :func:`headline_columns`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from msdepth.analysis.comparison import settings_text
from msdepth.analysis.runs import UNIT_KEYS, paired_statistics, unit_clusters
from msdepth.config.params import CompareConfig
from msdepth.evaluation.classes import class_unit_tables
from msdepth.stats import paired_table, seed_bootstrap

METRIC = "abs_rel"
FULL_FRAME = "full frame"
# The surface classes' order in every table and figure; other classes follow, sorted.
CLASS_ORDER = (FULL_FRAME, "car", "windshield", "glass", "sign", "reflective")
MIN_UNITS = 5
# The kinds of instrument, in the tables' order: {kind: (what its intervals are over, its colour)}.
KINDS = {
    "network": ("trained stereo networks: seed pairs × units", "tab:blue"),
    "optimum": ("the loss's own optimum: over units", "tab:orange"),
}
# How tables and sentences name a variant; a variant not listed keeps its own name.
NAMES = {"ssim": "SSIM", "msssim": "MS-SSIM", "mix": "MS-SSIM + L1 mix"}


@dataclass(frozen=True)
class Row:
    """One instrument's ``variant − reference`` abs_rel on one class, with its interval (None
    below :data:`MIN_UNITS` independent units) and, for paired networks, the paired t's."""

    instrument: str
    cls: str
    diff: float
    low: float | None
    high: float | None
    n: int
    method: str
    kind: str
    t_low: float | None = None
    t_high: float | None = None
    seeds: int = 0  # seed pairs (paired network rows) or seeds per variant; 0 = no training noise
    settings: str = ""
    per_seed: tuple[float, ...] = ()  # paired network rows: each seed pair's difference (diff is their mean)
    unit: str = ""  # what n counts where it is not images or ROIs (an extra set's frames); "" = those

    @property
    def has_interval(self) -> bool:
        return self.low is not None and self.high is not None

    @property
    def excludes_zero(self) -> bool:
        return self.has_interval and (self.low > 0 or self.high < 0)

    @property
    def t_excludes_zero(self) -> bool:
        return self.t_low is not None and self.t_high is not None and (self.t_low > 0 or self.t_high < 0)

    def as_dict(self) -> dict:
        """The row as compare.json holds it: its first eight fields, then the others where set."""
        d = dataclasses.asdict(self) | {"per_seed": list(self.per_seed)}
        kept = [k for i, (k, v) in enumerate(d.items()) if i < 8 or v not in (None, 0, "", [])]
        return {"class" if k == "cls" else k: d[k] for k in kept}

    @classmethod
    def from_dict(cls, d: Mapping) -> Row:
        """The inverse of :meth:`as_dict`."""
        fields = {k: v for k, v in d.items() if k != "class"}
        return cls(cls=d["class"], **fields | {"per_seed": tuple(d.get("per_seed", ()))})


def settings_label(settings: Mapping[str, Mapping], variants: Sequence[str]) -> str:
    """The settings of ``variants`` in one line, sorted, so that two rows made alike have one label.

    Example:
        >>> settings_label({"msssim": {"kernel_size": 7, "levels": 4}, "ssim": {"kernel_size": 3}},
        ...                ["ssim", "msssim"])
        'msssim: kernel_size=7, levels=4; ssim: kernel_size=3'
    """
    return "; ".join(f"{v}: {settings_text(settings.get(v, {}), names={})}" for v in sorted(variants))


def class_order(classes: Sequence[str]) -> list[str]:
    """``classes`` in :data:`CLASS_ORDER`, unknown ones after it, sorted."""
    known = [c for c in CLASS_ORDER if c in classes]
    return known + sorted(set(classes) - set(CLASS_ORDER))


def _class_tables(
    tables: Mapping[str, Mapping[str, pd.DataFrame]], anchor: str, whole_frame: bool = False
) -> list[tuple[str, str, dict]]:
    """``(class, suite, {run: table})``: the full-image tables as the full frame, with
    ``whole_frame`` each exact class of them (:func:`~msdepth.evaluation.classes.class_unit_tables`),
    then the ROI tables per class of ``anchor``'s."""
    out = [(FULL_FRAME, "full", dict(tables["full"]))] if "full" in tables else []
    if whole_frame and "full" in tables:
        out += [(cls, "full", chosen) for cls, chosen in class_unit_tables(dict(tables["full"]), anchor)]
    if "roi" in tables:
        roi = tables["roi"]
        for cls in class_order(list(roi[anchor]["class"].unique())):
            out.append((cls, "roi", {run: t[t["class"] == cls] for run, t in roi.items()}))
    return out


@dataclass(frozen=True)
class RowScope:
    """Where rows are made: ``whole_frame``, an extra set's exact classes (:func:`_class_tables`);
    ``unit``, what n counts (:attr:`Row.unit`); ``keep_few``, rows below :data:`MIN_UNITS` units
    kept without an interval rather than left out."""

    whole_frame: bool = False
    unit: str = ""
    keep_few: bool = False

    def units(self, suite: str) -> str:
        return self.unit or ("images" if suite == "full" else "ROIs")


def network_rows(
    tables: Mapping[str, Mapping[str, pd.DataFrame]],
    groups: Mapping[str, Sequence[str]],
    cfg: CompareConfig,
    cap: float,
    instrument: str = "stereo networks",
    pairing: Mapping[str, str | None] | None = None,
    settings: str = "",
    scope: RowScope = RowScope(),
) -> list[Row]:
    """Per class, each variant of ``groups`` (variant -> its runs) minus ``cfg.reference`` by the
    comparison's bootstrap over units and seeds (:func:`~msdepth.analysis.runs.paired_statistics`,
    seed pairs where ``pairing`` says so)."""
    rows = []
    others = [v for v in groups if v != cfg.reference]
    for cls, suite, chosen in _class_tables(tables, groups[cfg.reference][0], scope.whole_frame):
        block = paired_statistics({suite: chosen}, dict(groups), cfg, [cap], pairing)
        for variant in others:
            d = block[suite][f"cap{cap:g}"][variant][METRIC]
            few = (d.get("clusters") or d["n"]) < MIN_UNITS  # independent units: frames where drawn by frame
            if few and not scope.keep_few:
                continue
            unit = _unit_words(scope.units(suite), d.get("clusters"))
            method = _network_method(
                d, _drawn(scope.units(suite), d.get("clusters")), block["pairing"][variant]
            )
            name = instrument if len(others) == 1 else f"{instrument}, {variant}"
            seeds = d["seeds"] if d["paired"] else min(d["seeds"], d["reference_seeds"])
            low, high = (None, None) if few else (d["low"], d["high"])
            rows.append(
                Row(
                    name, cls, d["mean"], low, high, d["n"], method + _few_words(few), "network",
                    None if few else d.get("t_low"), None if few else d.get("t_high"), seeds, settings,
                    per_seed=tuple(d.get("per_seed", ())), unit=unit if d.get("clusters") else scope.unit,
                )
            )  # fmt: skip
    return rows


def _unit_words(unit: str, clusters: int | None) -> str:
    """What a row's n counts: ``ROIs``, or ``ROIs in 35 frames`` where the frames were drawn."""
    return unit if clusters is None else f"{unit} in {clusters} frame{'' if clusters == 1 else 's'}"


def _drawn(unit: str, clusters: int | None) -> str:
    """What the bootstrap resampled: the units, or the frames with all their units."""
    return unit if clusters is None else f"frames (each with all its {unit})"


def _few_words(few: bool) -> str:
    return f"; fewer than {MIN_UNITS} independent units: no interval" if few else ""


def _network_method(d: Mapping, unit: str, unpaired: str | None) -> str:
    """How a network row's interval was made, in words (its ``method``)."""
    if d.get("paired"):
        text = f"paired by seed ({d['seeds']} pairs): bootstrap over seed pairs and {unit}"
        if d.get("t_low") is not None:
            text += f"; paired t over the per-seed differences [{d['t_low']:+.3f}, {d['t_high']:+.3f}]"
        return text
    why = f"unpaired ({unpaired})" if unpaired else "unpaired"
    return f"{why}: bootstrap over {unit} and each variant's seeds ({d['seeds']} and {d['reference_seeds']})"


def optimum_rows(
    tables: Mapping[str, Mapping[str, pd.DataFrame]],
    runs: Mapping[str, Mapping[str, str]],
    cfg: CompareConfig,
    cap: float,
    settings: str = "",
    scope: RowScope = RowScope(),
    instrument: str = "optimum",
) -> list[Row]:
    """Per weight label (``runs``: e.g. ``w10`` -> {variant: its run}) and class, each variant minus
    ``cfg.reference``: :func:`~msdepth.stats.seed_bootstrap` of one run each over the shared units
    (ROIs drawn by frame). Rows are named ``<instrument> <label>``."""
    rows = []
    for weight, by_variant in runs.items():
        ref = by_variant[cfg.reference]
        others = [v for v in by_variant if v != cfg.reference]
        for cls, suite, chosen in _class_tables(tables, ref, scope.whole_frame):
            keys = UNIT_KEYS[suite]
            for variant in others:
                what = f"{suite} {instrument} {variant} vs {cfg.reference} {weight}, {cls}"
                a, b = (chosen[by_variant[variant]], chosen[ref])
                values, reference = paired_table(a[a["cap"] == cap], b[b["cap"] == cap], keys, METRIC, what)
                clusters = unit_clusters(suite, a[a["cap"] == cap])  # in values' order: a's rows
                k = None if clusters is None else len(set(clusters))
                few = (k or len(values)) < MIN_UNITS
                if (few and not scope.keep_few) or not len(values):
                    continue
                name = f"{instrument} {weight}" if len(others) == 1 else f"{instrument} {weight}, {variant}"
                drawn = _drawn(scope.units(suite), k)
                method = f"paired bootstrap over {drawn} (one deterministic run per variant)"
                if few:
                    diff, low, high = float(np.mean(values - reference)), None, None
                else:
                    d = seed_bootstrap(
                        values[None], reference[None], cfg.bootstrap_samples, cfg.confidence, cfg.seed,
                        clusters=clusters,
                    )  # fmt: skip
                    diff, low, high = d.mean, d.low, d.high
                unit = _unit_words(scope.units(suite), k) if k is not None else scope.unit
                method += _few_words(few)
                rows.append(
                    Row(
                        name,
                        cls,
                        diff,
                        low,
                        high,
                        len(values),
                        method,
                        "optimum",
                        settings=settings,
                        unit=unit,
                    )
                )
    return rows


def _class_sentence(cls: str, rows: Sequence[Row], better: str = "MS-SSIM") -> str:
    """``cls``'s rows in a sentence: where ``better``'s error is lower, which intervals exclude 0
    (which side, whether the paired t agrees), which rows have no interval."""
    own = [r for r in rows if r.cls == cls]
    lower = sum(r.diff < 0 for r in own)
    noun = "instrument" if len(own) == 1 else "instruments"
    text = f"{cls}: {better}'s error is lower in {lower} of {len(own)} {noun}"
    excluding = [r for r in own if r.excludes_zero]
    if excluding:
        text += f"; intervals excluding 0: {', '.join(_excluding_words(r) for r in excluding)}"
    else:
        text += "; no interval excludes 0"
    bare = [r for r in own if not r.has_interval]
    if bare:
        named = ", ".join(f"{r.instrument} (n={r.n})" for r in bare)
        text += f"; no interval (too few independent units): {named}"
    return text + "."


def _excluding_words(r: Row) -> str:
    """A row whose interval excludes 0, in a sentence: its side, and whether the paired t agrees."""
    words = f"{r.instrument} ({'lower' if r.diff < 0 else 'higher'}"
    if r.t_low is not None:
        words += "; the paired t agrees" if r.t_excludes_zero else "; the paired t includes 0"
    return words + ")"


def display_names(variants: Sequence[str], reference: str) -> tuple[str, str]:
    """The sentences' names of the compared variant and the reference (:data:`NAMES`)."""
    others = [v for v in variants if v != reference]
    if len(others) == 1:
        better = NAMES.get(others[0], others[0])
    else:  # none (one variant: no rows) or several
        better = "each other variant" if others else "MS-SSIM"
    return better, NAMES.get(reference, reference)


# --- the table: one function lays rows out, the renderers format it ----------------------------


@dataclass(frozen=True)
class Column:
    """One column of the verdict table: its ``header`` and its rows' ``kind`` and ``instrument``."""

    header: str
    kind: str
    instrument: str


# The optimum at each variant's own best smoothness weight (msdepth.optimum.selection).
OWN_BEST = "own best"


def headline_columns(
    weight: float, sets: Sequence[str] = (), box_sets: Sequence[str] = (), own_best: Sequence[str] = ()
) -> list[Column]:
    """The summary table's columns, one per instrument family: the stereo networks, the optimum at
    its default smoothness ``weight`` and at each loss's own best weight, and the optimum on each
    extra evaluation set of ``sets`` (its rows are named ``<instrument> on <set>``) and on the boxes
    of each set of ``box_sets`` (``<instrument> on <set> boxes``). A new instrument in the summary
    table is one more entry here.

    Args:
        weight: the optimum's default smoothness weight (``optimum.smoothness_weight``).
        sets: the extra evaluation sets (``eval.extra_sets``).
        box_sets: those of ``sets`` whose boxes were scored.
        own_best: the places (a set's name, or ``<set> boxes``) with own-best rows (the set ran
            more than one of ``optimum.set_weights``); each gets its column beside the fixed weight's.

    Returns:
        The columns, in the table's order.

    Example:
        >>> [c.header for c in headline_columns(10, ["kitti2012", "kitti2015"], ["kitti2015"])][3:]
        ['optimum w10, kitti2012 frames', 'optimum w10, kitti2015 frames', 'optimum w10, kitti2015 boxes']
        >>> [c.header for c in headline_columns(10, ["kitti2015"], own_best=["kitti2015"])][3:]
        ['optimum w10, kitti2015 frames', 'optimum own best, kitti2015 frames']
    """
    w = f"w{weight:g}"
    columns = [
        Column("stereo networks", "network", "stereo networks"),
        Column(f"loss's own optimum, {w}", "optimum", f"optimum {w}"),
        Column(f"optimum, each loss's {OWN_BEST} weight", "optimum", f"optimum {OWN_BEST}"),
    ]
    places = [(name, f"{name} frames") for name in sets] + [(f"{n} boxes", f"{n} boxes") for n in box_sets]
    for where, header in places:
        columns.append(Column(f"optimum {w}, {header}", "optimum", f"optimum {w} on {where}"))
        if where in own_best:
            columns.append(
                Column(f"optimum {OWN_BEST}, {header}", "optimum", f"optimum {OWN_BEST} on {where}")
            )
    return columns


def instrument_columns(rows: Sequence[Row]) -> list[Column]:
    """One column per instrument of ``rows``, by kind in :data:`KINDS`' order (the figure's)."""
    rank = {k: i for i, k in enumerate(KINDS)}
    ordered = sorted(rows, key=lambda r: rank.get(r.kind, len(rank)))
    return list(dict.fromkeys(Column(r.instrument, r.kind, r.instrument) for r in ordered))


def verdict_table(
    rows: Sequence[Row], columns: Sequence[Column], classes: Sequence[str]
) -> list[tuple[str, list[Row | None]]]:
    """The verdict table, the one layout every renderer formats.

    Args:
        rows: the verdict's rows.
        columns: the table's columns (:func:`headline_columns`, or :func:`instrument_columns`).
        classes: the table's rows, in order.

    Returns:
        Per class, one cell per column: the first row of its kind and instrument on that class, or None.

    Example:
        >>> car = Row("stereo networks", "car", -0.02, -0.04, 0.01, 40, "m", "network")
        >>> ((cls, cells),) = verdict_table([car], headline_columns(10), ["car"])
        >>> cls, [r and r.diff for r in cells]
        ('car', [-0.02, None, None])
    """
    cells = {(r.cls, r.kind, r.instrument): r for r in reversed(rows)}
    return [(cls, [cells.get((cls, c.kind, c.instrument)) for c in columns]) for cls in classes]


def columns_of(data: Mapping) -> list[Column]:
    """The summary table's columns as compare.json's ``verdict.headline`` stores them."""
    return [Column(header, kind, instrument) for header, (kind, instrument) in data["headline"].items()]


def rows_of(data: Mapping) -> list[Row]:
    """compare.json's ``verdict.rows`` as :class:`Row` s."""
    return [Row.from_dict(d) for d in data["rows"]]


def verdict_data(
    rows: Sequence[Row],
    cap: float,
    confidence: float,
    better: str,
    than: str,
    settings: str = "",
    columns: Sequence[Column] | None = None,
) -> dict:
    """compare.json's ``verdict``: the rows, the summary table's columns (``headline``, default
    :func:`headline_columns` at weight 10) and cells (``summary``), the classes, a sentence per class."""
    classes = class_order(sorted({r.cls for r in rows}))
    columns = list(columns or headline_columns(10.0))
    summary = {
        cls: {c.header: None if r is None else r.as_dict() for c, r in zip(columns, cells, strict=True)}
        for cls, cells in verdict_table(rows, columns, classes)
    }
    return {
        "metric": METRIC,
        "cap": f"cap{cap:g}",
        "confidence": confidence,
        "variant": better,
        "reference": than,
        "settings": settings,
        "min_units": MIN_UNITS,
        "classes": classes,
        "headline": {c.header: [c.kind, c.instrument] for c in columns},
        "summary": summary,
        "rows": [r.as_dict() for r in rows],
        "sentences": {c: _class_sentence(c, rows, better) for c in classes},
    }
