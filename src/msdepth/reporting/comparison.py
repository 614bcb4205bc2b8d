"""compare.md: the :class:`~msdepth.analysis.comparison.Comparison` of every run (loss variants and
baselines) over the three suites as Markdown, a renderer per section."""

from __future__ import annotations

from typing import Callable, Sequence

from msdepth.analysis.comparison import OPTIMUM_METRICS, Comparison, optimum_row, settings_text
from msdepth.analysis.runs import IMAGE_BLIND_BELOW, MIN_SEEDS_FOR_MARKS, marks_allowed
from msdepth.evaluation.metrics import HIGHER_IS_BETTER, METRICS
from msdepth.evaluation.suites import GRADIENTS

ROIS_SKIPPED = "no ROIs: ROI suites skipped"  # compare.md's line when the ROI index is empty


def _ci_rows(block: dict, baselines: Sequence[str], label: Callable[[str], str] = str) -> list[list[str]]:
    """One row per run: ``mean [low, high]`` per metric, ``*`` where the interval excludes 0 and
    covers seed-to-seed variation (:func:`marks_allowed`)."""
    rows = []
    for run, metrics in block.items():
        cells = []
        for m in METRICS:
            d = metrics[m]
            mark = d["excludes_zero"] and marks_allowed(d, run in baselines)
            cells.append(f"{d['mean']:+.4f} [{d['low']:+.4f}, {d['high']:+.4f}]{' *' if mark else ''}")
        rows.append([label(run), *cells])
    return rows


def _fmt(v: float | None) -> str:
    return "–" if v is None else f"{v:.4f}"


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A Markdown table of ``header`` and ``rows`` (cells as given), the lines joined."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _best(values: dict[str, float], metric: str) -> str | None:
    if not values:
        return None
    pick = max if metric in HIGHER_IS_BETTER else min
    return pick(values, key=values.get)


def _missing_lines(missing: dict[str, str] | None) -> list[str]:
    """The header line naming the baselines that could not be built and why (none if all were)."""
    if not missing:
        return []
    reasons = set(missing.values())
    if len(reasons) == 1:
        return [f"Missing baselines (not built): {', '.join(missing)}: {reasons.pop()}."]
    return [f"Missing baselines (not built): {'; '.join(f'{b}: {r}' for b, r in missing.items())}."]


def _metric_rows(
    block: dict[str, dict], runs: Sequence[str], variants: Sequence[str], label: Callable[[str], str] = str
) -> list[list[str]]:
    """One table row per run, the best variant per metric in bold."""
    best = {m: _best({v: block[v][m] for v in variants}, m) for m in METRICS}
    rows = []
    for r in runs:
        cells = [f"**{_fmt(block[r][m])}**" if best[m] == r else _fmt(block[r][m]) for m in METRICS]
        rows.append([label(r), *cells])
    return rows


def _ci_lines(
    stats: dict, suite: str, cap: str, unit: str, baselines: Sequence[str], label: Callable[[str], str] = str
) -> list[str]:
    """Every run minus the reference with its interval (:func:`_ci_rows`), as Markdown lines."""
    block = stats[suite][cap]
    first = next(iter(next(iter(block.values())).values())) if block else {"n": 0}
    k = first.get("clusters")
    frames = "" if k is None else f" in {k} frame{'' if k == 1 else 's'}, drawn by frame"
    return [
        f"Difference to {stats['reference']} ({first['n']} paired {unit}{frames}):",
        "",
        markdown_table(["run", *METRICS], _ci_rows(block, baselines, label)),
        "",
    ]


def _spread_lines(
    block: dict, variants: Sequence[str], seeds: int, label: Callable[[str], str] = str
) -> list[str]:
    """The mean ± sd over seeds of each variant's per-run mean, as Markdown lines."""
    rows = [
        [label(v), *[f"{d[m]['mean']:.4f} ± {d[m]['sd']:.4f}" for m in METRICS]]
        for v, d in block.items()
        if v in variants
    ]
    return [
        f"Seed-to-seed spread (mean ± sd over {seeds} seeds of the per-run mean):",
        "",
        markdown_table(["variant", *METRICS], rows),
        "",
    ]


# The extra evaluation sets' names in compare.md (msdepth.data.eval_sets).
SET_TITLES = {
    "eigen": "Eigen split (raw LiDAR GT, Garg crop)",
    "eigen_benchmark": "Eigen benchmark split (KITTI's annotated depth GT, Garg crop)",
    "kitti2012": "KITTI 2012 stereo training frames (disp_occ with the reflective surfaces' GT)",
    "kitti2015": "KITTI 2015 stereo training frames (disp_occ_0; obj_map's cars where present)",
    "folder": "Stereo folder (data.folder.root: its evaluation list, class maps and boxes)",
}
# What a set evaluates, where it is not the Eigen sets' (msdepth.evaluation.suites' Frame.crop).
SET_PIXELS = {
    "kitti2012": "every GT pixel of the whole frame (GT beyond the cap kept, as KITTI 2015's)",
    "kitti2015": "every GT pixel of the whole frame (GT beyond the cap kept, as data.source kitti's)",
    "folder": "every GT pixel of the whole frame (GT beyond the cap kept, as data.source folder's)",
}


def _class_lines(
    name: str, groups: dict[str, dict], runs: Sequence[str], cap: str, label: Callable
) -> list[str]:
    """An extra set's exact classes at ``cap`` (the summaries' ``masks``): per class and run,
    abs_rel, a1, D1 and EPE."""
    masks = {r: groups[r].get("masks") for r in runs}
    if any(m is None or cap not in m for m in masks.values()):
        return []
    rows = [
        [cls, label(r), *(f"{m[cap]['by_class'][cls][k]:.4f}" for k in ("abs_rel", "a1")),
         f"{m['stereo'][cls]['d1']:.1f}", f"{m['stereo'][cls]['epe']:.2f}"]
        for cls in sorted(masks[runs[0]][cap]["by_class"])
        for r, m in masks.items()
    ]  # fmt: skip
    return [
        f"## {name}: exact class pixels, cap {cap[3:]} m",
        "",
        "Each class's exact GT pixels of every frame that has some (D1 %, EPE px: KITTI's, uncapped).",
        "",
        markdown_table(["class", "run", "abs_rel", "a1", "D1 %", "EPE px"], rows),
        "",
    ]


def _stereo_lines(
    block: dict[str, dict], runs: Sequence[str], label: Callable[[str], str] = str
) -> list[str]:
    """KITTI's D1 (%) and EPE (px) of the whole frame per run (``block``: run -> its numbers)."""
    if any("d1" not in block[r] for r in runs):
        return []
    rows = [[label(r), f"{100 * block[r]['d1']:.1f}", f"{block[r]['epe']:.2f}"] for r in runs]
    return ["Whole frame, KITTI's stereo metrics:", "", markdown_table(["run", "D1 %", "EPE px"], rows), ""]


def set_roi_lines(
    name: str,
    roi: dict[str, dict],
    runs: Sequence[str],
    stats: dict,
    baselines: Sequence[str],
    label: Callable,
) -> list[str]:
    """An extra set's boxes (``roi``: group -> its ROI summary): per cap, every run's abs_rel, a1, D1
    and EPE over all boxes and its abs_rel per class, then its difference to the reference."""
    lines = []
    for cap in [k for k in roi[runs[0]] if k.startswith("cap")]:
        classes = sorted({c for r in runs for c in roi[r][cap]["by_class"]})
        rows = [
            [label(r), *(_fmt(roi[r][cap]["overall"][k]) for k in ("abs_rel", "a1")),
             f"{100 * roi[r][cap]['overall']['d1']:.1f}", f"{roi[r][cap]['overall']['epe']:.2f}",
             *(_fmt(roi[r][cap]["by_class"].get(c, {}).get("abs_rel")) for c in classes)]
            for r in runs
        ]  # fmt: skip
        first = roi[runs[0]][cap]
        counts = ", ".join(f"{c} {first['by_class'][c]['count']}" for c in classes)
        lines += [
            f"## {name}: ROI boxes, cap {cap[3:]} m ({first['overall']['count']} boxes: {counts})",
            "",
            markdown_table(
                ["run", "abs_rel", "a1", "D1 %", "EPE px", *(f"{c} abs_rel" for c in classes)], rows
            ),
            "",
            *_ci_lines(stats, "roi", cap, f"{name} boxes", baselines, label),
        ]
    return lines


def _unrun_lines(unrun: dict[str, str] | None) -> list[str]:
    """The header line naming the network-free instruments without metrics on a set, and why."""
    if not unrun:
        return []
    return [f"Instruments without metrics: {'; '.join(f'{k}: {r}' for k, r in unrun.items())}.", ""]


def build_set_section(
    name: str,
    suites: dict[str, dict[str, dict]],
    variants: Sequence[str],
    baselines: Sequence[str],
    stats: dict,
    spread: dict,
    seeds: Sequence[int],
    missing_baselines: dict[str, str] | None = None,
    label: Callable[[str], str] = str,
    unrun: dict[str, str] | None = None,
) -> tuple[dict, str]:
    """An extra set's full-image tables per cap as compare.json's dict and compare.md's text;
    ``baselines``: the groups of one run, ``unrun``: instruments without metrics, and why."""
    runs = [*variants, *baselines]
    caps = [k for k in suites["full"][runs[0]] if k.startswith("cap")]
    images = suites["full"][runs[0]]["images"]
    md = [f"# {SET_TITLES.get(name, name)}", "", *_missing_lines(missing_baselines), *_unrun_lines(unrun)]
    result: dict = {"full": {}, "statistics": stats, "seed_spread": spread, "images": images}
    scaling = suites["full"][runs[0]][caps[0]].get("median_scaling")
    pixels = SET_PIXELS.get(name, "GT in (min_depth, cap) inside Garg's crop")
    md += [
        f"{images} images; {pixels}, the 7 metrics per image, then "
        + (
            "averaged; every prediction median-scaled per image (eval.median_scaling)."
            if scaling
            else "averaged; metric depth, no median scaling."
        ),
        "",
    ]
    for cap in caps:
        block = {r: suites["full"][r][cap] for r in runs}
        result["full"][cap] = block
        md += [
            f"## {name}: full image, cap {cap[3:]} m",
            "",
            markdown_table(["run", *METRICS], _metric_rows(block, runs, variants, label)),
            "",
        ]
        md += _stereo_lines(block, runs, label)
        md += _ci_lines(stats, "full", cap, "images", baselines, label)
        if len(seeds) > 1:
            md += _spread_lines(spread["full"][cap], variants, len(seeds), label)
        md += _class_lines(name, suites["full"], runs, cap, label)
    masks = {r: suites["full"][r]["masks"] for r in runs if "masks" in suites["full"][r]}
    if masks:  # KITTI 2012's reflective class (msdepth.evaluation.classes)
        result["masks"] = masks
    return result, "\n".join(md) + "\n"


def _header_lines(c: Comparison) -> list[str]:
    """The title, what was compared and how many training runs each variant's numbers average."""
    if len(c.seeds) > 1:
        trained = (
            f"Each variant's numbers are the mean of {len(c.seeds)} training runs "
            f"(seeds {', '.join(map(str, c.seeds))})."
        )
    else:
        trained = f"One training run per variant (seed {c.seeds[0]})."
    stated = "; ".join(f"{v} {settings_text(c.settings[v])}" for v in c.variants if v in (c.settings or {}))
    settings = f"Settings: {stated} (a row names where its variant differs from the defaults)."
    return [
        "# Comparison of loss variants",
        "",
        f"Variants: {', '.join(c.variants)}. "
        f"Baselines (image-blind, from training GT): {', '.join(c.baselines) or 'none'}.",
        *_missing_lines(c.missing_baselines),
        *([settings] if c.settings else []),
        trained,
        "Errors: lower is better; a1–a3: higher is better. Best variant per column in **bold**.",
        "",
    ]


def _seed_resampling(statistics: dict, variants: Sequence[str], several: bool) -> str:
    """How the seeds enter the intervals: as pairs, else per variant with the reason."""
    if not several:
        return ""
    pairing = statistics.get("pairing", {})
    paired = [g for g in variants if g in pairing and pairing[g] is None]
    unpaired = [f"{g}: {pairing[g]}" for g in variants if pairing.get(g) is not None]
    parts = []
    if paired:
        parts.append(
            f" jointly with seed pairs for {', '.join(paired)} (the same seed of both variants: the same "
            "initial weights and batches, so only the loss differs; the paired t over the per-seed "
            "differences is in compare.json and the verdict)"
        )
    if unpaired:
        parts.append(
            f"{',' if paired else ' and'} per variant, seeds for the unpaired ({'; '.join(unpaired)})"
        )
    return "".join(parts)


def _statistics_lines(c: Comparison) -> list[str]:
    """How the differences' intervals were computed and what they cover."""
    if c.statistics is None:
        return []
    seeds, several = len(c.seeds), len(c.seeds) > 1
    s = c.statistics
    resampled = f"resampling images (ROIs by their frames){_seed_resampling(s, c.variants, several)}"
    if seeds >= MIN_SEEDS_FOR_MARKS:
        covers = (
            f"{resampled}: the intervals cover the choice of images and training noise. "
            "`*`: the interval excludes 0."
        )
    else:
        covers = (
            f"{resampled}. With {seeds} seed{'s' if several else ''} per variant the intervals cover the "
            f"choice of images {'and barely any' if several else 'only, not'} training noise, so no "
            f"difference is marked (that takes at least {MIN_SEEDS_FOR_MARKS} seeds, see docs/user-guide.md)."
        )
    return [
        f"Differences are `run − {s['reference']}` (mean over images or ROIs) with a "
        f"bootstrap {s['confidence']:.0%} interval ({s['bootstrap_samples']} resamples) {covers}",
        "",
    ]


def _verdict(dependence: dict) -> str:
    """Whether a trained run uses the image, from its :func:`image_dependence` entry."""
    if dependence["variation_ratio"] is None:
        return (
            "not measured: too few evaluation frames with GT at the same pixels, "
            "or metrics from before image_dependence (re-run eval_full)"
        )
    if dependence["image_blind"]:
        return "image-blind: its predictions barely change between images"
    return "follows the image"


def _dependence_lines(c: Comparison) -> list[str]:
    """Per run: how much its predictions vary between images, and the verdict."""
    if c.image_dependence is None:
        return []
    rows = []
    for g in c.runs:
        for r in c.groups.get(g, [g]):
            d = c.image_dependence[r]
            verdict = "image-blind by construction" if g in c.baselines else _verdict(d)
            rows.append([r, _fmt(d["variation_ratio"]), _fmt(d["prior_correlation"]), verdict])
    return [
        "## Does each run use the image?",
        "",
        "Variation: how much the predicted depth changes from image to image, as a fraction of how "
        "much the GT does (per pixel, std/mean across frames; 0 for a constant or the prior). "
        "Correlation: of the run's per-image abs_rel with the per-pixel prior's. A network with "
        f"variation below {IMAGE_BLIND_BELOW} has learned the average scene, not depth from the image: "
        "its numbers say nothing about its loss.",
        "",
        markdown_table(["run", "variation", "corr. with prior", "verdict"], rows),
        "",
    ]


def _monocular_lines(c: Comparison) -> list[str]:
    """The monocular runs' median-scaling ratios and pose ATE (none for stereo runs)."""
    if not c.monocular:
        return []
    rows = [
        [
            c.settings_label(g),
            _fmt(m["scale_ratio"]),
            _fmt(m["scale_spread"]),
            _fmt(m.get("pose_ate")),
            _fmt(m.get("pose_ate_std")),
        ]
        for g, m in c.monocular.items()
    ]
    return [
        "## Monocular training: scale and pose",
        "",
        "Trained with train.mode mono or mono_stereo (Monodepth2's M, MS): depth is known up to scale, "
        "so every prediction is median-scaled per image (median GT / median prediction) before every "
        "suite. Ratio: the median of the per-image ratios; spread: their std / median (0 for a "
        "consistent scale). Pose ATE: Monodepth2's over 5-frame snippets of the training sequences "
        "(scale-aligned, in metres), mean and std over snippets. Means over each variant's seeds.",
        "",
        markdown_table(["run", "scale ratio", "ratio spread", "pose ATE", "ATE std"], rows),
        "",
    ]


def _rois_skipped_lines(c: Comparison) -> list[str]:
    """The one line that replaces the ROI and gradient tables without ROIs."""
    if c.rois_skipped is None:
        return []
    return [f"{ROIS_SKIPPED}: the ROI index is empty (no boxes to evaluate).", ""]


def _suite_lines(c: Comparison, cap: str, suite: str) -> list[str]:
    """The metrics at ``cap`` of the full image or over all ROIs, the differences to the reference
    (with ``statistics``) and the seed spread (with several seeds)."""
    if suite == "roi" and cap not in c.roi:
        return []
    block = c.full[cap] if suite == "full" else {r: c.roi[cap][r]["overall"] for r in c.runs}
    title = "Full image" if suite == "full" else "ROI"
    count = "" if suite == "full" else f" (mean over {block[c.runs[0]]['count']} ROIs)"
    lines = [
        f"## {title}, cap {cap[3:]} m{count}",
        "",
        markdown_table(["run", *METRICS], _metric_rows(block, c.runs, c.variants, c.label)),
        "",
    ]
    unit = "images" if suite == "full" else "ROIs"
    if c.statistics is not None:
        lines += _ci_lines(c.statistics, suite, cap, unit, c.baselines, c.settings_label)
    if c.seed_spread is not None and len(c.seeds) > 1:
        lines += _spread_lines(c.seed_spread[suite][cap], c.variants, len(c.seeds), c.settings_label)
    return lines


def _roi_class_lines(c: Comparison, cap: str) -> list[str]:
    """The ROIs' abs_rel per class at ``cap``."""
    if cap not in c.roi:
        return []
    by_class = {r: c.roi[cap][r]["by_class"] for r in c.runs}
    classes = sorted({k for r in c.runs for k in by_class[r]})
    rows = [[c.label(r), *[_fmt(by_class[r].get(k, {}).get("abs_rel")) for k in classes]] for r in c.runs]
    return [f"### ROI abs rel per class, cap {cap[3:]} m", "", markdown_table(["run", *classes], rows), ""]


def _roi_mask_lines(c: Comparison, cap: str) -> list[str]:
    """The ROIs scored on their exact masks at ``cap``, where every run has them."""
    if c.roi_masks is None or cap not in c.roi_masks:
        return []
    masks = c.roi_masks[cap]
    classes = sorted({k for r in c.runs for k in masks[r]["by_class"]})
    rows = [
        [
            c.label(r),
            *[_fmt(masks[r]["overall"][m]) for m in ("abs_rel", "rmse", "a1")],
            *[_fmt(masks[r]["by_class"].get(k, {}).get("abs_rel")) for k in classes],
        ]
        for r in c.runs
    ]
    return [
        f"### ROI, exact masks, cap {cap[3:]} m",
        "",
        f"Each box's own pixels of its class (the renderer's class map: a car without the road "
        f"behind it, a windshield without the bonnet); {c.mask_counts['rois']} ROIs, "
        f"{c.mask_counts['excluded_rois']} without valid GT on their pixels excluded.",
        "",
        markdown_table(["run", "abs_rel", "rmse", "a1", *[f"{k} abs_rel" for k in classes]], rows),
        "",
    ]


def _gradient_lines(c: Comparison, cap: str) -> list[str]:
    """The depth maps' mean |derivative| on the ROIs at ``cap``, predicted and its error."""
    if cap not in c.gradients:
        return []
    grad = c.gradients[cap]
    header = ["run", *[f"pred {g}" for g in GRADIENTS], *[f"|pred−GT| {g}" for g in GRADIENTS]]
    rows = [
        [
            c.settings_label(r),
            *[_fmt(grad[r]["overall"][f"pred_{g}"]) for g in GRADIENTS],
            *[_fmt(grad[r]["dense_gt"]["overall"].get(f"error_{g}")) for g in GRADIENTS],
        ]
        for r in c.runs
    ]
    gt_row = grad[c.runs[0]]["dense_gt"]["overall"]
    rows.append(["GT (dense ROIs)", *[_fmt(gt_row.get(f"gt_{g}")) for g in GRADIENTS], "", "", ""])
    return [
        f"## Gradient consistency on ROIs, cap {cap[3:]} m (mean |derivative| of depth, m/px)",
        "",
        markdown_table(header, rows),
        "",
    ]


# The tables repeated per cap, in order (the ROI ones are empty without ROIs).
CAP_SECTIONS: tuple[Callable[[Comparison, str], list[str]], ...] = (
    lambda c, cap: _suite_lines(c, cap, "full"),
    lambda c, cap: _suite_lines(c, cap, "roi"),
    _roi_class_lines,
    _roi_mask_lines,
    _gradient_lines,
)


def _cap_lines(c: Comparison) -> list[str]:
    """:data:`CAP_SECTIONS` for every cap."""
    return [line for cap in c.caps for section in CAP_SECTIONS for line in section(c, cap)]


# ----------------------------------------------------------------------------- the losses' optimum

OPTIMUM_TITLE = "The losses' own optimum (no network)"


def difference_cell(d: dict | None) -> str:
    """A PairedDifference dict as ``mean [low, high]``, `` *`` where it excludes 0; "" for none."""
    if d is None:
        return ""
    star = " *" if d["excludes_zero"] else ""
    return f"{d['mean']:+.3f} [{d['low']:+.3f}, {d['high']:+.3f}]{star}"


def _optimum_side_rows(c: Comparison, cap: str) -> dict[str, dict]:
    """The trained runs (mean over seeds) and the baselines, as optimum rows at ``cap``."""
    out = {}
    for r in c.runs:
        roi = {cap: c.roi[cap][r]} if cap in c.roi else None
        if roi is not None and c.roi_masks and cap in c.roi_masks:
            roi["masks"] = {cap: c.roi_masks[cap][r]}
        out[c.label(r)] = optimum_row({cap: c.full[cap][r], "images": (c.images or {}).get(r)}, roi, cap)
    return out


def _optimum_main_row(name: str, r: dict) -> list[str]:
    """A row of the optimum section's main table: D1 in %, EPE in px (– where a run has none)."""
    d1, epe = r.get("d1"), r.get("epe")
    return [
        name,
        str(r.get("images") or ""),
        _fmt(r.get("abs_rel")),
        _fmt(r.get("a1")),
        "–" if d1 is None else f"{100 * d1:.1f}",
        "–" if epe is None else f"{epe:.2f}",
        _fmt(r.get("roi_abs_rel")),
        _fmt(r.get("mask_abs_rel")),
    ]


def _optimum_lines(c: Comparison) -> list[str]:
    """The optimum of every variant and weight beside the trained runs and the baselines, its
    differences to the reference with intervals, and its ROI abs_rel per class."""
    if c.optimum is None:
        return []
    o, cap = c.optimum, c.optimum["cap"]
    rows = {**_optimum_side_rows(c, cap), **o["runs"]}
    main = [_optimum_main_row(name, r) for name, r in rows.items()]
    classes = sorted({k for r in rows.values() for k in r.get("by_class", {})})
    per_class = [
        [
            name,
            *[_fmt(r.get("by_class", {}).get(k)) for k in classes],
            *[_fmt(r.get("mask_by_class", {}).get(k)) for k in classes],
        ]
        for name, r in rows.items()
    ]
    lines = [
        f"# {OPTIMUM_TITLE}",
        "",
        "Per stereo pair, the disparity that minimises each variant's own training objective, optimised "
        "directly with both views (docs/optimum.md), scored with the same suites. The weight is the "
        f"optimum's own smoothness weight; images: the frames each row was scored on. Cap {cap[3:]} m. "
        "The matchers, unrefined: SGM on a variant's own cost volume and OpenCV's SGBM (the optimum's "
        "`cost` and `sgbm` starts). D1: KITTI's share of GT pixels off by > 3 px and > 5 %; EPE: the "
        "mean disparity error, on the capped depth's disparity f·B/depth.",
        "",
        markdown_table(
            ["run", "images", "abs_rel", "a1", "D1 (%)", "EPE (px)", "ROI abs_rel", "mask abs_rel"], main
        ),
        "",
    ]
    if o.get("skipped"):
        lines += [" ".join(f"{label}: skipped ({why})." for label, why in o["skipped"].items()), ""]
    if o["differences"]:
        diff = [
            [label, *[difference_cell(d.get(s, {}).get(m)) for s in ("full", "roi") for m in OPTIMUM_METRICS]]
            for label, d in o["differences"].items()
        ]
        lines += [
            f"Differences to {o['reference']} (mean over its seeds), paired bootstrap over images "
            "(ROIs for the ROI columns); `*`: the interval excludes 0. The optimum has no training "
            "seed, so its interval covers the choice of images (and the reference's seeds) only.",
            "",
            markdown_table(["run", "Δ abs_rel", "Δ a1", "Δ ROI abs_rel", "Δ ROI a1"], diff),
            "",
        ]
    if classes:
        lines += [
            f"## {OPTIMUM_TITLE}: ROI abs rel per class, cap {cap[3:]} m",
            "",
            markdown_table(["run", *classes, *[f"{k} (mask)" for k in classes]], per_class),
            "",
        ]
    return lines


# compare.md's sections in order; each renders a Comparison as Markdown lines (none if absent).
SECTIONS: tuple[Callable[[Comparison], list[str]], ...] = (
    _header_lines,
    _statistics_lines,
    _dependence_lines,
    _monocular_lines,
    _rois_skipped_lines,
    _cap_lines,
    _optimum_lines,
)


def build_comparison(comparison: Comparison) -> tuple[dict, str]:
    """``comparison`` as ``compare.json``'s dict and ``compare.md``'s text (:data:`SECTIONS`)."""
    return comparison.as_json(), "\n".join(line for s in SECTIONS for line in s(comparison)) + "\n"
