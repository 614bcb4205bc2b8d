"""The losses' own optimum per MS-SSIM kernel size, from committed runs and `dvc exp run` results.

Each REF is a git revision (a commit, a branch or an experiment's ref, ``dvc exp show`` lists
them) whose ``metrics/`` hold the optimum stages' results. The first REF's ``ssim`` optimum is the
reference: every MS-SSIM kernel's optimum is paired with it frame by frame (ROI by ROI for the
ROI columns) at the same smoothness weight, with a percentile-bootstrap interval over the frames
(ROIs). Prints a markdown report; the optimum has no training seed, so the intervals cover the
choice of frames only::

    dvc exp run -S msssim.kernel_size=7 optimum@msssim-10.0 optimum@msssim-3.0 optimum@msssim-30.0
    python studies/optimum_kernels.py HEAD exp-ref-k5 exp-ref-k7 > studies/results/optimum/kernels.md
"""

from __future__ import annotations

import argparse
import sys

from msdepth.data.kitti import ROI_CLASSES as CLASSES
from msdepth.errors import MsdepthError, run_main
from msdepth.reporting.revisions import CAP, optimum_run_at, optimum_settings_at, paired_cell


def rows_for(label: str, run: dict, ref: dict, what: str) -> tuple[str, str]:
    """A row of the absolute table and a row of the difference table for one run."""
    full, roi = run["full"], run["roi"]
    by_class = [roi[roi["class"] == c]["abs_rel"].mean() for c in CLASSES]
    absolute = (
        f"| {label} | {len(full)} | {full['abs_rel'].mean():.4f} | {full['a1'].mean():.4f} | "
        f"{roi['abs_rel'].mean():.4f} | "
        + " | ".join(f"{v:.4f}" for v in by_class)
        + f" | {run['masks']['overall']['abs_rel']:.4f} |"
    )
    cells = [paired_cell(full, ref["full"], ["frame"], what), paired_cell(roi, ref["roi"], ["roi"], what)]
    cells += [
        paired_cell(roi[roi["class"] == c], ref["roi"][ref["roi"]["class"] == c], ["roi"], f"{what} {c}")
        for c in CLASSES
    ]
    return absolute, f"| {label} | " + " | ".join(cells) + " |"


def report(refs: list[str]) -> str:
    """The markdown report over ``refs`` (the first one's ssim optimum is the reference)."""
    base = optimum_settings_at(refs[0])
    head = "| run | frames | abs_rel | a1 | ROI abs_rel | " + " | ".join(CLASSES) + " | mask abs_rel |"
    dhead = "| run | Δ abs_rel | Δ ROI abs_rel | " + " | ".join(f"Δ {c}" for c in CLASSES) + " |"
    lines = [f"Cap {CAP} m; ROI columns: box abs_rel, the mean over ROIs. Refs: {', '.join(refs)}.", ""]
    for weight in base["weights"]:
        w = f"{float(weight):.1f}"
        ref = optimum_run_at(refs[0], "ssim", w)
        absolute, diffs = [rows_for(f"ssim w{w}", ref, ref, "ssim")[0]], []
        for r in refs:
            s = optimum_settings_at(r)
            label = f"msssim k{s['kernel']} L{s['levels']} w{w}"
            a, d = rows_for(label, optimum_run_at(r, "msssim", w), ref, f"{r} {label}")
            absolute.append(a)
            diffs.append(d)
        lines += [f"## Smoothness weight {weight:g}", "", head, "|---" * 10 + "|", *absolute, ""]
        lines += [f"Paired with ssim w{w}:", "", dhead, "|---" * 7 + "|", *diffs, ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Print the report for the revisions on the command line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("refs", nargs="+", help="git revisions; the first one's ssim optimum is the reference")
    try:
        print(report(ap.parse_args(argv).refs))
    except MsdepthError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/optimum_kernels.py", main))
