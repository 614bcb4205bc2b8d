"""Every real stereo pair at hand, scored for every loss variant's optimum and networks (issue #39).

The pairs, from ``../shared/real-samples`` (a pair whose folder is absent is skipped and named):
- ``object``: the KITTI object pair against its Velodyne scan projected into the left camera
  (``studies/score_lidar.py``'s GT; its ``calib.txt``'s focal and baseline; GT in (1e-3, 80) m);
- ``2015 <frame>``: KITTI 2015 training frames against ``disp_occ_0`` (721.5377 px, 0.54 m);
- ``2012 <frame>``: KITTI 2012 training frames against ``disp_occ`` with the reflective surfaces of
  ``disp_refl_occ`` in its place, and the exact class ``reflective`` on its own
  (:mod:`msdepth.data.kitti2012`: its camera, its GT).

Methods per pair: OpenCV's SGBM at full size (:mod:`msdepth.optimum.sgbm`, the reference); per
variant (ssim; msssim with kernel 3 and 7), the cost-volume start (SGM on the variant's own cost
volume, :func:`msdepth.optimum.starts.matched_disparity`) and the variant's optimum at every weight
of ``optimum.smoothness_sweep`` from ``optimum.start`` (:func:`msdepth.optimum.solver.optimum_disparities`),
both at the working size (``--size``, default half) and brought to full size (bilinear on the
disparity as a fraction of the width). With ``--models DIR``, also every trained network
``DIR/<variant>/seed<S>/model.pt`` of the params' ``variants`` (method ``network <variant>
seed<S>``), run as ``msdepth predict`` runs a model file (:func:`msdepth.cli.predict.load_trained`,
the hardened loader; the left image alone at the file's own input size; flip post-processing as
``eval.post_process``), its left disparity (a fraction of the width) brought to full size as
above. Scores at full size on the GT pixels of each class: abs_rel and a1 of depth (predictions
capped at 80 m: a disparity below f·B/80 reads as 80 m; ``metrics.compute_errors``), abs_rel after
median scaling (``abs_rel med``: the prediction times median(GT) / median(prediction) over those
pixels, then capped), KITTI's D1 (%) and EPE (px) (``metrics.stereo_errors``); and seconds. The
networks were trained on the synthetic set, whose camera differs from KITTI's: their metric depth
(reported as is) on real frames mostly measures that domain gap, which ``abs_rel med`` takes the
scale out of. Writes ``<out>/real_pairs.md`` through the output policy: the means over the pairs
(each variant's networks also over their seeds, ``network <variant> (<n> seeds)``), then every row.

From the same disparities it also writes ``<out>/verdict.json``, the real pairs' rows of the
verdict (:mod:`msdepth.reporting.verdict`, whose external schema it follows; the pipeline's
compare stage does not read it: the same instruments on real frames come from
``eval.extra_sets``): MS-SSIM at ``msssim.kernel_size`` minus ``compare.reference`` (SSIM) in
abs_rel, per instrument (``optimum w<weight>``, the pipeline's names; ``cost start``, SGM on each
variant's own cost volume; with ``--models``,
``stereo networks``, the pipeline's name, which the verdict labels "stereo networks, real pairs":
each non-reference variant of ``variants`` minus ``compare.reference``) and class, each with a
:func:`msdepth.reporting.stats.seed_bootstrap` interval (``compare``'s samples, confidence and
seed) over units of that class, and for the networks over each variant's seeds too (with one run
a side, as the optimum and the cost start, it is the paired bootstrap over units, draw for draw):

- ``full frame``: the pairs (abs_rel over each pair's GT pixels, as in ``real_pairs.md``);
- each ROI class (car, windshield, glass, sign): the hand-drawn boxes of
  ``data_lists/kitti2015_rois.csv`` on the KITTI 2015 frames that hold GT
  (:func:`msdepth.evaluation.suites.evaluate_roi`, cap 80 m, as ``studies/real_rois.py``);
- ``reflective`` (and any exact class a pair carries): the frames that hold at least
  ``CLASS_PIXELS`` GT pixels of it, each frame's abs_rel over those pixels. Neighbouring pixels or
  tiles of one car are not independent samples of reflective surfaces, so the frame is the unit.

A class with fewer than ``verdict.MIN_UNITS`` units gets a row without an interval (``low`` and
``high`` null) whose method says how many units it has. Each row records the two variants'
settings (``settings``): the compare stage shows a row made under other settings apart. The
networks of one seed are paired (the same seeds in both variants: the same initial weights and
batches, :mod:`msdepth.training.pairing`) and compared seed pair by seed pair. ``--weights`` restricts the
sweep (e.g. ``--weights 10``); ``--models`` names the trained networks' folder (the pipeline's
``models``)::

    OMP_NUM_THREADS=1 python studies/real_pairs.py --models models --out studies/results/real
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
import pandas as pd
import torch

from msdepth.cli.predict import load_trained
from msdepth.config.params import CompareConfig, EvalConfig, Params
from msdepth.data import kitti, kitti2012
from msdepth.data.annotations import KITTI2015_SIZE, gt_density, read_annotation
from msdepth.data.pairs import resize, to_tensor
from msdepth.errors import run_main
from msdepth.evaluation.infer import network_disparity
from msdepth.evaluation.metrics import compute_errors, median_scale, stereo_errors
from msdepth.evaluation.suites import Frame, evaluate_roi
from msdepth.geometry.depth import clamp_depth, disparity_to_depth
from msdepth.io import OutputPolicy, write_json, write_text
from msdepth.optimum.sgbm import sgbm_disparity
from msdepth.optimum.solver import optimum_disparities
from msdepth.optimum.starts import matched_disparity
from msdepth.reporting.compare import variant_settings
from msdepth.reporting.stats import paired_table, seed_bootstrap
from msdepth.reporting.verdict import (
    FULL_FRAME,
    METRIC,
    MIN_UNITS,
    class_order,
    read_external_rows,
    settings_label,
)
from msdepth.studies.real_samples import (
    BASELINE,
    CAP,
    FOCAL,
    MIN_DEPTH,
    lidar_gt,
    samples_dir,
    variants_of,
    working_size,
)

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = samples_dir(ROOT)
FRAMES = ("000000_10", "000001_10")
REPORT, VERDICT = "real_pairs.md", "verdict.json"
ROIS_CSV = ROOT / "data_lists" / "kitti2015_rois.csv"
CLASS_PIXELS = 50  # an exact class (reflective) counts a frame as its unit from this many GT px
COST_START = "cost start"  # the matcher's instrument (the pipeline's verdict has no matcher row)
NETWORKS = "stereo networks"  # the trained networks' instrument (as the pipeline names its own)
MODEL_FILE = "model.pt"  # --models DIR: DIR/<variant>/seed<S>/model.pt

Results = dict[str, tuple[np.ndarray, float]]  # method -> (full-size disparity in px, seconds)
Runs = dict[str, list[str]]  # variant -> its methods (one per seed; the optimum: one)


@dataclass
class RealPair:
    """One real pair: images (uint8 RGB), GT disparity (px, 0 = none), camera, exact classes."""

    label: str
    gt_name: str
    left: np.ndarray
    right: np.ndarray
    gt_disp: np.ndarray
    focal: float
    baseline: float
    classes: dict[str, np.ndarray] = field(default_factory=dict)  # class -> its pixels (bool)
    gt_in_range: bool = False  # LiDAR GT: only GT in (MIN_DEPTH, CAP), as the Eigen evaluation
    roi_frame: str | None = None  # the frame's name in the hand-drawn ROIs' CSV (KITTI 2015)


def object_pair(base: Path) -> RealPair:
    """The KITTI object pair and its Velodyne scan's disparity in the left camera."""
    left, right = (kitti.read_image(base / f"{side}.png") for side in ("left", "right"))
    focal, baseline = kitti.stereo_from_calib(kitti.read_calib(base / "calib.txt"))
    depth = lidar_gt(base / "lidar.bin", base / "calib.txt", left.shape[:2])
    disp = np.where(depth > 0, focal * baseline / np.maximum(depth, MIN_DEPTH), 0.0).astype(np.float32)
    return RealPair("object", "LiDAR", left, right, disp, focal, baseline, gt_in_range=True)


def kitti2015_pair(base: Path, frame: str) -> RealPair:
    """A KITTI 2015 training frame against ``disp_occ_0`` (no calib: Monodepth's camera)."""
    left, right = (kitti.read_image(base / d / f"{frame}.png") for d in ("image_2", "image_3"))
    gt = kitti.read_disparity(base / "disp_occ_0" / f"{frame}.png")
    return RealPair(f"2015 {frame}", "disp_occ_0", left, right, gt, FOCAL, BASELINE, roi_frame=frame)


def kitti2012_pair(base: Path, frame: str) -> RealPair:
    """A KITTI 2012 training frame against its GT, with its ``reflective`` pixels as a class."""
    paths = kitti2012.frame_paths(base, frame)
    left, right = kitti.read_image(paths["left"]), kitti.read_image(paths["right"])
    gt, reflective = kitti2012.read_gt_disparity(paths["gt"])
    focal, baseline = kitti2012.camera(base, frame, left.shape[1])
    classes = {kitti2012.REFLECTIVE: reflective}
    return RealPair(f"2012 {frame}", "disp_occ+refl", left, right, gt, focal, baseline, classes)


def real_pairs(samples: Path) -> tuple[list[RealPair], list[str]]:
    """Every pair of ``samples`` at hand, and the folders that are absent."""
    pairs, absent = [], []
    readers = {
        "kitti-object-pair": lambda b: [object_pair(b)],
        "kitti2015-training": lambda b: [kitti2015_pair(b, f) for f in FRAMES],
        "kitti2012-training": lambda b: [kitti2012_pair(b, f) for f in kitti2012.frames(b)],
    }
    for folder, read in readers.items():
        if (samples / folder).is_dir():
            pairs += read(samples / folder)
        else:
            absent.append(folder)
    return pairs, absent


def full_size(fraction: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """A disparity (fraction of the width) at a working size as px at the frame's ``shape``."""
    height, width = shape[:2]
    return cv2.resize(fraction, (width, height), interpolation=cv2.INTER_LINEAR) * width


def evaluated(pair: RealPair, mask: np.ndarray) -> np.ndarray:
    """The GT pixels of ``mask`` that are scored (LiDAR GT: only those in (MIN_DEPTH, CAP) m)."""
    mask = mask & (pair.gt_disp > 0)
    if pair.gt_in_range:
        gt_depth = disparity_to_depth(pair.gt_disp, pair.focal, pair.baseline)
        mask &= (gt_depth > MIN_DEPTH) & (gt_depth < CAP)
    return mask


def capped_depth(pair: RealPair, disparity: np.ndarray) -> np.ndarray:
    """The depth (m) of a disparity (px): a disparity below f·B/CAP, none included, reads as CAP."""
    floor = pair.focal * pair.baseline / CAP  # px: a disparity below it is beyond the cap
    return disparity_to_depth(np.maximum(disparity, floor), pair.focal, pair.baseline)


def scores(pair: RealPair, disparity: np.ndarray, mask: np.ndarray) -> dict[str, float] | None:
    """abs_rel and a1 (depth, capped), abs_rel after median scaling (``abs_rel_med``: the prediction
    times median(GT) / median(prediction) over these pixels, then capped), D1 (%) and EPE (px) on the
    GT pixels of ``mask``; None if none."""
    mask = evaluated(pair, mask)
    if not mask.any():
        return None
    gt_depth = disparity_to_depth(pair.gt_disp, pair.focal, pair.baseline)[mask]
    pred = capped_depth(pair, disparity)[mask]
    depth = compute_errors(gt_depth, clamp_depth(pred, MIN_DEPTH, CAP))
    scaled = compute_errors(gt_depth, clamp_depth(median_scale(gt_depth, pred)[0], MIN_DEPTH, CAP))
    stereo = stereo_errors(np.where(mask, pair.gt_disp, 0.0), disparity)
    return {"pixels": int(mask.sum()), "abs_rel": depth["abs_rel"], "abs_rel_med": scaled["abs_rel"],
            "a1": depth["a1"], "d1": 100 * stereo["d1"], "epe": stereo["epe"]}  # fmt: skip


def methods(pair: RealPair, variants: dict, size: tuple[int, int], weights: Sequence[float]):  # noqa: ANN201 - a generator
    """Yield ``(method, full-size disparity in px, seconds)`` for every method on ``pair``."""
    began = time.perf_counter()
    yield "SGBM", sgbm_disparity(pair.left, pair.right)[0], time.perf_counter() - began
    small = [cv2.resize(image, size[::-1], interpolation=cv2.INTER_AREA) for image in (pair.left, pair.right)]
    for label, (name, params) in variants.items():
        began = time.perf_counter()
        start = matched_disparity(*small, params, name, "cost") / size[1]
        yield f"{label} {COST_START}", full_size(start, pair.left.shape), time.perf_counter() - began
        for weight in weights:
            began = time.perf_counter()
            images = [(pair.left, pair.right)]
            disp = optimum_disparities(images, params, name, weight, size, progress=False)[0]
            seconds = time.perf_counter() - began
            yield f"{label} {optimum_name(weight)}", full_size(disp, pair.left.shape), seconds


def optimum_name(weight: float) -> str:
    """The optimum's instrument at ``weight``, as the pipeline names it (``optimum w10``)."""
    return f"optimum w{weight:g}"


def disparities(
    pairs: list[RealPair], variants: dict, size_name: str, weights: Sequence[float]
) -> list[Results]:
    """Per pair (in order), every method's full-size disparity and seconds, printing progress."""
    out = []
    for number, pair in enumerate(pairs, 1):
        results: Results = {}
        size = working_size(size_name, pair.left.shape)
        for method, disparity, seconds in methods(pair, variants, size, weights):
            results[method] = (disparity, seconds)
            print(f"[{number}/{len(pairs)}] {pair.label} {method}: {seconds:.1f} s", flush=True)
        out.append(results)
    return out


# --- the trained networks (--models) -------------------------------------------------------------


def model_files(models: Path, variants: Sequence[str]) -> dict[str, dict[int, Path]]:
    """Per variant (in order), its model files ``models/<variant>/seed<S>/model.pt`` by seed (sorted);
    a SystemExit naming the folder where a variant has none."""
    found = {}
    for variant in variants:
        seeds = {}
        for path in (models / variant).glob(f"seed*/{MODEL_FILE}"):
            number = path.parent.name.removeprefix("seed")
            if number.isdigit():
                seeds[int(number)] = path
        if not seeds:
            raise SystemExit(f"--models: no {models / variant}/seed<S>/{MODEL_FILE}")
        found[variant] = dict(sorted(seeds.items()))
    return found


def network_name(variant: str, seed: int) -> str:
    """A trained network's method (``network ssim seed0``)."""
    return f"network {variant} seed{seed}"


def network_pixels(model: torch.nn.Module, meta: dict, pair: RealPair, post_process: bool) -> np.ndarray:
    """The network's left disparity of ``pair`` as ``msdepth predict`` makes it: the left image alone
    at the model file's input size (area resize), flip post-processing if asked, then the disparity
    (a fraction of the width) brought to the pair's full size in px by :func:`full_size`."""
    height, width = int(meta["height"]), int(meta["width"])
    batch = to_tensor(resize(pair.left, height, width)).unsqueeze(0)
    return full_size(network_disparity(model, batch, post_process)[0], pair.left.shape)


def network_disparities(
    pairs: list[RealPair], results: list[Results], files: dict[str, dict[int, Path]], post_process: bool
) -> Runs:
    """Add every trained network's full-size disparity and seconds to ``results`` (per pair, in
    order), loading each model file once; returns each variant's methods (one per seed)."""
    runs: Runs = {}
    for variant, by_seed in files.items():
        for seed, path in by_seed.items():
            model, meta = load_trained(path)
            method = network_name(variant, seed)
            runs.setdefault(variant, []).append(method)
            for number, (pair, by_method) in enumerate(zip(pairs, results, strict=True), 1):
                began = time.perf_counter()
                by_method[method] = (
                    network_pixels(model, meta, pair, post_process),
                    time.perf_counter() - began,
                )
                print(
                    f"[{number}/{len(pairs)}] {pair.label} {method}: {by_method[method][1]:.1f} s", flush=True
                )
    return runs


def score_pairs(pairs: list[RealPair], results: list[Results]) -> list[dict]:
    """One row per pair, method and class (``all`` and each exact class)."""
    rows = []
    for pair, by_method in zip(pairs, results, strict=True):
        masks = {"all": np.ones(pair.gt_disp.shape, bool), **pair.classes}
        for method, (disparity, seconds) in by_method.items():
            for cls, mask in masks.items():
                found = scores(pair, disparity, mask)
                if found is not None:
                    rows.append({"pair": pair.label, "gt": pair.gt_name, "method": method, "class": cls,
                                 "s": seconds, **found})  # fmt: skip
    return rows


# --- the verdict's rows: MS-SSIM − SSIM per instrument and class, over units ---------------------


def class_values(pair: RealPair, disparity: np.ndarray, cls: str) -> list[dict]:
    """The frame as ``cls``'s one unit: its abs_rel over the class's scored GT pixels; [] where the
    frame holds fewer than CLASS_PIXELS of them."""
    mask = evaluated(pair, pair.classes[cls])
    if int(mask.sum()) < CLASS_PIXELS:
        return []
    gt_depth = disparity_to_depth(pair.gt_disp, pair.focal, pair.baseline)
    pred = clamp_depth(capped_depth(pair, disparity), MIN_DEPTH, CAP)
    errors = compute_errors(gt_depth[mask], pred[mask])
    return [{"class": cls, "unit": pair.label, METRIC: errors[METRIC]}]


def roi_values(pairs: list[RealPair], results: list[Results], method: str, boxes: pd.DataFrame) -> list[dict]:
    """Per hand-drawn box with GT on the KITTI 2015 frames at hand (at the size the boxes were drawn
    on), ``method``'s abs_rel at cap CAP (:func:`~msdepth.evaluation.suites.evaluate_roi`, as
    ``studies/real_rois.py``); [] where no box has GT."""
    frames, pred, gt = [], {}, {}
    for pair, by_method in zip(pairs, results, strict=True):
        if pair.roi_frame in set(boxes["image"]) and pair.gt_disp.shape == KITTI2015_SIZE:
            frames.append(Frame.from_disparity(pair.roi_frame, pair.gt_disp, pair.focal, pair.baseline))
            pred[pair.roi_frame] = capped_depth(pair, by_method[method][0])
            gt[pair.roi_frame] = pair.gt_disp
    chosen = boxes[boxes["image"].isin(pred)]
    if chosen.empty or not (gt_density(chosen, gt) > 0).any():  # the suite needs a box with GT
        return []
    _, table = evaluate_roi(pred, frames, chosen.reset_index(drop=True), EvalConfig(caps=(CAP,)))
    lines = chosen.index + 2  # a box's CSV line (header 1) names it; the suite numbers them 0, 1, ...
    return [
        {"class": r["class"], "unit": f"{r['image']} line {lines[r['roi']]}", METRIC: r[METRIC]}
        for r in table.to_dict("records")
    ]


def unit_table(
    pairs: list[RealPair], results: list[Results], method: str, boxes: pd.DataFrame
) -> pd.DataFrame:
    """``method``'s abs_rel per unit (columns class, unit, abs_rel): each pair as the full frame,
    each box with GT under its class, each frame of every exact class (KITTI 2012's reflective)."""
    rows = []
    for pair, by_method in zip(pairs, results, strict=True):
        disparity = by_method[method][0]
        found = scores(pair, disparity, np.ones(pair.gt_disp.shape, bool))
        if found is not None:
            rows.append({"class": FULL_FRAME, "unit": pair.label, METRIC: found[METRIC]})
        for cls in pair.classes:
            rows += class_values(pair, disparity, cls)
    rows += roi_values(pairs, results, method, boxes)
    return pd.DataFrame(rows, columns=["class", "unit", METRIC])


def unit_words(cls: str, pairs: list[RealPair]) -> str:
    """The units of a verdict row of ``cls``, in words (what its bootstrap draws)."""
    if cls == FULL_FRAME:
        names = ", ".join(p.label for p in pairs)
        return f"the pairs ({names}; the object pair's GT is LiDAR)"
    if any(cls in p.classes for p in pairs):
        names = ", ".join(p.label for p in pairs if cls in p.classes)
        return f"the frames with >= {CLASS_PIXELS} {cls} GT px ({names}), a frame's abs_rel over them"
    names = ", ".join(p.label for p in pairs if p.roi_frame is not None)
    return f"the hand-drawn ROIs with GT ({names}; {ROIS_CSV.name})"


def unit_method(cls: str, pairs: list[RealPair], seeds: int = 0, n: int = MIN_UNITS) -> str:
    """How a verdict row of ``cls`` was made, in words (the row's ``method``): over its units, with
    ``seeds`` seed pairs as well (networks); with ``n`` below MIN_UNITS units, why it has no interval."""
    units = unit_words(cls, pairs)
    if n < MIN_UNITS:
        return f"real pairs: no interval, {n} independent units (fewer than {MIN_UNITS}): {units}"
    if not seeds:
        return f"real pairs: paired bootstrap over {units}"
    return (
        f"real pairs: paired by seed ({seeds} pairs), bootstrap over seed pairs and units; the units: {units}"
    )


def unit_matrix(tables: dict[str, pd.DataFrame], methods: Sequence[str], anchor: str, cls: str) -> np.ndarray:
    """(methods, units): each method's abs_rel on ``cls``'s units, in the order of ``anchor``'s
    (:func:`~msdepth.reporting.stats.paired_table`: the units must match one to one)."""
    base = tables[anchor][tables[anchor]["class"] == cls]
    rows = []
    for method in methods:
        table = tables[method][tables[method]["class"] == cls]
        what = f"real pairs, {method} vs {anchor}, {cls}"
        rows.append(paired_table(base, table, ["unit"], METRIC, what)[1])
    return np.array(rows)


def difference_rows(
    pairs: list[RealPair],
    results: list[Results],
    runs: Runs,
    reference: str,
    instrument: str,
    cfg: CompareConfig,
    settings: str = "",
) -> list[dict]:
    """Per class, each variant of ``runs`` minus ``reference`` in abs_rel over the class's units
    (:func:`unit_table`) and, for networks, their seed pairs (runs listed in seed order, the same
    seeds a side): :func:`~msdepth.reporting.stats.seed_bootstrap` at ``cfg``'s settings, paired.
    A class with fewer than MIN_UNITS units gets its mean difference without an interval. A row is
    named ``instrument`` (with the variant after a comma where several are compared, as the
    pipeline names them) and records ``settings``."""
    boxes = read_annotation(ROIS_CSV)
    tables = {m: unit_table(pairs, results, m, boxes) for methods in runs.values() for m in methods}
    anchor = runs[reference][0]
    others = [v for v in runs if v != reference]
    rows = []
    for cls in class_order(list(tables[anchor]["class"].unique())):
        ref = unit_matrix(tables, runs[reference], anchor, cls)
        for variant in others:
            values = unit_matrix(tables, runs[variant], anchor, cls)
            name = instrument if len(others) == 1 else f"{instrument}, {variant}"
            n, seeds = values.shape[1], len(values) if len(values) > 1 else 0
            row = {"instrument": name, "class": cls, "n": int(n), "method": unit_method(cls, pairs, seeds, n)}
            if n < MIN_UNITS:
                row |= {"diff": float((values - ref).mean()), "low": None, "high": None}
            else:
                d = seed_bootstrap(values, ref, cfg.bootstrap_samples, cfg.confidence, cfg.seed, paired=True)
                row |= {"diff": d.mean, "low": d.low, "high": d.high}
                if d.t_low is not None:
                    row |= {"t_low": d.t_low, "t_high": d.t_high, "seeds": seeds}
            rows.append(row | ({"settings": settings} if settings else {}))
    return rows


def verdict_rows(
    pairs: list[RealPair],
    results: list[Results],
    cfg: CompareConfig,
    labels: tuple[str, str],
    weights: Sequence[float],
    networks: Runs | None = None,
    settings: str = "",
) -> list[dict]:
    """The rows of ``verdict.json`` (:mod:`msdepth.reporting.verdict`'s external schema): per
    instrument and class, ``labels[0]`` minus ``labels[1]`` (methods' labels) for the cost start and
    each optimum weight, and with ``networks`` (variant -> its networks' methods) every variant
    minus ``cfg.reference`` as the instrument NETWORKS (:func:`difference_rows`)."""
    rows = []
    for instrument in [COST_START, *(optimum_name(w) for w in weights)]:
        runs = {label: [f"{label} {instrument}"] for label in labels}
        rows += difference_rows(pairs, results, runs, labels[1], instrument, cfg, settings)
    if networks:
        rows += difference_rows(pairs, results, networks, cfg.reference, NETWORKS, cfg, settings)
    return rows


def verdict_labels(variants: dict[str, tuple[str, Params]]) -> tuple[str, str]:
    """The labels of the verdict's two variants: MS-SSIM at the params' ``msssim.kernel_size`` (the
    pipeline's ``msssim``) and ``compare.reference``; a SystemExit where either is not a variant here."""
    params = next(iter(variants.values()))[1]
    labels = (f"msssim k{params.msssim.kernel_size}", params.compare.reference)
    for label in labels:
        if label not in variants:
            raise SystemExit(f"verdict: no variant {label!r} here (variants: {', '.join(variants)})")
    return labels


def table(rows: list[dict]) -> list[str]:
    """The markdown table of every row."""
    lines = [
        "| pair | GT | method | class | GT px | abs_rel | abs_rel med | a1 | D1 % | EPE px | s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['pair']} | {r['gt']} | {r['method']} | {r['class']} | {r['pixels']} | {r['abs_rel']:.3f} | "
        f"{r['abs_rel_med']:.3f} | {r['a1']:.3f} | {r['d1']:.1f} | {r['epe']:.2f} | {r['s']:.1f} |"
        for r in rows
    ]
    return lines


def mean_table(rows: list[dict], groups: Runs | None = None) -> list[str]:
    """Per class and method, the mean over the pairs that have the class (each pair weighs one);
    after each class's methods, each of ``groups`` (a name -> its methods, e.g. a variant's networks
    over seeds) as the mean over its methods and those pairs."""
    lines = [
        "| class | method | pairs | abs_rel | abs_rel med | a1 | D1 % | EPE px | s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    named = {m: [m] for m in dict.fromkeys(r["method"] for r in rows)} | dict(groups or {})
    for cls in sorted(dict.fromkeys(r["class"] for r in rows), key=lambda c: c != "all"):
        for name, members in named.items():
            sel = [r for r in rows if r["class"] == cls and r["method"] in members]
            if not sel:
                continue
            mean = {
                k: float(np.mean([r[k] for r in sel]))
                for k in ("abs_rel", "abs_rel_med", "a1", "d1", "epe", "s")
            }
            lines.append(
                f"| {cls} | {name} | {len({r['pair'] for r in sel})} | {mean['abs_rel']:.3f} | "
                f"{mean['abs_rel_med']:.3f} | {mean['a1']:.3f} | {mean['d1']:.1f} | {mean['epe']:.2f} | "
                f"{mean['s']:.1f} |"
            )
    return lines


def network_words(files: dict[str, dict[int, Path]], post_process: bool) -> str:
    """The report's sentences on the trained networks (``--models``); "" without them."""
    if not files:
        return ""
    shown = "; ".join(f"{v}: seeds {', '.join(map(str, s))}" for v, s in files.items())
    return (
        f" Networks (`network <variant> seed<S>`, {shown}; `network <variant> (<n> seeds)`: their mean): "
        "each model file as `msdepth predict` runs it, the left image alone at the file's input size, "
        f"flip post-processing {'on' if post_process else 'off'} (`eval.post_process`), its disparity "
        "(a fraction of the width) bilinear to the full size in px. They were trained on the synthetic "
        "set, whose camera differs from KITTI's: their metric depth on real frames (abs_rel, a1, D1, "
        "EPE, reported as is) mostly measures that domain gap; `abs_rel med` (every method's abs_rel "
        "after per-row median scaling, Monodepth2's) takes the scale out of it. Their verdict rows "
        f"(`{NETWORKS}`, over units and seeds) use unscaled abs_rel as every other row."
    )


def report(
    rows: list[dict],
    pairs: list[RealPair],
    absent: list[str],
    size: str,
    loads: tuple,
    networks: Runs | None = None,
    words: str = "",
) -> str:
    """The study's markdown: how it was made (``words``: :func:`network_words`), the mean table (with
    ``networks``, variant -> its networks' methods, each variant also over its seeds), then every row."""
    shown = ", ".join(f"{p.label} {p.left.shape[1]}x{p.left.shape[0]}" for p in pairs)
    groups = {f"network {v} ({len(m)} seeds)": m for v, m in (networks or {}).items()}
    lines = [
        "# Every real pair at hand: SGBM, the cost-volume start, each variant's optimum"
        f"{' and trained networks' if networks else ''} (issue #39)",
        "",
        f"`OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', '')} python studies/real_pairs.py "
        f"{' '.join(sys.argv[1:])}` (its docstring says what each column is). Pairs: {shown}"
        f"{'; absent: ' + ', '.join(absent) if absent else ''}. Working size: `{size}` of each frame "
        f"(optimum and cost start; SGBM at full size); scored at full size. Torch threads "
        f"{torch.get_num_threads()}; load average {loads[0][0]:.1f} at the start, {loads[1][0]:.1f} at "
        "the end (seconds are indicative). Class `all`: every GT pixel; `reflective`: KITTI 2012's "
        "disp_refl_occ pixels (msdepth.data.kitti2012). The verdict's rows (MS-SSIM − SSIM per "
        "instrument and class, over pairs, hand-drawn ROIs and reflective frames) are in `verdict.json`, "
        f"from the same disparities.{words}",
        "",
        "## Means over the pairs",
        "",
        *mean_table(rows, groups),
        "",
        "## Every pair",
        "",
        *table(rows),
    ]
    return "\n".join(lines) + "\n"


def arguments(argv: list[str] | None) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=Path, default=SAMPLES, help="the real-samples folder")
    parser.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    parser.add_argument("--size", default="half", help="working size: full, half, quarter or HxW")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a params override")
    parser.add_argument(
        "--weights", help="the optimum's weights, e.g. 3,10 (default: optimum.smoothness_sweep)"
    )
    parser.add_argument(
        "--models",
        type=Path,
        help="also the trained networks DIR/<variant>/seed<S>/model.pt (params' variants)",
    )
    parser.add_argument(
        "--out", type=Path, required=True, help="the folder of real_pairs.md and verdict.json"
    )
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Score every real pair at hand; write ``<out>/real_pairs.md`` and ``<out>/verdict.json``."""
    args = arguments(argv)
    policy = OutputPolicy(args.out, "real-pairs")
    policy.claim([args.out / REPORT, args.out / VERDICT], args.samples)
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))
    variants = variants_of(args.params, args.set)
    labels = verdict_labels(variants)
    params = variants[labels[1]][1]
    weights = [float(w) for w in args.weights.split(",")] if args.weights else params.optimum.smoothness_sweep
    files = model_files(args.models, params.variants) if args.models else {}
    for variant, by_seed in files.items():
        if list(by_seed) != list(params.train.seeds):  # the networks are compared seed pair by seed pair
            print(f"--models: {variant} has seeds {list(by_seed)}, train.seeds {list(params.train.seeds)}",
                  file=sys.stderr)  # fmt: skip
            return 1
    pairs, absent = real_pairs(args.samples)
    if not pairs:
        print(f"{args.samples}: no real pair at hand ({', '.join(absent)} absent)", file=sys.stderr)
        return 1
    before = os.getloadavg()
    results = disparities(pairs, variants, args.size, weights)
    networks = network_disparities(pairs, results, files, params.eval.post_process) if files else None
    loads = (before, os.getloadavg())
    words = network_words(files, params.eval.post_process)
    text = report(score_pairs(pairs, results), pairs, absent, args.size, loads, networks, words)
    write_text(args.out / REPORT, text)
    settings = settings_label(variant_settings(params), [params.compare.reference, "msssim"])
    rows = verdict_rows(pairs, results, params.compare, labels, weights, networks, settings)
    write_json(args.out / VERDICT, rows)
    read_external_rows(args.out / VERDICT)  # the verdict module reads it back: the schema holds
    print(text)
    print(f"{args.out / VERDICT}: {len(rows)} rows")
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/real_pairs.py", main))
