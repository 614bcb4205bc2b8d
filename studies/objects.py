"""Do the networks see objects? Curves of the object classes' error as one run trains long.

Issue 52's diagnosis: one variant and seed trained with the pipeline's own code out to ``--steps``
steps; every ``--every`` steps (at the first epoch end past each multiple) the evaluation frames
are scored: each object class's abs_rel on its exact pixels and the full frame (cap 80 m), the
large car boxes' correlation with the image-blind prior (:mod:`msdepth.evaluation.box_errors`: near
1 = cars placed where the layout prior puts them), and image dependence. Writes ``history.json``
(resumable from the last epoch checkpoint), ``curve.png``, ``strip.png`` and ``summary.md`` into
``--out``. Run from the repository root after ``dvc repro cache rois``::

    python studies/objects.py --out studies/results/objects/diagnosis --steps 10000 --threads 1

``--table`` writes ``--out/table.md``: a row per run below ``--out`` (folders named
``<recipe>[_msssim][_seed<k>]``), the means over seeds and MS-SSIM − SSIM paired by seed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import re
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from msdepth.config.params import MAX_THREADS, Params, apply_overrides, params_from_dict, read_params_file
from msdepth.data import kitti
from msdepth.data.eval_index import read_eval_index
from msdepth.data.pairs import build_pair_cache, load_pair_cache, load_pair_list
from msdepth.errors import ConfigError, DataError, OutputError, run_main
from msdepth.evaluation import baselines
from msdepth.evaluation.box_errors import box_medians, prior_correlation
from msdepth.evaluation.suites import depth_maps, evaluate_full, evaluate_roi, image_dependence, load_frames
from msdepth.io import save_npy, write_text
from msdepth.outputs import OutputPolicy, claim_output_file
from msdepth.readers import read_json_file
from msdepth.reporting.comparison import markdown_table
from msdepth.stats import paired_t

INDEX = Path("data/index")
CLASSES = ("car", "windshield", "glass", "sign")
STRIP_FRAMES = 3
LARGE_PX = 4.0  # a box this tall at the network's input is "large" (studies/roi_errors.py's default)


@dataclasses.dataclass(frozen=True)
class EvalSet:
    """The evaluation frames and images, the ROIs (which are large cars) and the image-blind baselines."""

    frames: list
    images: list[Path]
    boxes: object
    large_cars: np.ndarray
    prior_medians: np.ndarray
    baseline_depth: dict[str, dict]


def load_eval_set(params: Params) -> EvalSet:
    """The pipeline's evaluation frames and ROIs (``data/index``), with the per-pixel prior."""
    index = read_eval_index(INDEX / "eval_frames.csv")
    frames = load_frames(index)
    boxes = kitti.read_rois(INDEX / "rois.csv")
    pairs = load_pair_list(INDEX / "train_pairs.txt")
    gt = baselines.training_gt([left for left, _ in pairs], progress=False).maps
    if gt is None:
        raise DataError(f"{INDEX / 'train_pairs.txt'}: no training frame has GT to build the prior")
    disparities = baselines.baseline_disparities(gt, len(frames))
    baseline_depth = {name: depth_maps(d, frames) for name, d in disparities.items()}
    by_name = {f.name: f for f in frames}
    scale = params.data.height / frames[0].shape[0]
    large = ((boxes["y1"] - boxes["y0"]).to_numpy() * scale >= LARGE_PX) & (
        boxes["class"] == "car"
    ).to_numpy()
    images = [Path(p) for p in index["left"]]
    medians = box_medians(baseline_depth["prior"], by_name, boxes)
    return EvalSet(frames, images, boxes, large, medians, baseline_depth)


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
    # Training seconds (scoring excluded) since the last mark: the recipe's step time, on a resumed
    # run from its resumption on.
    clock = {"since": time.perf_counter()}

    def on_epoch(epoch: int, model, means: dict) -> None:
        # Marks from this epoch on are another run's: one that went further before it was killed, or
        # one whose checkpoint did not match (other params or code) so that training started anew.
        history[:] = [h for h in history if h["epoch"] < epoch]
        step, previous = epoch * spe, (epoch - 1) * spe
        if step // every == previous // every and epoch != params.train.epochs:
            return
        seconds, last = time.perf_counter() - clock["since"], history[-1] if history else {"step": 0}
        disp = predict_disparities(model, ev.images, *params.image_size, False, progress=False)
        model.train()
        timing = {"seconds_per_step": seconds / (step - last["step"])} if step > last["step"] else {}
        history.append(
            {
                "epoch": epoch,
                "step": step,
                **means,
                **timing,
                **scores(depth_maps(disp, ev.frames), ev, params),
            }
        )
        write_text(out / "history.json", json.dumps(history, indent=1))
        mark = step // every * every
        if mark in strip_marks:
            save_npy(out / "work" / f"disp_{mark}.npy", disp[:STRIP_FRAMES].astype(np.float32))
        print(
            json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in history[-1].items()}),
            flush=True,
        )
        clock["since"] = time.perf_counter()

    return on_epoch


def read_history(path: Path) -> list[dict]:
    """A run's history.json: marks, each with an integer ``step`` and a number per score; else a DataError."""
    history = read_json_file(path, "objects history")
    if not isinstance(history, list) or not all(isinstance(h, dict) for h in history):
        raise DataError(f"{path}: needs a JSON list of scored marks")
    for h in history:
        step = h.get("step")
        if isinstance(step, bool) or not isinstance(step, int):
            raise DataError(f"{path}: a mark's step must be an integer, got {step!r}")
        # seconds_per_step: absent on a mark scored right after a resume
        bad = [k for k, _ in COLUMNS if k != "seconds_per_step" and not _is_number(h.get(k))]
        if bad:
            raise DataError(f"{path}: step {step} has no number for {', '.join(bad)}")
    return history


def _is_number(value: object) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _resumed_history(out: Path) -> list[dict]:
    """The curve so far of a run resumed from its checkpoint."""
    path = out / "history.json"
    return read_history(path) if path.exists() else []


def diagnose(
    base: dict, ev: EvalSet, variant: str, seed: int, steps: int, every: int, out: Path, threads: int
) -> list[dict]:
    """Train ``variant`` / ``seed`` for at least ``steps`` steps, scoring every ``every`` on ``ev``."""
    import torch

    from msdepth.training.train import TrainOptions, TrainOutputs, train_variant

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
    cache = training_cache(params, pairs, out / "work")
    history = [h for h in _resumed_history(out) if h["epoch"] <= epochs]
    on_epoch = _recorder(params, ev, out, history, spe, steps, every)
    work = out / "work"
    train_variant(
        params,
        variant,
        pairs,
        TrainOutputs(work / "model.pt", work / "ck.pt"),
        TrainOptions(progress=False, cache=cache, seed=seed, on_epoch=on_epoch),
    )
    return history


def crop_cache_path(work: Path, size: tuple[int, int]) -> Path:
    """Where a run whose images are not the pipeline's cache size (``train.crop_scale`` > 1) keeps
    its own pair cache."""
    return work / f"pairs_{size[0]}x{size[1]}.npy"


def training_cache(params: Params, pairs: list, work: Path) -> np.ndarray:
    """The training pairs at ``params.image_size``: the pipeline's cache, or (``train.crop_scale``
    > 1) a cache of the run's own, built once in ``work``."""
    size = params.image_size
    if size == (params.data.height, params.data.width):
        return load_pair_cache("data/cache/train_pairs.npy", len(pairs), *size)
    path = crop_cache_path(work, size)
    if not path.is_file():
        report = build_pair_cache(pairs, *size, path, progress=False)
        if len(report.pairs) != len(pairs):
            raise DataError(f"{path}: {len(pairs) - len(report.pairs)} training pairs are unreadable")
    return load_pair_cache(path, len(pairs), *size)


def window_starts(side: int, window: int, stride: int) -> list[int]:
    """Where the windows of ``window`` px at ``stride`` start along a ``side``-px side, the last one
    flush with the end, so that every pixel is covered.

    Example:
        >>> window_starts(384, 192, 80)
        [0, 80, 160, 192]
    """
    return sorted({*range(0, side - window + 1, stride), side - window})


def tiled_disparities(model, images: list[Path], size: tuple[int, int], crop: tuple[int, int]) -> np.ndarray:
    """A crop-trained network's (``train.crop_scale`` > 1) disparity of each image resized to
    ``size``: the mean of its plain predictions on the ``crop`` windows at half a crop's stride,
    the input size it trained at, where the whole image (:func:`predict_disparities`) is not."""
    import torch

    from msdepth.data.pairs import resize, to_tensor
    from msdepth.evaluation.infer import network_disparity

    (height, width), (h, w) = size, crop
    windows = [
        np.s_[..., top : top + h, left : left + w]
        for top in window_starts(height, h, h // 2)
        for left in window_starts(width, w, w // 2)
    ]
    total = np.zeros((len(images), height, width), np.float32)
    count = np.zeros((height, width), np.float32)
    for window in windows:
        count[window] += 1
    for i, path in enumerate(images):
        image = to_tensor(resize(kitti.read_image(path), height, width))[None]
        for window in windows:
            with torch.no_grad():
                total[i][window] += network_disparity(model, image[window], False)[0]
    return total / count


def tile_scores(params: Params, ev: EvalSet, out: Path) -> dict:
    """The final model of the run in ``out`` scored on the whole images and on tiles
    (:func:`tiled_disparities`), for a run with ``train.crop_scale`` > 1."""
    from msdepth.evaluation.infer import predict_disparities
    from msdepth.networks.model_file import load_model

    model, meta = load_model(out / "work" / "model.pt")
    size, crop = (meta["height"], meta["width"]), (params.data.height, params.data.width)
    whole = predict_disparities(model, ev.images, *size, False, progress=False)
    tiles = tiled_disparities(model, ev.images, size, crop)
    return {
        name: scores(depth_maps(d, ev.frames), ev, params) for name, d in (("whole", whole), ("tiles", tiles))
    }


def baseline_scores(params: Params, ev: EvalSet) -> dict[str, dict]:
    """The image-blind baselines' scores (the constant, the per-pixel prior): the curves' floor."""
    return {name: scores(depth, ev, params) for name, depth in ev.baseline_depth.items()}


CURVES = (
    ("car_mask", "car"),
    ("windshield_mask", "windshield"),
    ("glass_mask", "glass"),
    ("sign_mask", "sign"),
)


def curve_figure(history: list[dict], floor: dict[str, dict], path: Path) -> None:
    """curve.png: per class, exact-mask abs_rel against steps (the prior's dashed); the car boxes'
    correlation with the prior; image dependence and full-frame abs_rel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from msdepth.reporting.figures import write_figure

    steps = [h["step"] for h in history]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4))
    for (key, label), color in zip(CURVES, ("tab:blue", "tab:orange", "tab:green", "tab:red"), strict=True):
        axes[0].plot(steps, [h[key] for h in history], color=color, label=label)
        axes[0].axhline(floor["prior"][key], color=color, ls="--", lw=0.8)
    axes[0].set_ylabel("exact-mask abs_rel (cap 80 m)")
    axes[0].set_title("classes (dashed: the per-pixel prior)", fontsize=9)
    axes[0].legend(fontsize=7)
    axes[1].plot(steps, [h["car_prior_corr"] for h in history], color="k")
    axes[1].axhline(0.3, color="grey", ls=":", lw=0.8)
    axes[1].set_title("car boxes: corr. of log error with the prior's", fontsize=9)
    axes[2].plot(steps, [h["abs_rel"] for h in history], label="full-frame abs_rel")
    axes[2].plot(steps, [h["variation_ratio"] for h in history], label="image dependence")
    axes[2].axhline(floor["prior"]["abs_rel"], color="tab:blue", ls="--", lw=0.8)
    axes[2].legend(fontsize=7)
    for ax in axes:
        ax.set_xlabel("step")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    write_figure(path, fig, dpi=110)
    plt.close(fig)


def strip_figure(out: Path, ev: EvalSet, marks: list[int], path: Path) -> None:
    """strip.png: per frame, the image, its GT disparity and the network's at each saved mark."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from msdepth.data.kitti import read_image
    from msdepth.reporting.figures import write_figure

    saved = [
        (m, np.load(out / "work" / f"disp_{m}.npy"))
        for m in marks
        if (out / "work" / f"disp_{m}.npy").is_file()
    ]
    fig, axes = plt.subplots(
        STRIP_FRAMES, len(saved) + 2, figsize=(2.6 * (len(saved) + 2), 1.0 * STRIP_FRAMES + 0.5)
    )
    for i, frame in enumerate(ev.frames[:STRIP_FRAMES]):
        gt = np.where(
            frame.gt_depth > 0, frame.focal * frame.baseline / np.maximum(frame.gt_depth, 1e-3), np.nan
        )
        gt = gt / gt.shape[1]  # as a fraction of the width, the networks' unit
        axes[i, 0].imshow(read_image(ev.images[i]))
        axes[i, 1].imshow(gt, cmap="magma", vmin=0, vmax=np.nanpercentile(gt, 95))
        for j, (mark, disp) in enumerate(saved, 2):
            axes[i, j].imshow(disp[i], cmap="magma", vmin=0, vmax=np.nanpercentile(gt, 95))
            axes[i, j].set_title(f"step {mark}" if i == 0 else "", fontsize=8)
        axes[i, 0].set_title("image" if i == 0 else "", fontsize=8)
        axes[i, 1].set_title("GT" if i == 0 else "", fontsize=8)
    for ax in axes.ravel():
        ax.axis("off")
    fig.tight_layout()
    write_figure(path, fig, dpi=110)
    plt.close(fig)


# The tables' score columns: (key of scores(), header).
COLUMNS = (
    ("abs_rel", "full abs_rel"),
    ("car_mask", "car"),
    ("windshield_mask", "windshield"),
    ("glass_mask", "glass"),
    ("sign_mask", "sign"),
    ("car_prior_corr", "car corr. prior"),
    ("variation_ratio", "image dependence"),
    ("seconds_per_step", "s/step"),  # the training's own, on the machine's load of the moment
)


def _cell(value: float | None) -> str:
    """A score to three decimals; a blank for none (a baseline's step time)."""
    return "" if value is None else f"{value:.3f}"


def _table_lines(first: Sequence[str], rows: Sequence[tuple[Sequence[str], dict]]) -> list[str]:
    """A markdown table: the ``first`` columns' headers, then :data:`COLUMNS`; each row its first
    cells and a scores dict."""
    cells = [[*first_cells, *(_cell(row.get(k)) for k, _ in COLUMNS)] for first_cells, row in rows]
    return markdown_table([*first, *(h for _, h in COLUMNS)], cells).split("\n")


def summary_table(history: list[dict], floor: dict[str, dict]) -> str:
    """summary.md: one row per scored step, the baselines first."""
    rows = [([name], row) for name, row in floor.items()] + [([str(h["step"])], h) for h in history]
    return "\n".join(_table_lines(["step"], rows)) + "\n"


def runs_table(root: Path) -> str:
    """table.md: per run below ``root``, the scores at its last mark and at the one nearest 1,200 steps."""
    rows = []
    for path in sorted(root.rglob("history.json")):
        history = read_history(path)
        if not history:
            continue
        name = path.parent.relative_to(root).as_posix()
        near = min(history, key=lambda h: abs(h["step"] - 1200))
        for h in [near] if near is history[-1] else [near, history[-1]]:
            rows.append(([name, str(h["step"])], h))
    return "\n".join(_table_lines(["run", "steps"], rows)) + "\n"


# A screen run's folder name: <recipe>[_msssim][_seed<k>] (no suffix: SSIM, seed 0).
RUN_NAME = re.compile(r"^(?P<recipe>.+?)(?P<msssim>_msssim)?(?:_seed(?P<seed>\d+))?$")
PAIRED = ("car_mask", "windshield_mask", "glass_mask", "abs_rel", "car_prior_corr")


def run_key(name: str) -> tuple[str, str, int]:
    """``(recipe, variant, seed)`` of a screen run from its folder's name.

    Example:
        >>> run_key("busy_cosine3e-4_x4_msssim_seed1"), run_key("default_x1")
        (('busy_cosine3e-4_x4', 'msssim', 1), ('default_x1', 'ssim', 0))
    """
    m = RUN_NAME.match(name)
    return m["recipe"], "msssim" if m["msssim"] else "ssim", int(m["seed"] or 0)


def _seed_groups(root: Path) -> dict[tuple[str, str], dict[int, list[dict]]]:
    """Every run's history below ``root`` by (recipe, variant) and seed; a run named twice is a DataError."""
    groups: dict[tuple[str, str], dict[int, list[dict]]] = {}
    seen: dict[tuple[str, str, int], Path] = {}
    for path in sorted(root.rglob("history.json")):
        recipe, variant, seed = run_key(path.parent.name)
        folder = path.parent.parent.relative_to(root).as_posix()
        key = (recipe if folder == "." else f"{folder}/{recipe}", variant)
        if (*key, seed) in seen:
            raise DataError(
                f"{seen[(*key, seed)].parent} and {path.parent}: both are {key[0]} {variant} seed {seed}; "
                "rename or move one"
            )
        seen[(*key, seed)] = path
        history = read_history(path)
        if history:
            groups.setdefault(key, {})[seed] = history
    return groups


def _common_step(histories: Sequence[list[dict]]) -> int | None:
    """The last step that every history scored (None: no common one)."""
    common = set.intersection(*({h["step"] for h in history} for history in histories))
    return max(common) if common else None


def _row_at(history: list[dict], step: int) -> dict:
    """A history's scores at ``step``."""
    return next(h for h in history if h["step"] == step)


def seed_means_lines(groups: dict[tuple[str, str], dict[int, list[dict]]]) -> list[str]:
    """A table row per (recipe, variant) of 2 seeds or more: each score's mean over the seeds at
    the last mark all of them reached."""
    rows = []
    for (recipe, variant), runs in sorted(groups.items()):
        step = _common_step(list(runs.values())) if len(runs) >= 2 else None
        if step is None:
            continue
        ends = [_row_at(h, step) for h in runs.values()]
        means = {k: float(np.mean([e[k] for e in ends])) for k, _ in COLUMNS if k != "seconds_per_step"}
        rows.append(([recipe, variant, ",".join(map(str, sorted(runs))), str(step)], means))
    return _table_lines(["recipe", "variant", "seeds", "steps"], rows)


def paired_lines(groups: dict[tuple[str, str], dict[int, list[dict]]], confidence: float = 0.95) -> list[str]:
    """Per recipe both variants ran with 2 seeds or more in common, MS-SSIM − SSIM paired by seed at
    the last common mark: mean, paired t interval, seeds where MS-SSIM's is lower."""
    rows = []
    for (recipe, variant), ssim in sorted(groups.items()):
        msssim = groups.get((recipe, "msssim"), {})
        seeds = sorted(set(ssim) & set(msssim)) if variant == "ssim" else []
        runs = [ssim[s] for s in seeds] + [msssim[s] for s in seeds]
        step = _common_step(runs) if len(seeds) >= 2 else None
        if step is None:
            continue
        cells = []
        for key in (k for k, _ in COLUMNS if k in PAIRED):
            d = np.array([_row_at(msssim[s], step)[key] - _row_at(ssim[s], step)[key] for s in seeds])
            mean, low, high = paired_t(d, confidence)
            cells.append(f"{mean:+.3f} [{low:+.3f}, {high:+.3f}] {int((d < 0).sum())}/{len(d)}")
        rows.append([recipe, ",".join(map(str, seeds)), str(step), *cells])
    head = ["recipe", "seeds", "steps", *(h for k, h in COLUMNS if k in PAIRED)]
    return markdown_table(head, rows).split("\n")


def seed_tables(root: Path) -> str:
    """table.md's second part: the means over seeds, then MS-SSIM − SSIM paired by seed."""
    groups = _seed_groups(root)
    intro = (
        "Means over seeds (each recipe and variant with 2 seeds or more, at the last mark all reached):",
        "MS-SSIM − SSIM paired by seed: mean [95 % paired t interval], seeds where MS-SSIM's is lower:",
    )
    return (
        "\n".join([intro[0], "", *seed_means_lines(groups), "", intro[1], "", *paired_lines(groups)]) + "\n"
    )


def claim(out: Path, steps: int, every: int, size: tuple[int, int]) -> None:
    """Every file the study may write under ``out``, claimed before it starts (output policy). The
    run's scratch (model, checkpoint, saved disparities) has a manifest of its own in ``out/work``,
    so that the results' manifest lists only results."""
    results = [out / n for n in ("history.json", "curve.png", "strip.png", "summary.md", "baselines.json")]
    results.append(out / "tiles.json")
    scratch = [out / "work" / n for n in ("model.pt", "ck.pt")] + [crop_cache_path(out / "work", size)]
    scratch += [out / "work" / f"disp_{m}.npy" for m in checkpoint_steps(steps, every)]
    OutputPolicy(out, "objects").claim(results, "params.yaml")
    OutputPolicy(out / "work", "objects").claim(scratch, "params.yaml")


def check_args(args: argparse.Namespace) -> None:
    """``--steps``, ``--every`` and ``--threads`` in range, a ConfigError naming the option else:
    checked before anything is claimed, read or set (torch.set_num_threads)."""
    for option, value in (("--steps", args.steps), ("--every", args.every)):
        if value < 1:
            raise ConfigError(f"{option}: must be a whole number >= 1, got {value}")
    if not 1 <= args.threads <= MAX_THREADS:
        raise ConfigError(f"--threads: must be in 1..{MAX_THREADS}, got {args.threads}")


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
    ap.add_argument("--report", action="store_true", help="only the tables and figures of a run in --out")
    ap.add_argument("--table", action="store_true", help="only --out/table.md, a row per run below --out")
    ap.add_argument(
        "--tiles",
        action="store_true",
        help="train.crop_scale > 1: also score the final model on crop-sized tiles (--out/tiles.json)",
    )
    args = ap.parse_args(argv)
    check_args(args)
    if args.table:
        text = runs_table(args.out) + "\n" + seed_tables(args.out)
        if not claim_output_file(args.out / "table.md", "objects-table", args.out):
            return 1
        write_text(args.out / "table.md", text)
        print(text)
        return 0
    base = apply_overrides(read_params_file("params.yaml"), args.set)
    params = params_from_dict(base)
    try:
        claim(args.out, args.steps, args.every, params.image_size)
        ev = load_eval_set(params)
        if args.report:
            history = _resumed_history(args.out)
            if not history:
                raise DataError(f"{args.out / 'history.json'}: no scored checkpoint to report")
        else:
            history = diagnose(
                base, ev, args.variant, args.seed, args.steps, args.every, args.out, args.threads
            )
    except (OutputError, DataError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    floor = baseline_scores(params, ev)
    write_text(args.out / "baselines.json", json.dumps(floor, indent=1))
    text = summary_table(history, floor)
    write_text(args.out / "summary.md", text)
    if args.tiles and params.train.crop_scale > 1:
        write_text(args.out / "tiles.json", json.dumps(tile_scores(params, ev, args.out), indent=1))
    try:
        curve_figure(history, floor, args.out / "curve.png")
        strip_figure(args.out, ev, checkpoint_steps(args.steps, args.every), args.out / "strip.png")
    except ImportError:  # a GPU machine's image may have no matplotlib: the numbers are the result
        print("matplotlib is not installed: no curve.png or strip.png", file=sys.stderr)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/objects.py", main))
