"""Does every run learn from the image? Train variants x seeds, evaluate each, print the spread.

Issue 17's instrument: per loss variant (SSIM, MS-SSIM at several kernel sizes) and seed, train
with the pipeline's own code, predict the evaluation frames and report full-image and ROI abs_rel
(cap 80), image dependence, whether the loss fell within the first epoch, and the per-pixel
prior's abs_rel. Runs are independent processes (``--jobs``), kept in ``--out`` (resumable);
``--set key=value`` overrides a param for every run. From the repository root after ``dvc repro
cache rois baselines``::

    python studies/learning.py --variants ssim msssim:3 msssim:5 msssim:7 msssim:11 \\
        --seeds 0 1 2 3 4 --out studies/results/default --jobs 2
    python studies/learning.py ... --set model.norm=none --set train.warmup_steps=0
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from msdepth.config.params import Params, apply_overrides, kernel_variant, params_from_dict, read_params_file
from msdepth.data import kitti
from msdepth.data.eval_index import read_eval_index
from msdepth.data.pairs import build_pair_cache, load_pair_cache, load_pair_list
from msdepth.errors import DataError, OutputError, run_main
from msdepth.evaluation import baselines
from msdepth.evaluation.suites import depth_maps, evaluate_full, evaluate_roi, image_dependence, load_frames
from msdepth.io import write_text
from msdepth.outputs import OutputPolicy

INDEX = Path("data/index")


def _params_for(base: dict, spec: str, threads: int) -> tuple[Params, str]:
    """Params for a variant spec ``ssim`` / ``msssim`` / ``msssim:K`` (MS-SSIM with kernel K)."""
    variant, raw = kernel_variant(base, spec)
    raw.setdefault("train", {})["threads"] = threads
    return params_from_dict(raw), variant


def run_name(spec: str, seed: int) -> str:
    """The name of one run's result ``<name>.json`` and work folder ``work/<name>``."""
    return f"{spec.replace(':', '_k')}_seed{seed}"


def cache_path(params: Params, out: Path) -> Path:
    """The study's own pair cache, built where the pipeline's is of another input size."""
    return out / f"cache_{params.data.height}x{params.data.width}.npy"


def claim_outputs(out: Path, base: dict, jobs: list[tuple[str, int]]) -> OutputPolicy:
    """Claim every file the study may write under ``out`` (manifest ``out/.msdepth-learning``) before
    any run starts: an OutputError names the first that exists and was not written by the study."""
    paths = [out / "overrides.json", out / "summary.md", out / "curves.png"]
    paths += sorted({cache_path(_params_for(base, spec, 1)[0], out) for spec, _ in jobs})
    for spec, seed in jobs:
        name = run_name(spec, seed)
        paths += [out / f"{name}.json", out / "work" / name / "model.pt", out / "work" / name / "ck.pt"]
    policy = OutputPolicy(out, "learning")
    policy.claim(paths, "params.yaml")
    return policy


def _pairs_and_cache(params: Params, out: Path) -> tuple[list, np.ndarray]:
    """The training pairs and their decoded cache: the pipeline's, or the study's own at its size."""
    pairs = load_pair_list("data/cache/train_pairs.txt")
    h, w = params.data.height, params.data.width
    try:
        return pairs, load_pair_cache("data/cache/train_pairs.npy", len(pairs), h, w)
    except Exception:  # another input size than the pipeline's cache: build one for the study
        path = cache_path(params, out)
        if not path.exists():
            build_pair_cache(pairs, h, w, path, progress=False)
        return pairs, load_pair_cache(path, len(pairs), h, w)


@dataclasses.dataclass(frozen=True)
class EvalSet:
    """The evaluation frames (with their GT), their left images and the ROI boxes."""

    frames: list
    images: list[Path]
    boxes: pd.DataFrame


def load_eval_set() -> EvalSet:
    """The pipeline's evaluation index, frames and ROIs (from ``data/index``)."""
    index = read_eval_index(INDEX / "eval_frames.csv")
    frames = load_frames(index)
    return EvalSet(frames, [Path(p) for p in index["left"]], kitti.read_rois(INDEX / "rois.csv"))


def _scores(pred: dict, ev: EvalSet, params: Params) -> tuple[dict, pd.DataFrame, dict]:
    """The full-image summary and per-image table, and the ROI summary, of the depth maps ``pred``."""
    full, table = evaluate_full(pred, ev.frames, params.eval)
    roi, _ = evaluate_roi(pred, ev.frames, ev.boxes, params.eval)
    return full, table, roi


def _roi_cap80(roi: dict) -> dict:
    """The ROI abs_rel at cap 80, overall and per class."""
    return {
        "roi_abs_rel": roi["cap80"]["overall"]["abs_rel"],
        "roi_by_class": {c: v["abs_rel"] for c, v in roi["cap80"]["by_class"].items()},
    }


def _epoch_recorder(params: Params, ev: EvalSet, history: list[dict]) -> Callable:
    """``train_variant``'s ``on_epoch``: evaluates the model after every epoch into ``history``."""
    from msdepth.evaluation.infer import predict_disparities

    def on_epoch(epoch: int, model, means: dict) -> None:
        # Plain predictions (no flip post-processing) after every epoch: the learning curve in abs_rel.
        disp = predict_disparities(
            model, ev.images, params.data.height, params.data.width, False, progress=False
        )
        pred = depth_maps(disp, ev.frames)
        full, _, roi = _scores(pred, ev, params)
        model.train()
        history.append(
            {
                "epoch": epoch,
                **means,
                "abs_rel": full["cap80"]["abs_rel"],
                **_roi_cap80(roi),
                "variation_ratio": image_dependence(pred, ev.frames, 80.0)["variation_ratio"],
            }
        )

    return on_epoch


def _final_depth(model_path: Path, params: Params, ev: EvalSet, threads: int) -> dict:
    """The trained model's depth maps of the evaluation frames, as the pipeline predicts them."""
    import torch

    from msdepth.evaluation.infer import predict_disparities
    from msdepth.training.train import load_model

    torch.set_num_threads(threads)
    model, meta = load_model(model_path)
    disp = predict_disparities(
        model, ev.images, meta["height"], meta["width"], params.eval.post_process, progress=False
    )
    return depth_maps(disp, ev.frames)


def run_one(base: dict, spec: str, seed: int, out: str, threads: int) -> dict:
    """Train and evaluate one (variant spec, seed); the result is also written to ``out``."""
    from msdepth.training.train import TrainOptions, TrainOutputs, train_variant

    out_dir = Path(out)
    name = run_name(spec, seed)
    result_path = out_dir / f"{name}.json"
    if result_path.exists():
        return json.loads(result_path.read_text())
    params, variant = _params_for(base, spec, threads)
    params = dataclasses.replace(params, train=dataclasses.replace(params.train, seeds=(seed,)))
    pairs, cache = _pairs_and_cache(params, out_dir)
    work = out_dir / "work" / name
    ev = load_eval_set()
    history: list[dict] = []
    # The curve comes from this run's epochs only: never resume a half-finished run.
    (work / "ck.pt").unlink(missing_ok=True)
    started = time.perf_counter()
    result = train_variant(
        params,
        variant,
        pairs,
        TrainOutputs(work / "model.pt", work / "ck.pt"),
        TrainOptions(progress=False, cache=cache, seed=seed, on_epoch=_epoch_recorder(params, ev, history)),
    )
    seconds = time.perf_counter() - started
    pred = _final_depth(work / "model.pt", params, ev, threads)
    full, table, roi = _scores(pred, ev, params)
    row = {
        "per_image_abs_rel": table[table["cap"] == 80]["abs_rel"].tolist(),
        "spec": spec,
        "seed": seed,
        "seconds": seconds,
        "steps": result.steps,
        "abs_rel": full["cap80"]["abs_rel"],
        "a1": full["cap80"]["a1"],
        "rmse": full["cap80"]["rmse"],
        **_roi_cap80(roi),
        "image_dependence": image_dependence(pred, ev.frames, params.eval.caps[0]),
        "history": history,
    }
    write_text(result_path, json.dumps(row, indent=1))
    return row


def prior_metrics(params: Params) -> dict:
    """The image-blind per-pixel prior's abs_rel (full and ROI, cap 80) on the evaluation frames."""
    pairs = load_pair_list(INDEX / "train_pairs.txt")
    gt = baselines.training_gt([left for left, _ in pairs], progress=False).maps
    if gt is None:
        raise DataError(f"{INDEX / 'train_pairs.txt'}: no training frame has GT (disp_02 or a Velodyne scan)")
    frames = load_frames(read_eval_index(INDEX / "eval_frames.csv"))
    boxes = kitti.read_rois(INDEX / "rois.csv")
    out = {}
    for name, disp in baselines.baseline_disparities(gt, len(frames)).items():
        pred = depth_maps(disp, frames)
        full, table = evaluate_full(pred, frames, params.eval)
        roi, _ = evaluate_roi(pred, frames, boxes, params.eval)
        out[name] = {
            "per_image_abs_rel": table[table["cap"] == 80]["abs_rel"].tolist(),
            "abs_rel": full["cap80"]["abs_rel"],
            **_roi_cap80(roi),
        }
    return out


# Epoch-1 image variation above which a run counts as learning from the image in its first epoch:
# the dead starts of the dissertation's network measured 0.003-0.035 after one or two epochs.
EARLY_VARIATION = 0.15


def _learned_early(history: list[dict]) -> bool:
    """After the first epoch the predictions already change with the image."""
    return history[0]["variation_ratio"] >= EARLY_VARIATION


def summarise(rows: list[dict], prior: dict) -> str:
    lines = [
        f"prior abs_rel {prior['prior']['abs_rel']:.4f}, ROI {prior['prior']['roi_abs_rel']:.4f}; "
        f"constant {prior['constant']['abs_rel']:.4f}, ROI {prior['constant']['roi_abs_rel']:.4f}",
        "",
        "| variant | seed | abs_rel | ROI abs_rel | image dependence | corr. with prior "
        "| epoch 1: abs_rel, dependence | s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(rows, key=lambda r: (r["spec"], r["seed"])):
        dep = r["image_dependence"]
        lines.append(
            f"| {r['spec']} | {r['seed']} | {r['abs_rel']:.4f} | {r['roi_abs_rel']:.4f} | "
            f"{dep['variation_ratio']:.3f} | {r.get('prior_correlation', float('nan')):.3f} | "
            f"{r['history'][0]['abs_rel']:.3f}, {r['history'][0]['variation_ratio']:.2f}"
            f"{'' if _learned_early(r['history']) else ' (dead start)'} | {r['seconds']:.0f} |"
        )
    lines += [
        "",
        "| variant | runs | abs_rel mean ± sd | ROI abs_rel mean ± sd | worst abs_rel |",
        "|---|---|---|---|---|",
    ]
    for spec in sorted({r["spec"] for r in rows}):
        a = np.array([r["abs_rel"] for r in rows if r["spec"] == spec])
        b = np.array([r["roi_abs_rel"] for r in rows if r["spec"] == spec])
        sd = lambda x: x.std(ddof=1) if len(x) > 1 else float("nan")  # noqa: E731
        lines.append(
            f"| {spec} | {len(a)} | {a.mean():.4f} ± {sd(a):.4f} | {b.mean():.4f} ± {sd(b):.4f} "
            f"| {a.max():.4f} |"
        )
    classes = sorted({c for r in rows for c in r["roi_by_class"]})
    lines += [
        "",
        "ROI abs_rel per class (cap 80; mean over the runs), against the image-blind baselines:",
        "",
        f"| run | {' | '.join(classes)} |",
        f"|---|{'---|' * len(classes)}",
    ]
    for spec in sorted({r["spec"] for r in rows}):
        means = [np.mean([r["roi_by_class"][c] for r in rows if r["spec"] == spec]) for c in classes]
        lines.append(f"| {spec} | {' | '.join(f'{m:.3f}' for m in means)} |")
    for name in ("constant", "prior"):
        cells = " | ".join(f"{prior[name]['roi_by_class'][c]:.3f}" for c in classes)
        lines.append(f"| {name} | {cells} |")
    return "\n".join(lines)


def curves_figure(rows: list[dict], prior: dict, path: Path) -> None:
    """Per variant, every seed's appearance loss (top) and full-image abs_rel (bottom) per epoch;
    the image-blind prior's abs_rel as a dashed line: a curve that stays on it is a dead start."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from msdepth.reporting.figures import write_figure  # matplotlib's, so only where it is there

    specs = sorted({r["spec"] for r in rows})
    fig, axes = plt.subplots(2, len(specs), figsize=(3.2 * len(specs), 5.2), sharex=True, squeeze=False)
    for col, spec in enumerate(specs):
        for r in sorted((r for r in rows if r["spec"] == spec), key=lambda r: r["seed"]):
            epochs = [h["epoch"] for h in r["history"]]
            axes[0][col].plot(
                epochs, [h["appearance"] for h in r["history"]], lw=1, label=f"seed {r['seed']}"
            )
            axes[1][col].plot(epochs, [h["abs_rel"] for h in r["history"]], lw=1, label=f"seed {r['seed']}")
        axes[1][col].axhline(prior["prior"]["abs_rel"], color="grey", ls="--", lw=1, label="per-pixel prior")
        axes[0][col].set_title(spec)
        axes[1][col].set_xlabel("epoch")
        axes[1][col].set_ylim(0, max(0.5, prior["prior"]["abs_rel"] * 1.2))
    axes[0][0].set_ylabel("appearance loss (own scale)")
    axes[1][0].set_ylabel("abs_rel, cap 80 m")
    axes[1][-1].legend(fontsize=7)
    fig.tight_layout()
    write_figure(path, fig, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Train and evaluate every (variant, seed) not yet in ``--out``; write the summary and curves."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variants", nargs="+", default=["ssim", "msssim:3"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--jobs", type=int, default=1)
    args = ap.parse_args(argv)
    base = apply_overrides(read_params_file("params.yaml"), args.set)
    jobs = [(spec, seed) for seed in args.seeds for spec in args.variants]
    try:
        claim_outputs(args.out, base, jobs)
    except OutputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    write_text(args.out / "overrides.json", json.dumps(args.set))
    threads = max(1, (os.cpu_count() or 1) // args.jobs)
    with ProcessPoolExecutor(args.jobs) as pool:
        list(
            pool.map(
                run_one, *zip(*[(base, s, seed, str(args.out), threads) for s, seed in jobs], strict=True)
            )
        )
    # Every run in the folder, also those of earlier invocations with other variants or seeds.
    rows = [json.loads(p.read_text()) for p in sorted(args.out.glob("*_seed*.json"))]
    prior = prior_metrics(params_from_dict(base))
    for r in rows:
        r["prior_correlation"] = float(
            np.corrcoef(r["per_image_abs_rel"], prior["prior"]["per_image_abs_rel"])[0, 1]
        )
    text = summarise(rows, prior)
    write_text(args.out / "summary.md", text + "\n")
    try:
        curves_figure(rows, prior, args.out / "curves.png")
    except ImportError:  # e.g. the GPU machine's image has no matplotlib: the numbers are the result
        print("matplotlib is not installed: no curves.png", file=sys.stderr)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/learning.py", main))
