"""The default run before and after a renderer change, from two git revisions' ``metrics/``.

Written for the glass model (docs/glass.md): a change that keeps every non-glass pixel, the GT,
the class maps and the ROI boxes, so each frame and each ROI is the same unit in both revisions
and the differences are paired (after - before, percentile-bootstrap 95 % interval, ``*`` where
it excludes 0). Two parts:

- the losses' own optimum (no network; one per variant and smoothness weight);
- the trained networks, paired by frame (ROI) and seed: retraining changes the networks, so
  these intervals hold the change of data and the training noise together.

::

    python studies/glass_before_after.py 23fb0b9 HEAD > studies/results/glass/before_after.md
"""

from __future__ import annotations

import argparse
import io
import json
import sys

import pandas as pd

from msdepth.data.kitti import ROI_CLASSES as CLASSES
from msdepth.errors import MsdepthError, run_main
from msdepth.reporting.revisions import CAP, optimum_run_at, optimum_settings_at, paired_cell, show

HEAD = "| run | frames | abs_rel | a1 | ROI abs_rel | " + " | ".join(CLASSES) + " | mask abs_rel |"
DHEAD = "| after − before | Δ abs_rel | Δ ROI abs_rel | " + " | ".join(f"Δ {c}" for c in CLASSES) + " |"


def absolute_row(label: str, run: dict) -> str:
    """One row of the absolute table: frame and ROI means, per class, and the masks' abs_rel."""
    full, roi = run["full"], run["roi"]
    by_class = [roi[roi["class"] == c]["abs_rel"].mean() for c in CLASSES]
    return (
        f"| {label} | {full['frame'].nunique()} | {full['abs_rel'].mean():.4f} | {full['a1'].mean():.4f} | "
        f"{roi['abs_rel'].mean():.4f} | "
        + " | ".join(f"{v:.4f}" for v in by_class)
        + f" | {run['masks']['overall']['abs_rel']:.4f} |"
    )


def diff_row(label: str, after: dict, before: dict, keys: list[str]) -> str:
    """One row of the paired differences, after - before, on the full frames, the ROIs and per class."""
    full_keys, roi_keys = ["frame", *keys], ["roi", *keys]
    a_roi, b_roi = after["roi"], before["roi"]
    cells = [
        paired_cell(after["full"], before["full"], full_keys, label),
        paired_cell(a_roi, b_roi, roi_keys, label),
    ]
    cells += [
        paired_cell(a_roi[a_roi["class"] == c], b_roi[b_roi["class"] == c], roi_keys, f"{label} {c}")
        for c in CLASSES
    ]
    return f"| {label} | " + " | ".join(cells) + " |"


def trained_at(ref: str, variant: str) -> dict:
    """Every seed's evaluation of ``variant`` at ``ref``, stacked with a ``seed`` column."""
    seeds = json.loads(show(ref, "metrics/compare.json"))["seeds"]
    full, roi, masks = [], [], []
    for seed in seeds:
        stem = f"{variant}/seed{seed}"
        full.append(pd.read_csv(io.StringIO(show(ref, f"metrics/full/{stem}.csv"))).assign(seed=seed))
        roi.append(pd.read_csv(io.StringIO(show(ref, f"metrics/roi/{stem}.csv"))).assign(seed=seed))
        masks.append(
            json.loads(show(ref, f"metrics/roi/{stem}.json"))["masks"][f"cap{CAP}"]["overall"]["abs_rel"]
        )
    full, roi = pd.concat(full), pd.concat(roi)
    return {
        "full": full[full["cap"] == CAP],
        "roi": roi[roi["cap"] == CAP],
        "masks": {"overall": {"abs_rel": sum(masks) / len(masks)}},
        "seeds": seeds,
    }


def section(title: str, pairs: list[tuple[str, dict, dict]], keys: list[str]) -> list[str]:
    """A titled absolute table (before and after rows) and its paired-difference table."""
    absolute, diffs = [], []
    for label, before, after in pairs:
        absolute += [absolute_row(f"{label} before", before), absolute_row(f"{label} after", after)]
        diffs.append(diff_row(label, after, before, keys))
    return [f"## {title}", "", HEAD, "|---" * 10 + "|", *absolute, "", DHEAD, "|---" * 7 + "|", *diffs, ""]


def report(before: str, after: str) -> str:
    """The markdown report: the optimum per variant and weight, then the trained networks."""
    weights = optimum_settings_at(after)["weights"]
    lines = [
        f"Before: {before}; after: {after}. Cap {CAP} m; ROI columns: box abs_rel, the mean over ROIs; "
        "mask abs_rel: the exact-mask suite's. Δ: after − before, paired, mean [95 % interval], "
        "* where it excludes 0.",
        "",
    ]
    pairs = []
    for variant in ("ssim", "msssim"):
        for weight in weights:
            w = f"{float(weight):.1f}"
            runs = optimum_run_at(before, variant, w), optimum_run_at(after, variant, w)
            pairs.append((f"optimum {variant} w{w}", *runs))
    lines += section("The losses' optimum (no network)", pairs, [])
    variants = json.loads(show(after, "metrics/compare.json"))["variants"]
    nets = [(f"{v} (seeds)", trained_at(before, v), trained_at(after, v)) for v in variants]
    lines += section("The trained networks (mean over seeds)", nets, ["seed"])
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Print the report for the two revisions on the command line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", help="git revision of the run before the change")
    ap.add_argument("after", help="git revision of the run after it")
    args = ap.parse_args(argv)
    try:
        print(report(args.before, args.after))
    except MsdepthError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/glass_before_after.py", main))
