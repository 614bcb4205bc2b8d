"""The verdict in numbers: per surface class, MS-SSIM − SSIM abs_rel as every instrument measures it.

A *row* is one instrument's difference ``variant − reference`` (``compare.reference``, SSIM by
default) in abs_rel on one surface class, with its interval: ``{"instrument", "class", "diff",
"low", "high", "n", "method"}`` plus ``"kind"``. Negative: the variant's error is lower. The
classes are the full frame (``"full frame"``) and each ROI class (car, windshield, glass, sign,
``reflective`` where a set has it). The instruments, and how each interval is made:

- ``network``: the pipeline's trained stereo networks, every seed. The comparison's own bootstrap
  (:func:`msdepth.reporting.compare.paired_statistics`, i.e.
  :func:`msdepth.reporting.stats.seed_bootstrap`) over images, or over the class's ROIs (the ROI
  table filtered to the class), and each variant's seeds.
- ``optimum``: the losses' own optimum at each smoothness weight (one run per variant and weight,
  no training noise): :func:`msdepth.reporting.stats.seed_bootstrap` of one run each, over the
  images that weight was scored on, or over the frames of its ROIs (each with all its ROIs).
- the same two on each extra evaluation set (``eval.extra_sets``), named ``<instrument> on <set>``
  (:func:`msdepth.reporting.pipeline_compare.set_verdict_rows`): the frames are the units, on the
  whole frame and on each exact class the set's frames carry (KITTI 2012's ``reflective``, KITTI
  2015's ``car``: :class:`RowScope`), with the SGM matcher on each variant's cost volume (``SGM
  cost start``) beside the optimum; a set of fewer than :data:`MIN_UNITS` frames shows its rows
  without an interval.
- ``seeds``: the monocular study's mono and mono+stereo networks (``studies/monocular.py``),
  known per seed (its ``table.json``) or, where only its ``table.md`` exists, as mean ± sd over
  ``n`` seeds (:func:`_parse_monocular_table`). Welch's t interval of the difference of the two
  variants' means over seeds (:func:`welch_interval`): it covers training noise, with the images
  held fixed. Their full-frame abs_rel is median-scaled per image, as the study scores it.
- ``external``: rows another study wrote, read from a JSON file (:func:`read_external_rows`; the
  pipeline's own verdict reads none: real frames enter as extra sets). Its schema: a JSON list
  (``[]`` for none) of objects with exactly these keys::

      {"instrument": "optimum w10",      # a name; the same name as a pipeline row means the same quantity
       "class": "windshield",           # "full frame" or a ROI class
       "diff": -0.012,                  # mean of MS-SSIM − SSIM abs_rel (negative: MS-SSIM better)
       "low": -0.030, "high": 0.004,    # its interval at compare.confidence (95 %), low <= diff <= high
       "n": 14,                         # the units (images, ROIs or seeds) the interval is over, >= 1
       "method": "paired bootstrap over ROIs, 2 KITTI 2015 frames"}   # how, in words

- ``pooled``: see :func:`pooled_rows`. Rows of different instruments are never pooled: they
  measure different quantities (a training mode, a weight) on the same frames, so they are not
  independent of the frames' draw. Network rows are never pooled either: every row of a network
  instrument scores the same trained networks, so their seed noise is shared. Only rows of one
  optimum instrument (``optimum w<weight>``, a per-frame quantity without training noise) from
  different sources (the pipeline's frames and an external study's other frames) are pooled, by
  inverse-variance weighting (the fixed-effect estimate of one common difference; each row's
  variance from its interval's half-width, normal approximation).

A row over fewer than :data:`MIN_UNITS` units is left out: a percentile interval over one or two
ROIs is 0 wide, not certain. :func:`_class_sentence` states each class in one sentence.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from msdepth.config.params import CompareConfig
from msdepth.errors import DataError
from msdepth.evaluation.classes import class_unit_tables
from msdepth.readers import read_json_file, read_text_file
from msdepth.reporting.compare import UNIT_KEYS, paired_statistics, unit_clusters
from msdepth.reporting.power import t_quantile
from msdepth.reporting.stats import paired_t, paired_table, seed_bootstrap

METRIC = "abs_rel"
VERDICT_FIGURE = "verdict.png"  # below plots/figures: the figures stage draws it (figures.verdict_figure)
FULL_FRAME = "full frame"
CLASS_ORDER = (FULL_FRAME, "car", "windshield", "glass", "sign", "reflective")
MIN_UNITS = 5
EXTERNAL_FIELDS = ("instrument", "class", "diff", "low", "high", "n", "method")
EXTERNAL_OPTIONAL = ("settings", "t_low", "t_high", "seeds", "per_seed", "unit")
KINDS = ("network", "seeds", "optimum", "external", "pooled")
DISPLAY_NAMES = {"ssim": "SSIM", "msssim": "MS-SSIM"}  # the two losses the verdict is about
MONOCULAR_MODES = {"mono": "mono networks", "mono_stereo": "mono+stereo networks"}
POOLABLE = re.compile(r"optimum w\S+$")  # the optimum's instruments: no training noise


@dataclass(frozen=True)
class Row:
    """One instrument's ``variant − reference`` abs_rel on one class, with its interval.

    ``low`` and ``high`` are None where the row has too few independent units for an interval
    (fewer than :data:`MIN_UNITS`): its ``method`` says why. ``t_low`` / ``t_high``: the paired t
    interval over seed pairs beside a network row's bootstrap. ``settings``: the two variants'
    settings the row was made with (:func:`settings_label`); a row made under other settings than
    the run's is shown apart (``apart``: why), never counted or pooled.
    """

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
    apart: str = ""
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

    @property
    def family(self) -> str:
        """The instrument family of the README's table: networks, the optimum, or real pairs."""
        return FAMILIES.get(self.kind, self.kind)

    @property
    def label(self) -> str:
        """The row's name in sentences, tables and figures: the instrument, and for another
        study's row also its source (its method's text before ":"), so that a real-pairs
        ``optimum w10`` is not read as, or drawn over, the pipeline's own row of that name."""
        if self.kind != "external":
            return self.instrument
        source = self.method.split(":", 1)[0].strip() if ":" in self.method else "another study"
        return f"{self.instrument}, {source}"

    def as_dict(self) -> dict:
        """The row as compare.json holds it (the external schema's keys, then the optional ones)."""
        d = {
            "instrument": self.instrument,
            "class": self.cls,
            "diff": self.diff,
            "low": self.low,
            "high": self.high,
            "n": self.n,
            "method": self.method,
            "kind": self.kind,
        }
        optional = {"t_low": self.t_low, "t_high": self.t_high, "seeds": self.seeds}
        optional |= {"settings": self.settings, "apart": self.apart, "per_seed": list(self.per_seed)}
        optional |= {"unit": self.unit}
        return d | {k: v for k, v in optional.items() if v not in (None, 0, "", [])}

    @classmethod
    def from_dict(cls, d: Mapping) -> Row:
        """The inverse of :meth:`as_dict` (``kind`` defaults to ``external``)."""

        def number(key: str) -> float | None:
            return None if d.get(key) is None else float(d[key])

        return cls(
            str(d["instrument"]),
            str(d["class"]),
            float(d["diff"]),
            number("low"),
            number("high"),
            int(d["n"]),
            str(d["method"]),
            str(d.get("kind", "external")),
            number("t_low"),
            number("t_high"),
            int(d.get("seeds", 0)),
            str(d.get("settings", "")),
            str(d.get("apart", "")),
            tuple(float(x) for x in d.get("per_seed", ())),
            str(d.get("unit", "")),
        )


FAMILIES = {
    "network": "networks",
    "seeds": "networks",
    "optimum": "loss's own optimum",
    "external": "real pairs",
    "pooled": "pooled",
}


def settings_label(settings: Mapping[str, Mapping], variants: Sequence[str]) -> str:
    """The settings of ``variants`` (each its params section, e.g. compare's ``variant_settings``)
    in one line, the variants in sorted order, so that two rows made alike have one label.

    Example:
        >>> settings_label({"msssim": {"kernel_size": 7, "levels": 4}, "ssim": {"kernel_size": 3}},
        ...                ["ssim", "msssim"])
        'msssim: kernel_size=7, levels=4; ssim: kernel_size=3'
    """
    parts = []
    for v in sorted(variants):
        items = ", ".join(
            f"{k}={x:g}" if isinstance(x, float) else f"{k}={x}" for k, x in settings.get(v, {}).items()
        )
        parts.append(f"{v}: {items}")
    return "; ".join(parts)


def class_order(classes: Sequence[str]) -> list[str]:
    """``classes`` in :data:`CLASS_ORDER`, unknown ones after it, sorted."""
    known = [c for c in CLASS_ORDER if c in classes]
    return known + sorted(set(classes) - set(CLASS_ORDER))


def _class_tables(
    tables: Mapping[str, Mapping[str, pd.DataFrame]], anchor: str, whole_frame: bool = False
) -> list[tuple[str, str, dict]]:
    """``(class, suite, {run: table})``: the full-image tables as the full frame, then the ROI
    tables filtered to each class that ``anchor``'s ROI table holds; with ``whole_frame`` (an
    extra set's exact classes), each class column of the full-image tables instead
    (:func:`msdepth.evaluation.classes.class_unit_tables`: per frame, its pixels of the class)."""
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
    """Where rows are made: ``whole_frame``, an extra set's exact classes per frame
    (:func:`_class_tables`); ``unit``, what n counts there (:attr:`Row.unit`; "" = images or ROIs);
    ``keep_few``, rows over fewer than :data:`MIN_UNITS` units kept without an interval (a set of a
    few frames shows its point estimates) rather than left out."""

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
    """Per class, each variant of ``groups`` (variant -> its runs, the reference's included) minus
    ``cfg.reference``, by the comparison's bootstrap over units and seeds; ``tables`` is
    :func:`msdepth.reporting.compare.load_unit_tables`' ``{suite: {run: table}}``. ``pairing``
    (:func:`msdepth.reporting.compare.pairing_status`): the variants whose seeds pair with the
    reference's are compared pair by pair, with the paired t beside the bootstrap."""
    rows = []
    others = [v for v in groups if v != cfg.reference]
    for cls, suite, chosen in _class_tables(tables, groups[cfg.reference][0], scope.whole_frame):
        block = paired_statistics({suite: chosen}, dict(groups), cfg, [cap], pairing)
        for variant in others:
            d = block[suite][f"cap{cap:g}"][variant][METRIC]
            few = _independent(d["n"], d.get("clusters")) < MIN_UNITS
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


def _independent(n: int, clusters: int | None) -> int:
    """The independent units of a difference: its clusters (frames) where its units were drawn by them."""
    return n if clusters is None else clusters


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
    """Per weight (``runs``: weight label, e.g. ``w10``, -> {variant: its optimum run}) and class,
    each variant minus ``cfg.reference``: :func:`~msdepth.reporting.stats.seed_bootstrap` of one
    run each over the units both runs were scored on (ROIs: drawn by frame). ``instrument``: the
    rows' name before the weight label (``SGM`` with the label ``cost start``: the SGM matchers on
    each variant's cost volume)."""
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
                few = _independent(len(values), k) < MIN_UNITS
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
                row = Row(
                    name,
                    cls,
                    diff,
                    low,
                    high,
                    len(values),
                    method + _few_words(few),
                    "optimum",
                    settings=settings,
                )
                unit = _unit_words(scope.units(suite), k) if k is not None else scope.unit
                rows.append(dataclasses.replace(row, unit=unit))
    return rows


# --- the monocular study's networks: intervals over seeds -------------------------------------


def welch_interval(
    a: tuple[float, float, int], b: tuple[float, float, int], confidence: float = 0.95
) -> tuple[float, float, float]:
    """``(diff, low, high)`` of ``mean(a) − mean(b)``, each side ``(mean, sd, n)`` over independent
    runs: Welch's t interval (Welch–Satterthwaite degrees of freedom).

    Args:
        a: the variant's (mean, sd, n) over its runs.
        b: the reference's.
        confidence: the interval's level.

    Returns:
        The difference and its interval's ends.

    Raises:
        ValueError: fewer than 2 runs a side.

    Example:
        >>> [round(x, 4) for x in welch_interval((1.0, 0.1, 3), (0.9, 0.1, 3))]
        [0.1, -0.1267, 0.3267]
    """
    (ma, sa, na), (mb, sb, nb) = a, b
    if na < 2 or nb < 2:
        raise ValueError(f"welch_interval: need at least 2 runs a side, got {na} and {nb}")
    va, vb = sa * sa / na, sb * sb / nb
    diff = ma - mb
    if va + vb == 0:
        return diff, diff, diff
    df = (va + vb) ** 2 / (va * va / (na - 1) + vb * vb / (nb - 1))
    half = t_quantile(0.5 + confidence / 2, df) * math.sqrt(va + vb)
    return diff, diff - half, diff + half


Spread = tuple[float, float, int]  # (mean, sd, n) over seeds
# {mode: {variant: {class: spread, or one value per seed (the same seeds for every variant)}}}
MonocularStats = dict[str, dict[str, dict[str, Spread | list[float]]]]
SETTINGS_LINE = "Variant settings: "  # the monocular table's line naming what its runs were trained with


def _parse_monocular_table(path: Path) -> MonocularStats:
    """The monocular study's ``table.md``, read as written by ``studies/monocular.py``'s ``table``:
    ``n`` from its line "Mean ± sd over seeds [s, ...]", then per row of its table (``mode``,
    ``variant``) the cells ``mean ± sd`` of the columns ``abs_rel`` (the full frame) and ``ROI
    <class>``; cells without `` ± `` (``–``) are skipped. A DataError names the file when the line
    or the table is not there or a cell is not two numbers."""
    text = read_text_file(path, "monocular table")
    seeds = re.search(r"over seeds \[([^\]]*)\]", text)
    lines = [x.strip() for x in text.splitlines() if x.strip().startswith("| ")]
    if not seeds or not lines or not lines[0].startswith("| mode | variant |"):
        raise DataError(
            f"{path}: not the monocular study's table (no 'over seeds [...]' line or '| mode |' table)"
        )
    n = len([s for s in seeds.group(1).split(",") if s.strip()])
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    columns = {
        i: FULL_FRAME if h == METRIC else h[4:]
        for i, h in enumerate(header)
        if h == METRIC or h.startswith("ROI ")
    }
    out: MonocularStats = {}
    for line in lines[1:]:
        cells = [c.strip() for c in line.strip("|").split("|")]
        for i, cls in columns.items():
            if i >= len(cells) or " ± " not in cells[i]:
                continue
            try:
                mean, sd = (float(x) for x in cells[i].split(" ± "))
            except ValueError:
                raise DataError(
                    f"{path}: row {cells[:2]}, column {header[i]!r}: {cells[i]!r} is not 'mean ± sd'"
                ) from None
            out.setdefault(cells[0], {}).setdefault(cells[1], {})[cls] = (mean, sd, n)
    return out


def read_monocular(json_path: Path, table_path: Path) -> MonocularStats:
    """The monocular study's numbers: per seed from ``json_path`` (``{"seeds": [...], "modes":
    {mode: {variant: {class: [one value per seed]}}}}``, what ``studies/monocular.py`` writes),
    else :func:`_parse_monocular_table` of ``table_path``; {} when neither exists."""
    if Path(json_path).is_file():
        try:
            modes = read_json_file(json_path, "monocular per-seed values")["modes"]
            return {
                mode: {
                    variant: {cls: [float(x) for x in v] for cls, v in classes.items()}
                    for variant, classes in variants.items()
                }
                for mode, variants in modes.items()
            }
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise DataError(f"{json_path}: not the monocular study's per-seed values ({exc})") from None
    return _parse_monocular_table(table_path) if Path(table_path).is_file() else {}


def read_monocular_settings(json_path: Path, table_path: Path) -> str:
    """The settings label (:func:`settings_label`) the monocular study's runs were trained with:
    ``json_path``'s ``settings``, else ``table_path``'s line starting :data:`SETTINGS_LINE`; "" when
    neither records them."""
    if Path(json_path).is_file():
        try:
            return str(read_json_file(json_path, "monocular per-seed values").get("settings", ""))
        except AttributeError:  # not an object: read_monocular names the file
            return ""
    if Path(table_path).is_file():
        for line in read_text_file(table_path, "monocular table").splitlines():
            if line.startswith(SETTINGS_LINE):
                return line[len(SETTINGS_LINE) :].strip().strip("`")
    return ""


def _spread(v: Spread | list[float]) -> Spread:
    return v if isinstance(v, tuple) else (float(np.mean(v)), float(np.std(v, ddof=1)), len(v))


def _seed_difference(a: Spread | list[float], b: Spread | list[float], confidence: float) -> tuple:
    """``(diff, low, high, n, method)`` of ``a − b`` over seeds: by seed pair (paired t) where both
    are per-seed values of the same seeds, else Welch's t from mean ± sd (unpaired)."""
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b) >= 2:
        diff, low, high = paired_t(np.subtract(a, b), confidence)
        return (
            diff,
            low,
            high,
            len(a),
            f"paired by seed ({len(a)} pairs): paired t over the per-seed differences",
        )
    sa, sb = _spread(a), _spread(b)
    diff, low, high = welch_interval(sa, sb, confidence)
    why = "the study's table keeps mean ± sd, not each seed's value"
    return diff, low, high, min(sa[2], sb[2]), f"unpaired ({why}): Welch t over {sa[2]} and {sb[2]} seeds"


def seed_rows(stats: MonocularStats, reference: str, confidence: float, settings: str = "") -> list[Row]:
    """Per mode of :data:`MONOCULAR_MODES` and class, each variant minus ``reference`` over seeds
    (:func:`_seed_difference`). (The study's stereo rows are the pipeline's own networks, which
    :func:`network_rows` compares unit by unit.)"""
    rows = []
    for mode, instrument in MONOCULAR_MODES.items():
        variants = stats.get(mode, {})
        if reference not in variants:
            continue
        others = [v for v in variants if v != reference]
        for variant in others:
            for cls in class_order([c for c in variants[variant] if c in variants[reference]]):
                diff, low, high, n, method = _seed_difference(
                    variants[variant][cls], variants[reference][cls], confidence
                )
                if cls == FULL_FRAME:
                    method += " (median-scaled per image)"
                name = instrument if len(others) == 1 else f"{instrument}, {variant}"
                rows.append(Row(name, cls, diff, low, high, n, method, "seeds", seeds=n, settings=settings))
    return rows


# --- other studies' rows ------------------------------------------------------------------------


def _checked_row(item: object, i: int, path: Path) -> Row:
    """One external row, checked against the schema (module docstring); a DataError names ``path``."""
    where = f"{path}: row {i}"
    if not isinstance(item, dict) or not set(EXTERNAL_FIELDS) <= set(item) <= {
        *EXTERNAL_FIELDS,
        *EXTERNAL_OPTIONAL,
    }:
        got = sorted(item) if isinstance(item, dict) else type(item).__name__
        keys, optional = ", ".join(EXTERNAL_FIELDS), ", ".join(EXTERNAL_OPTIONAL)
        raise DataError(f"{where}: needs the keys {keys} (optional: {optional}), got {got}")
    for key in ("instrument", "class", "method"):
        if not isinstance(item[key], str) or not item[key]:
            raise DataError(f"{where}: {key} must be a non-empty string, got {item[key]!r}")
    if not isinstance(item.get("settings", ""), str):
        raise DataError(f"{where}: settings must be a string, got {item['settings']!r}")
    nullable = ("low", "high", "t_low", "t_high")
    for key in ("diff", "low", "high", "t_low", "t_high"):
        value = item.get(key)
        if value is None and key in nullable:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise DataError(f"{where}: {key} must be a finite number, got {value!r}")
    per_seed = item.get("per_seed", [])
    if not isinstance(per_seed, list) or not all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in per_seed
    ):
        raise DataError(f"{where}: per_seed must be a list of finite numbers")
    if (item["low"] is None) != (item["high"] is None):
        raise DataError(f"{where}: low and high are both numbers or both null")
    if item["low"] is not None and not item["low"] <= item["diff"] <= item["high"]:
        raise DataError(
            f"{where}: needs low <= diff <= high, got {item['low']}, {item['diff']}, {item['high']}"
        )
    if isinstance(item["n"], bool) or not isinstance(item["n"], int) or item["n"] < 1:
        raise DataError(f"{where}: n must be a positive integer, got {item['n']!r}")
    return Row.from_dict({**item, "kind": "external"})


def read_external_rows(path: Path) -> list[Row]:
    """Another study's rows from the JSON file ``path`` (schema: the module docstring); [] when the
    file does not exist. A DataError, one line naming the file, when it is not that schema."""
    path = Path(path)
    if not path.is_file():
        return []
    items = read_json_file(path, "verdict rows")
    if not isinstance(items, list):
        raise DataError(f"{path}: needs a JSON list of rows, got {type(items).__name__}")
    return [_checked_row(item, i, path) for i, item in enumerate(items)]


# --- pooling and words --------------------------------------------------------------------------


def pooled_rows(rows: Sequence[Row], confidence: float = 0.95) -> list[Row]:
    """Per class, one pooled row per optimum instrument measured by two rows or more (the
    pipeline's and an external study's, on other frames): inverse-variance weighted mean, each
    row's standard error its interval's half-width over the normal quantile; interval ±quantile·SE.
    Only rows with an interval, made under the same settings and not shown apart, are pooled; other
    instruments never are (module docstring: why).

    Args:
        rows: the verdict's rows.
        confidence: the level of the rows' intervals and of the pooled one.

    Returns:
        One ``pooled`` row per (class, optimum instrument, settings) measured twice or more.

    Example:
        >>> a = Row("optimum w10", "car", -0.02, -0.04, 0.0, 40, "m", "optimum")
        >>> b = Row("optimum w10", "car", -0.04, -0.06, -0.02, 16, "real pairs: m", "external")
        >>> (p,) = pooled_rows([a, b])
        >>> p.instrument, round(p.diff, 3), p.n
        ('optimum w10, pooled', -0.03, 56)
    """
    z = float(np.sqrt(2) * _erfinv(confidence))
    groups: dict[tuple[str, str, str], list[Row]] = {}
    for r in rows:
        if (
            r.kind in ("optimum", "external")
            and POOLABLE.match(r.instrument)
            and r.has_interval
            and not r.apart
        ):
            groups.setdefault((r.cls, r.instrument, r.settings), []).append(r)
    out = []
    for (cls, instrument, settings), members in groups.items():
        if len(members) < 2:
            continue
        se = [max((r.high - r.low) / (2 * z), 1e-12) for r in members]  # a 0-wide interval: all weight
        w = np.array([1 / s**2 for s in se])
        mean = float(np.dot(w, [r.diff for r in members]) / w.sum())
        half = z / math.sqrt(w.sum())
        sources = ", ".join(r.label for r in members)
        method = f"inverse-variance pool of {len(members)} independent rows ({sources})"
        n = sum(r.n for r in members)
        out.append(
            Row(
                f"{instrument}, pooled",
                cls,
                mean,
                mean - half,
                mean + half,
                n,
                method,
                "pooled",
                settings=settings,
            )
        )
    return out


def _set_apart(rows: Sequence[Row], settings: str) -> list[Row]:
    """``rows`` with those made under other settings than ``settings`` (the run's own) marked
    ``apart``: a study's committed rows after `dvc exp run -S msssim.kernel_size=7`, say. Such a row
    is shown with its settings and never counted or pooled."""
    out = []
    for r in rows:
        if r.settings == settings or not settings:
            out.append(r)
        elif not r.settings:
            out.append(dataclasses.replace(r, apart="its settings are not recorded"))
        else:
            out.append(dataclasses.replace(r, apart=f"made with {r.settings}"))
    return out


def _erfinv(y: float) -> float:
    """The inverse error function, by bisection (``0 <= y < 1``)."""
    low, high = 0.0, 10.0
    for _ in range(100):
        mid = (low + high) / 2
        low, high = (mid, high) if math.erf(mid) < y else (low, mid)
    return (low + high) / 2


def signed(x: float, decimals: int = 3) -> str:
    """``x`` with its sign, the minus as U+2212 (as the results page writes numbers)."""
    return f"{x:+.{decimals}f}".replace("-", "\u2212")


def _class_sentence(cls: str, rows: Sequence[Row], better: str = "MS-SSIM") -> str:
    """One sentence from ``cls``'s rows (those shown apart left out): in how many instruments
    ``better``'s error (abs_rel) is lower, which intervals exclude 0 (and on which side, with the
    paired t's agreement where a row has one), and the pooled estimates."""
    own = [r for r in rows if r.cls == cls and r.kind != "pooled" and not r.apart]
    pooled = [r for r in rows if r.cls == cls and r.kind == "pooled"]
    if not own:
        return f"{cls}: no row under this run's settings (rows made under others: `metrics/compare.md`)."
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
        text += (
            f"; no interval (too few independent units): {', '.join(f'{r.label} (n={r.n})' for r in bare)}"
        )
    for r in pooled:
        text += f"; {r.instrument}: {signed(r.diff)} [{signed(r.low)}, {signed(r.high)}]"
    return text + "."


def _excluding_words(r: Row) -> str:
    """A row whose interval excludes 0, in a sentence: its side, and whether the paired t agrees."""
    words = f"{r.label} ({'lower' if r.diff < 0 else 'higher'}"
    if r.t_low is not None:
        words += "; the paired t agrees" if r.t_excludes_zero else "; the paired t includes 0"
    return words + ")"


def display_names(variants: Sequence[str], reference: str) -> tuple[str, str]:
    """The sentences' names of the compared variant and of the reference: ``MS-SSIM``, ``SSIM``
    (with several compared variants, ``each variant``)."""
    others = [v for v in variants if v != reference]
    if len(others) == 1:
        better = DISPLAY_NAMES.get(others[0], others[0])
    else:  # none (one variant: no rows but external ones) or several
        better = "each other variant" if others else "MS-SSIM"
    return better, DISPLAY_NAMES.get(reference, reference)


def headline_instruments(
    weight: float, sets: Sequence[str] = (), box_sets: Sequence[str] = ()
) -> dict[str, tuple[str, str]]:
    """The instrument of each family that the summary table shows: ``{family: (kind, instrument)}``:
    the stereo networks, the optimum at its default smoothness ``weight``, and that optimum on each
    extra evaluation set of ``sets`` (its rows are named ``<instrument> on <set>``) and on the boxes
    of each set of ``box_sets`` (``<instrument> on <set> boxes``).

    Example:
        >>> list(headline_instruments(10, ["kitti2012", "kitti2015"], ["kitti2015"]))[2:]
        ['optimum w10, kitti2012 frames', 'optimum w10, kitti2015 frames', 'optimum w10, kitti2015 boxes']
    """
    families = {
        "stereo networks": ("network", "stereo networks"),
        f"loss's own optimum, w{weight:g}": ("optimum", f"optimum w{weight:g}"),
    }
    for name in sets:
        families[f"optimum w{weight:g}, {name} frames"] = ("optimum", f"optimum w{weight:g} on {name}")
    for name in box_sets:
        families[f"optimum w{weight:g}, {name} boxes"] = ("optimum", f"optimum w{weight:g} on {name} boxes")
    return families


def summary_table(rows: Sequence[Row], headline: Mapping[str, tuple[str, str]]) -> dict:
    """``{class: {family: row dict or None}}``: per class, each family's headline instrument."""
    out: dict = {}
    for cls in class_order(sorted({r.cls for r in rows})):
        out[cls] = {}
        for family, (kind, instrument) in headline.items():
            match = [
                r
                for r in rows
                if r.cls == cls and r.kind == kind and r.instrument == instrument and not r.apart
            ]
            out[cls][family] = match[0].as_dict() if match else None
    return out


def verdict_data(
    rows: Sequence[Row],
    cap: float,
    confidence: float,
    better: str,
    than: str,
    settings: str = "",
    headline: Mapping[str, tuple[str, str]] | None = None,
) -> dict:
    """compare.json's ``verdict``: the rows (those of other settings than ``settings`` marked apart:
    :func:`_set_apart`; with :func:`pooled_rows`), the summary table of ``headline``'s instruments
    (:func:`summary_table`), the classes in order and a sentence per class (:func:`_class_sentence`)."""
    rows = _set_apart(rows, settings)
    rows = [*rows, *pooled_rows(rows, confidence)]
    classes = class_order(sorted({r.cls for r in rows}))
    headline = dict(headline or headline_instruments(10.0))
    return {
        "metric": METRIC,
        "cap": f"cap{cap:g}",
        "confidence": confidence,
        "variant": better,
        "reference": than,
        "settings": settings,
        "min_units": MIN_UNITS,
        "classes": classes,
        "headline": {family: list(v) for family, v in headline.items()},
        "summary": summary_table(rows, headline),
        "rows": [r.as_dict() for r in rows],
        "sentences": {c: _class_sentence(c, rows, better) for c in classes},
    }


VERDICT_TITLE = "The verdict per surface class"


def interval_cell(r: Row, decimals: int = 3) -> str:
    """A row's difference and interval as a table cell: ``−0.036 [−0.068, −0.002] *`` (``*``: it
    excludes 0); a row without an interval says so.

    Example:
        >>> interval_cell(Row("x", "car", -0.036, -0.068, -0.002, 66, "m", "network"))
        '−0.036 [−0.068, −0.002] *'
    """
    if not r.has_interval:
        return f"{signed(r.diff, decimals)} (no interval)"
    star = " *" if r.excludes_zero else ""
    return f"{signed(r.diff, decimals)} [{signed(r.low, decimals)}, {signed(r.high, decimals)}]{star}"


def _units_text(r: Row) -> str:
    """What a row's n counts, short: ``66 ROIs × 3 seed pairs``, ``5 frames``, ``3 seeds``."""
    unit = r.unit or ("images" if r.cls == FULL_FRAME else "ROIs")
    if r.kind == "network":
        pairs = "seed pairs" if r.method.startswith("paired") else "seeds a side"
        return f"{r.n} {unit} × {r.seeds} {pairs}"
    if r.kind == "seeds":
        return f"{r.n} {'seed pairs' if r.method.startswith('paired') else 'seeds a side'}"
    if r.kind == "external":
        return f"{r.n} units"
    return f"{r.n} {unit}" if r.kind == "optimum" else f"{r.n} units"


def summary_lines(data: dict) -> list[str]:
    """The summary table: one row per surface class, one column per instrument family (its
    headline instrument), each cell the difference, its interval and its n."""
    families = list(data["headline"])
    header = " | ".join(families)
    lines = [f"| class | {header} |", "|---" * (len(families) + 1) + "|"]
    for cls in data["classes"]:
        cells = []
        for f in families:
            d = data["summary"].get(cls, {}).get(f)
            cells.append(
                "–"
                if d is None
                else f"{interval_cell(Row.from_dict(d))}, n = {_units_text(Row.from_dict(d))}"
            )
        lines.append(f"| {cls} | {' | '.join(cells)} |")
    return lines


def answer_sentence(data: dict) -> str:
    """The summary table in one sentence: per instrument family, on how many surface classes the
    variant's error is lower and where its interval excludes 0 (with the paired t's agreement).

    Example:
        >>> rows = [Row("stereo networks", "car", -0.02, -0.03, -0.01, 91, "m", "network", -0.05, 0.01)]
        >>> print(answer_sentence(verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM")))
        stereo networks: lower on 1 of 1 surface class; its interval excludes 0 on car (the paired t
        over seeds includes 0).
    """
    parts = []
    for family in data["headline"]:
        cells = {c: Row.from_dict(f[family]) for c, f in data["summary"].items() if f.get(family)}
        if not cells:
            continue
        lower = [c for c, r in cells.items() if r.diff < 0]
        noun = "class" if len(cells) == 1 else "classes"
        text = f"{family}: lower on {len(lower)} of {len(cells)} surface {noun}"
        excluding = [c for c, r in cells.items() if r.excludes_zero]
        if excluding:
            words = [c + _t_words(cells[c]) for c in excluding]
            text += f"; its interval excludes 0 on {', '.join(words)}"
            higher = [c for c in excluding if cells[c].diff > 0]
            text += f" (higher on {', '.join(higher)})" if higher else ""
        else:
            text += "; no interval excludes 0"
        parts.append(text)
    return "; ".join(parts) + "." if parts else "No instrument compares two variants here."


def _t_words(r: Row) -> str:
    """`` (the paired t over seeds agrees)`` or ``... includes 0)`` where the row has a paired t."""
    if r.t_low is None:
        return ""
    return (
        " (the paired t over seeds agrees)" if r.t_excludes_zero else " (the paired t over seeds includes 0)"
    )


def verdict_lines(data: dict | None) -> list[str]:
    """compare.md's verdict section from :func:`verdict_data`'s dict: the summary table, what a row
    is, one table row per instrument and class (those made under other settings apart), then the
    sentences."""
    if not data or not data["rows"]:
        return [f"# {VERDICT_TITLE}", "", "No instrument compares two variants here.", ""]
    level = f"{data['confidence'] * 100:g} %"
    rows = [Row.from_dict(d) for d in data["rows"]]
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
        "n: the units (images, ROIs, frames, objects or seed pairs); ROIs are resampled with their "
        f"frame, so the frames are their independent units; with fewer than {MIN_UNITS} independent "
        "units a row has no interval. Pooled only where rows measure one quantity "
        "independently under one setting (src/msdepth/reporting/verdict.py). "
        "The figure: `plots/figures/verdict.png`.",
        "",
        "| class | instrument | difference | paired t | n | method |",
        "|---|---|---|---|---|---|",
    ]
    for cls in data["classes"]:
        for r in rows:
            if r.cls == cls and not r.apart:
                t = f"[{signed(r.t_low)}, {signed(r.t_high)}]" if r.t_low is not None else "–"
                lines.append(
                    f"| {cls} | {r.label} | {interval_cell(r)} | {t} | {_units_text(r)} | {r.method} |"
                )
    apart = [r for r in rows if r.apart]
    if apart:
        lines += ["", "Made under other settings (shown apart, never counted or pooled):", ""]
        lines += ["| class | instrument | difference | n | why apart |", "|---|---|---|---|---|"]
        lines += [
            f"| {r.cls} | {r.label} | {interval_cell(r)} | {_units_text(r)} | {r.apart} |" for r in apart
        ]
    lines += ["", *[f"- {data['sentences'][c]}" for c in data["classes"]], ""]
    return lines
