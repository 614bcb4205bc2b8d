"""Global starts for the losses' own optimum (issue #38) on the real KITTI frames of
../shared/real-samples, against OpenCV's SGBM.

Per frame (KITTI 2015 training 000000_10 and 000001_10 against ``disp_occ_0``; KITTI 2012 training
000000_10 and 000001_10 against ``disp_occ`` and, separately, the reflective surfaces of
``disp_refl_occ``) and per method: abs_rel of depth (f = 721.5377 px, B = 0.54 m, predictions
capped at 80 m: a disparity below f·B/80 reads as 80 m; ``metrics.compute_errors`` on the GT pixels),
KITTI's D1 and end-point error (``metrics.stereo_errors``), the share of pixels that passed the
matcher's own checks before hole filling, and seconds. Methods: SGBM (``optimum.sgbm``); per
variant (ssim; msssim with kernel 3 and 7) the winner-take-all of its own cost volume
(``optimum.cost_volume``) and the semi-global start on it (``optimum.sgm``). All at full size,
D = 0.3·W (the network heads' range).

``--refine SIZE`` (``full``, ``half``, ``quarter`` or ``HxW``) adds, per variant, the variant's own
optimum (``optimum.solver.optimise``, the params' settings) at that working size from each start:
the constant (coarse to fine), its SGM result and SGBM's (refined at the finest level; the right
view warped from the left, ``optimum.starts``), brought to full size (bilinear on the disparity as
a fraction of width) and scored there; its seconds are the optimisation's alone (the start's are
in the start's row). KITTI 2012's reflective pixels (``disp_refl_occ``) and the rest (``disp_occ``)
are then also compared per method (abs_rel and D1, reflective minus the rest). Prints markdown::

    python studies/optimum_starts.py --out studies/results/optimum/starts.md
    python studies/optimum_starts.py --refine half --out studies/results/optimum/starts_refined.md
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from msdepth.data.kitti import read_disparity, read_image
from msdepth.data.pairs import resize, to_tensor
from msdepth.errors import run_main
from msdepth.io import write_text
from msdepth.optimum.cost_volume import cost_volume, matching_cost, winner_take_all
from msdepth.optimum.sgbm import sgbm_disparity
from msdepth.optimum.sgm import SGMConfig, sgm
from msdepth.optimum.solver import disparity_pyramid, objective, optimise, working_weight
from msdepth.optimum.starts import both_views
from msdepth.outputs import claim_output_file
from msdepth.studies.real_samples import Result, samples_dir, scores, variants_of, working_size

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = samples_dir(ROOT)
SETS = (
    ("2015", "kitti2015-training", "image_2", "image_3", ("disp_occ_0",)),
    ("2012", "kitti2012-training", "colored_0", "colored_1", ("disp_occ", "disp_refl_occ")),
)
FRAMES = ("000000_10", "000001_10")


def run_frame(
    left: np.ndarray, right: np.ndarray, variants: dict, timings: dict, size: tuple[int, int] | None = None
) -> list[Result]:
    """Every method on one pair (``variants``: label -> (name, params)), and with a working ``size``
    each variant's optimum from each start; ``timings`` collects the seconds of each part per method."""
    start = time.perf_counter()
    sgbm_result = Result("SGBM", *sgbm_disparity(left, right), time.perf_counter() - start)
    out = [sgbm_result]
    timings.setdefault("SGBM", []).append(out[0].seconds)
    left_t, right_t = to_tensor(left), to_tensor(right)
    for label, (name, params) in variants.items():
        start = time.perf_counter()
        volume = cost_volume(left_t, right_t, matching_cost(params, name))
        built = time.perf_counter() - start
        wta = winner_take_all(volume).numpy()
        out.append(Result(f"{label} WTA", wta, np.ones(wta.shape, dtype=bool), built))
        start = time.perf_counter()
        disparity, valid = sgm(volume, SGMConfig())
        matched = time.perf_counter() - start
        out.append(Result(f"{label} SGM", disparity, valid, built + matched))
        timings.setdefault(f"{label} volume", []).append(built)
        timings.setdefault(f"{label} SGM", []).append(matched)
        del volume
        if size is not None:
            starts = {"constant": None, "SGM": disparity, "SGBM": sgbm_result.disparity}
            out += refined(left, right, (label, name, params), starts, size, timings)
    return out


def refined(
    left: np.ndarray, right: np.ndarray, variant: tuple, starts: dict, size: tuple[int, int], timings: dict
) -> list[Result]:
    """``variant`` ((label, name, params))'s optimum at the working ``size`` from each start (label ->
    the left disparity in px at full size, or None for the constant), at full size in px."""
    label, name, params = variant
    criterion = objective(params, name, working_weight(params, size[1]))
    pair = [to_tensor(resize(x, *size))[None] for x in (left, right)]
    height, width = left.shape[:2]
    out = []
    for start_label, disparity in starts.items():
        began = time.perf_counter()
        init = None if disparity is None else torch.from_numpy(both_views(disparity, size))[None]
        disp = optimise(*pair, criterion, params.optimum, start=init)
        seconds = time.perf_counter() - began
        with torch.no_grad():
            loss = float(criterion(disparity_pyramid(disp), *pair)["total"])
        full = cv2.resize(disp[0, 0].numpy(), (width, height), interpolation=cv2.INTER_LINEAR) * width
        method = f"{label} optimum from {start_label}"
        out.append(Result(method, full, np.ones(full.shape, dtype=bool), seconds, loss))
        timings.setdefault(method, []).append(seconds)
    return out


def table(rows: list[tuple[str, str, str, dict, float]]) -> list[str]:
    """The markdown table of ``(frame, GT, method, scores, seconds)`` rows."""
    lines = [
        "| frame | GT | method | abs_rel | D1 % | EPE px | valid % | s | loss |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for frame, gt, method, s, seconds in rows:
        loss = "" if s.get("loss") is None else f"{s['loss']:.5f}"
        lines.append(
            f"| {frame} | {gt} | {method} | {s['abs_rel']:.3f} | {s['d1']:.1f} | {s['epe']:.2f} | "
            f"{s['valid']:.0f} | {seconds:.1f} | {loss} |"
        )
    return lines


def class_table(rows: list[tuple[str, str, str, dict, float]]) -> list[str]:
    """Per KITTI 2012 frame and method: abs_rel and D1 on the reflective pixels (``disp_refl_occ``),
    on the rest (``disp_occ``), and the difference (reflective minus the rest)."""
    by_key = {(frame, gt, method): s for frame, gt, method, s, _ in rows}
    lines = [
        "| frame | method | abs_rel refl | abs_rel rest | diff | D1 % refl | D1 % rest | diff |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for (frame, gt, method), refl in by_key.items():
        rest = by_key.get((frame, "disp_occ", method))
        if gt != "disp_refl_occ" or rest is None:
            continue
        lines.append(
            f"| {frame} | {method} | {refl['abs_rel']:.3f} | {rest['abs_rel']:.3f} | "
            f"{refl['abs_rel'] - rest['abs_rel']:+.3f} | {refl['d1']:.1f} | {rest['d1']:.1f} | "
            f"{refl['d1'] - rest['d1']:+.1f} |"
        )
    return lines


def header(loads: tuple[tuple[float, ...], tuple[float, ...]], size: str | None) -> list[str]:
    """The table's title and how it was made (the machine's load: timings depend on it)."""
    (start, end), threads = loads, torch.get_num_threads()
    command = " ".join(sys.argv[1:])
    refine = (
        f" Optimum rows: the variant's optimum at the working size `{size}` from each start "
        "(`--refine`; its s is the optimisation's alone; loss: the objective there), scored at full size."
        if size
        else ""
    )
    return [
        "# Global starts for the losses' own optimum on real KITTI frames (issue #38)",
        "",
        f"`python studies/optimum_starts.py {command}` "
        "(its docstring says what each column is). Matched at full size, D = 0.3·W; "
        f"SGM with its defaults (8 paths, p1 0.25, p2 4). Torch threads: {threads}; load average "
        f"{start[0]:.1f} at the start, {end[0]:.1f} at the end "
        "(seconds are indicative: 2 shared AMD EPYC cores). "
        "WTA: the cost volume's winner-take-all, no check (valid 100 %). s: SGBM's own; WTA's is building "
        "the volume, SGM's the volume and SGM. abs_rel: depth with f = 721.5377 px, B = 0.54 m, "
        f"capped at 80 m.{refine}",
        "",
    ]


def main(argv: list[str] | None = None) -> int:
    """Score every method on every frame; print the markdown and write it to ``--out``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=Path, default=SAMPLES, help="the real-samples folder")
    parser.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    parser.add_argument("--refine", help="also each variant's optimum from each start at this working size")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a params override")
    parser.add_argument("--out", type=Path, help="also write the markdown here")
    args = parser.parse_args(argv)
    if not claim_output_file(args.out, "optimum-starts", args.samples):  # before the work
        return 1
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))
    variants, timings, rows = variants_of(args.params, args.set), {}, []
    load_before = os.getloadavg()
    for label, folder, left_dir, right_dir, gts in SETS:
        base = args.samples / folder
        for frame in FRAMES:
            left, right = (read_image(base / d / f"{frame}.png") for d in (left_dir, right_dir))
            size = working_size(args.refine, left.shape)
            results = run_frame(left, right, variants, timings, size)
            for gt_dir in gts:
                gt = read_disparity(base / gt_dir / f"{frame}.png")
                rows += [(f"{label} {frame}", gt_dir, r.method, scores(gt, r), r.seconds) for r in results]
            print(f"{label} {frame} done", flush=True)
    loads = (load_before, os.getloadavg())
    lines = header(loads, args.refine) + table(rows) + ["", "| part | s per pair (mean) |", "|---|---|"]
    lines += [f"| {part} | {np.mean(values):.2f} |" for part, values in timings.items()]
    if args.refine:
        lines += ["", "KITTI 2012: reflective pixels (disp_refl_occ) against the rest (disp_occ).", ""]
        lines += class_table(rows)
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        write_text(args.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/optimum_starts.py", main))
