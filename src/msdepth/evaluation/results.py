"""The evaluation suites run and written as the pipeline's metric files, shared by the stages
that score a run or a baseline: :func:`run_suite`, :func:`score_set` and :func:`headline`, the
few numbers per suite that ``dvc metrics show`` lists (and compare averages)."""

from __future__ import annotations

from pathlib import Path

from msdepth.config.params import Params
from msdepth.evaluation.suites import (
    evaluate_full,
    evaluate_gradients,
    evaluate_roi,
    median_scaled_maps,
    no_rois,
)
from msdepth.io import atomic_path, write_json
from msdepth.pipeline.paths import SETS_METRICS

SUITES = {"full": evaluate_full, "roi": evaluate_roi, "gradients": evaluate_gradients}  # SUITE_NAMES' order


def headline(suite: str, summary: dict) -> dict[str, float] | None:
    """The few numbers of a suite's summary that a reader compares (first cap): what
    ``dvc metrics show`` and ``dvc metrics diff`` list, one small file per run and suite. The
    full summary stays beside it as a plain output. An ROI suite run without ROIs: ``{"rois": 0}``
    (a valid metrics file with nothing to compare)."""
    if suite == "roi" and no_rois(summary):
        return {"rois": 0}
    cap = next((k for k in summary if k.startswith("cap")), None)
    if cap is None:
        return None
    if suite == "full":
        m = summary[cap]
        out = {"abs_rel": m["abs_rel"], "rmse": m["rmse"], "a1": m["a1"]}
        if "image_dependence" in summary:
            out["variation"] = summary["image_dependence"]["variation_ratio"]
        if "median_scaling" in m:  # a monocular run's depth, median-scaled per image
            out["scale_ratio"] = m["median_scaling"]["ratio_median"]
        return out
    if suite == "roi":
        m = summary[cap]["overall"]
        out = {"roi_abs_rel": m["abs_rel"], "roi_a1": m["a1"]}
        if cap in summary.get("masks", {}):
            out["mask_abs_rel"] = summary["masks"][cap]["overall"]["abs_rel"]
        return out
    return None


def write_suite(
    suite: str,
    run: str,
    summary: dict,
    table,  # noqa: ANN001 - a DataFrame
    root: Path = Path("metrics"),
    headline_root: str = "",
) -> None:
    """A suite's summary JSON, its headline JSON (full, roi) and its per-unit CSV for one run:
    ``<root>/<suite>/<run>.json|csv`` and ``metrics/headline/[<headline_root>/]<suite>/<run>.json``
    (an extra set's: ``metrics/sets/<set>/full/...`` and ``metrics/headline/sets/<set>/full/...``)."""
    write_json(root / suite / f"{run}.json", summary)
    top = headline(suite, summary)
    if top is not None:
        write_json(Path("metrics") / "headline" / headline_root / suite / f"{run}.json", top)
    with atomic_path(root / suite / f"{run}.csv") as tmp:
        table.to_csv(tmp, index=False, float_format="%.6g")


def run_suite(  # noqa: ANN001 - frames, boxes
    params: Params, suite: str, run: str, pred: dict, frames, boxes, *, scaled: bool = False
) -> None:
    """Evaluate ``pred`` (frame -> depth map) with one suite and write its files as run ``run``.

    ``scaled``: ``pred`` is up to scale (a train.mode mono | mono_stereo run's), median-scaled per
    image: by the full-image suite, which reports the ratios, and before the ROI suites. The
    baselines and the optimum are metric, whatever train.mode.
    """
    fn = SUITES[suite]
    if suite == "full":
        summary, table = fn(pred, frames, params.eval, median_scaling=scaled)
    else:
        pred = median_scaled_maps(pred, frames, params.eval)[0] if scaled else pred
        summary, table = fn(pred, frames, boxes, params.eval)
    write_suite(suite, run, summary, table)


def median_scaling(params: Params) -> bool:
    """Whether a trained run's extra sets median-scale: ``eval.median_scaling``, or a monocular run."""
    return params.eval.median_scaling or params.train.monocular


def score_set(  # noqa: ANN001 - frames
    params: Params, name: str, run: str, pred: dict, frames, *, scaled: bool | None = None
) -> None:
    """The full-image suite of ``pred`` on extra set ``name``, written below ``metrics/sets/<set>/``;
    median-scaled when ``scaled`` (default: ``eval.median_scaling``)."""
    scaled = params.eval.median_scaling if scaled is None else scaled
    summary, table = evaluate_full(pred, frames, params.eval, median_scaling=scaled)
    write_suite("full", run, summary, table, root=SETS_METRICS / name, headline_root=f"sets/{name}")
