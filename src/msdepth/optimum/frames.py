"""The losses' own optimum (:mod:`msdepth.optimum.solver`) on the pipeline's evaluation frames, scored
with the same depth conversion and suites as a trained run; the matchers beside it (SGM on a
variant's own cost volume, OpenCV's SGBM: :mod:`msdepth.optimum.starts`, no refinement), scored the
same way; and the cost curves of every ROI with dense GT. The stages ``optimum``, ``match`` and
``cost_curves`` (stages/*.py) call these."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from msdepth.config.checks import has_per_pixel_cost
from msdepth.config.params import Params
from msdepth.errors import ConfigError
from msdepth.pipeline.paths import OPTIMUM, SGBM, match_run, optimum_run, suite_dir

if TYPE_CHECKING:
    from msdepth.losses.monodepth import MonodepthLoss


def checked_weight(params: Params, weight: str) -> float:
    """``weight`` as a float, a ConfigError unless it is one of ``optimum.smoothness_sweep``."""
    try:
        value = float(weight)
    except ValueError:
        raise ConfigError(f"smoothness weight {weight!r} is not a number") from None
    if value not in params.optimum.smoothness_sweep:
        sweep = list(params.optimum.smoothness_sweep)
        raise ConfigError(f"smoothness weight {weight} is not in optimum.smoothness_sweep {sweep}")
    return value


def sweep_frames(params: Params, index: pd.DataFrame, weight: float) -> pd.DataFrame:
    """The evaluation frames optimised at ``weight``: all of them at ``optimum.smoothness_weight``,
    the first ``optimum.sweep_frames`` (0 = all) at the sweep's other weights, to bound the time."""
    if weight == params.optimum.smoothness_weight:
        return index
    return _first_frames(index, params.optimum.sweep_frames)


def _first_frames(index: pd.DataFrame, n: int) -> pd.DataFrame:
    """The first ``n`` rows of an evaluation index (0 = all)."""
    return index if n <= 0 else index.iloc[:n].reset_index(drop=True)


def frame_disparities(params: Params, variant: str, weight: float, index: pd.DataFrame) -> np.ndarray:
    """The left optimum disparity (N, h, w; fraction of width, as the infer stage writes a
    network's) of every row ``(left, right)`` of an evaluation index, at the working size."""
    from msdepth.data.kitti import read_image
    from msdepth.optimum.solver import optimum_disparities

    pairs = [(read_image(lp), read_image(rp)) for lp, rp in zip(index["left"], index["right"], strict=True)]
    shapes = {p[0].shape for p in pairs}
    if len(shapes) > 1 and not (params.optimum.height and params.optimum.width):
        raise ConfigError(
            f"evaluation frames of {len(shapes)} sizes: set optimum.height/width to optimise them at one"
        )
    return np.stack(optimum_disparities(pairs, params, variant, weight))


def _boxes_of(rois: pd.DataFrame, names: Sequence[str]) -> pd.DataFrame:
    """The ROIs of the frames ``names`` (a sweep's subset of the evaluation frames)."""
    return rois[rois["image"].isin(set(names))].reset_index(drop=True)


def _gt_disparity_px(frame) -> np.ndarray:  # noqa: ANN001 - an evaluate.Frame
    """A frame's GT as disparity in px (0 where there is no GT, read by the cost curve as infinitely far)."""
    depth = frame.gt_depth
    return np.where(depth > 0, frame.focal * frame.baseline / np.maximum(depth, 1e-6), 0.0).astype(np.float32)


def _roi_cost_curves(params: Params, variant: str, index: pd.DataFrame, rois: pd.DataFrame) -> dict:
    """Per ROI class, the cost curve (:func:`msdepth.optimum.solver.cost_curve`) of every ROI whose GT is
    dense (valid fraction >= ``eval.dense_gt_fraction``), on the whole frame at the GT's size."""
    from msdepth.data.kitti import read_image
    from msdepth.errors import DataError
    from msdepth.evaluation.suites import load_frames
    from msdepth.optimum.solver import objective

    criterion = objective(params, variant)
    curves: dict[str, list[np.ndarray]] = {}
    for row, frame in zip(index.itertuples(), load_frames(index), strict=True):
        boxes = rois[rois["image"] == frame.name]
        if boxes.empty:
            continue
        left, right = read_image(row.left), read_image(row.right)
        if left.shape[:2] != frame.shape or right.shape != left.shape:
            raise DataError(f"{row.left}: image {left.shape[:2]} does not match its GT {frame.shape}")
        dense = []
        for b in boxes.to_dict("records"):
            box = (int(b["x0"]), int(b["y0"]), int(b["x1"]), int(b["y1"]))
            if frame.valid[box[1] : box[3], box[0] : box[2]].mean() < params.eval.dense_gt_fraction:
                continue
            dense.append((b["class"], box))
        add_cost_curves(curves, criterion, left, right, _gt_disparity_px(frame), dense)
    return curves


def add_cost_curves(
    curves: dict[str, list[np.ndarray]],
    criterion: MonodepthLoss,
    left: np.ndarray,
    right: np.ndarray,
    gt_disp_px: np.ndarray,
    boxes: Sequence[tuple[str, tuple[int, int, int, int]]],
) -> None:
    """Append to ``curves[class]`` the cost curve (:func:`msdepth.optimum.solver.cost_curve`) of
    each ``(class, (x0, y0, x1, y1))`` box of one frame under ``criterion`` (the variant's
    :func:`msdepth.optimum.solver.objective`), from its images (H, W, 3) and GT disparity in px."""
    from msdepth.data.pairs import to_tensor
    from msdepth.optimum.solver import cost_curve

    left_t, right_t = to_tensor(left), to_tensor(right)
    for cls, box in boxes:
        curves.setdefault(cls, []).append(cost_curve(left_t, right_t, gt_disp_px, box, criterion))


def cost_summary(curves: dict[str, list[np.ndarray]]) -> dict:
    """A variant's cost curves summarised: the s grid, each class's mean curve and
    :func:`msdepth.optimum.solver.class_summary` (s_min, basin, basin_ratio)."""
    from msdepth.optimum.solver import COST_SCALES, class_summary

    classes = class_summary(curves)
    summary = {
        "scales": [float(s) for s in COST_SCALES],
        "classes": classes,
        "mean_curves": {
            c: [float(v) for v in np.mean(np.stack(r), axis=0)] for c, r in sorted(curves.items())
        },
    }
    return summary


def score_optimum(
    params: Params,
    variant: str,
    weight: float,
    run: str,
    eval_index: Path,
    rois: Path,
    *,
    disparities: Path,
    depth: Path,
) -> None:
    """``variant``'s optimum at smoothness ``weight`` on the frames of ``eval_index`` that the weight
    sees (:func:`sweep_frames`), with ``optimum.threads`` torch threads: its disparities saved to
    ``disparities``, its depth to ``depth``, and every suite run on it as run ``run`` (ROIs
    ``rois``), exactly as a trained run's."""
    import torch

    from msdepth.data.eval_index import read_eval_index
    from msdepth.evaluation.suites import depth_maps, load_frames
    from msdepth.io import save_npy, save_npz

    torch.set_num_threads(params.optimum.threads)
    index = sweep_frames(params, read_eval_index(eval_index), weight)
    disp = frame_disparities(params, variant, weight, index)
    save_npy(disparities, disp)
    frames = load_frames(index)
    pred = depth_maps(disp, frames)
    save_npz(depth, **pred)
    _score_depth(params, run, pred, frames, rois)


def _score_depth(params: Params, run: str, pred: dict[str, np.ndarray], frames: list, rois: Path) -> None:
    """Every suite on ``pred`` (frame -> depth at GT size) of ``frames`` as run ``run``, the ROI
    suites on the boxes of ``rois`` that lie on those frames: what a trained run's eval stages do."""
    from msdepth.data import kitti
    from msdepth.evaluation.results import run_suite
    from msdepth.pipeline.paths import SUITE_NAMES

    boxes = _boxes_of(kitti.read_rois(rois), [f.name for f in frames])
    for suite in SUITE_NAMES:
        run_suite(params, suite, run, pred, frames, None if suite == "full" else boxes)


def checked_matcher(params: Params, matcher: str) -> str:
    """``matcher`` if it is ``sgbm`` or a configured variant, else a ConfigError naming them."""
    return matcher if matcher == SGBM else params.variant(matcher)


def _match_disparities(params: Params, matcher: str, index: pd.DataFrame) -> list[np.ndarray]:
    """The left disparity (h, w; fraction of the width, as the infer stage writes a network's) of
    every row ``(left, right)`` of an evaluation index, at the pair's own size: OpenCV's SGBM
    (``matcher`` ``sgbm``) or SGM on the variant ``matcher``'s own cost volume, winner-take-all with
    sub-pixel refinement, the left-right check and holes filled
    (:func:`msdepth.optimum.starts.matched_disparity`): the optimum's matched start, unrefined."""
    from msdepth.data.kitti import read_image
    from msdepth.optimum.starts import matched_disparity

    start = "sgbm" if matcher == SGBM else "cost"
    out = []
    for left, right in zip(index["left"], index["right"], strict=True):
        left_image = read_image(left)
        px = matched_disparity(left_image, read_image(right), params, matcher, start)
        out.append(px / np.float32(left_image.shape[1]))
    return out


def score_match(params: Params, matcher: str, eval_index: Path, rois: Path) -> None:
    """A matcher (:func:`_match_disparities`) on every frame of ``eval_index``, with
    ``optimum.threads`` torch threads, converted to depth and scored by every suite as run
    :func:`~msdepth.pipeline.paths.match_run` (metrics only: no disparities or depth kept). A
    variant without a per-pixel cost (``mix``) writes skipped metrics, as a baseline that cannot be
    built does (:func:`msdepth.evaluation.baselines.write_skipped`)."""
    import torch

    from msdepth.data.eval_index import read_eval_index
    from msdepth.evaluation.baselines import write_skipped
    from msdepth.evaluation.suites import depth_maps, load_frames
    from msdepth.pipeline.paths import HEADLINE, METRICS, SUITE_NAMES

    run = match_run(checked_matcher(params, matcher))
    if matcher != SGBM and not has_per_pixel_cost(params.appearance[matcher]):
        reason = f"variant {matcher} has no per-pixel cost: no cost volume to match on"
        for suite in SUITE_NAMES:
            write_skipped(METRICS, suite, run, reason, suite != "gradients", HEADLINE)
        return
    torch.set_num_threads(params.optimum.threads)
    index = read_eval_index(eval_index)
    frames = load_frames(index)
    _score_depth(params, run, depth_maps(_match_disparities(params, matcher, index), frames), frames, rois)


def write_cost_curves(params: Params, variant: str, eval_index: Path, rois: Path, out: Path) -> None:
    """The cost curves of every dense-GT ROI (``rois``) of the first ``optimum.cost_frames`` frames of
    ``eval_index``, per class, summarised (:func:`cost_summary`) into ``out``; ``optimum.threads``
    torch threads."""
    import torch

    from msdepth.data import kitti
    from msdepth.data.eval_index import read_eval_index
    from msdepth.io import write_json

    torch.set_num_threads(params.optimum.threads)
    curves = _roi_cost_curves(
        params,
        params.variant(variant),
        _first_frames(read_eval_index(eval_index), params.optimum.cost_frames),
        kitti.read_rois(rois),
    )
    write_json(out, cost_summary(curves))


def optimum_runs(params: Params, metrics_dir: Path) -> dict[str, str]:
    """``{label: run}`` of the optimum runs the optimum stages wrote below ``metrics_dir/full``, for
    every variant and weight of ``optimum.smoothness_sweep`` (label ``optimum <variant> w<weight>``).
    Found by value: dvc.yaml writes a weight as params.yaml spells it (``10`` or ``10.0``)."""
    from msdepth.errors import DataError

    out = {}
    for variant in params.variants:
        found, folder = {}, suite_dir("full", Path(metrics_dir)) / OPTIMUM / variant
        for path in folder.glob("w*.json"):
            try:
                found[float(path.stem[1:])] = path.stem[1:]
            except ValueError:
                continue
        for weight in params.optimum.smoothness_sweep:
            if weight not in found:
                raise DataError(f"{folder}: no optimum at weight {weight:g}")
            out[f"{OPTIMUM} {variant} w{weight:g}"] = optimum_run(variant, found[weight])
    return out


def matcher_runs(params: Params) -> dict[str, str]:
    """``{label: run}`` of the matchers' runs (:func:`score_match`): ``SGM (<variant> cost)`` per
    variant of ``variants`` (a skipped one included), then ``SGBM``."""
    runs = {f"SGM ({variant} cost)": match_run(variant) for variant in params.variants}
    return {**runs, "SGBM": match_run(SGBM)}
