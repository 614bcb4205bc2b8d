"""The evaluation suites run and written as the pipeline's metric files, shared by the stages
that score a run or a baseline: :func:`run_suite`, :func:`score_set` and :func:`headline`, the
few numbers per suite that ``dvc metrics show`` lists (and compare averages); and the depth maps
they score (:func:`write_depth_maps`)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from msdepth.config.params import Params
from msdepth.data import kitti
from msdepth.data.eval_index import read_eval_index
from msdepth.errors import ConfigError, DataError
from msdepth.evaluation.classes import exact_class_scores, with_class_columns
from msdepth.evaluation.suites import (
    NO_ROIS,
    Frame,
    depth_maps,
    evaluate_full,
    evaluate_gradients,
    evaluate_roi,
    load_frames,
    median_scaled_maps,
    no_rois,
    read_depth_maps,
)
from msdepth.io import atomic_path, save_npz, write_json
from msdepth.pipeline.paths import (
    HEADLINE,
    METRICS,
    headline_path,
    set_headline_dir,
    set_metrics_dir,
    suite_path,
    train_summary_path,
)
from msdepth.readers import read_json_file, read_npy_file, read_table_file

SUITES = {"full": evaluate_full, "roi": evaluate_roi, "gradients": evaluate_gradients}  # SUITE_NAMES' order


def headline(suite: str, summary: dict) -> dict[str, float] | None:
    """The few numbers of a suite's summary that a reader compares (first cap): what
    ``dvc metrics show`` and ``dvc metrics diff`` list, one small file per run and suite. Full
    image: ``abs_rel`` and ``a1`` (a monocular run's ``scale_ratio`` too); ROI suite: the abs_rel
    of all ROIs (``roi``) and of all exact masks (``masks``), as each class's abs_rel stands under
    the class's name in the means. Every other number (rmse, image variation, ROI a1) stays in the
    full summary beside it, a plain output: each key is one column of ``dvc metrics show``, whose
    lines stay within 132 characters. An ROI suite run without ROIs: ``{"rois": 0}`` (a valid
    metrics file with nothing to compare)."""
    if suite == "roi" and no_rois(summary):
        return {"rois": 0}
    cap = next((k for k in summary if k.startswith("cap")), None)
    if cap is None:
        return None
    if suite == "full":
        m = summary[cap]
        out = {"abs_rel": m["abs_rel"], "a1": m["a1"]}
        if "median_scaling" in m:  # a monocular run's depth, median-scaled per image
            out["scale_ratio"] = m["median_scaling"]["ratio_median"]
        return {**out, **_class_headline(summary, cap)}
    if suite == "roi":
        m = summary[cap]["overall"]
        out = {"roi": m["abs_rel"]}
        if cap in summary.get("masks", {}):
            out["masks"] = summary["masks"][cap]["overall"]["abs_rel"]
        return out
    return None


def _class_headline(summary: dict, cap: str) -> dict[str, float]:
    """An extra set's exact classes in its full-image headline (KITTI 2012's ``reflective``): each
    class's abs_rel at ``cap`` and its D1 (%); nothing for a set without classes."""
    masks = summary.get("masks", {})
    out = {}
    for cls, m in masks.get(cap, {}).get("by_class", {}).items():
        out[f"{cls}_abs_rel"] = m["abs_rel"]
        if cls in masks.get("stereo", {}):
            out[f"{cls}_d1"] = masks["stereo"][cls]["d1"]
    return out


def _write_suite(
    suite: str,
    run: str,
    summary: dict,
    table,  # noqa: ANN001 - a DataFrame
    root: Path = METRICS,
    headline_root: Path = HEADLINE,
) -> None:
    """A suite's summary JSON, its headline JSON (full, roi) and its per-unit CSV for one run:
    :func:`~msdepth.pipeline.paths.suite_path` below ``root`` and
    :func:`~msdepth.pipeline.paths.headline_path` below ``headline_root`` (an extra set's:
    ``metrics/sets/<set>/full/...`` and ``metrics/headline/sets/<set>/full/...``)."""
    write_json(suite_path(suite, run, ".json", root), summary)
    top = headline(suite, summary)
    if top is not None:
        write_json(headline_path(suite, run, headline_root), top)
    with atomic_path(suite_path(suite, run, ".csv", root)) as tmp:
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
        summary, table = full_suite(params, pred, frames, scaled)
    else:
        pred = median_scaled_maps(pred, frames, params.eval)[0] if scaled else pred
        summary, table = fn(pred, frames, boxes, params.eval)
    _write_suite(suite, run, summary, table)


def full_suite(
    params: Params, pred: dict[str, np.ndarray], frames: list[Frame], scaled: bool
) -> tuple[dict, pd.DataFrame]:
    """The full-image suite (:func:`~msdepth.evaluation.suites.evaluate_full`) with, for a set whose
    every frame has whole-frame classes (KITTI 2012's reflective, KITTI 2015's obj_map cars, a
    stereo folder's class maps: ``Frame.whole_frame_classes``), the scores on each exact class
    (of ``pred`` median-scaled where ``scaled``), computed once
    (:func:`~msdepth.evaluation.classes.exact_class_scores`): ``summary["masks"]`` and per frame a
    column per class (:func:`~msdepth.evaluation.classes.with_class_columns`). Other sets' files stay
    as they were."""
    summary, table = evaluate_full(pred, frames, params.eval, median_scaling=scaled)
    if not frames or not all(f.class_map is not None and f.whole_frame_classes for f in frames):
        return summary, table
    scored = median_scaled_maps(pred, frames, params.eval)[0] if scaled else pred
    found = exact_class_scores(scored, frames, params.eval)
    if found is None:
        return summary, table
    masks, exact = found
    return {**summary, "masks": masks}, with_class_columns(table, exact)


def write_depth_maps(run: str, disparities: Path, eval_index: Path, out: Path, *, monocular: bool) -> None:
    """Run ``run``'s disparities (the file ``disparities``) as depth maps of the frames of
    ``eval_index`` at their GT resolution (:func:`~msdepth.evaluation.suites.depth_maps`: metric, or
    up to scale for a ``monocular`` run), written to ``out``; a DataError without disparities."""
    if not disparities.exists():
        raise DataError(f"{disparities}: no disparities for run {run!r}")
    frames = load_frames(read_eval_index(eval_index))
    save_npz(out, **depth_maps(read_npy_file(disparities, "disparities"), frames, monocular=monocular))


def checked_suite(suite: str) -> str:
    """``suite`` if it is one of :data:`SUITES`, else a ConfigError naming them."""
    if suite not in SUITES:
        raise ConfigError(f"unknown evaluation suite {suite!r}; known: {sorted(SUITES)}")
    return suite


def score_run(params: Params, suite: str, run: str, depth: Path, eval_index: Path, rois: Path) -> None:
    """:func:`run_suite` on run ``run``'s depth maps (the file ``depth``) of the frames of
    ``eval_index`` (ROIs ``rois``, read by the ROI suites only); a monocular run's
    (``train.mode`` mono | mono_stereo) median-scaled."""
    frames = load_frames(read_eval_index(eval_index))
    boxes = kitti.read_rois(rois) if suite != "full" else None
    pred = read_depth_maps(depth, frames)
    run_suite(params, suite, run, pred, frames, boxes, scaled=params.train.monocular)


def median_scaling(params: Params) -> bool:
    """Whether a trained run's extra sets median-scale: ``eval.median_scaling``, or a monocular run."""
    return params.eval.median_scaling or params.train.monocular


def score_set(  # noqa: ANN001 - frames
    params: Params,
    name: str,
    run: str,
    pred: dict,
    frames,
    *,
    scaled: bool | None = None,
    rois: Path | None = None,
) -> None:
    """The full-image suite of ``pred`` on extra set ``name``, written below ``metrics/sets/<set>/``;
    median-scaled when ``scaled`` (default: ``eval.median_scaling``). With ``rois`` (the set's ROI
    file, :func:`~msdepth.data.eval_index.set_rois_path`), the ROI suite too, each box a unit with
    D1 and EPE beside the 7 metrics (the explicit "no ROIs" summary where the file lists none)."""
    scaled = params.eval.median_scaling if scaled is None else scaled
    root, headline_root = set_metrics_dir(name), set_headline_dir(name)
    summary, table = full_suite(params, pred, frames, scaled)
    _write_suite("full", run, summary, table, root=root, headline_root=headline_root)
    if rois is None:
        return
    boxes = kitti.read_rois(rois)
    scored = median_scaled_maps(pred, frames, params.eval)[0] if scaled else pred
    summary, table = evaluate_roi(scored, frames, boxes, params.eval, stereo=True)
    if no_rois(summary):
        summary[NO_ROIS] = f"no ROIs: {Path(rois).as_posix()} lists no box on set {name}"
    _write_suite("roi", run, summary, table, root=root, headline_root=headline_root)


# --- reading the metric files back (the compare stage, the studies) ---------------------------------


def _load_runs(
    metrics_dir: str | os.PathLike, suites: Sequence[str], runs: Sequence[str], suffix: str, read, what: str
) -> dict:
    """``{suite: {run: read(metrics_dir/<suite>/<run><suffix>)}}``, naming any missing file."""
    out: dict[str, dict] = {}
    for suite in suites:
        out[suite] = {}
        for run in runs:
            path = suite_path(suite, run, suffix, Path(metrics_dir))
            if not path.exists():
                raise DataError(f"{path}: missing {what} of run {run!r} (suite {suite})")
            out[suite][run] = read(path)
    return out


def load_suite_metrics(
    metrics_dir: str | os.PathLike, runs: Sequence[str], suites: Sequence[str] = tuple(SUITES)
) -> dict[str, dict[str, dict]]:
    """``{suite: {run: metrics}}`` from ``metrics_dir/<suite>/<run>.json``."""
    return _load_runs(metrics_dir, suites, runs, ".json", lambda p: read_json_file(p, "metrics"), "metrics")


def load_training_summaries(runs: Sequence[str], root: str | os.PathLike = ".") -> dict[str, dict]:
    """``{run: its training summary}`` of the runs that have one (the baselines were not trained)."""
    paths = {r: Path(root) / train_summary_path(r) for r in runs}
    return {r: read_json_file(p, "training summary") for r, p in paths.items() if p.is_file()}


def load_unit_tables(
    metrics_dir: str | os.PathLike, runs: Sequence[str], suites: Sequence[str] = ("full", "roi")
) -> dict[str, dict[str, pd.DataFrame]]:
    """``{suite: {run: per-image or per-ROI table}}`` from ``metrics_dir/<suite>/<run>.csv``."""
    return _load_runs(
        metrics_dir,
        suites,
        runs,
        ".csv",
        lambda p: read_table_file(p, "per-unit metrics", dtype={"frame": str, "image": str}),
        "per-unit metrics",
    )
