"""Do the networks see objects? Curves of the object classes' error as one run trains long.

Issue 52's diagnosis: one variant and seed trained with the pipeline's own code
(``msdepth.training.train.train_variant`` on the cached pairs) out to ``--steps`` steps; every
``--every`` steps (at the first epoch end past each multiple) the plain predictions of the
evaluation frames are scored:

- car / windshield / glass / sign abs_rel on each class's exact pixels (cap 80 m), and full frame;
- the per-box correlation of log(run / GT) with the image-blind prior's log(prior / GT) over the
  large car boxes (:mod:`msdepth.evaluation.box_errors`): near 1 = cars placed where the layout
  prior puts them;
- image dependence (:func:`msdepth.evaluation.suites.image_dependence`).

If the classes' errors fall late, the default is a budget problem; if they never fall, a recipe
problem. Writes ``history.json`` (resumable: a killed run resumes from its last epoch
checkpoint), ``curve.png``, ``strip.png`` (disparity at a few checkpoints beside the GT) and
``summary.md`` into ``--out``. Run from the repository root after ``dvc repro cache rois``::

    python studies/objects.py --out studies/results/objects/diagnosis --steps 10000 --threads 1
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np

from msdepth.config.params import Params, apply_overrides, params_from_dict, read_params_file
from msdepth.data import kitti
from msdepth.data.eval_index import read_eval_index
from msdepth.data.pairs import load_pair_cache, load_pair_list
from msdepth.errors import DataError, OutputError
from msdepth.evaluation import baselines
from msdepth.evaluation.box_errors import box_medians, prior_correlation
from msdepth.evaluation.suites import depth_maps, evaluate_full, evaluate_roi, image_dependence, load_frames
from msdepth.io import OutputPolicy, save_npy, write_text

INDEX = Path("data/index")
CLASSES = ("car", "windshield", "glass", "sign")
STRIP_FRAMES = 3
LARGE_PX = 4.0  # a box this tall at the network's input is "large" (studies/roi_errors.py's default)


@dataclasses.dataclass(frozen=True)
class EvalSet:
    """The evaluation frames, their left images, the ROI boxes, which are large cars, and the
    prior's per-box medians."""

    frames: list
    images: list[Path]
    boxes: object
    large_cars: np.ndarray
    prior_medians: np.ndarray
    prior_depth: dict


def load_eval_set(params: Params) -> EvalSet:
    """The pipeline's evaluation frames and ROIs (``data/index``), with the per-pixel prior."""
    frames = load_frames(read_eval_index(INDEX / "eval_frames.csv"))
    boxes = kitti.read_rois(INDEX / "rois.csv")
    pairs = load_pair_list(INDEX / "train_pairs.txt")
    gt = baselines.training_gt([left for left, _ in pairs], progress=False).maps
    if gt is None:
        raise DataError(f"{INDEX / 'train_pairs.txt'}: no training frame has GT to build the prior")
    prior = depth_maps(baselines.baseline_disparities(gt, len(frames))["prior"], frames)
    by_name = {f.name: f for f in frames}
    scale = params.data.height / frames[0].shape[0]
    large = ((boxes["y1"] - boxes["y0"]).to_numpy() * scale >= LARGE_PX) & (
        boxes["class"] == "car"
    ).to_numpy()
    images = [Path(p) for p in read_eval_index(INDEX / "eval_frames.csv")["left"]]
    return EvalSet(frames, images, boxes, large, box_medians(prior, by_name, boxes), prior)


def scores(pred: dict, ev: EvalSet, params: Params) -> dict:
    """One checkpoint's (or a baseline's) scores, all at cap 80 m."""
    full, _ = evaluate_full(pred, ev.frames, params.eval)
    roi, _ = evaluate_roi(pred, ev.frames, ev.boxes, params.eval)
    masks = roi.get("masks", {}).get("cap80", {}).get("by_class", {})
    medians = box_medians(pred, {f.name: f for f in ev.frames}, ev.boxes)
    corr = prior_correlation(medians, ev.prior_medians, ev.large_cars)
    return {
        "abs_rel": full["cap80"]["abs_rel"],
        "roi_abs_rel": roi["cap80"]["overall"]["abs_rel"],
        **{f"{c}_mask": masks.get(c, {}).get("abs_rel", float("nan")) for c in CLASSES},
        "car_prior_corr": corr["corr"],
        "car_run_ratio": corr["run_ratio"],
        "large_cars": corr["n"],
        "variation_ratio": image_dependence(pred, ev.frames, 80.0)["variation_ratio"],
    }


def checkpoint_steps(steps: int, every: int) -> list[int]:
    """The marks (multiples of ``every``) whose disparities go into the strip: the first, the one
    nearest 1,200 steps (the default's budget), and a quarter, half and all of ``steps``.

    Example:
        >>> checkpoint_steps(10000, 500)
        [500, 1000, 2500, 5000, 10000]
    """
    marks = {round(m / every) * every for m in (every, 1200, steps / 4, steps / 2, steps)}
    return sorted(m for m in marks if every <= m <= steps)


def _recorder(params: Params, ev: EvalSet, out: Path, history: list[dict], spe: int, steps: int, every: int):
    """``train_variant``'s ``on_epoch``: scores the model at the first epoch end past each mark."""
    from msdepth.evaluation.infer import predict_disparities

    strip_marks = checkpoint_steps(steps, every)

    def on_epoch(epoch: int, model, means: dict) -> None:
        step, previous = epoch * spe, (epoch - 1) * spe
        if step // every == previous // every and epoch != params.train.epochs:
            return
        disp = predict_disparities(
            model, ev.images, params.data.height, params.data.width, False, progress=False
        )
        model.train()
        history.append(
            {"epoch": epoch, "step": step, **means, **scores(depth_maps(disp, ev.frames), ev, params)}
        )
        write_text(out / "history.json", json.dumps(history, indent=1))
        mark = step // every * every
        if mark in strip_marks:
            save_npy(out / "work" / f"disp_{mark}.npy", disp[:STRIP_FRAMES].astype(np.float32))
        print(
            json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in history[-1].items()}),
            flush=True,
        )

    return on_epoch


def _resumed_history(out: Path) -> list[dict]:
    """The curve so far of a run resumed from its checkpoint."""
    path = out / "history.json"
    return json.loads(path.read_text()) if path.exists() else []


def diagnose(
    base: dict, variant: str, seed: int, steps: int, every: int, out: Path, threads: int
) -> list[dict]:
    """Train ``variant`` / ``seed`` for at least ``steps`` steps, scoring every ``every``."""
    import torch

    from msdepth.training.train import train_variant

    torch.set_num_threads(threads)
    raw = json.loads(json.dumps(base))
    raw.setdefault("train", {})["threads"] = threads
    params = params_from_dict(raw)
    pairs = load_pair_list("data/cache/train_pairs.txt")
    spe = max(1, len(pairs) // params.train.batch_size)
    epochs = math.ceil(steps / spe)
    params = dataclasses.replace(
        params, train=dataclasses.replace(params.train, epochs=epochs, seeds=(seed,))
    )
    cache = load_pair_cache("data/cache/train_pairs.npy", len(pairs), params.data.height, params.data.width)
    ev = load_eval_set(params)
    history = [h for h in _resumed_history(out) if h["epoch"] <= epochs]
    on_epoch = _recorder(params, ev, out, history, spe, steps, every)
    work = out / "work"
    train_variant(
        params,
        variant,
        pairs,
        work / "model.pt",
        work / "ck.pt",
        progress=False,
        cache=cache,
        seed=seed,
        on_epoch=on_epoch,
    )
    return history


def claim(out: Path, steps: int, every: int) -> OutputPolicy:
    """Every file the study may write under ``out``, claimed before it starts (output policy)."""
    paths = [out / n for n in ("history.json", "curve.png", "strip.png", "summary.md", "baselines.json")]
    paths += [out / "work" / n for n in ("model.pt", "ck.pt")]
    paths += [out / "work" / f"disp_{m}.npy" for m in checkpoint_steps(steps, every)]
    policy = OutputPolicy(out, "objects")
    policy.claim(sorted(set(paths)), "params.yaml")
    return policy


def main(argv: list[str] | None = None) -> int:
    """Run the diagnosis into ``--out``; write its curve, strip and summary."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variant", default="ssim")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=10000)
    ap.add_argument("--every", type=int, default=500)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    base = apply_overrides(read_params_file("params.yaml"), args.set)
    try:
        claim(args.out, args.steps, args.every)
        history = diagnose(base, args.variant, args.seed, args.steps, args.every, args.out, args.threads)
    except (OutputError, DataError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"{len(history)} checkpoints scored into {args.out / 'history.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
