"""Which camera effect flips the order of the losses' own optimum (issue 66, item 4)?

A controlled screen on the rendered evaluation frames. Each condition renders the first ``--frames``
evaluation frames through one photometric camera (``data.synthetic.camera``,
:mod:`msdepth.render.sensor`), runs the optimum (:mod:`msdepth.optimum.solver`) for SSIM and MS-SSIM
at each smoothness weight, and scores it per frame (full-frame abs_rel at cap 80 m) and per ROI box.
Each variant then gets its own best weight (:mod:`msdepth.optimum.selection`: two folds of frames,
each scored at the weight best on the other), and MS-SSIM − SSIM per class comes with the verdict's
paired bootstrap (:func:`msdepth.analysis.verdict.optimum_rows`: ROIs drawn with their frame), beside
the fixed weight 10's.

The conditions (:data:`CONDITIONS`): ``ideal`` (no camera: the views of earlier releases);
``neutral`` (the camera with every effect off: only auto-exposure to ``exposure`` and 8-bit
quantisation, which every condition below has too); one effect alone: ``blur``, ``vignetting``,
``rectification``, ``exposure`` (the two views' gain mismatch and white balance), ``noise`` (read
and shot) and ``jpeg`` (quality 90); ``all``: the calibrated default, every effect at its param.
Each effect takes its value from params.yaml (``--set data.synthetic.camera.blur=0.6``).

Writes to ``--out`` (through the output policy): ``screen.md`` (the summary tables, then one table
per condition), ``summary.csv`` (every row with its interval) and ``scores_<condition>.csv`` (every
variant's per-frame and per-ROI scores at every weight, for a re-aggregation without a rerun). A
condition whose scores file is complete is not run again::

    python studies/camera_screen.py --out studies/results/camera_screen --threads 2
    python studies/camera_screen.py --frames 2 --conditions ideal all --weights 3 10 --out /tmp/screen
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from msdepth.analysis.verdict import NAMES, Row, RowScope, class_order, optimum_rows
from msdepth.config.params import (
    MAX_THREADS,
    MAX_WEIGHT,
    CameraConfig,
    Params,
    apply_overrides,
    kernel_variant,
    params_from_dict,
    read_params_file,
)
from msdepth.errors import ConfigError, run_main
from msdepth.evaluation.rendered import rendered_eval_set
from msdepth.evaluation.suites import Frame, depth_maps, evaluate_full, evaluate_roi
from msdepth.io import write_text
from msdepth.optimum.selection import choose_weights, select_rows
from msdepth.outputs import OutputPolicy
from msdepth.reporting.verdict import interval_cell, units_text

ROOT = Path(__file__).resolve().parents[1]  # its params.yaml is the base
CAP = 80.0
VARIANTS = ("ssim", "msssim")  # the reference first (compare.reference)
FIXED = 10.0  # the fixed weight reported beside each variant's own best
SCORE_COLUMNS = ["suite", "image", "roi", "class", "cap", "abs_rel"]
# Every effect off: the camera then only exposes the views and quantises them.
_OFF = {"blur": 0.0, "vignetting": 0.0, "rectification": 0.0, "gain_mismatch": 0.0, "white_balance": 0.0}
_OFF |= {"read_noise": 0.0, "shot_noise": 0.0, "jpeg_quality": 0}
# Each condition: the params of the camera it turns on (from params.yaml's camera), or None (no camera).
CONDITIONS: dict[str, tuple[str, ...] | None] = {
    "ideal": None,
    "neutral": (),
    "blur": ("blur",),
    "vignetting": ("vignetting",),
    "rectification": ("rectification",),
    "exposure": ("gain_mismatch", "white_balance"),
    "noise": ("read_noise", "shot_noise"),
    "jpeg": ("jpeg_quality",),
    "all": tuple(_OFF),
}
JPEG_QUALITY = 90  # the jpeg condition's quality where params.yaml's is 0 (PNG, as KITTI's)


def camera(name: str, default: CameraConfig) -> CameraConfig:
    """Condition ``name``'s camera: ``default`` (params.yaml's) with every effect not named off.

    Example:
        >>> camera("blur", CameraConfig()).blur, camera("blur", CameraConfig()).read_noise
        (0.2, 0.0)
        >>> camera("ideal", CameraConfig()).enabled, camera("jpeg", CameraConfig()).jpeg_quality
        (False, 90)
    """
    effects = CONDITIONS[name]
    if effects is None:
        return dataclasses.replace(default, enabled=False)
    kept = {k: getattr(default, k) for k in effects}
    if name == "jpeg" and not default.jpeg_quality:
        kept["jpeg_quality"] = JPEG_QUALITY
    return dataclasses.replace(default, enabled=True, **(_OFF | kept))


def scored(disps: list[np.ndarray], frames: list[Frame], rois: pd.DataFrame, params: Params) -> pd.DataFrame:
    """The per-frame (``suite`` full) and per-ROI box (``suite`` roi) abs_rel at cap 80 m."""
    pred = depth_maps(disps, frames)
    cfg = dataclasses.replace(params.eval, caps=(CAP,))
    full = evaluate_full(pred, frames, cfg)[1].assign(suite="full", image=lambda t: t["frame"])
    roi = evaluate_roi(pred, frames, rois, cfg)[1].assign(suite="roi")
    return pd.concat([full, roi], ignore_index=True).reindex(columns=SCORE_COLUMNS)


def expected_keys(frames: int, weights: list[float]) -> set[tuple[str, float, str]]:
    """The (variant, weight, frame) every complete scores file holds."""
    return {(v, w, f"{i:06d}_10") for v in VARIANTS for w in weights for i in range(frames)}


def complete(path: Path, frames: int, weights: list[float]) -> pd.DataFrame | None:
    """The scores in ``path`` if they hold every variant, weight and frame asked for, else None."""
    if not path.is_file():
        return None
    try:
        table = pd.read_csv(path)
        full = table[table["suite"] == "full"]
        found = set(zip(full["variant"], full["weight"].astype(float), full["image"], strict=True))
    except (ValueError, KeyError, pd.errors.ParserError):
        return None
    return table if found == expected_keys(frames, weights) else None


def run_condition(base: dict, name: str, args: argparse.Namespace, weights: list[float]) -> pd.DataFrame:
    """Condition ``name``'s scores: every variant at every weight, per frame and per ROI box."""
    from msdepth.optimum.solver import optimum_disparities

    params = params_from_dict(base)
    synthetic = params.data.synthetic
    rendered = rendered_eval_set(synthetic, args.frames, camera(name, synthetic.camera))
    pairs, frames, rois = rendered.pairs, rendered.frames, rendered.rois
    parts = []
    for label in VARIANTS:
        variant, raw = kernel_variant(base, label)
        p = params_from_dict(raw)
        for w in weights:
            clock = time.perf_counter()
            disps = optimum_disparities(pairs, p, variant, w, progress=False)
            parts.append(scored(disps, frames, rois, p).assign(variant=label, weight=w))
            took = time.perf_counter() - clock
            print(f"{name}: {label} w{w:g} {took:.1f} s ({took / len(pairs):.2f} s/pair)", file=sys.stderr)
    return pd.concat(parts, ignore_index=True)


def per_weight_tables(scores: pd.DataFrame, variant: str) -> dict[str, dict[float, pd.DataFrame]]:
    """``{suite: {weight: table}}`` of one variant: the full-frame table's units are ``frame``, the ROI
    table's ``roi`` (each with its frame, ``image``), as the verdict's tables are."""
    mine = scores[scores["variant"] == variant]
    out: dict[str, dict[float, pd.DataFrame]] = {"full": {}, "roi": {}}
    for w, t in mine.groupby("weight", sort=True):
        full = t[t["suite"] == "full"].drop(columns=["roi", "class"]).rename(columns={"image": "frame"})
        roi = t[t["suite"] == "roi"].astype({"roi": int})
        out["full"][float(w)] = full.reset_index(drop=True)
        out["roi"][float(w)] = roi.reset_index(drop=True)
    return out


@dataclasses.dataclass(frozen=True)
class Screened:
    """One condition's verdict rows (own best and the fixed weight), chosen weights and mean errors."""

    own_best: list[Row]
    fixed: list[Row]
    chosen: dict[str, dict[int, float]]  # variant -> {fold: the weight it was scored at}
    means: dict[str, dict[str, float]]  # variant -> {class: mean abs_rel at its own best weight}


def _means(full: pd.DataFrame, roi: pd.DataFrame) -> dict[str, float]:
    """Mean abs_rel over the frames (``full frame``) and over each class's ROI boxes."""
    return {"full frame": float(full["abs_rel"].mean()), **roi.groupby("class")["abs_rel"].mean().to_dict()}


def screen(scores: pd.DataFrame, params: Params) -> Screened:
    """Each variant at its own best weight (two folds) and at :data:`FIXED`, MS-SSIM − SSIM per class
    by the verdict's paired bootstrap (ROIs drawn with their frame)."""
    tables: dict[str, dict[str, pd.DataFrame]] = {"full": {}, "roi": {}}
    own, fixed, chosen, means = {}, {}, {}, {}
    for variant in VARIANTS:
        by_suite = per_weight_tables(scores, variant)
        frames, chosen[variant] = choose_weights(by_suite["full"])
        own[variant] = f"{variant}/own_best"
        tables["full"][own[variant]] = select_rows(by_suite["full"], frames, "frame")
        tables["roi"][own[variant]] = select_rows(by_suite["roi"], frames, "image")
        means[variant] = _means(tables["full"][own[variant]], tables["roi"][own[variant]])
        if FIXED in by_suite["full"]:
            fixed[variant] = f"{variant}/w{FIXED:g}"
            tables["full"][fixed[variant]] = by_suite["full"][FIXED]
            tables["roi"][fixed[variant]] = by_suite["roi"][FIXED]
    cfg = dataclasses.replace(params.compare, reference=VARIANTS[0])
    scope = RowScope(keep_few=True)  # a smoke run's few frames: the differences, without intervals
    rows = optimum_rows(tables, {"own best": own}, cfg, CAP, scope=scope)
    at_fixed = optimum_rows(tables, {f"w{FIXED:g}": fixed}, cfg, CAP, scope=scope) if fixed else []
    return Screened(rows, at_fixed, chosen, means)


def _weights_text(chosen: dict[str, dict[int, float]]) -> str:
    """``SSIM w3, w10; MS-SSIM w10, w10``: each variant's weight per fold."""
    return "; ".join(
        f"{NAMES.get(v, v)} " + ", ".join(f"w{w:g}" for _, w in sorted(folds.items()))
        for v, folds in chosen.items()
    )


def condition_table(name: str, result: Screened) -> str:
    """Condition ``name``'s markdown: per class, own best and fixed-weight differences, mean errors."""
    fixed = {r.cls: r for r in result.fixed}
    lines = [
        f"### {name}",
        "",
        f"Own best weights, per fold of frames (0, 1): {_weights_text(result.chosen)}.",
        "",
        f"| class | MS-SSIM − SSIM, own best | SSIM | MS-SSIM | MS-SSIM − SSIM, w{FIXED:g} | units |",
        "|---|---|---|---|---|---|",
    ]
    for r in result.own_best:
        means = [f"{result.means[v].get(r.cls, float('nan')):.4f}" for v in VARIANTS]
        at_fixed = interval_cell(fixed[r.cls], 4) if r.cls in fixed else ""
        lines.append(
            f"| {r.cls} | {interval_cell(r, 4)} | {' | '.join(means)} | {at_fixed} | {units_text(r)} |"
        )
    return "\n".join(lines) + "\n"


def summary_tables(results: dict[str, Screened]) -> str:
    """The summary: one row per condition, one column per class; own best, then the fixed weight."""
    classes = class_order(sorted({r.cls for res in results.values() for r in res.own_best}))
    out = []
    for title, pick in (("own best weight", "own_best"), (f"fixed weight {FIXED:g}", "fixed")):
        out += [f"MS-SSIM − SSIM abs_rel (cap {CAP:g} m), each variant at its {title}:", ""]
        out += [f"| condition | {' | '.join(classes)} | weights |", "|---" * (len(classes) + 2) + "|"]
        for name, res in results.items():
            cells = {r.cls: interval_cell(r, 4) for r in getattr(res, pick)}
            weights = _weights_text(res.chosen) if pick == "own_best" else f"w{FIXED:g}"
            out.append(f"| {name} | {' | '.join(cells.get(c, '') for c in classes)} | {weights} |")
        out.append("")
    return "\n".join(out)


def summary_csv(results: dict[str, Screened]) -> str:
    """Every row of every condition, with its interval, as CSV."""
    rows = [
        {"condition": name, "weights": kind, **r.as_dict()}
        for name, res in results.items()
        for kind, rows in (("own best", res.own_best), (f"w{FIXED:g}", res.fixed))
        for r in rows
    ]
    return pd.DataFrame(rows).to_csv(index=False)


def parse(argv: list[str] | None) -> argparse.Namespace:
    """The arguments, checked: ConfigError (one line, naming the option) on a bad one."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="the results folder")
    ap.add_argument("--frames", type=int, default=40, help="the first N evaluation frames (default 40)")
    ap.add_argument("--conditions", nargs="+", default=list(CONDITIONS), metavar="NAME")
    ap.add_argument(
        "--weights", nargs="+", type=float, default=None, help="default: optimum.smoothness_sweep"
    )
    ap.add_argument("--threads", type=int, default=2, help="torch threads (rounding differs with the count)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args(argv)
    if args.frames < 2:
        raise ConfigError(f"--frames: must be at least 2 (two folds of frames), got {args.frames}")
    unknown = [c for c in args.conditions if c not in CONDITIONS]
    if unknown:
        raise ConfigError(f"--conditions: unknown {unknown}; known: {list(CONDITIONS)}")
    if args.weights and not all(0 <= w <= MAX_WEIGHT for w in args.weights):  # NaN too
        raise ConfigError(f"--weights: each must be in [0, {MAX_WEIGHT:g}], got {args.weights}")
    if not 1 <= args.threads <= MAX_THREADS:
        raise ConfigError(f"--threads: must be in 1..{MAX_THREADS}, got {args.threads}")
    args.conditions = list(dict.fromkeys(args.conditions))
    return args


def main(argv: list[str] | None = None) -> int:
    import torch

    args = parse(argv)
    base = apply_overrides(read_params_file(ROOT / "params.yaml"), args.set)
    params = params_from_dict(base)
    weights = sorted(set(args.weights or params.optimum.smoothness_sweep))
    torch.set_num_threads(args.threads)
    out = args.out
    names = [f"scores_{c}.csv" for c in args.conditions] + ["screen.md", "summary.csv", "settings.json"]
    OutputPolicy(out, "camera-screen").claim([out / n for n in names], ROOT / "params.yaml")
    settings = json.dumps({"frames": args.frames, "weights": weights, "set": args.set}, indent=1)
    check_settings(out / "settings.json", settings)
    results = {}
    for name in args.conditions:
        path = out / f"scores_{name}.csv"
        scores = complete(path, args.frames, weights)
        if scores is None:
            clock = time.perf_counter()
            scores = run_condition(base, name, args, weights)
            write_text(path, scores.to_csv(index=False))
            print(f"{name}: done in {time.perf_counter() - clock:.0f} s", file=sys.stderr)
        else:
            print(f"{name}: complete in {path}, not run again", file=sys.stderr)
        results[name] = screen(scores, params)
    sections = [condition_table(n, r) for n, r in results.items()]
    write_text(out / "screen.md", "\n".join([summary_tables(results), *sections]))
    write_text(out / "summary.csv", summary_csv(results))
    print(summary_tables(results))
    return 0


def check_settings(path: Path, settings: str) -> None:
    """Record the run's settings in ``path``; ConfigError where the folder holds another run's, whose
    scores a resume would mix with this one's."""
    if path.is_file() and path.read_text() != settings:
        raise ConfigError(
            f"--out: {path.parent} holds a screen of other settings ({path}); choose another folder"
        )
    write_text(path, settings)


if __name__ == "__main__":
    sys.exit(run_main("studies/camera_screen.py", main))
