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
  no training noise): :func:`msdepth.reporting.stats.paired_bootstrap` over the images or ROIs
  that weight was scored on.
- ``seeds``: the monocular study's mono and mono+stereo networks (``studies/monocular.py``),
  known per seed (its ``table.json``) or, where only its ``table.md`` exists, as mean ± sd over
  ``n`` seeds (:func:`parse_monocular_table`). Welch's t interval of the difference of the two
  variants' means over seeds (:func:`welch_interval`): it covers training noise, with the images
  held fixed. Their full-frame abs_rel is median-scaled per image, as the study scores it.
- ``external``: rows another study wrote, read from a JSON file (:func:`read_external_rows`),
  e.g. ``studies/results/real/verdict.json`` (real KITTI pairs). Its schema: a JSON list (``[]``
  for none) of objects with exactly these keys::

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
ROIs is 0 wide, not certain. :func:`class_sentence` states each class in one sentence.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from msdepth.config.params import CompareConfig
from msdepth.errors import DataError
from msdepth.reporting.compare import UNIT_KEYS, paired_statistics
from msdepth.reporting.stats import paired_bootstrap, paired_table

METRIC = "abs_rel"
VERDICT_FIGURE = "verdict.png"  # below plots/figures: the figures stage draws it (figures.verdict_figure)
FULL_FRAME = "full frame"
CLASS_ORDER = (FULL_FRAME, "car", "windshield", "glass", "sign", "reflective")
MIN_UNITS = 5
EXTERNAL_FIELDS = ("instrument", "class", "diff", "low", "high", "n", "method")
KINDS = ("network", "seeds", "optimum", "external", "pooled")
DISPLAY_NAMES = {"ssim": "SSIM", "msssim": "MS-SSIM"}  # the two losses the verdict is about
MONOCULAR_MODES = {"mono": "mono networks", "mono_stereo": "mono+stereo networks"}
POOLABLE = re.compile(r"optimum w\S+$")  # the optimum's instruments: no training noise


@dataclass(frozen=True)
class Row:
    """One instrument's ``variant − reference`` abs_rel on one class, with its interval."""

    instrument: str
    cls: str
    diff: float
    low: float
    high: float
    n: int
    method: str
    kind: str

    @property
    def excludes_zero(self) -> bool:
        return self.low > 0 or self.high < 0

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
        """The row as compare.json holds it (the external schema's keys, then ``kind``)."""
        return {
            "instrument": self.instrument,
            "class": self.cls,
            "diff": self.diff,
            "low": self.low,
            "high": self.high,
            "n": self.n,
            "method": self.method,
            "kind": self.kind,
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> Row:
        """The inverse of :meth:`as_dict` (``kind`` defaults to ``external``)."""
        return cls(
            str(d["instrument"]),
            str(d["class"]),
            float(d["diff"]),
            float(d["low"]),
            float(d["high"]),
            int(d["n"]),
            str(d["method"]),
            str(d.get("kind", "external")),
        )


def class_order(classes: Sequence[str]) -> list[str]:
    """``classes`` in :data:`CLASS_ORDER`, unknown ones after it, sorted."""
    known = [c for c in CLASS_ORDER if c in classes]
    return known + sorted(set(classes) - set(CLASS_ORDER))


def class_tables(
    tables: Mapping[str, Mapping[str, pd.DataFrame]], anchor: str
) -> list[tuple[str, str, dict]]:
    """``(class, suite, {run: table})``: the full-image tables as the full frame, then the ROI
    tables filtered to each class that ``anchor``'s ROI table holds."""
    out = [(FULL_FRAME, "full", dict(tables["full"]))] if "full" in tables else []
    if "roi" in tables:
        roi = tables["roi"]
        for cls in class_order(list(roi[anchor]["class"].unique())):
            out.append((cls, "roi", {run: t[t["class"] == cls] for run, t in roi.items()}))
    return out


def network_rows(
    tables: Mapping[str, Mapping[str, pd.DataFrame]],
    groups: Mapping[str, Sequence[str]],
    cfg: CompareConfig,
    cap: float,
    instrument: str = "stereo networks",
) -> list[Row]:
    """Per class, each variant of ``groups`` (variant -> its runs, the reference's included) minus
    ``cfg.reference``, by the comparison's bootstrap over units and seeds; ``tables`` is
    :func:`msdepth.reporting.compare.load_unit_tables`' ``{suite: {run: table}}``."""
    rows = []
    others = [v for v in groups if v != cfg.reference]
    for cls, suite, chosen in class_tables(tables, groups[cfg.reference][0]):
        stats = paired_statistics({suite: chosen}, dict(groups), cfg, [cap])[suite][f"cap{cap:g}"]
        for variant in others:
            d = stats[variant][METRIC]
            if d["n"] < MIN_UNITS:
                continue
            unit = "images" if suite == "full" else "ROIs"
            method = f"paired bootstrap over {unit} and seeds ({d['seeds']} and {d['reference_seeds']})"
            name = instrument if len(others) == 1 else f"{instrument}, {variant}"
            rows.append(Row(name, cls, d["mean"], d["low"], d["high"], d["n"], method, "network"))
    return rows


def optimum_rows(
    tables: Mapping[str, Mapping[str, pd.DataFrame]],
    runs: Mapping[str, Mapping[str, str]],
    cfg: CompareConfig,
    cap: float,
) -> list[Row]:
    """Per weight (``runs``: weight label, e.g. ``w10``, -> {variant: its optimum run}) and class,
    each variant minus ``cfg.reference``: :func:`~msdepth.reporting.stats.paired_bootstrap` over
    the units both runs were scored on."""
    rows = []
    for weight, by_variant in runs.items():
        ref = by_variant[cfg.reference]
        others = [v for v in by_variant if v != cfg.reference]
        for cls, suite, chosen in class_tables(tables, ref):
            keys = UNIT_KEYS[suite]
            for variant in others:
                what = f"{suite} optimum {variant} vs {cfg.reference} {weight}, {cls}"
                a, b = (chosen[by_variant[variant]], chosen[ref])
                values, reference = paired_table(a[a["cap"] == cap], b[b["cap"] == cap], keys, METRIC, what)
                if len(values) < MIN_UNITS:
                    continue
                d = paired_bootstrap(values, reference, cfg.bootstrap_samples, cfg.confidence, cfg.seed)
                name = f"optimum {weight}" if len(others) == 1 else f"optimum {weight}, {variant}"
                unit = "images" if suite == "full" else "ROIs"
                rows.append(
                    Row(name, cls, d.mean, d.low, d.high, d.n, f"paired bootstrap over {unit}", "optimum")
                )
    return rows


# --- the monocular study's networks: intervals over seeds -------------------------------------


def t_quantile(p: float, df: float) -> float:
    """Student's t quantile (``0.5 < p < 1``, ``df > 0``), by bisection on its CDF, the density
    integrated numerically (no SciPy in the project's dependencies)."""
    log_norm = math.lgamma((df + 1) / 2) - math.lgamma(df / 2) - 0.5 * math.log(df * math.pi)

    def cdf(t: float) -> float:
        x = np.linspace(0.0, t, 20_001)
        density = np.exp(log_norm - (df + 1) / 2 * np.log1p(x * x / df))
        return 0.5 + float(np.sum((density[1:] + density[:-1]) / 2) * (x[1] - x[0]))

    low, high = 0.0, 1.0
    while cdf(high) < p:  # bracket: the tails of df ~ 1 reach far
        low, high = high, high * 2
    for _ in range(60):
        mid = (low + high) / 2
        low, high = (mid, high) if cdf(mid) < p else (low, mid)
    return (low + high) / 2


def welch_interval(
    a: tuple[float, float, int], b: tuple[float, float, int], confidence: float = 0.95
) -> tuple[float, float, float]:
    """``(diff, low, high)`` of ``mean(a) − mean(b)``, each side ``(mean, sd, n)`` over independent
    runs: Welch's t interval (Welch–Satterthwaite degrees of freedom)."""
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
MonocularStats = dict[str, dict[str, dict[str, Spread]]]  # {mode: {variant: {class: spread}}}


def parse_monocular_table(path: Path) -> MonocularStats:
    """The monocular study's ``table.md``, read as written by ``studies/monocular.py``'s ``table``:
    ``n`` from its line "Mean ± sd over seeds [s, ...]", then per row of its table (``mode``,
    ``variant``) the cells ``mean ± sd`` of the columns ``abs_rel`` (the full frame) and ``ROI
    <class>``; cells without `` ± `` (``–``) are skipped. A DataError names the file when the line
    or the table is not there or a cell is not two numbers."""
    text = Path(path).read_text(encoding="utf-8")
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
    else :func:`parse_monocular_table` of ``table_path``; {} when neither exists."""
    if Path(json_path).is_file():
        try:
            modes = json.loads(Path(json_path).read_text(encoding="utf-8"))["modes"]
            return {
                mode: {
                    variant: {
                        cls: (float(np.mean(v)), float(np.std(v, ddof=1)), len(v))
                        for cls, v in classes.items()
                    }
                    for variant, classes in variants.items()
                }
                for mode, variants in modes.items()
            }
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise DataError(f"{json_path}: not the monocular study's per-seed values ({exc})") from None
    return parse_monocular_table(table_path) if Path(table_path).is_file() else {}


def seed_rows(stats: MonocularStats, reference: str, confidence: float) -> list[Row]:
    """Per mode of :data:`MONOCULAR_MODES` and class, each variant minus ``reference`` with
    :func:`welch_interval` over seeds. (The study's stereo rows are the pipeline's own networks,
    which :func:`network_rows` compares unit by unit.)"""
    rows = []
    for mode, instrument in MONOCULAR_MODES.items():
        variants = stats.get(mode, {})
        if reference not in variants:
            continue
        others = [v for v in variants if v != reference]
        for variant in others:
            for cls in class_order([c for c in variants[variant] if c in variants[reference]]):
                a, b = variants[variant][cls], variants[reference][cls]
                diff, low, high = welch_interval(a, b, confidence)
                method = f"Welch t over seeds, from mean ± sd of {a[2]} and {b[2]} runs"
                if cls == FULL_FRAME:
                    method += " (median-scaled per image)"
                name = instrument if len(others) == 1 else f"{instrument}, {variant}"
                rows.append(Row(name, cls, diff, low, high, min(a[2], b[2]), method, "seeds"))
    return rows


# --- other studies' rows ------------------------------------------------------------------------


def _checked_row(item: object, i: int, path: Path) -> Row:
    """One external row, checked against the schema (module docstring); a DataError names ``path``."""
    where = f"{path}: row {i}"
    if not isinstance(item, dict) or set(item) != set(EXTERNAL_FIELDS):
        got = sorted(item) if isinstance(item, dict) else type(item).__name__
        raise DataError(f"{where}: needs exactly the keys {', '.join(EXTERNAL_FIELDS)}, got {got}")
    for key in ("instrument", "class", "method"):
        if not isinstance(item[key], str) or not item[key]:
            raise DataError(f"{where}: {key} must be a non-empty string, got {item[key]!r}")
    for key in ("diff", "low", "high"):
        value = item[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise DataError(f"{where}: {key} must be a finite number, got {value!r}")
    if not item["low"] <= item["diff"] <= item["high"]:
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
    try:
        items = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise DataError(f"{path}: not readable as JSON ({str(exc).splitlines()[0]})") from None
    if not isinstance(items, list):
        raise DataError(f"{path}: needs a JSON list of rows, got {type(items).__name__}")
    return [_checked_row(item, i, path) for i, item in enumerate(items)]


# --- pooling and words --------------------------------------------------------------------------


def pooled_rows(rows: Sequence[Row], confidence: float = 0.95) -> list[Row]:
    """Per class, one pooled row per optimum instrument measured by two rows or more (the
    pipeline's and an external study's, on other frames): inverse-variance weighted mean, each
    row's standard error its interval's half-width over the normal quantile; interval ±quantile·SE.
    Other instruments are never pooled (module docstring: why)."""
    z = float(np.sqrt(2) * _erfinv(confidence))
    groups: dict[tuple[str, str], list[Row]] = {}
    for r in rows:
        if r.kind in ("optimum", "external") and POOLABLE.match(r.instrument):
            groups.setdefault((r.cls, r.instrument), []).append(r)
    out = []
    for (cls, instrument), members in groups.items():
        if len(members) < 2:
            continue
        se = [max((r.high - r.low) / (2 * z), 1e-12) for r in members]  # a 0-wide interval: all weight
        w = np.array([1 / s**2 for s in se])
        mean = float(np.dot(w, [r.diff for r in members]) / w.sum())
        half = z / math.sqrt(w.sum())
        method = f"inverse-variance pool of {len(members)} independent rows"
        out.append(
            Row(
                f"{instrument}, pooled",
                cls,
                mean,
                mean - half,
                mean + half,
                sum(r.n for r in members),
                method,
                "pooled",
            )
        )
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


def class_sentence(cls: str, rows: Sequence[Row], better: str = "MS-SSIM") -> str:
    """One sentence from ``cls``'s rows: in how many instruments ``better``'s error (abs_rel) is
    lower, which intervals exclude 0 (and on which side), and the pooled estimates."""
    own = [r for r in rows if r.cls == cls and r.kind != "pooled"]
    pooled = [r for r in rows if r.cls == cls and r.kind == "pooled"]
    lower = sum(r.diff < 0 for r in own)
    noun = "instrument" if len(own) == 1 else "instruments"
    text = f"{cls}: {better}'s error is lower in {lower} of {len(own)} {noun}"
    excluding = [r for r in own if r.excludes_zero]
    if excluding:
        parts = [f"{r.label} ({'lower' if r.diff < 0 else 'higher'})" for r in excluding]
        text += f"; intervals excluding 0: {', '.join(parts)}"
    else:
        text += "; no interval excludes 0"
    for r in pooled:
        text += f"; {r.instrument}: {signed(r.diff)} [{signed(r.low)}, {signed(r.high)}]"
    return text + "."


def display_names(variants: Sequence[str], reference: str) -> tuple[str, str]:
    """The sentences' names of the compared variant and of the reference: ``MS-SSIM``, ``SSIM``
    (with several compared variants, ``each variant``)."""
    others = [v for v in variants if v != reference]
    if len(others) == 1:
        better = DISPLAY_NAMES.get(others[0], others[0])
    else:  # none (one variant: no rows but external ones) or several
        better = "each other variant" if others else "MS-SSIM"
    return better, DISPLAY_NAMES.get(reference, reference)


def verdict_data(rows: Sequence[Row], cap: float, confidence: float, better: str, than: str) -> dict:
    """compare.json's ``verdict``: the rows (with :func:`pooled_rows`), the classes in order and a
    sentence per class (:func:`class_sentence`)."""
    rows = [*rows, *pooled_rows(rows, confidence)]
    classes = class_order(sorted({r.cls for r in rows}))
    return {
        "metric": METRIC,
        "cap": f"cap{cap:g}",
        "confidence": confidence,
        "variant": better,
        "reference": than,
        "classes": classes,
        "rows": [r.as_dict() for r in rows],
        "sentences": {c: class_sentence(c, rows, better) for c in classes},
    }


VERDICT_TITLE = "The verdict per surface class"


def verdict_lines(data: dict | None) -> list[str]:
    """compare.md's verdict section from :func:`verdict_data`'s dict: what a row is, one table row
    per instrument and class, then the sentences."""
    if not data or not data["rows"]:
        return [f"# {VERDICT_TITLE}", "", "No instrument compares two variants here.", ""]
    level = f"{data['confidence'] * 100:g} %"
    lines = [
        f"# {VERDICT_TITLE}",
        "",
        f"{data['variant']} − {data['reference']} in abs_rel (cap {data['cap'][3:]} m; negative: "
        f"{data['variant']}'s error is lower), each instrument's {level} interval; `*`: it excludes 0. "
        "n: the images, ROIs or seeds the interval is over; rows over fewer than "
        f"{MIN_UNITS} are left out. Pooled only where rows measure one quantity independently "
        "(src/msdepth/reporting/verdict.py). The figure: `plots/figures/verdict.png`.",
        "",
        "| class | instrument | difference | n | method |",
        "|---|---|---|---|---|",
    ]
    for cls in data["classes"]:
        for r in (Row.from_dict(d) for d in data["rows"]):
            if r.cls == cls:
                star = " *" if r.excludes_zero else ""
                cell = f"{r.diff:+.3f} [{r.low:+.3f}, {r.high:+.3f}]{star}"
                lines.append(f"| {cls} | {r.label} | {cell} | {r.n} | {r.method} |")
    lines += ["", *[f"- {data['sentences'][c]}" for c in data["classes"]], ""]
    return lines
