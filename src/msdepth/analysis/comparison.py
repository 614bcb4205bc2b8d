"""What compare.md and compare.json show, as data: the :class:`Comparison` of every group's metrics
per suite and cap, each variant's settings, and the losses' own optimum beside them."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Mapping, Sequence

from msdepth.config.params import Params
from msdepth.config.variants import configs as variant_configs
from msdepth.evaluation.metrics import STEREO_METRICS
from msdepth.evaluation.suites import NO_ROIS

# Short names of variant settings in compare.md ("msssim (k=7)"); other keys keep their own name.
SETTING_NAMES = {"kernel_size": "k"}


def variant_settings(params: Params) -> dict[str, dict]:
    """Each compared variant's params section as a dict (what its runs were trained with)."""
    return {v: dataclasses.asdict(getattr(params, v)) for v in params.variants}


def changed_settings(variant: str, settings: dict) -> dict:
    """The entries of ``variant``'s ``settings`` that differ from its config's defaults."""
    defaults = dataclasses.asdict(variant_configs()[variant]())
    return {k: v for k, v in settings.items() if k not in defaults or defaults[k] != v}


def settings_text(settings: Mapping, names: Mapping[str, str] = SETTING_NAMES) -> str:
    """``settings`` as compare.md writes them, keys shortened by ``names``: ``k=7, levels=3``."""
    return ", ".join(
        f"{names.get(k, k)}={v:g}" if isinstance(v, float) else f"{names.get(k, k)}={v}"
        for k, v in settings.items()
    )


# compare.json's keys in order; the optional ones (None in :class:`Comparison`) are left out.
JSON_FIELDS = (
    "variants",
    "baselines",
    "seeds",
    "settings",
    "full",
    "roi",
    "gradients",
    "missing_baselines",
    "statistics",
    "image_dependence",
    "seed_spread",
    "rois_skipped",
    "roi_masks",
    "optimum",
    "monocular",
)


@dataclass(frozen=True)
class Comparison:
    """What ``compare.md`` shows (a renderer per section in :data:`msdepth.reporting.comparison.SECTIONS`,
    or per cap in its ``CAP_SECTIONS``); :meth:`as_json` is ``compare.json``."""

    variants: list[str]
    baselines: list[str]
    seeds: list[int]
    full: dict  # {capN: {run: metrics}}
    roi: dict  # {capN: {run: ROI summary}}; empty without ROIs
    gradients: dict  # {capN: {run: gradient summary}}; empty without ROIs
    groups: dict[str, Sequence[str]]  # variant -> its runs (one per seed); not in compare.json
    missing_baselines: dict[str, str] | None = None
    statistics: dict | None = None
    image_dependence: dict[str, dict] | None = None
    seed_spread: dict | None = None
    rois_skipped: str | None = None  # why (NO_ROIS's text) when the ROI suites were skipped
    roi_masks: dict | None = None  # {capN: {run: exact-mask summary}} for the caps every run has
    mask_counts: dict[str, int] | None = None  # the ROIs with exact masks and those excluded
    optimum: dict | None = None  # :func:`optimum_data`: the losses' own optimum, no network
    settings: dict[str, dict] | None = None  # :func:`variant_settings`: each variant's params section
    monocular: dict[str, dict] | None = None  # :func:`monocular_data`: scale ratios and pose ATE
    images: dict[str, int] | None = None  # per run, the images its full-image suite scored

    @property
    def runs(self) -> list[str]:
        """The variants, then the baselines."""
        return [*self.variants, *self.baselines]

    @property
    def caps(self) -> list[str]:
        """The caps' keys (``capN``), in the metrics' order."""
        return list(self.full)

    def as_json(self) -> dict:
        """``compare.json``'s content."""
        return {k: getattr(self, k) for k in JSON_FIELDS if getattr(self, k) is not None}

    def settings_label(self, group: str) -> str:
        """``group`` with its variant's settings that differ from the defaults: ``msssim (k=7)``."""
        changed = changed_settings(group, self.settings[group]) if group in (self.settings or {}) else {}
        return f"{group} ({settings_text(changed)})" if changed else group

    def label(self, group: str) -> str:
        """``group``'s name in the metric tables (:meth:`settings_label`), flagging its image-blind runs."""
        name = self.settings_label(group)
        dependence = self.image_dependence or {}
        runs = self.groups.get(group, [group])
        blind = sum(1 for r in runs if dependence.get(r, {}).get("image_blind"))
        if not blind or group in self.baselines:
            return name
        return (
            f"{name} (image-blind)"
            if blind == len(runs)
            else f"{name} ({blind} of {len(runs)} runs image-blind)"
        )


def _by_cap(suite: dict[str, dict], runs: Sequence[str], caps: Sequence[str]) -> dict:
    """``{capN: {run: suite[run][capN]}}``."""
    return {cap: {r: suite[r][cap] for r in runs} for cap in caps}


def _roi_masks(
    roi: dict[str, dict], runs: Sequence[str], caps: Sequence[str]
) -> tuple[dict | None, dict | None]:
    """The exact-mask summaries per cap that every run has, and the first run's ROI counts."""
    masks = {
        cap: {r: roi[r]["masks"][cap] for r in runs}
        for cap in caps
        if all(cap in roi[r].get("masks", {}) for r in runs)
    }
    if not masks:
        return None, None
    first = roi[runs[0]]["masks"]
    return masks, {"rois": first["rois"], "excluded_rois": first["excluded_rois"]}


def comparison_data(
    suites: dict[str, dict[str, dict]],
    variants: Sequence[str],
    baselines: Sequence[str],
    *,
    seeds: Sequence[int] = (0,),
    stats: dict | None = None,
    spread: dict | None = None,
    dependence: dict[str, dict] | None = None,
    groups: dict[str, Sequence[str]] | None = None,
    missing_baselines: dict[str, str] | None = None,
    optimum: dict | None = None,
    settings: dict[str, dict] | None = None,
    monocular: dict[str, dict] | None = None,
) -> Comparison:
    """What ``compare.md`` shows: ``suites`` (each group's metrics per suite, :func:`group_metrics`)
    by cap, and each optional table (None: its section left out) from the function of its name."""
    runs = [*variants, *baselines]
    caps = [k for k in suites["full"][runs[0]] if k.startswith("cap")]
    skipped = all(NO_ROIS in suites["roi"][r] for r in runs)
    masks, counts = (None, None) if skipped else _roi_masks(suites["roi"], runs, caps)
    return Comparison(
        variants=list(variants),
        baselines=list(baselines),
        seeds=list(seeds),
        full=_by_cap(suites["full"], runs, caps),
        roi={} if skipped else _by_cap(suites["roi"], runs, caps),
        gradients={} if skipped else _by_cap(suites["gradients"], runs, caps),
        groups=groups or {r: [r] for r in runs},
        missing_baselines=dict(missing_baselines) if missing_baselines else None,
        statistics=stats,
        image_dependence=dependence,
        seed_spread=spread,
        rois_skipped=suites["roi"][runs[0]][NO_ROIS] if skipped else None,
        roi_masks=masks,
        mask_counts=counts,
        optimum=optimum,
        settings=settings,
        monocular=monocular,
        images={r: suites["full"][r]["images"] for r in runs if "images" in suites["full"][r]},
    )


OPTIMUM_METRICS = ("abs_rel", "a1")


def optimum_row(full: dict, roi: dict | None, cap: str) -> dict:
    """One run's numbers in the optimum section: full image (D1 and EPE where present), ROIs, masks."""
    row = {"images": full.get("images"), **{m: full[cap][m] for m in OPTIMUM_METRICS}}
    row.update({m: full[cap][m] for m in STEREO_METRICS if m in full[cap]})
    if roi is not None and cap in roi:
        row["roi_abs_rel"] = roi[cap]["overall"]["abs_rel"]
        row["by_class"] = {k: v["abs_rel"] for k, v in roi[cap]["by_class"].items()}
        if cap in roi.get("masks", {}):
            row["mask_abs_rel"] = roi["masks"][cap]["overall"]["abs_rel"]
            row["mask_by_class"] = {k: v["abs_rel"] for k, v in roi["masks"][cap]["by_class"].items()}
    return row


def optimum_data(
    suites: dict[str, dict[str, dict]],
    runs: dict[str, str],
    stats: dict | None,
    cap: str,
    skipped: dict[str, str] | None = None,
) -> dict:
    """Per optimum or matcher label (``runs``: label -> run) its numbers at ``cap``, its differences
    to the reference in ``stats`` (:func:`paired_statistics`), and the matchers ``skipped`` (why)."""
    roi = suites.get("roi", {})
    rows = {label: optimum_row(suites["full"][run], roi.get(run), cap) for label, run in runs.items()}
    differences: dict = {}
    for suite in ("full", "roi"):
        for label, block in ((stats or {}).get(suite, {}).get(cap) or {}).items():
            if label in runs:
                differences.setdefault(label, {})[suite] = {m: block[m] for m in OPTIMUM_METRICS}
    return {
        "cap": cap,
        "reference": (stats or {}).get("reference"),
        "runs": rows,
        "differences": differences,
        "skipped": dict(skipped or {}),
    }


def mean_rows(result: dict, variants: Sequence[str], cap: str) -> dict[str, dict[str, float]]:
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
