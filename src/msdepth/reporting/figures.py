"""The dissertation's figures, drawn from the pipeline's outputs (one PNG each, by :func:`make_figures`).

- ``disparity.png`` (Figure 4.1): per evaluation frame, the input, the GT and each variant's
  disparity at GT size, one colour scale per row.
- ``roi_depth.png`` (Figures 4.2 / 4.3): per ROI class, its first ROI with >= 50 % valid GT (else
  the densest): the image with the box, the GT depth and each variant's depth, clamped as the
  evaluation does, with its abs rel on the ROI.
- ``roi_gradients.png`` (Figure 4.4): the same ROIs' |Sobel x| of GT and predicted depth, as the
  gradient suite computes them. Both ROI figures are left out without ROIs.
- ``training_curves.png``: total and appearance loss per epoch of every run.
- ``error_scatter.png``: per-image abs rel of each variant against the reference (two or more).

:func:`pipeline_figures` adds ``cost_curves.png`` (:func:`cost_curve_figure`) and ``verdict.png``
(:func:`verdict_figure`, compare.json's verdict table). Every number printed on a figure comes from
the evaluation code itself, so it equals the metrics files (:func:`roi_examples` returns them).
"""

from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import cv2
import matplotlib
import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import Colormap, LogNorm
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.ticker import MaxNLocator, NullFormatter

from msdepth.analysis.verdict import (
    KINDS,
    Column,
    Row,
    class_order,
    instrument_columns,
    rows_of,
    verdict_table,
)
from msdepth.config.params import EvalConfig, Params
from msdepth.data import kitti
from msdepth.data.eval_index import read_eval_index
from msdepth.errors import DataError
from msdepth.evaluation.suites import Frame, evaluate_roi, gradient_maps, load_frames, read_depth_maps
from msdepth.geometry.depth import clamp_depth, depth_to_disparity, pixel_disparity
from msdepth.io import atomic_path
from msdepth.pipeline.paths import (
    COMPARE_JSON,
    COST_CURVES,
    EVAL_FRAMES,
    METRICS,
    OUTPUTS,
    ROIS,
    TRAIN_PLOTS,
    cost_curves_path,
    depth_path,
    disparities_path,
    suite_path,
    train_plots_dir,
    variant_runs,
)
from msdepth.readers import read_json_file, read_json_object, read_npy_file, read_table_file
from msdepth.reporting.verdict import VERDICT_FIGURE

log = logging.getLogger("msdepth")

DPI = 120
REFERENCE = "ssim"
MIN_VALID_FRACTION = 0.5  # an example ROI needs at least this much valid GT to be worth showing
LOSS_TERMS = ("total", "appearance")
SEED_STYLES = ("-", "--", ":", "-.")  # training_curves.png: a variant's seeds, in order
FIGURES = ("disparity.png", "roi_depth.png", "roi_gradients.png", "training_curves.png", "error_scatter.png")
ROI_FIGURES = ("roi_depth.png", "roi_gradients.png")  # drawn only where there are ROIs
COST_CURVES_FIGURE = "cost_curves.png"  # drawn by cost_curve_figure
# Everything the figures stage writes to plots/figures.
STAGE_FIGURES = (*FIGURES, COST_CURVES_FIGURE, VERDICT_FIGURE)


@dataclass
class RoiExample:
    """One example ROI and everything drawn for it; the scalars are the numbers printed."""

    roi: int  # row number in rois.csv (the ``roi`` column of the ROI and gradient suites)
    image: str
    cls: str
    box: tuple[int, int, int, int]  # x0, y0, x1, y1 (exclusive)
    gt_valid_fraction: float
    abs_rel: dict[str, float]  # per variant, cap caps[0], = metrics/roi/<variant>.csv
    pred_sobel_x: dict[str, float]  # per variant, mean over the box, = pred_sobel_x of the gradient suite
    gt_sobel_x: float  # mean over GT pixels with a valid 3x3 neighbourhood (NaN if none)
    gt_depth: np.ndarray = field(repr=False)  # ROI crop, NaN where GT is invalid
    pred_depth: dict[str, np.ndarray] = field(repr=False)  # ROI crops, clamped
    gt_grad: np.ndarray = field(repr=False)  # |Sobel x| crop, NaN outside the valid neighbourhood
    pred_grad: dict[str, np.ndarray] = field(repr=False)


@dataclass
class _Inputs:
    """Everything the figures read, loaded (and checked) before anything is drawn."""

    variants: list[str]  # labels
    runs: dict[str, str]  # label -> run path below outputs/, metrics/<suite>/, plots/train/
    index: pd.DataFrame
    rois: pd.DataFrame
    disparities: dict[str, np.ndarray]
    depth: dict[str, dict[str, np.ndarray]]
    cfg: EvalConfig
    _frames: dict[str, Frame] = field(default_factory=dict)

    def frame(self, name: str) -> Frame:
        """GT of one frame, read on first use (the figures need only a few of them)."""
        if name not in self._frames:
            rows = self.index[self.index["frame"] == name]
            if rows.empty:
                raise DataError(f"frame {name!r} is not in the evaluation index")
            frame = load_frames(rows)[0]
            # Index paths are relative to the project root: run from elsewhere they could name
            # another project's files of another size, and every number would be silently wrong.
            for v in self.variants:
                if self.depth[v][name].shape != frame.shape:
                    raise DataError(
                        f"{rows['gt'].iloc[0]}: GT of frame {name} is {frame.shape} "
                        "but the depth map of "
                        f"{v!r} is {self.depth[v][name].shape} (index paths are relative to the project root)"
                    )
            self._frames[name] = frame
        return self._frames[name]

    def left_image(self, name: str) -> np.ndarray:
        return kitti.read_image(self.index.loc[self.index["frame"] == name, "left"].iloc[0])


def _runs(variants: Sequence[str] | Mapping[str, str]) -> dict[str, str]:
    return dict(variants) if isinstance(variants, Mapping) else {v: v for v in variants}


def _load(
    variants: Sequence[str] | Mapping[str, str], eval_index: Path, rois: Path, outputs: Path, cfg: EvalConfig
) -> _Inputs:
    runs = _runs(variants)
    if not runs:
        raise ValueError("make_figures needs at least one variant")
    index = read_eval_index(eval_index)
    boxes = kitti.read_rois(rois)
    disparities, depth = {}, {}
    for v, run in runs.items():
        path = disparities_path(run, Path(outputs))
        if not path.exists():
            raise DataError(f"{path}: no disparities for run {run!r} (run the infer stage)")
        disp = read_npy_file(path, "disparities")
        if disp.ndim != 3 or len(disp) != len(index):
            raise DataError(
                f"{path}: expected ({len(index)}, h, w) disparities for {eval_index}, got {disp.shape}"
            )
        disparities[v] = disp
        npz = depth_path(run, Path(outputs))
        depth[v] = read_depth_maps(npz)
        missing = sorted(set(index["frame"]) - set(depth[v]))
        if missing:
            raise DataError(f"{npz}: no depth for evaluation frame(s) {missing[:5]}")
    return _Inputs(list(runs), runs, index, boxes, disparities, depth, cfg)


def _cmap(name: str) -> Colormap:
    # A copy with masked (invalid) pixels in grey; the registered map is left alone.
    return matplotlib.colormaps[name].with_extremes(bad="0.75")


def _new_figure(width: float, height: float) -> Figure:
    # A bare Figure on the Agg canvas: no pyplot, so no GUI backend and no global figure registry
    # that would keep every figure alive until closed.
    fig = Figure(figsize=(width, height), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def write_figure(path: str | os.PathLike, fig: Any, **savefig_kwargs: Any) -> None:
    """Save a matplotlib figure (anything with ``savefig``) to ``path`` atomically
    (:func:`msdepth.io.atomic_path`), for every figure the project writes; the format follows
    ``path``'s suffix unless ``savefig_kwargs`` names one."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **savefig_kwargs)


def _save(fig: Figure, path: Path) -> Path:
    # No "Software: matplotlib <version>" text chunk: the file then depends on the drawing only.
    write_figure(path, fig, dpi=DPI, format="png", metadata={"Software": None})
    fig.clear()  # drop the artists (and their image arrays) now rather than at garbage collection
    return path


def _colorbar(fig: Figure, im, axes, label: str, **kwargs: Any) -> None:
    cb = fig.colorbar(im, ax=list(axes), fraction=0.05, pad=0.01, **kwargs)
    cb.set_label(label, fontsize=8)
    cb.ax.tick_params(labelsize=7)


def _message_figure(text: str, width: float, height: float, path: Path) -> Path:
    """A figure of one line of text, where there is nothing to draw."""
    fig = _new_figure(width, height)
    ax = fig.add_subplot(1, 1, 1)
    ax.text(0.5, 0.5, text, ha="center", va="center")
    _off(ax)
    return _save(fig, path)


def _off(ax) -> None:
    ax.set_xticks([])
    ax.set_yticks([])


# ---------------------------------------------------------------------------------------------
# Figure 4.1: disparity maps


# The exact-mask classes outlined on every panel of disparity.png, with their outline colours:
# whether a network finds the cars and windshields shows against these at a glance.
OUTLINED = (("car", "cyan"), ("windshield", "lime"))


def _gt_disparity(frame: Frame) -> np.ma.MaskedArray:
    """The frame's GT as disparity in pixels, masked where it has none."""
    disp = depth_to_disparity(frame.gt_depth, frame.focal, frame.baseline)
    return np.ma.masked_where(frame.gt_depth <= 0, disp)


def _outline_classes(ax, frame: Frame) -> None:
    """Outline the :data:`OUTLINED` classes' exact pixels (a frame with a class map only)."""
    if frame.class_map is None:
        return
    for cls, colour in OUTLINED:
        mask = (frame.class_map & kitti.CLASS_BITS[cls]) > 0
        if mask.any():
            ax.contour(mask.astype(np.float32), levels=[0.5], colors=colour, linewidths=0.6)


def _disparity_figure(inp: _Inputs, frames: int, path: Path) -> Path:
    n = min(frames, len(inp.index))
    names = list(inp.index["frame"][:n])
    h, w = inp.frame(names[0]).shape
    cols = 2 + len(inp.variants)
    panel_w = 3.2
    fig = _new_figure(panel_w * cols + 1.0, n * (panel_w * h / w + 0.45) + 0.5)
    axes = fig.subplots(n, cols, squeeze=False)
    cmap = _cmap("plasma")
    for r, name in enumerate(names):
        frame = inp.frame(name)
        fh, fw = frame.shape
        i = int(np.flatnonzero(inp.index["frame"].to_numpy() == name)[0])
        panels = {"GT": _gt_disparity(frame)}
        panels.update({v: pixel_disparity(inp.disparities[v][i], fh, fw) for v in inp.variants})
        # One scale per row (the predictions' 1st-99th percentile) so that GT and the variants are
        # compared colour for colour, and a few extreme pixels do not wash out the rest.
        lo, hi = np.percentile(np.concatenate([panels[v].ravel() for v in inp.variants]), [1, 99])
        axes[r, 0].imshow(inp.left_image(name))
        axes[r, 0].set_title(f"input {name}", fontsize=9)
        for c, (label, disp) in enumerate(panels.items(), start=1):
            im = axes[r, c].imshow(disp, cmap=cmap, vmin=lo, vmax=hi)
            axes[r, c].set_title(label, fontsize=9)
        for ax in axes[r]:
            _outline_classes(ax, frame)
            _off(ax)
        _colorbar(fig, im, axes[r, 1:], "disparity (px)")
    outlines = ", ".join(f"{cls}s {colour}" for cls, colour in OUTLINED)
    fig.suptitle(
        f"Predicted disparity at ground-truth resolution, beside the GT (grey: none); outlined: {outlines}",
        fontsize=11,
    )
    return _save(fig, path)


# ---------------------------------------------------------------------------------------------
# Figures 4.2-4.4: ROIs


def _select_rois(inp: _Inputs) -> list[tuple[int, dict]]:
    """The first ROI of each class (in ``kitti.ROI_CLASSES`` order) with enough valid GT.

    If no ROI at all has :data:`MIN_VALID_FRACTION` valid GT (sparse GT, e.g. a single LiDAR
    scan, covers a few per cent of a box), each class's ROI with the most valid GT is shown.
    """
    cap = inp.cfg.caps[0]
    chosen: dict[str, tuple[int, dict]] = {}
    densest: dict[str, tuple[float, int, dict]] = {}
    for i, roi in enumerate(inp.rois.to_dict("records")):
        if roi["class"] in chosen:
            continue
        frame = inp.frame(roi["image"])
        box = (slice(roi["y0"], roi["y1"]), slice(roi["x0"], roi["x1"]))
        valid = frame.valid[box]
        if valid.size == 0:
            continue
        # With GT masked beyond the cap the suite may have no pixel left to score: skip such ROIs.
        if inp.cfg.mask_gt_beyond_cap and not (valid & (frame.gt_depth[box] <= cap)).any():
            continue
        if valid.any() and valid.mean() > densest.get(roi["class"], (0.0,))[0]:
            densest[roi["class"]] = (float(valid.mean()), i, roi)
        if valid.mean() >= MIN_VALID_FRACTION:
            chosen[roi["class"]] = (i, roi)
    if not chosen:
        chosen = {c: (i, roi) for c, (_, i, roi) in densest.items()}
    return [chosen[c] for c in kitti.ROI_CLASSES if c in chosen]


def _roi_examples(inp: _Inputs) -> list[RoiExample]:
    cap = inp.cfg.caps[0]
    one_cap = dataclasses.replace(inp.cfg, caps=(cap,))
    selected = _select_rois(inp)
    if not selected:
        raise DataError("no ROI has valid ground truth for the ROI figures")
    kernel = np.ones((3, 3), np.uint8)
    out = []
    for i, roi in selected:
        frame = inp.frame(roi["image"])
        box = (slice(roi["y0"], roi["y1"]), slice(roi["x0"], roi["x1"]))
        valid = frame.valid
        abs_rel, pred_depth, pred_grad, pred_sx = {}, {}, {}, {}
        for v in inp.variants:
            pred = inp.depth[v][frame.name]
            # The ROI suite itself on this one box: the printed abs rel is the CSV's number.
            _, table = evaluate_roi({frame.name: pred}, [frame], inp.rois.iloc[[i]], one_cap)
            abs_rel[v] = float(table["abs_rel"].iloc[0])
            clamped = clamp_depth(pred, inp.cfg.min_depth, cap)
            pred_depth[v] = clamped[box]
            # As the gradient suite: derivatives of the whole capped map, then cropped.
            pred_grad[v] = gradient_maps(clamped)["sobel_x"][box]
            pred_sx[v] = float(pred_grad[v].mean())
        # GT derivatives as the gradient suite takes them: capped GT, 0 where invalid, and only
        # pixels whose 3x3 neighbourhood is valid (elsewhere the kernel straddles a hole).
        gt_capped = np.where(valid, np.minimum(frame.gt_depth, cap), 0.0)
        inner = cv2.erode(valid.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
        gt_grad = np.where(inner, gradient_maps(gt_capped)["sobel_x"], np.nan)[box]
        sel = inner[box]
        out.append(
            RoiExample(
                roi=i,
                image=frame.name,
                cls=roi["class"],
                box=(roi["x0"], roi["y0"], roi["x1"], roi["y1"]),
                gt_valid_fraction=float(valid[box].mean()),
                abs_rel=abs_rel,
                pred_sobel_x=pred_sx,
                gt_sobel_x=float(gt_grad[sel].mean()) if sel.any() else float("nan"),
                gt_depth=np.where(valid[box], frame.gt_depth[box], np.nan),
                pred_depth=pred_depth,
                gt_grad=gt_grad,
                pred_grad=pred_grad,
            )
        )
    return out


def roi_examples(
    variants: list[str],
    *,
    eval_index: Path = EVAL_FRAMES,
    rois: Path = ROIS,
    outputs: Path = OUTPUTS,
    eval_cfg: EvalConfig,
) -> list[RoiExample]:
    """The ROIs shown in ``roi_depth.png`` / ``roi_gradients.png`` and the numbers printed on them."""
    return _roi_examples(_load(variants, eval_index, rois, outputs, eval_cfg))


def _roi_grid(inp: _Inputs, examples: list[RoiExample], first_col_ratio: float):
    """One row per ROI; rows as tall as their widest-to-tallest panel needs (no empty bands)."""
    cols = 2 + len(inp.variants)
    unit = 2.0  # inches per width-ratio unit
    img_h, img_w = inp.frame(examples[0].image).shape
    heights = []
    for ex in examples:
        x0, y0, x1, y1 = ex.box
        # Very tall or very flat boxes are limited so that one ROI cannot squash the others.
        roi_aspect = min(max((y1 - y0) / (x1 - x0), 0.3), 1.3)
        heights.append(unit * max(first_col_ratio * img_h / img_w, roi_aspect) + 0.55)  # + two title lines
    fig = _new_figure(unit * (first_col_ratio + cols - 1) + 1.0, sum(heights) + 0.4)
    axes = fig.subplots(
        len(examples),
        cols,
        squeeze=False,
        gridspec_kw={"width_ratios": [first_col_ratio] + [1.0] * (cols - 1), "height_ratios": heights},
    )
    return fig, axes


def _roi_title(ex: RoiExample) -> str:
    x0, y0, x1, y1 = ex.box
    return f"{ex.cls}: {ex.image}, ROI {ex.roi}\n{x1 - x0}x{y1 - y0} px, GT {ex.gt_valid_fraction:.0%} valid"


def _roi_depth_figure(inp: _Inputs, examples: list[RoiExample], path: Path) -> Path:
    cap = inp.cfg.caps[0]
    fig, axes = _roi_grid(inp, examples, 1.6)
    cmap = _cmap("viridis_r")  # near = bright
    for r, ex in enumerate(examples):
        ax = axes[r, 0]
        ax.imshow(inp.left_image(ex.image))
        x0, y0, x1, y1 = ex.box
        ax.add_patch(
            Rectangle((x0 - 0.5, y0 - 0.5), x1 - x0, y1 - y0, fill=False, edgecolor="cyan", linewidth=1.5)
        )
        ax.set_title(_roi_title(ex), fontsize=8)
        _off(ax)
        values = np.concatenate(
            [ex.gt_depth[np.isfinite(ex.gt_depth)]] + [d.ravel() for d in ex.pred_depth.values()]
        )
        lo, hi = float(values.min()), float(values.max())
        im = axes[r, 1].imshow(
            np.ma.masked_invalid(ex.gt_depth), cmap=cmap, vmin=lo, vmax=hi, interpolation="nearest"
        )
        axes[r, 1].set_title("GT depth\n(grey: no GT)", fontsize=8)
        _off(axes[r, 1])
        for c, v in enumerate(inp.variants, start=2):
            axes[r, c].imshow(ex.pred_depth[v], cmap=cmap, vmin=lo, vmax=hi, interpolation="nearest")
            axes[r, c].set_title(f"{v}\nabs rel {ex.abs_rel[v]:.3f}", fontsize=8)
            _off(axes[r, c])
        _colorbar(fig, im, axes[r, 1:], "depth (m)")
    fig.suptitle(
        f"Depth in example ROIs (predictions clamped to [{inp.cfg.min_depth:g}, {cap:g}] m)", fontsize=11
    )
    return _save(fig, path)


def _roi_gradient_figure(inp: _Inputs, examples: list[RoiExample], path: Path) -> Path:
    fig, axes = _roi_grid(inp, examples, 1.0)
    cmap = _cmap("inferno")
    for r, ex in enumerate(examples):
        x0, y0, x1, y1 = ex.box
        ax = axes[r, 0]
        ax.imshow(inp.left_image(ex.image)[y0:y1, x0:x1], interpolation="nearest")
        ax.set_title(f"{ex.cls}: {ex.image}\nROI {ex.roi}", fontsize=8)
        _off(ax)
        values = np.concatenate(
            [ex.gt_grad[np.isfinite(ex.gt_grad)]] + [g.ravel() for g in ex.pred_grad.values()]
        )
        # Depth edges give derivatives orders of magnitude above smooth surfaces: a log scale
        # shows both (values below its floor, including exact zeros, take the floor's colour).
        hi = max(float(values.max()), 1e-3)
        norm = LogNorm(vmin=hi * 1e-3, vmax=hi)
        floor = norm.vmin
        im = axes[r, 1].imshow(
            np.ma.masked_invalid(np.maximum(ex.gt_grad, floor)), cmap=cmap, norm=norm, interpolation="nearest"
        )
        gt_mean = "n/a" if np.isnan(ex.gt_sobel_x) else f"{ex.gt_sobel_x:.3g}"
        axes[r, 1].set_title(f"GT |Sobel x|\nmean {gt_mean} (valid px)", fontsize=8)
        _off(axes[r, 1])
        for c, v in enumerate(inp.variants, start=2):
            axes[r, c].imshow(
                np.maximum(ex.pred_grad[v], floor), cmap=cmap, norm=norm, interpolation="nearest"
            )
            axes[r, c].set_title(f"{v} |Sobel x|\nmean {ex.pred_sobel_x[v]:.3g}", fontsize=8)
            _off(axes[r, c])
        _colorbar(fig, im, axes[r, 1:], "m/px (log)", extend="min")
    fig.suptitle(
        f"Horizontal depth derivative in example ROIs (depth capped at {inp.cfg.caps[0]:g} m)", fontsize=11
    )
    return _save(fig, path)


# ---------------------------------------------------------------------------------------------
# Training curves and per-image errors


def _read_curve(path: Path, name: str) -> pd.DataFrame:
    if not path.exists():
        raise DataError(f"{path}: no training curve {name!r} (run the train stage)")
    df = read_table_file(path, "dvclive TSV", sep="\t")
    if not {"step", name} <= set(df.columns) or df.empty:
        raise DataError(
            f"{path}: expected columns 'step' and {name!r} with at least one row, got {list(df.columns)}"
        )
    return df


def _curve_path(train_plots: Path, run: str, term: str) -> Path:
    # dvclive's layout below a run's folder (msdepth.training.train logs the losses as train/<term>)
    return train_plots_dir(run, Path(train_plots)) / "plots" / "metrics" / "train" / f"{term}.tsv"


def _training_figure(runs: dict[str, list[str]], train_plots: Path, path: Path) -> Path:
    """Per variant (a colour), one line per run, each seed labelled and drawn in its own style."""
    curves = {
        (run, term): _read_curve(_curve_path(train_plots, run, term), term)
        for group in runs.values()
        for run in group
        for term in LOSS_TERMS
    }
    fig = _new_figure(4.2 * len(LOSS_TERMS), 3.4)
    axes = fig.subplots(1, len(LOSS_TERMS), squeeze=False)[0]
    for ax, term in zip(axes, LOSS_TERMS, strict=True):
        for colour, group in enumerate(runs.values()):
            for i, run in enumerate(group):
                df = curves[run, term]
                # dvclive steps once per epoch, from 0: step k holds the mean loss of epoch k + 1.
                ax.plot(
                    df["step"] + 1,
                    df[term],
                    color=f"C{colour}",
                    linestyle=SEED_STYLES[i % len(SEED_STYLES)],
                    marker="o",
                    markersize=2.5,
                    linewidth=1.2,
                    label=run.replace("/", ", "),  # "ssim, seed0"
                )
        ax.set_title(f"{term} loss", fontsize=10)
        ax.set_xlabel("epoch")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylabel("mean training loss")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("Training losses per epoch (each variant's own appearance term)", fontsize=11)
    return _save(fig, path)


def _read_full(metrics: Path, variant: str, cap: float) -> pd.DataFrame:
    path = suite_path("full", variant, ".csv", Path(metrics))
    if not path.exists():
        raise DataError(f"{path}: no per-image metrics of run {variant!r} (run the eval_full stage)")
    df = read_table_file(path, "per-image metrics", dtype={"frame": str})
    if not {"frame", "cap", "abs_rel"} <= set(df.columns):
        raise DataError(f"{path}: expected columns frame, cap, abs_rel; got {list(df.columns)}")
    df = df[np.isclose(df["cap"], cap)]
    if df.empty:
        raise DataError(f"{path}: no rows for cap {cap:g}")
    return df.set_index("frame")["abs_rel"]


def _scatter_figure(runs: dict[str, str], metrics: Path, cap: float, path: Path) -> Path:
    variants = list(runs)
    ref = REFERENCE if REFERENCE in variants else variants[0]
    others = [v for v in variants if v != ref]
    errors = {v: _read_full(metrics, runs[v], cap) for v in [ref, *others]}
    fig = _new_figure(5.0, 5.0 + 0.2 * len(others))
    ax = fig.subplots()
    lines, all_values = [], [errors[ref].to_numpy()]
    for v, marker in zip(others, "osD^v<>", strict=False):
        x, y = errors[ref].align(errors[v], join="inner")
        all_values.append(y.to_numpy())
        ax.scatter(x, y, s=18, marker=marker, alpha=0.75, label=runs[v].replace("/", ", "))
        lines.append(f"{runs[v]}: {int((y < x).sum())} of {len(x)} images below y = x")
    lo = 0.0
    hi = float(max(a.max() for a in all_values)) * 1.05
    ax.plot([lo, hi], [lo, hi], color="0.4", linestyle="--", linewidth=1, label="y = x")
    ax.set_xlim(lo, hi)
    ax.set_ylim(lo, hi)
    ax.set_aspect("equal")
    ax.set_xlabel(f"abs rel, {runs[ref]} (cap {cap:g} m)")
    ax.set_ylabel(f"abs rel, {runs[others[0]] if len(others) == 1 else 'other variants'} (cap {cap:g} m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    ax.set_title(
        "Per-image abs rel\n" + "\n".join(lines) + f"\n(below: lower error than {runs[ref]})", fontsize=9
    )
    return _save(fig, path)


# ---------------------------------------------------------------------------------------------


def make_figures(
    variants: Sequence[str] | Mapping[str, str],
    out_dir: Path,
    *,
    eval_cfg: EvalConfig,
    frames: int = 3,
    eval_index: Path = EVAL_FRAMES,
    rois: Path = ROIS,
    outputs: Path = OUTPUTS,
    metrics: Path = METRICS,
    train_plots: Path = TRAIN_PLOTS,
    curves: Mapping[str, Sequence[str]] | None = None,
) -> list[Path]:
    """Write the figures listed in the module docstring to ``out_dir``; returns their paths.

    Every input is read before the first figure is drawn (a DataError names a missing or malformed
    file), so a missing file leaves no figure half-made.

    Args:
        variants: the runs to draw, as names or as ``{label: run}`` (e.g. ``{"ssim": "ssim/seed0"}``).
        out_dir: the folder the PNGs go to.
        eval_cfg: the evaluation's caps and depth range.
        frames: the evaluation frames (rows) of ``disparity.png``.
        eval_index, rois, outputs, metrics, train_plots: where the inputs are (the pipeline's paths).
        curves: the runs whose training curves to draw per label; None: each label's own run.

    Returns:
        The paths of the figures written, in the order drawn.
    """
    out_dir = Path(out_dir)
    cap = eval_cfg.caps[0]
    inp = _load(variants, eval_index, rois, outputs, eval_cfg)
    examples = _roi_examples(inp) if not inp.rois.empty else []  # no ROIs: no ROI figures
    # Read the remaining inputs up front too (cheap): a missing TSV or CSV fails before drawing.
    curve_runs = {v: list(curves[v]) if curves and v in curves else [run] for v, run in inp.runs.items()}
    for v, run in inp.runs.items():
        for curve_run in curve_runs[v]:
            for term in LOSS_TERMS:
                _read_curve(_curve_path(train_plots, curve_run, term), term)
        _read_full(metrics, run, cap)
    written = [_disparity_figure(inp, frames, out_dir / "disparity.png")]
    if not inp.rois.empty:
        written += [
            _roi_depth_figure(inp, examples, out_dir / "roi_depth.png"),
            _roi_gradient_figure(inp, examples, out_dir / "roi_gradients.png"),
        ]
    written.append(_training_figure(curve_runs, train_plots, out_dir / "training_curves.png"))
    if len(inp.variants) > 1:
        written.append(_scatter_figure(inp.runs, metrics, cap, out_dir / "error_scatter.png"))
    return written


def _read_cost_curves(directory: Path, variants: Sequence[str]) -> dict[str, dict]:
    """``{variant: its cost_curves stage summary}`` from ``directory/<variant>.json``; a DataError
    names a missing or unreadable file."""
    out = {}
    for v in variants:
        path = cost_curves_path(v, Path(directory))
        try:
            out[v] = read_json_file(path, "cost curves")
        except DataError as exc:
            why = str(exc).removeprefix(f"{path}: ")
            raise DataError(f"{path}: cannot read the cost curves of {v!r} ({why})") from None
    return out


def cost_curve_figure(summaries: Mapping[str, dict], path: Path) -> Path:
    """``cost_curves.png``: one panel per ROI class, one line per variant (its mean cost over the
    class's boxes against s, log axis, minus its own minimum: the two losses' costs differ in scale,
    and the curves' shapes are what is compared), s = 1 (the GT) marked, each variant's minimum dotted."""
    classes = class_order(sorted({c for s in summaries.values() for c in s.get("mean_curves", {})}))
    if not classes:
        return _message_figure("no ROI with dense GT", 3.2, 3.0, path)
    fig = _new_figure(3.2 * len(classes), 3.0)
    axes = fig.subplots(1, len(classes), squeeze=False)[0]
    for ax, cls in zip(axes, classes, strict=True):
        for variant, summary in summaries.items():
            if cls not in summary.get("mean_curves", {}):
                continue
            curve = np.asarray(summary["mean_curves"][cls], float)
            (line,) = ax.plot(summary["scales"], curve - curve.min(), label=variant)
            s_min = summary["classes"][cls]["s_min"]
            ax.axvline(s_min, color=line.get_color(), linestyle=":", label=f"{variant}'s minimum")
        ax.axvline(1.0, color="k", linewidth=0.8, label="GT (s = 1)")
        rois = max(s["classes"][cls]["rois"] for s in summaries.values() if cls in s.get("classes", {}))
        ax.set(xscale="log", title=f"{cls} ({rois} ROIs)", xlabel="s (box disparity = GT × s)")
        ax.set_xticks([0.5, 1.0, 2.0], ["0.5", "1", "2"])
        ax.xaxis.set_minor_formatter(NullFormatter())  # the log axis's own labels overlap these
    axes[0].set_ylabel("mean appearance cost − its minimum")
    axes[0].legend(fontsize="small")
    return _save(fig, path)


def _verdict_panel(ax, column: Column, cells: Sequence[tuple[str, Row]], reach: float) -> None:
    """One instrument: a dot and a horizontal bar per surface class it has a row on (filled where
    the interval excludes 0; a cross without a bar where the row has too few units for an
    interval), a line at 0, the x-scale ``±reach`` of its kind, each row's n right of the frame."""
    color = KINDS.get(column.kind, ("", "grey"))[1]
    for y, (_, r) in enumerate(cells):
        if r.has_interval:
            ax.errorbar(
                r.diff, y, xerr=[[r.diff - r.low], [r.high - r.diff]], fmt="o",
                color=color, mfc=color if r.excludes_zero else "white", capsize=3, markersize=5,
            )  # fmt: skip
        else:
            ax.plot(r.diff, y, "x", color=color, markersize=6)
        frames = f", {r.unit.split(' in ', 1)[1]}" if " in " in r.unit else ""  # ROIs in K frames
        ax.annotate(
            f"n={r.n}{frames}",
            (1.01, y),
            xycoords=("axes fraction", "data"),
            ha="left",
            va="center",
            fontsize=7,
        )
    ax.axvline(0.0, color="k", linewidth=0.8)
    lower = sum(r.diff < 0 for _, r in cells)
    ax.set_title(f"{column.header}: lower on {lower} of {len(cells)}", fontsize=8, loc="left")
    ax.set_yticks(range(len(cells)), [cls for cls, _ in cells], fontsize=7)
    ax.set_ylim(len(cells) - 0.5, -0.5)  # the first class on top
    ax.grid(axis="x", alpha=0.3)
    ax.tick_params(axis="x", labelsize=7)
    ax.set_xlim(-reach, reach)  # 0 in the middle: left of it the variant is better, right the reference


def _verdict_legend(fig: Figure, rows: list[Row], confidence: float) -> None:
    """The legend below the panels."""
    from matplotlib.lines import Line2D

    handles = [
        Line2D([], [], marker="o", color=color, linestyle="", label=text)
        for kind, (text, color) in KINDS.items()
        if any(r.kind == kind for r in rows)
    ]
    handles.append(
        Line2D([], [], marker="o", color="grey", mfc="white", linestyle="", label="hollow: includes 0")
    )
    if any(not r.has_interval for r in rows):
        handles.append(
            Line2D([], [], marker="x", color="grey", linestyle="", label="too few units: no interval")
        )
    title = f"{confidence * 100:g} % intervals; n: units (ROIs: and their frames)"
    fig.legend(
        handles=handles, loc="outside lower center", ncols=2, fontsize=7, frameon=False, title=title,
        title_fontsize=8,
    )  # fmt: skip


def _reach(rows: Sequence[Row]) -> float:
    """Half the x-range that holds every row's interval (or point), with a margin."""
    ends = [abs(v) for r in rows for v in ((r.low, r.high) if r.has_interval else (r.diff,))]
    return max([*ends, 1e-3]) * 1.15


def verdict_figure(verdict: Mapping | None, path: Path) -> Path:
    """``verdict.png``: the verdict table with one column per instrument
    (:func:`~msdepth.analysis.verdict.instrument_columns`), a panel each, a row per surface class
    it measured: its difference and interval on one x-scale per kind, its n right of the frame."""
    rows = rows_of(verdict) if verdict else []
    if not rows:
        return _message_figure("no instrument compares two variants", 4.0, 1.5, path)
    columns = instrument_columns(rows)
    table = verdict_table(rows, columns, verdict["classes"])
    panels = [[(cls, cells[i]) for cls, cells in table if cells[i] is not None] for i in range(len(columns))]
    reach = {kind: _reach([r for r in rows if r.kind == kind]) for kind in {c.kind for c in columns}}
    heights = [len(p) + 1.2 for p in panels]
    fig = _new_figure(7.0, 0.22 * sum(heights) + 1.4)
    axes = fig.subplots(len(columns), 1, squeeze=False, gridspec_kw={"height_ratios": heights}).ravel()
    for ax, column, cells in zip(axes, columns, panels, strict=True):
        _verdict_panel(ax, column, cells, reach[column.kind])
    better, than = verdict["variant"], verdict["reference"]
    fig.suptitle(f"{better} − {than} abs_rel (negative: {better}'s error lower)", fontsize=9)
    _verdict_legend(fig, rows, verdict["confidence"])
    return _save(fig, path)


def pipeline_figures(
    params: Params, out_dir: Path, cost_curves: Path = COST_CURVES, compare_json: Path = COMPARE_JSON
) -> list[Path]:
    """The figures stage's figures in ``out_dir``: :func:`make_figures` of each variant's first seed
    (every seed's training curves), :func:`cost_curve_figure` and :func:`verdict_figure`."""
    groups = variant_runs(params)
    paths = make_figures(
        {v: runs[0] for v, runs in groups.items()}, Path(out_dir), eval_cfg=params.eval, curves=groups
    )
    summaries = _read_cost_curves(cost_curves, params.variants)
    paths.append(cost_curve_figure(summaries, Path(out_dir) / COST_CURVES_FIGURE))
    comparison = read_json_object(compare_json, "comparison", "run the compare stage first")
    paths.append(verdict_figure(comparison.get("verdict"), Path(out_dir) / VERDICT_FIGURE))
    log.info("figures: %s", ", ".join(p.name for p in paths))
    return paths
