"""How a stereo pair looks to a photometric loss: statistics that tell rendered pairs from real ones.

A photometric loss compares the left view with the right one warped by a disparity. How hard that
comparison is depends on the camera more than on the scene: real views differ in gain and white
balance, vignetting, sensor noise drawn per view, blur and rectification error. Each pair is
measured at one width (``width``: the render width by default, so a KITTI pair is measured at the
scale of the synthetic set, which is KITTI at a third of its size) on its grey level
(ITU-R BT.601 luma, 0-255):

- ``residual_mean`` / ``residual_median``: |left - right warped by the GT disparity| over the GT
  pixels whose match lies inside the right view (the loss's L1 term at the true disparity);
- ``brightness_gap``: |mean grey of the left view - mean grey of the right view|;
- ``grey_mean`` and ``grey_spread``: the left view's mean grey level and its standard deviation;
- ``noise_sigma``: Immerkaer's (1996) estimator, sqrt(pi/2) / (6 (W-2)(H-2)) sum |I * N|, on the
  left view;
- ``gradient_energy``: the mean |Laplacian| of the left view (4-neighbour kernel);
- ``ssim_gt``: the mean per-pixel SSIM (3 x 3, :func:`msdepth.losses.ssim.ssim`) between the left
  view and the right one warped by the GT disparity, over the same pixels as the residual.

The warp is the training loss's own (:func:`msdepth.geometry.warp.warp`), the SSIM its own.
"""

from __future__ import annotations

import os
from dataclasses import astuple, dataclass, fields
from math import pi, sqrt
from pathlib import Path
from typing import Any, Iterable

import cv2
import numpy as np
import pandas as pd
import torch

from msdepth.data import kitti, kitti2012
from msdepth.data.ground_truth import read_gt_depth
from msdepth.data.pairs import check_same_size
from msdepth.errors import DataError
from msdepth.geometry.warp import warp
from msdepth.losses.ssim import ssim
from msdepth.readers import read_table_file

_LUMA = np.array([0.299, 0.587, 0.114], np.float32)  # ITU-R BT.601
_IMMERKAER = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
# A resized GT pixel keeps its value only where most of the pixels it averages had one ...
_MIN_VALID_FRACTION = 0.5
# ... unless the GT is a scan of points (a projected LiDAR sweep covers ~5 % of a KITTI image, the
# densest KITTI 2012/2015 disparity maps 19-36 %): then one valid pixel is enough.
_POINTS_DENSITY = 0.1


@dataclass(frozen=True)
class PairStats:
    """The photometric statistics of one stereo pair (module docstring)."""

    residual_mean: float
    residual_median: float
    brightness_gap: float
    grey_mean: float
    grey_spread: float
    noise_sigma: float
    gradient_energy: float
    ssim_gt: float


STATS: tuple[str, ...] = tuple(f.name for f in fields(PairStats))


def grey(rgb: np.ndarray) -> np.ndarray:
    """The BT.601 luma (float32, 0-255) of a uint8 or float RGB (H, W, 3) image in 0-255."""
    return np.asarray(rgb, np.float32) @ _LUMA


def resize_pair(
    left: np.ndarray, right: np.ndarray, disp: np.ndarray, width: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pair and its GT disparity (px, 0 = none) at ``width`` px wide, the aspect kept.

    Images are area-averaged (what a smaller sensor of the same optics would record). The sparse GT
    is averaged over its valid pixels only and kept where at least half of them were valid (where
    any was, for GT covering under 10 % of the image: a LiDAR scan); its values scale with the width.
    """
    h, w = disp.shape
    if w == width:
        return left, right, disp
    size = (width, max(1, round(h * width / w)))
    valid = (disp > 0).astype(np.float32)
    total = cv2.resize(disp * valid, size, interpolation=cv2.INTER_AREA)
    count = cv2.resize(valid, size, interpolation=cv2.INTER_AREA)
    least = _MIN_VALID_FRACTION if valid.mean() >= _POINTS_DENSITY else 1e-6
    with np.errstate(invalid="ignore", divide="ignore"):
        small = np.where(count >= least, total / count, 0.0) * (width / w)
    shrink = [cv2.resize(v, size, interpolation=cv2.INTER_AREA) for v in (left, right)]
    return shrink[0], shrink[1], small.astype(np.float32)


def immerkaer_sigma(image: np.ndarray) -> float:
    """Immerkaer's (1996) noise standard deviation of a grey image (same units as the image)."""
    h, w = image.shape
    response = cv2.filter2D(image.astype(np.float32), -1, _IMMERKAER)[1:-1, 1:-1]
    return float(sqrt(pi / 2) * np.abs(response).sum() / (6.0 * (w - 2) * (h - 2)))


def _warped_right(left: np.ndarray, right: np.ndarray, disp: np.ndarray) -> tuple[torch.Tensor, ...]:
    """Left and right-warped-by-``disp`` as (1, 3, H, W) tensors in [0, 1], and the mask of GT
    pixels whose match ``x - d`` lies inside the right view."""
    h, w = disp.shape
    as_tensor = lambda a: torch.from_numpy(np.ascontiguousarray(a, np.float32) / 255.0).permute(2, 0, 1)[None]  # noqa: E731
    frac = torch.from_numpy(-disp / w)[None, None]
    warped = warp(as_tensor(right), frac)
    inside = (disp > 0) & (np.arange(w)[None, :] - disp >= 0)
    return as_tensor(left), warped, torch.from_numpy(inside)


def pair_stats(left: np.ndarray, right: np.ndarray, disp: np.ndarray) -> PairStats:
    """The statistics of one pair: RGB views (H, W, 3, 0-255) and the left view's GT disparity (px,
    0 = none), at the size they are given (:func:`resize_pair` first to compare sets).

    Example:
        >>> import numpy as np
        >>> rng = np.random.default_rng(0)
        >>> right = rng.integers(0, 256, (32, 48, 3)).astype(np.uint8)
        >>> left = np.roll(right, 2, axis=1)  # the right view seen 2 px further right
        >>> disp = np.full((32, 48), 2.0, np.float32)
        >>> s = pair_stats(left, right, disp)
        >>> round(s.residual_mean, 3), round(s.ssim_gt, 2)  # the views agree at the GT disparity
        (0.0, 0.99)
        >>> round(pair_stats(left, right, disp + 1).residual_mean)  # and not 1 px off
        60
    """
    lt, warped, inside = _warped_right(left, right, disp)
    if not bool(inside.any()):
        raise ValueError("pair_stats: no GT pixel has its match inside the right view")
    as_grey = lambda t: grey(t[0].permute(1, 2, 0).numpy() * 255.0)  # noqa: E731
    residual = np.abs(as_grey(lt) - as_grey(warped))[inside.numpy()]
    ssim_map = ssim(lt, warped).mean(dim=1)[0]  # valid padding: 1 px less on each side
    ssim_valid = ssim_map[inside[1:-1, 1:-1]]
    gl, gr = grey(left), grey(right)
    lap = cv2.Laplacian(gl, cv2.CV_32F, ksize=1)[1:-1, 1:-1]
    return PairStats(
        residual_mean=float(residual.mean()),
        residual_median=float(np.median(residual)),
        brightness_gap=float(abs(gl.mean() - gr.mean())),
        grey_mean=float(gl.mean()),
        grey_spread=float(gl.std()),
        noise_sigma=immerkaer_sigma(gl),
        gradient_energy=float(np.abs(lap).mean()),
        ssim_gt=float(ssim_valid.mean()) if ssim_valid.numel() else float("nan"),
    )


def as_row(stats: PairStats) -> list[float]:
    """The statistics as a list in :data:`STATS`' order."""
    return list(astuple(stats))


# ----------------------------------------------------------------------------- sets of pairs

# A folder of real pairs with GT in one of KITTI's training layouts: (left, right, GT disparity).
REAL_LAYOUTS = {
    "kitti2015": ("image_2", "image_3", "disp_occ_0"),
    "kitti2012": ("colored_0", "colored_1", "disp_occ"),
}
FRAME_COLUMNS = ("set", "frame", "width")
# Within this fraction of the real pairs' mean, a statistic counts as calibrated (issue 66).
TOLERANCE = 0.2


def real_layout(root: Path) -> tuple[str, Path]:
    """The layout name and the training folder of ``root`` (the folder or its ``training/``)."""
    for folder in (root, root / "training"):
        for name, (left, right, gt) in REAL_LAYOUTS.items():
            if all((folder / sub).is_dir() for sub in (left, right, gt)):
                return name, folder
    layouts = "; ".join(f"{name}: {'/, '.join(subs)}/" for name, subs in REAL_LAYOUTS.items())
    raise DataError(
        f"{root}: not a folder of real pairs with GT (expected {layouts}, or training/ holding one)"
    )


def _measured(
    gt: str | os.PathLike, left: np.ndarray, right: np.ndarray, disp: np.ndarray, width: int
) -> list:
    """The pair's statistics at ``width`` (:func:`as_row`); DataError naming its GT file ``gt``
    where no GT pixel is left with a match inside the right view."""
    try:
        return as_row(pair_stats(*resize_pair(left, right, disp, width)))
    except ValueError as err:
        raise DataError(f"{gt}: at {width} px wide {str(err).removeprefix('pair_stats: ')}") from None


def measure_real(root: str | os.PathLike, width: int) -> pd.DataFrame:
    """Per frame (``*_10.png``) of a KITTI 2015 or 2012 training folder, its statistics at ``width``.

    KITTI 2012's ``disp_occ`` is read as the evaluation reads it (its reflective surfaces from
    ``disp_refl_occ`` where that folder exists).
    """
    name, folder = real_layout(Path(root))
    left_dir, right_dir, gt_dir = REAL_LAYOUTS[name]
    frames = sorted(p.stem for p in (folder / left_dir).glob("*_10.png"))
    if not frames:
        raise DataError(f"{folder / left_dir}: no *_10.png frame")
    rows = []
    for frame in frames:
        paths = [folder / sub / f"{frame}.png" for sub in (left_dir, right_dir, gt_dir)]
        has_refl = name == "kitti2012" and (folder / "disp_refl_occ").is_dir()
        disp = kitti2012.read_gt_disparity(paths[2])[0] if has_refl else kitti.read_disparity(paths[2])
        left, right = kitti.read_image(paths[0]), kitti.read_image(paths[1])
        check_same_size(paths[0], left.shape, paths[1], right.shape, "right image")
        check_same_size(paths[0], left.shape, paths[2], disp.shape, "GT")
        rows.append([name, frame, width, *_measured(paths[2], left, right, disp, width)])
    return pd.DataFrame(rows, columns=[*FRAME_COLUMNS, *STATS])


def measure_index(index: pd.DataFrame, width: int = 0) -> pd.DataFrame:
    """Per frame of an evaluation index (:mod:`msdepth.data.eval_index`), its statistics at
    ``width`` (0: each frame's own), GT from the index's own kind of file."""
    rows = []
    for row in index.itertuples(index=False):
        left, right = kitti.read_image(row.left), kitti.read_image(row.right)
        check_same_size(Path(row.left), left.shape, Path(row.right), right.shape, "right image")
        depth = read_gt_depth(row.gt_kind, row.gt, calib=row.calib, focal=row.focal, baseline=row.baseline)
        check_same_size(Path(row.left), left.shape, Path(row.gt), depth.shape, "GT")
        disp = np.where(depth > 0, row.focal * row.baseline / np.maximum(depth, 1e-6), 0).astype(np.float32)
        size = width or disp.shape[1]
        rows.append(["eval", row.frame, size, *_measured(row.gt, left, right, disp, size)])
    return pd.DataFrame(rows, columns=[*FRAME_COLUMNS, *STATS])


def measure_pairs(name: str, pairs: Iterable[tuple[str, np.ndarray, np.ndarray, np.ndarray]]) -> pd.DataFrame:
    """The statistics of ``(frame, left, right, GT disparity)`` pairs at their own size, as set ``name``."""
    rows = [[name, frame, d.shape[1], *as_row(pair_stats(lt, rt, d))] for frame, lt, rt, d in pairs]
    return pd.DataFrame(rows, columns=[*FRAME_COLUMNS, *STATS])


def summarise(columns: dict[str, pd.DataFrame], real: str) -> dict[str, Any]:
    """Each set's mean of every statistic, and its ratio to the ``real`` set's mean.

    Returns ``{"frames": {set: n}, "mean": {set: {stat: v}}, "ratio": {set: {stat: v}},
    "worst": {set: max |ratio - 1|}}`` (ratios for every set but ``real``).
    """
    means = {name: {s: float(df[s].mean()) for s in STATS} for name, df in columns.items()}
    ratios = {name: {s: means[name][s] / means[real][s] for s in STATS} for name in columns if name != real}
    return {
        "frames": {name: int(len(df)) for name, df in columns.items()},
        "mean": means,
        "ratio": ratios,
        "worst": {name: max(abs(v - 1.0) for v in r.values()) for name, r in ratios.items()},
    }


def summary_table(summary: dict[str, Any], real: str) -> str:
    """The summary as a markdown table: one row per statistic, a column per set, then each set's
    ratio to ``real`` (bold where it is off by more than :data:`TOLERANCE`)."""
    names = list(summary["mean"])
    others = [n for n in names if n != real]
    head = [f"{n} ({summary['frames'][n]} frames)" for n in names] + [f"{n} / {real}" for n in others]
    lines = ["| statistic | " + " | ".join(head) + " |", "|---" * (len(head) + 1) + "|"]
    for stat in STATS:
        cells = [f"{summary['mean'][n][stat]:.3f}" for n in names]
        for n in others:
            ratio = summary["ratio"][n][stat]
            cells.append(f"**{ratio:.2f}**" if abs(ratio - 1.0) > TOLERANCE else f"{ratio:.2f}")
        lines.append(f"| {stat} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def read_reference(path: str | os.PathLike) -> pd.DataFrame:
    """A reference table written by ``msdepth photometry``: DataError (one line naming the file) if
    it lacks a column, holds no frame, a non-finite value, or more than one width."""
    table = read_table_file(path, "photometry reference")
    missing = [c for c in (*FRAME_COLUMNS, *STATS) if c not in table.columns]
    if missing:
        columns = ", ".join(missing)
        raise DataError(f"{path}: not a photometry table (`msdepth photometry`): no column {columns}")
    values = table[[*STATS, "width"]].apply(pd.to_numeric, errors="coerce")
    if table.empty or not np.isfinite(values.to_numpy(float)).all():
        raise DataError(f"{path}: needs at least one frame and finite numbers in every statistic")
    if table["width"].nunique() != 1 or not 16 <= int(table["width"].iloc[0]) <= 4096:
        widths = sorted(set(table["width"]))
        raise DataError(f"{path}: its frames must share one width of 16 to 4096 px, got {widths}")
    table[[*STATS, "width"]] = values
    return table


def photometry_report(
    index: pd.DataFrame, reference: pd.DataFrame | None, ideal: Iterable | None, label: str
) -> tuple[dict[str, Any], str, pd.DataFrame]:
    """The photometry stage's outputs: its summary, markdown table and per-frame rows.

    ``index``: the evaluation frames (``label`` names them, e.g. "rendered"); ``reference``: real
    pairs' rows (:func:`read_reference`; None: no real column); ``ideal``: the same frames without
    the camera (:func:`msdepth.render.kitti_tree.eval_pairs`; None: none). Every set is measured at
    the reference's width (else each frame's own).
    """
    width = int(reference["width"].iloc[0]) if reference is not None else 0
    columns = {label: measure_index(index, width)}
    if ideal is not None:
        columns[f"{label}, no camera"] = measure_pairs(f"{label}, no camera", ideal)
    if reference is not None:
        columns["real"] = reference
    real = "real" if reference is not None else label
    summary = summarise(columns, real)
    summary["width"] = width or int(columns[label]["width"].iloc[0])
    frames = pd.concat(list(columns.values()), ignore_index=True)
    return summary, summary_table(summary, real), frames
