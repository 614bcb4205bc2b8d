"""How many seeds would a verdict at the observed MS-SSIM − SSIM differences need, paired by seed?

From committed runs only: each variant's per-seed abs_rel at the headline cap on the full frame,
over all ROIs and per ROI class (``metrics/``), or with ``--compare`` a ``compare.json``'s
``seed_spread``. Seed ``s`` of both losses is a pair: δ is the mean of the per-seed differences,
σ_d their sd; the pairs needed for 80 % power (two-sided 5 % paired t), the power as run and the
smallest detectable difference come from :mod:`msdepth.stats`, the unpaired size beside them::

    python studies/power.py --out studies/results/power.md
    python studies/power.py --compare studies/results/seeds12/compare.json \\
        --out studies/results/seeds12/power.md
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from msdepth.errors import MsdepthError, run_main
from msdepth.evaluation.results import load_suite_metrics
from msdepth.io import write_text
from msdepth.outputs import claim_output_file
from msdepth.pipeline.paths import METRICS, run_name
from msdepth.readers import read_json_object
from msdepth.reporting.report import Results, load_results
from msdepth.reporting.verdict import signed
from msdepth.stats import detectable_difference, paired_t, pooled_sd, power_at, seeds_needed

ALPHA, POWER = 0.05, 0.8
CAP_SEEDS = 12  # issue 39's ceiling on extra stereo seeds
METRIC = "abs_rel"


def per_seed(results: Results, variant: str, metrics_root: Path) -> dict[str, list[float]]:
    """``{row: [value per seed]}`` of one variant: full frame, all ROIs, each ROI class."""
    runs = [run_name(variant, s) for s in results.seeds]
    suites = load_suite_metrics(metrics_root, runs, ("full", "roi"))
    cap = results.cap
    rows = {
        "full frame": [suites["full"][r][cap][METRIC] for r in runs],
        "all ROIs": [suites["roi"][r][cap]["overall"][METRIC] for r in runs],
    }
    for cls in results.classes():
        rows[cls] = [suites["roi"][r][cap]["by_class"][cls][METRIC] for r in runs]
    return rows


def per_seed_from_compare(data: dict, variant: str, cap: str) -> dict[str, list[float]]:
    """``{row: [value per seed]}`` from a compare.json's ``seed_spread`` (full frame, all ROIs), the
    runs in seed order."""
    rows = {}
    for suite, row in (("full", "full frame"), ("roi", "all ROIs")):
        runs = data["seed_spread"][suite][cap][variant][METRIC]["runs"]
        rows[row] = [runs[r] for r in sorted(runs, key=lambda r: int(r.rsplit("seed", 1)[1]))]
    return rows


def _size(n: float) -> str:
    return "∞" if math.isinf(n) else str(int(n))


HEADER = (
    "| class | {ref} | {var} | δ [95 % paired t] | σ_d (pairs) | r | pairs needed (t) | power at {n} "
    "| at {cap} "
    "| smallest δ at {n} | σ unpaired | n unpaired (t) |"
)


def table(labels: tuple[str, str], ours: dict, theirs: dict) -> list[str]:
    """The markdown table of one variant (``ours``) against the reference (``theirs``), one row per
    class, each ``{row: [value per seed]}`` over the same seeds in the same order."""
    seeds = len(next(iter(ours.values())))
    later = CAP_SEEDS if seeds < CAP_SEEDS else 2 * seeds  # the power a larger study would have
    lines = [HEADER.format(ref=labels[1], var=labels[0], n=seeds, cap=later), "|---" * 12 + "|"]
    needs: dict[str, float] = {}
    for row, values in ours.items():
        a, b = np.array(theirs[row]), np.array(values)
        d = b - a
        delta, sd_d, sd = float(d.mean()), float(d.std(ddof=1)), pooled_sd(list(a), list(b))
        r = float(np.corrcoef(a, b)[0, 1]) if a.std() > 0 and b.std() > 0 else float("nan")
        n_t = needs[row] = seeds_needed(delta, sd_d, ALPHA, POWER, paired=True)
        powers = [power_at(n, delta, sd_d, ALPHA, paired=True) for n in (seeds, later)]
        smallest = detectable_difference(seeds, sd_d, ALPHA, POWER, paired=True)
        _, low, high = paired_t(d)
        star = " *" if low > 0 or high < 0 else ""
        interval = f"{signed(delta, 4)} [{signed(low, 4)}, {signed(high, 4)}]{star}"
        lines.append(
            f"| {row} | {a.mean():.4f} | {b.mean():.4f} | {interval} | {sd_d:.4f} | {r:.2f} | "
            f"{_size(n_t)} | {powers[0]:.2f} | {powers[1]:.2f} | {smallest:.4f} | {sd:.4f} | "
            f"{_size(seeds_needed(delta, sd, ALPHA, POWER))} |"
        )
    return lines + ["", summary(needs)]


def summary(needs: dict[str, float]) -> str:
    """One sentence: which rows a study of up to CAP_SEEDS seed pairs could decide."""
    within = [row for row, n in needs.items() if n <= CAP_SEEDS]
    least = min(needs, key=needs.get)
    if within:
        return f"Within {CAP_SEEDS} seed pairs, 80 % power is reached for: {', '.join(within)}."
    return (
        f"No row reaches 80 % power within {CAP_SEEDS} seed pairs at the observed difference; "
        f"the fewest are needed for {least} ({_size(needs[least])} pairs)."
    )


def preamble(source: str, seeds: str, cap_m: str, reference: str) -> list[str]:
    """The study's opening paragraph: where the numbers come from and what each column is."""
    return [
        "# Seeds a verdict needs, paired by seed",
        "",
        f"Generated by `studies/power.py` from {source}: {METRIC} at cap {cap_m} m, seeds {seeds}. "
        "Both losses train with the same seeds (the same initial weights and data order), so seed s "
        f"of each is a pair. δ: the mean over seeds of the variant's value minus {reference}'s "
        "(negative: lower error), with the 95 % paired t interval over the seed pairs (`*`: it excludes "
        "0); σ_d: the standard deviation of those per-seed differences; r: the "
        "two variants' correlation over seeds. Pairs needed: for a two-sided paired t-test at "
        f"{ALPHA * 100:g} % with {POWER * 100:g} % power (`msdepth.stats`: "
        "n = (z₀.₉₇₅ + z₀.₈)²σ_d²/δ², then the smallest n whose noncentral-t power reaches 80 %, "
        "df = n − 1). Smallest δ: the difference the seeds as run detect with 80 % power. σ and n "
        "unpaired: the two-sample test that ignores the pairing, for comparison. With few seeds σ_d "
        "rests on few degrees of freedom: the sizes are a rough guide.",
    ]


def report(root: Path, compare: Path | None = None) -> str:
    """The study's markdown, for every variant against the comparison's reference: from the
    committed metrics below ``root``, or from ``compare`` (a compare.json) where given."""
    if compare is not None:
        data = read_json_object(compare, "comparison", "a compare.json of the compare stage")
        reference = data["statistics"]["reference"]
        cap = next(iter(data["seed_spread"]["full"]))  # the headline cap comes first
        variants = [v for v in data["variants"] if v != reference]
        seeds = ", ".join(map(str, data["seeds"]))
        source = f"`{compare.as_posix()}` (its per-seed values: full frame and all ROIs)"
        lines = preamble(source, seeds, cap[3:], reference)
        for variant in variants:
            ours = per_seed_from_compare(data, variant, cap)
            theirs = per_seed_from_compare(data, reference, cap)
            lines += ["", f"## {variant} vs {reference}", "", *table((variant, reference), ours, theirs)]
        return "\n".join(lines) + "\n"
    results = load_results(root)
    reference = results.reference or results.variants[0]
    source = "the committed runs (`metrics/compare.json`, `metrics/full/`, `metrics/roi/`)"
    lines = preamble(source, ", ".join(map(str, results.seeds)), results.cap_m, results.label(reference))
    for variant in results.variants:
        if variant != reference:
            labels = (results.label(variant), results.label(reference))
            ours = per_seed(results, variant, root / METRICS)
            theirs = per_seed(results, reference, root / METRICS)
            lines += ["", f"## {labels[0]} vs {labels[1]}", "", *table(labels, ours, theirs)]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("."), help="the project folder (committed metrics)")
    ap.add_argument("--compare", type=Path, help="a compare.json to read the per-seed values from")
    ap.add_argument("--out", type=Path, help="the markdown table (printed if not given)")
    args = ap.parse_args(argv)
    if not claim_output_file(args.out, "power", args.compare or args.root / METRICS):  # before the work
        return 1
    try:
        text = report(args.root, args.compare)
    except MsdepthError as exc:  # e.g. --root without the committed metrics: one line, no traceback
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyError as exc:
        where = args.compare or args.root
        print(f"error: {where}: not the per-seed values this study reads ({exc})", file=sys.stderr)
        return 1
    if args.out:
        write_text(args.out, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/power.py", main))
