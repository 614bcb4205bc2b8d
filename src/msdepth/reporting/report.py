"""The numbers blocks of ``docs/results.md`` and ``README.md``, written from the committed metrics.

Both pages are written by hand except their blocks between markers (:data:`BEGIN` … :data:`END`,
README's :data:`ANSWER_BEGIN` … :data:`ANSWER_END`), rendered from ``metrics/compare.json`` and
``metrics/train/`` alone: every number, and every sentence whose truth depends on one, so the text
cannot drift from the run. The verdict's table is compare.md's
(:func:`msdepth.reporting.verdict.summary_lines`). ``python -m msdepth.reporting.report --check``
compares the pages with the metrics.
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from pathlib import Path
from typing import Any, Sequence

from msdepth.analysis.comparison import changed_settings, settings_text
from msdepth.analysis.runs import MIN_SEEDS_FOR_MARKS, marks_allowed
from msdepth.analysis.verdict import NAMES, OWN_BEST, class_order
from msdepth.errors import DataError, MsdepthError
from msdepth.evaluation.metrics import HIGHER_IS_BETTER
from msdepth.io import write_text
from msdepth.pipeline.paths import (
    COMPARE_JSON,
    FIGURES_DIR,
    README,
    REAL_SETS_COMPARE,
    RESULTS,
    run_name,
    train_summary_path,
)
from msdepth.readers import read_json_object, read_text_file
from msdepth.reporting.comparison import SET_TITLES, markdown_table
from msdepth.reporting.verdict import (
    VERDICT_FIGURE,
    answer_sentence,
    on_places,
    short_answer,
    sign_caveat,
    signed,
    summary_lines,
)

# Whose frames the committed rows score, by data.source (compare.json's ``data_source``).
FRAMES = {"synthetic": "rendered", "kitti": "real KITTI", "folder": "your stereo folder's"}
REAL_SAMPLES = "studies/results/real_sets/README.md"  # the shared real KITTI frames, a study apart
# Its places: real KITTI 2012 and 2015 training frames and the boxes drawn on KITTI 2015's.
REAL_PLACES = ("kitti2012", "kitti2015", "kitti2015 boxes")

COMMAND = "python -m msdepth.reporting.report"
BEGIN = (
    "<!-- results: written by the report stage from metrics/ (src/msdepth/reporting/report.py); "
    "do not edit -->"
)
END = "<!-- end of results -->"
ANSWER_BEGIN = "<!-- answer: written by the report stage from metrics/compare.json; do not edit -->"
ANSWER_END = "<!-- end of answer -->"

# How the tables name a baseline (a variant: verdict.NAMES); one not listed keeps its own name.
BASELINE_NAMES = {"constant": "constant (image-blind)", "prior": "per-pixel prior (image-blind)"}
PROSE_NAMES = {"constant": "constant", "prior": "per-pixel prior"}  # in sentences, which say "image-blind"
# Settings a variant's label always states (the question is about MS-SSIM's kernel), besides
# those that differ from the defaults.
ALWAYS_NAMED = {"msssim": ("kernel_size",)}
# The headline's full-image columns: (metric, header, decimals).
FULL_COLUMNS = (("abs_rel", "abs_rel", 3), ("sq_rel", "sq_rel", 2), ("rmse", "rmse (m)", 2), ("a1", "a1", 3))
MINUS = "\u2212"


def _num(value: float, decimals: int) -> str:
    """``value`` rounded, with a typographic minus."""
    return f"{value:.{decimals}f}".replace("-", MINUS)


def _interval(d: dict, decimals: int = 3) -> str:
    return f"[{signed(d['low'], decimals)}, {signed(d['high'], decimals)}]"


class Results:
    """``metrics/compare.json`` with the lookups the texts need; a missing key is a DataError."""

    def __init__(self, data: dict, train: dict[str, dict] | None = None, source: str = str(COMPARE_JSON)):
        self.data, self.train, self.source = data, train or {}, source
        self.variants: list[str] = list(self.get("variants"))
        self.baselines: list[str] = list(self.get("baselines"))
        self.seeds: list[int] = list(self.get("seeds"))
        self.cap: str = next(iter(self.get("full")))
        self.reference: str | None = (data.get("statistics") or {}).get("reference")

    def get(self, *keys: str, default: Any = KeyError) -> Any:
        """``data[k1][k2]...``; ``default`` where a key is missing, else a DataError."""
        node: Any = self.data
        for k in keys:
            if not isinstance(node, dict) or k not in node:
                if default is KeyError:
                    raise DataError(f"{self.source}: no {'.'.join(keys)} (re-run the compare stage)")
                return default
            node = node[k]
        return node

    @property
    def cap_m(self) -> str:
        return f"{float(self.cap.removeprefix('cap')):g}"

    def label(self, run: str) -> str:
        """A run's row name: ``MS-SSIM (k=3)``, ``per-pixel prior (image-blind)``."""
        if run in self.baselines:
            return BASELINE_NAMES.get(run, run)
        settings = self.get("settings", run, default={}) or {}
        try:
            shown = changed_settings(run, settings)
        except KeyError:  # a variant this code does not know: name every setting
            shown = dict(settings)
        named = {k: settings[k] for k in ALWAYS_NAMED.get(run, ()) if k in settings}
        shown = {**named, **{k: v for k, v in shown.items() if k not in named}}
        name = f"{NAMES.get(run, run)} ({settings_text(shown)})" if shown else NAMES.get(run, run)
        return name + self._blind_note(run)

    def _blind_note(self, variant: str) -> str:
        """`` (image-blind)`` or `` (1 of 3 runs image-blind)`` where compare.md flags its runs."""
        deps = self.get("image_dependence", default={}) or {}
        runs = [d for k, d in deps.items() if k.split("/")[0] == variant]
        blind = sum(1 for d in runs if d.get("image_blind"))
        if not blind:
            return ""
        return " (image-blind)" if blind == len(runs) else f" ({blind} of {len(runs)} runs image-blind)"

    def difference(
        self, suite: str, run: str, metric: str = "abs_rel", cap: str | None = None
    ) -> dict | None:
        """``run − reference`` on ``suite`` (a PairedDifference dict), None without statistics."""
        return self.get("statistics", suite, cap or self.cap, run, metric, default=None)

    def marked(self, d: dict, run: str) -> bool:
        """Whether compare.md marks ``d`` (``*``): the interval excludes 0 and covers training noise."""
        return bool(d["excludes_zero"]) and marks_allowed(d, run in self.baselines)

    def frames(self) -> int | None:
        d = next(iter(self.get("statistics", "full", self.cap, default={}).values()), None)
        return None if d is None else int(d["abs_rel"]["n"])

    def rois(self) -> dict[str, dict]:
        """Per run its ROI block (``overall``, ``by_class``) at the headline cap; {} without ROIs."""
        return self.get("roi", self.cap, default={})

    def classes(self) -> list[str]:
        rois = self.rois()
        found = set().union(*(set(r.get("by_class", {})) for r in rois.values())) if rois else set()
        return class_order(sorted(found))


def load_results(root: Path = Path(".")) -> Results:
    """``metrics/compare.json`` and the runs' training summaries under ``root``."""
    path = root / COMPARE_JSON
    data = read_json_object(path, "comparison", "run `dvc repro compare` first")
    train = {}
    for variant in data.get("variants", []):
        for seed in data.get("seeds", []):
            file = root / train_summary_path(run_name(variant, seed))
            if file.is_file():
                train[run_name(variant, seed)] = read_json_object(file, "training summary")
    return Results(data, train, str(path))


# --- the headline table ---------------------------------------------------------------------


def _spread_cell(r: Results, suite: str, run: str, value: float) -> str:
    """``mean ± sd`` over the variant's seeds (the value alone for a baseline or one seed)."""
    spread = r.get("seed_spread", suite, r.cap, run, "abs_rel", default=None)
    if run in r.baselines or not isinstance(spread, dict) or spread.get("sd") is None:
        return _num(value, 3)
    return f"{_num(spread['mean'], 3)} ± {_num(spread['sd'], 3)}"


def _best_variant(r: Results, metric: str) -> str | None:
    """The variant with the best full-image ``metric`` (None with fewer than two variants)."""
    if len(r.variants) < 2:
        return None
    values = {v: r.get("full", r.cap, v, metric) for v in r.variants}
    pick = max if metric in HIGHER_IS_BETTER else min
    return pick(values, key=values.get)


def _roi_cells(r: Results, run: str, classes: Sequence[str]) -> list[str]:
    """ROI abs_rel (mean ± sd for a variant), exact masks, then per class (box) abs_rel."""
    block = r.rois()[run]
    masks = r.get("roi_masks", r.cap, run, "overall", "abs_rel", default=None)
    by_class = block.get("by_class", {})
    return [
        _spread_cell(r, "roi", run, block["overall"]["abs_rel"]),
        "–" if masks is None else _num(masks, 3),
        *("–" if c not in by_class else _num(by_class[c]["abs_rel"], 3) for c in classes),
    ]


def _headline_table(r: Results) -> str:
    """The headline table: each variant (mean ± sd over seeds) and baseline on the full image and,
    with ROIs, over the ROIs, their exact masks and per class; best variant per column in bold."""
    classes = r.classes() if r.rois() else []
    header = ["run", *(h for _, h, _ in FULL_COLUMNS)]
    if r.rois():
        header += ["ROI abs_rel", "exact masks", *classes]
    best = {m: _best_variant(r, m) for m, _, _ in FULL_COLUMNS}
    rows = []
    for run in [*r.variants, *r.baselines]:
        full = r.get("full", r.cap, run)
        cells = []
        for metric, _, decimals in FULL_COLUMNS:
            value = full[metric]
            text = _spread_cell(r, "full", run, value) if metric == "abs_rel" else _num(value, decimals)
            cells.append(f"**{text}**" if best[metric] == run else text)
        if r.rois():
            cells += _roi_cells(r, run, classes)
        rows.append([r.label(run), *cells])
    return markdown_table(header, rows)


def _headline_caption(r: Results) -> str:
    """What the table shows: the cap, how many frames and ROIs, how variants are averaged."""
    parts = [f"{_frames_words(r)} frames in KITTI 2015's layout, cap {r.cap_m} m"]
    if (frames := r.frames()) is not None:
        parts.append(f"{frames} frames")
    if r.rois():
        parts.append(f"{next(iter(r.rois().values()))['overall']['count']} ROIs")
    n = len(r.seeds)
    runs = f"variants: mean ± sd over {n} seeds" if n > 1 else f"variants: one run each (seed {r.seeds[0]})"
    return f"{', '.join(parts)}; {runs}"


# --- sentences whose truth depends on the numbers ------------------------------------------------


def _confidence(r: Results) -> str:
    return f"{round(float(r.get('statistics', 'confidence', default=0.95)) * 100):g} %"


def _over(r: Results, d: dict, run: str) -> str:
    """What the interval resamples: images, and seeds where every trained run in it has several."""
    seeds = [d["reference_seeds"]] + ([] if run in r.baselines else [d["seeds"]])
    return "over images and seeds" if min(seeds) > 1 else "over images"


def _than(r: Results, run: str, d: dict, metric: str = "abs_rel") -> str:
    """``MS-SSIM (k=3) has an abs_rel 0.005 lower than SSIM's`` from ``d`` (run − reference)."""
    subject, other = r.label(run), r.label(r.reference or "")
    if round(abs(d["mean"]), 3) == 0:
        return f"{subject} and {other} have the same {metric} to 3 decimals"
    way = "lower" if d["mean"] < 0 else "higher"
    return f"{subject} has an {metric} {_num(abs(d['mean']), 3)} {way} than {other}'s"


def _difference_clause(r: Results, suite: str, run: str) -> str:
    """One run's difference to the reference with its interval, and whether compare.md marks it."""
    d = r.difference(suite, run)
    if d is None:
        raise DataError(f"{r.source}: no statistics.{suite}.{r.cap}.{run}.abs_rel (re-run the compare stage)")
    text = (
        f"{_than(r, run, d)}, with a {_confidence(r)} interval of the difference of {_interval(d)} "
        f"{_over(r, d, run)}"
    )
    if r.marked(d, run):
        return text + ", which excludes 0 (marked `*` in `metrics/compare.md`)"
    if d["excludes_zero"]:
        return text + (
            f", which excludes 0 but does not cover training noise: compare.md marks a difference "
            f"only over at least {MIN_SEEDS_FOR_MARKS} seeds"
        )
    return text + ", which includes 0"


def _compared(r: Results) -> list[str]:
    """The variants with a paired difference to the reference."""
    return [v for v in r.variants if v != r.reference and r.difference("full", v) is not None]


def verdict(r: Results) -> str:
    """Per variant its full-image abs_rel against the reference's, then the ROI classes where an
    image-blind baseline still beats every variant."""
    others = _compared(r)
    if not others:
        return "**No comparison**: one variant, or no paired statistics in `metrics/compare.json`."
    marked = any(r.marked(r.difference("full", v), v) for v in others)
    lead = "**Verdict**" if marked else "**No verdict yet**"
    text = f"{lead}: " + "; ".join(_difference_clause(r, "full", v) for v in others) + "."
    if r.rois():
        text += " " + _baseline_classes_sentence(r)
    return text


def _class_standing(r: Results) -> dict[str, tuple[str, float, float, float]]:
    """Per ROI class: the best image-blind baseline, its abs_rel, and the variants' lowest and
    highest abs_rel (box, headline cap)."""
    rois, out = r.rois(), {}
    for c in r.classes():
        blind = {
            b: rois[b]["by_class"][c]["abs_rel"] for b in r.baselines if c in rois[b].get("by_class", {})
        }
        trained = [rois[v]["by_class"][c]["abs_rel"] for v in r.variants if c in rois[v].get("by_class", {})]
        if blind and trained:
            best = min(blind, key=blind.get)
            out[c] = (best, blind[best], min(trained), max(trained))
    return out


def _join(items: Sequence[str]) -> str:
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} and {items[-1]}"


def _baseline_classes_sentence(r: Results) -> str:
    """Which ROI classes an image-blind baseline still wins against every variant."""
    wins: dict[str, list[str]] = {}
    for c, (baseline, value, low, _) in _class_standing(r).items():
        if value <= low:
            wins.setdefault(baseline, []).append(c)
    if not wins:
        return "On every ROI class some variant beats the image-blind baselines."
    parts = [f"the {PROSE_NAMES.get(b, b)} on {_join(cs)}" for b, cs in wins.items()]
    return f"On the ROIs an image-blind baseline still beats every variant: {_join(parts)}."


def wrap(text: str, width: int = 100) -> str:
    """A paragraph wrapped at ``width`` (never inside a word), so diffs stay readable."""
    return textwrap.fill(text, width, break_long_words=False, break_on_hyphens=False)


def _verdict_items(r: Results) -> list[str]:
    """compare.json's sentence per surface class as a Markdown list."""
    block = r.get("verdict", default=None) or {}
    sentences = [block["sentences"][c] for c in block.get("classes", []) if c in block.get("sentences", {})]
    return [
        textwrap.fill(s, 100, initial_indent="- ", subsequent_indent="  ", break_on_hyphens=False)
        for s in sentences
    ]


def _answer_lines(r: Results) -> list[str]:
    """results.md's answer: the summary table, the sentence that reads it, one per class."""
    block = r.get("verdict", default=None) or {}
    if not block.get("summary"):
        return []
    lead = (
        f"Is {block['variant']}'s depth error (abs_rel) lower than {block['reference']}'s? "
        + answer_sentence(block)
    )
    figure = f"[{VERDICT_FIGURE}](../{FIGURES_DIR.as_posix()}/{VERDICT_FIGURE})"
    per_class = f"Per class, every instrument ({figure}; the full table: `metrics/compare.md`):"
    return [wrap(lead), "", *summary_lines(block), "", wrap(per_class), "", *_verdict_items(r)]


def _readme_answer(r: Results, real: dict | None = None) -> str:
    """The README's answer, markers included (without a verdict, the full-image difference); then,
    with ``real`` (:func:`real_verdict`), what the shared real frames say, apart."""
    block = r.get("verdict", default=None) or {}
    text = short_answer(block) if block.get("summary") else verdict(r)
    if block.get("summary") and (caveat := sign_caveat(block)):
        text += " " + caveat
    link = "[docs/results.md](docs/results.md)"
    frames = _frames_words(r)
    head = f"**Answer so far, on the {frames} frames** ({link}): {text}"
    if frames == FRAMES["synthetic"]:
        head += f" **On real KITTI frames**, never pooled with these ([their page]({REAL_SAMPLES})): "
        head += (
            (_real_words(real) + _frames_caveat(block, real))
            if real
            else "not measured in this project copy."
        )
    return "\n".join([ANSWER_BEGIN, wrap(head), ANSWER_END])


def real_verdict(root: Path = Path(".")) -> dict | None:
    """The real-sets study's verdict (:data:`~msdepth.pipeline.paths.REAL_SETS_COMPARE`, made by the
    pipeline's set stages) on :data:`REAL_PLACES` only; None without the file or those rows."""
    path = root / REAL_SETS_COMPARE
    if not path.is_file():
        return None
    data = read_json_object(path, "real-sets comparison").get("verdict") or {}
    real = on_places(data, REAL_PLACES) if data.get("headline") else {}
    return real if real.get("headline") else None


def _frames_caveat(block: dict, real: dict) -> str:
    """ " The sign depends on the frames (...)." where the own-best full-frame difference of the
    rendered frames and of each real set differ in sign; "" where they agree or one is missing."""
    where = lambda name: name.rsplit(" on ", 1)[1] if " on " in name else "rendered"  # noqa: E731
    diffs = {
        where(r["instrument"]): r["diff"]
        for data in (block, real)
        for r in data.get("rows", [])
        if r["class"] == "full frame" and r["instrument"].startswith(f"optimum {OWN_BEST}")
        and (data is real) == (" on " in r["instrument"])
    }  # fmt: skip
    if len({d < 0 for d in diffs.values()}) < 2 or "rendered" not in diffs:
        return ""
    each = ", ".join(f"{where} {signed(d, 3)}" for where, d in diffs.items())
    return f" The sign depends on the frames (full frame, own best: {each})."


def _real_words(real: dict) -> str:
    """The real frames' answer in a line: per place, its own-best column (each loss at its own
    weight; the fixed weight's where a place has none), without intervals where none could be drawn."""
    own = {h: c for h, c in real["headline"].items() if OWN_BEST in c[1]}
    places = {**real, "headline": own or real["headline"]}
    text = short_answer(places).split(": ", 1)[1].replace(f"optimum {OWN_BEST}, ", "")
    if all(r.get("low") is None for r in places["rows"] if r["instrument"] in {c[1] for c in own.values()}):
        text = text.replace(", no interval excluding 0", "")[:-1] + " (point estimates: too few frames)."
    lead = "each loss at its own best weight, " if own else ""
    return lead + text


def _frames_words(r: Results) -> str:
    """Whose frames the committed rows score: "rendered" (the synthetic set), "real KITTI", ..."""
    source = r.get("data_source", default="synthetic")
    return FRAMES.get(source, source)


def _readme_block(r: Results, real: dict | None = None) -> str:
    """The README's results block, markers included (without a verdict, the headline table); with
    ``real`` (:func:`real_verdict`), the real frames' table below, apart."""
    block = r.get("verdict", default=None) or {}
    caption = wrap(
        f"The committed run: {_headline_caption(r).split('; variants')[0]}, {len(r.seeds)} "
        f"seed{'s' if len(r.seeds) != 1 else ''} per loss. Terms, each run's metrics, the "
        "image-blind baselines and how to read them: [docs/results.md](docs/results.md)."
    )
    if not block.get("summary"):
        return "\n".join([BEGIN, _headline_table(r), "", wrap(verdict(r)), "", caption, END])
    lead = (
        f"{block['variant']} − {block['reference']} abs_rel per surface class and instrument at cap "
        f"{r.cap_m} m, on the {_frames_words(r)} frames (negative: {block['variant']}'s error is lower; "
        f"`*`: the {_confidence(r)} interval excludes 0; terms: [docs/results.md](docs/results.md#terms)):"
    )
    lines = [BEGIN, wrap(lead), "", *summary_lines(block), "", caption]
    if real:
        where = (
            "On the shared real frames, apart: 2 KITTI 2012 and 2 KITTI 2015 training frames and the "
            "boxes drawn on the latter, scored by the pipeline's set stages with the committed run's "
            f"models and params ([how]({REAL_SAMPLES})); under 5 frames a row has no interval:"
        )
        lines += ["", wrap(where), "", *summary_lines(real)]
    return "\n".join([*lines, END])


def _training_text(r: Results) -> str:
    """How many runs per variant and how long each trained (from ``metrics/train/``)."""
    seeds = ", ".join(map(str, r.seeds))
    s = "s" if len(r.seeds) > 1 else ""
    text = f"{len(r.seeds)} training run{s} per variant (seed{s} {seeds})"
    steps = sorted({int(t["steps"]) for t in r.train.values() if "steps" in t})
    epochs = sorted({int(t["epochs"]) for t in r.train.values() if "epochs" in t})
    if steps and epochs:
        span = lambda v: f"{v[0]:,}" if len(v) == 1 else f"{v[0]:,}–{v[-1]:,}"  # noqa: E731
        text += f", each {span(steps)} steps over {span(epochs)} epochs (`metrics/train/`)"
    return text


def _default_run_section(r: Results) -> str:
    """The setting in a paragraph, then the headline table."""
    settings = r.get("settings", default={}) or {}
    stated = "; ".join(
        f"{r.label(v).split(' (')[0]} {settings_text(settings[v])}" for v in r.variants if v in settings
    )
    setting = (
        "`params.yaml` as committed ([why the default network differs from the dissertation's]"
        "(design.md#why-the-default-network-differs-from-the-dissertations))"
        + (f"; the variants' settings: {stated}" if stated else "")
        + f". {_training_text(r)}. How long it takes and how reproducible it is across CPUs: "
        "[benchmarks/README.md](../benchmarks/README.md#the-default-run)."
    )
    return "\n\n".join(
        ["## Default run", wrap(setting), wrap(f"The headline ({_headline_caption(r)}):"), _headline_table(r)]
    )


def _marks_text(r: Results) -> str:
    """How a verdict is made, and whether the comparison has one."""
    others = _compared(r)
    text = (
        "A difference is a verdict only where `metrics/compare.md` marks it (`*`): its interval, "
        "resampling images (ROIs by their frames) and each variant's seeds, excludes 0, over at least "
        f"{MIN_SEEDS_FOR_MARKS} seeds per variant, so that it covers the choice of images and training noise."
    )
    marked = [v for v in others for s in ("full", "roi") if (d := r.difference(s, v)) and r.marked(d, v)]
    if not marked:
        text += " None between the losses is marked here: **no verdict**."
    return text


def _dependence_text(r: Results) -> str:
    """Whether each trained run follows the image (compare.md's first table)."""
    from msdepth.analysis.runs import IMAGE_BLIND_BELOW

    deps = r.get("image_dependence", default={}) or {}
    trained = {run: d for run, d in deps.items() if run not in r.baselines}
    ratios = [d["variation_ratio"] for d in trained.values() if d.get("variation_ratio") is not None]
    blind = [run for run, d in trained.items() if d.get("image_blind")]
    if not ratios:
        return "How much each run's predictions follow the image was not measured (too few frames)."
    low, high = f"{min(ratios):.2f}", f"{max(ratios):.2f}"
    span = low if low == high else f"{low}–{high}"
    if not blind:
        return (
            f"Every trained run follows the image (variation {span} of the GT's from image to image; "
            "an image-blind baseline scores 0)."
        )
    return (
        f"{_join(blind)} {'is' if len(blind) == 1 else 'are'} image-blind (variation below "
        f"{IMAGE_BLIND_BELOW} of the GT's): {'its' if len(blind) == 1 else 'their'} numbers say nothing "
        f"about {'its' if len(blind) == 1 else 'their'} loss. Over all trained runs the variation is {span}."
    )


def _baselines_text(r: Results) -> str:
    """The reference against each image-blind baseline on the full image."""
    rows = [(b, d) for b in r.baselines if (d := r.difference("full", b)) is not None]
    if not rows or r.reference is None:
        return ""
    ref = r.label(r.reference)
    cells = [f"the {PROSE_NAMES.get(b, b)} {signed(d['mean'])} {_interval(d)}" for b, d in rows]
    beaten = [PROSE_NAMES.get(b, b) for b, d in rows if d["mean"] > 0 and r.marked(d, b)]
    text = f"On the full image, baseline − {ref} in abs_rel ({_confidence(r)} interval): {_join(cells)}"
    return text + (f", so {ref} beats the {_join(beaten)}." if beaten else ".")


def _classes_text(r: Results) -> str:
    """Per ROI class, the variants against the best image-blind baseline."""
    standing = _class_standing(r)
    if not standing:
        return ""
    cells, ahead, behind = [], [], []
    for c, (b, value, low, high) in standing.items():
        span = _num(low, 3) if _num(low, 3) == _num(high, 3) else f"{_num(low, 3)}–{_num(high, 3)}"
        cells.append(f"{c} {span} against the {PROSE_NAMES.get(b, b)}'s {_num(value, 3)}")
        (ahead if high < value else behind if low >= value else []).append(c)
    text = (
        "Per ROI class (box abs_rel; the variants against the best image-blind baseline): "
        + "; ".join(cells)
        + "."
    )
    if ahead:
        text += f" Every variant is ahead on {_join(ahead)}."
    if behind:
        text += f" Every variant is behind on {_join(behind)}."
    return text


def _reading_section(r: Results) -> str:
    """ "How to read it": the differences between the losses, whether they are a verdict, whether
    the runs use the image, and where the image-blind baselines still win."""
    others = _compared(r)
    clauses = [f"on the full image {_difference_clause(r, 'full', v)}" for v in others]
    clauses += [f"on the ROIs {_difference_clause(r, 'roi', v)}" for v in others if r.difference("roi", v)]
    first = "How to read it. " + (
        "; ".join(clauses)[0].upper() + "; ".join(clauses)[1:] + ". " if clauses else ""
    )
    paragraphs = [first + _marks_text(r), f"{_dependence_text(r)} {_baselines_text(r)}".strip()]
    if r.rois():
        paragraphs.append(_classes_text(r))
    return "\n\n".join(wrap(p) for p in paragraphs if p)


def _set_results(r: Results, name: str, block: dict) -> Results:
    """An extra set's block of compare.json as a :class:`Results` of its own."""
    groups = next(iter(block.get("full", {}).values()), {})
    data = {
        **block,
        "variants": [v for v in r.variants if v in groups],
        "baselines": [b for b in r.baselines if b in groups],
        "seeds": r.seeds,
        "settings": r.data.get("settings", {}),
    }
    return Results(data, source=f"{r.source} (sets.{name})")


def _set_section(r: Results, name: str, block: dict) -> str:
    """An extra evaluation set's paragraph: its abs_rel per run, the differences, rmse and a1."""
    s = _set_results(r, name, block)
    full = s.get("full", s.cap)
    variants = [f"{s.label(v)} {_spread_cell(s, 'full', v, full[v]['abs_rel'])}" for v in s.variants]
    text = (
        f"{SET_TITLES.get(name, name)}, `metrics/sets/{name}/`: {s.get('images', default='–')} images, GT "
        "within (min_depth, cap), Monodepth2's protocol without median scaling. "
        f"At cap {s.cap_m} m, abs_rel {_join(variants)}"
    )
    text += "".join(f"; {_difference_clause(s, 'full', v)}" for v in _compared(s))
    if len(s.variants) > 1:
        text += (
            f"; rmse {_join([_num(full[v]['rmse'], 2) for v in s.variants])} m and a1 "
            f"{_join([_num(full[v]['a1'], 3) for v in s.variants])} (in that order)"
        )
    text += "".join(f"; the {PROSE_NAMES.get(b, b)} {_num(full[b]['abs_rel'], 3)}" for b in s.baselines)
    heading = "## The Eigen split" if name == "eigen" else f"## The {name} set"
    return "\n\n".join([heading, wrap(text + ".")])


def _results_block(r: Results) -> str:
    """results.md's numbers block, markers included: the answer, the default run, how to read it
    and the extra sets."""
    answer = _answer_lines(r)
    parts = [BEGIN, *(["## What the study finds", "\n".join(answer)] if answer else [])]
    parts += [_default_run_section(r), _reading_section(r)]
    parts += [_set_section(r, name, block) for name, block in (r.get("sets", default={}) or {}).items()]
    return "\n\n".join([*parts, END])


# --- writing and checking ------------------------------------------------------------------------


def _replace_block(text: str, block: str, path: Path, begin: str = BEGIN, end: str = END) -> str:
    """``text`` with the part from ``begin`` to ``end`` (inclusive) replaced by ``block``;
    DataError naming ``path`` unless each marker is there once, in order."""
    if text.count(begin) != 1 or text.count(end) != 1 or text.index(begin) > text.index(end):
        raise DataError(
            f"{path}: needs one generated block, a line {begin!r} and later a line {end!r}, to write the "
            "numbers into"
        )
    return text[: text.index(begin)] + block + text[text.index(end) + len(end) :]


def rendered(root: Path = Path(".")) -> dict[Path, str]:
    """What the report writes under ``root``: ``docs/results.md`` with its block rewritten (a
    project copy without the page gets a page of the block alone) and, where ``README.md`` exists,
    the README with its two blocks rewritten."""
    r = load_results(root)
    page, readme = root / RESULTS, root / README
    if page.is_file():
        out = {page: _replace_block(read_text_file(page, "results page"), _results_block(r), page)}
    else:
        out = {page: f"# Results\n\n{_results_block(r)}\n"}
    if readme.is_file():
        real = real_verdict(root)
        text = _replace_block(read_text_file(readme, "README"), _readme_block(r, real), readme)
        out[readme] = _replace_block(text, _readme_answer(r, real), readme, ANSWER_BEGIN, ANSWER_END)
    return out


def stale(root: Path = Path(".")) -> dict[Path, str]:
    """The files whose text differs from what the committed metrics give, with that text."""
    return {
        p: text
        for p, text in rendered(root).items()
        if not p.is_file() or read_text_file(p, "generated text") != text
    }


def write_report(root: Path = Path(".")) -> list[Path]:
    """Write the :func:`stale` files (atomically); the paths written."""
    differ = stale(root)
    for path, text in differ.items():
        write_text(path, text)
    return list(differ)


def main(argv: list[str] | None = None) -> int:
    """Write (or with ``--check`` only compare) docs/results.md and the README's headline block;
    exit code 1 on a difference under ``--check`` or an error."""
    ap = argparse.ArgumentParser(prog=COMMAND, description=__doc__)
    ap.add_argument("--root", type=Path, default=Path("."), help="the project folder (holding metrics/)")
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 if a file differs")
    args = ap.parse_args(argv)
    try:
        if args.check:
            if differ := stale(args.root):
                names = ", ".join(str(p) for p in differ)
                print(
                    f"{names}: not what the metrics give: run `{COMMAND}` (or `dvc repro report`)",
                    file=sys.stderr,
                )
                return 1
            print("docs/results.md and the README's headline match the metrics")
            return 0
        written = write_report(args.root)
    except (MsdepthError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"written: {', '.join(map(str, written))}" if written else "up to date")
    return 0


if __name__ == "__main__":
    sys.exit(main())
