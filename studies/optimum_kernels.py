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
import io
import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from msdepth.reporting.stats import paired_bootstrap, paired_table  # noqa: E402

CAP = 80
CLASSES = ("car", "windshield", "glass", "sign")


def show(ref: str, path: str) -> str:
    """The text of ``path`` at git revision ``ref`` of the repository in the current folder."""
    out = subprocess.run(["git", "show", f"{ref}:{path}"], capture_output=True, text=True)
    if out.returncode:
        raise SystemExit(f"error: {ref}:{path}: {out.stderr.strip()}")
    return out.stdout


def run_at(ref: str, variant: str, weight: str) -> dict:
    """One optimum run at ``ref``: its per-frame and per-ROI tables and the masks' abs_rel."""
    stem = f"optimum/{variant}/w{weight}"
    full = pd.read_csv(io.StringIO(show(ref, f"metrics/full/{stem}.csv")))
    roi = pd.read_csv(io.StringIO(show(ref, f"metrics/roi/{stem}.csv")))
    masks = json.loads(show(ref, f"metrics/roi/{stem}.json"))["masks"][f"cap{CAP}"]
    return {"full": full[full["cap"] == CAP], "roi": roi[roi["cap"] == CAP], "masks": masks}


def settings_at(ref: str) -> dict:
    """The optimum's weights and the MS-SSIM settings in ``ref``'s params.yaml."""
    params = yaml.safe_load(show(ref, "params.yaml"))
    weights = sorted({params["optimum"]["smoothness_weight"], *params["optimum"]["smoothness_sweep"]})
    return {
        "kernel": params["msssim"]["kernel_size"],
        "levels": params["msssim"]["levels"],
        "weights": weights,
    }


def diff_cell(run: pd.DataFrame, ref: pd.DataFrame, keys: list[str], what: str) -> str:
    """``mean(run - ref)`` of abs_rel over paired units with its 95 % interval (``*``: excludes 0)."""
    if run.empty:
        return "–"
    a, b = paired_table(run, ref, keys, "abs_rel", what)
    d = paired_bootstrap(a, b)
    return f"{d.mean:+.3f} [{d.low:+.3f}, {d.high:+.3f}]{' *' if d.excludes_zero else ''}"


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
    cells = [diff_cell(full, ref["full"], ["frame"], what), diff_cell(roi, ref["roi"], ["roi"], what)]
    cells += [
        diff_cell(roi[roi["class"] == c], ref["roi"][ref["roi"]["class"] == c], ["roi"], f"{what} {c}")
        for c in CLASSES
    ]
    return absolute, f"| {label} | " + " | ".join(cells) + " |"


def report(refs: list[str]) -> str:
    """The markdown report over ``refs`` (the first one's ssim optimum is the reference)."""
    base = settings_at(refs[0])
    head = "| run | frames | abs_rel | a1 | ROI abs_rel | " + " | ".join(CLASSES) + " | mask abs_rel |"
    dhead = "| run | Δ abs_rel | Δ ROI abs_rel | " + " | ".join(f"Δ {c}" for c in CLASSES) + " |"
    lines = [f"Cap {CAP} m; ROI columns: box abs_rel, the mean over ROIs. Refs: {', '.join(refs)}.", ""]
    for weight in base["weights"]:
        w = f"{float(weight):.1f}"
        ref = run_at(refs[0], "ssim", w)
        absolute, diffs = [rows_for(f"ssim w{w}", ref, ref, "ssim")[0]], []
        for r in refs:
            s = settings_at(r)
            label = f"msssim k{s['kernel']} L{s['levels']} w{w}"
            a, d = rows_for(label, run_at(r, "msssim", w), ref, f"{r} {label}")
            absolute.append(a)
            diffs.append(d)
        lines += [f"## Smoothness weight {weight:g}", "", head, "|---" * 10 + "|", *absolute, ""]
        lines += [f"Paired with ssim w{w}:", "", dhead, "|---" * 7 + "|", *diffs, ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Print the report for the revisions on the command line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("refs", nargs="+", help="git revisions; the first one's ssim optimum is the reference")
    print(report(ap.parse_args(argv).refs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
