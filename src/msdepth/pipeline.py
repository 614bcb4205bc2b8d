"""One function per DVC stage: where each stage reads and writes, and what it calls.

``stages/<name>.py`` only parse their arguments and call the function of the same name here,
through :func:`run_stage`, which loads ``params.yaml`` once and turns the project's errors
into one clear line on stderr and a non-zero exit.
"""

from __future__ import annotations

import inspect
import logging
import os
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

from . import baselines as baselines_mod
from .compare import (
    build_comparison,
    group_metrics,
    image_dependence,
    load_suite_metrics,
    load_unit_tables,
    paired_statistics,
    seed_spread,
)
from .config import Params, load_params
from .data import kitti
from .data.index import build_indexes, layout, read_eval_index
from .data.pairs import build_pair_cache, load_pair_cache, load_pair_list
from .errors import ConfigError, DataError, MsdepthError
from .evaluate import (
    depth_maps,
    evaluate_full,
    evaluate_gradients,
    evaluate_roi,
    load_frames,
    read_depth_maps,
)
from .io import atomic_path, save_npy, save_npz, write_json, write_text

log = logging.getLogger("msdepth")

INDEX_DIR = Path("data/index")
PAIR_CACHE = Path("data/cache/train_pairs.npy")
CACHED_PAIRS = Path("data/cache/train_pairs.txt")
CACHE_REPORT = Path("data/cache/report.json")
BASELINES = baselines_mod.BASELINES
SUITES = {"full": evaluate_full, "roi": evaluate_roi, "gradients": evaluate_gradients}


def run_name(variant: str, seed: int) -> str:
    """One training run: ``<variant>/seed<seed>``, also its path below models/, outputs/, metrics/<suite>/."""
    return f"{variant}/seed{seed}"


def checked_run(params: Params, variant: str, seed: str) -> str:
    """The run of a stage's ``VARIANT SEED`` arguments, a ConfigError if either is not configured."""
    return run_name(params.variant(variant), params.seed(seed))


def variant_runs(params: Params) -> dict[str, list[str]]:
    """``{variant: [its run of every seed in train.seeds]}``."""
    return {v: [run_name(v, s) for s in params.train.seeds] for v in params.variants}


def model_path(run: str) -> Path:
    return Path("models") / run / "model.pt"


def checkpoint_path(run: str) -> Path:
    return Path("checkpoints") / run / "checkpoint.pt"


def run_dir(run: str) -> Path:
    return Path("outputs") / run


def prepare_data(params: Params, *options: str) -> None:
    """Create the KITTI-format tree under ``data.root``: render the synthetic set, or fetch KITTI.

    For KITTI, ``--dry-run`` prints what would be downloaded and its total size.
    """
    if params.data.source == "synthetic":
        from .data import synthetic

        log.info("synthetic set: %s", synthetic.generate(params.data.synthetic, Path(params.data.root)))
        return
    from .data import download

    k, lay = params.data.kitti, layout(params)
    names = download.parse_archive_list(k.archive_list)
    subset = list(k.drives) if k.drives is not None else (k.drive_count or None)
    common = dict(jobs=k.jobs, dry_run="--dry-run" in options, jpeg=k.jpeg, allow_http=k.allow_http)
    raw = download.fetch_all(
        k.base_url, download.select_archives(names, subset), k.download_dir, lay.raw_root, **common
    )
    scene = download.fetch_all(
        k.base_url, [k.scene_flow_archive], k.download_dir, lay.kitti2015_root, **common
    )
    log.info("kitti: raw archives %s; KITTI 2015 %s", _summary(raw), _summary(scene))


def _summary(report: dict) -> str:
    return ", ".join(f"{k} {len(v) if isinstance(v, (list, dict)) else v}" for k, v in report.items())


def index(params: Params) -> None:
    """Index the training pairs and evaluation frames found on disk."""
    report = build_indexes(params, INDEX_DIR)
    log.info(
        "index: %d/%d training pairs found, %d evaluation frames",
        report["train_pairs_found"],
        report["train_pairs_listed"],
        report["eval_frames"],
    )


def rois(params: Params) -> None:
    """The ROI boxes: the synthetic set's exact ones, or KITTI's obj_map cars plus the user's CSV.

    Writes the ROI index and a contact sheet of the crops (``data/index/rois.png``).
    """
    from .data.rois import contact_sheet, extract_rois

    frames = read_eval_index(INDEX_DIR / "eval_frames.csv")
    source = layout(params).rois
    if source is not None:
        boxes = kitti.read_rois(source)
        unknown = sorted(set(boxes["image"]) - set(frames["frame"]))
        if unknown:
            raise DataError(f"{source}: boxes name images that are not evaluation frames: {unknown[:10]}")
    else:  # extract_rois checks the user's boxes against the frames itself
        k = params.data.kitti
        boxes = extract_rois(
            frames,
            user_csv=Path(k.rois_csv) if k.rois_csv else None,
            min_size=k.roi_min_size,
            min_valid=k.roi_min_valid,
        )
        if boxes.empty:
            raise DataError(
                "rois: no car in any obj_map passed data.kitti.roi_min_size/roi_min_valid, "
                "and no data.kitti.rois_csv"
            )
    kitti.write_rois(INDEX_DIR / "rois.csv", boxes)
    contact_sheet(boxes, frames, INDEX_DIR / "rois.png")
    log.info("rois: %d boxes, %s", len(boxes), boxes["class"].value_counts().to_dict())


def cache(params: Params) -> None:
    """Decode and resize the training pairs once; pairs with unreadable images are left out and reported."""
    pairs = load_pair_list(INDEX_DIR / "train_pairs.txt")
    report = build_pair_cache(pairs, params.data.height, params.data.width, PAIR_CACHE)
    kitti.write_split(CACHED_PAIRS, [(str(a), str(b)) for a, b in report.pairs])
    write_json(
        CACHE_REPORT,
        {
            "pairs_indexed": len(pairs),
            "pairs_cached": len(report.pairs),
            "pairs_unreadable": len(report.unreadable),
            "unreadable": [{"left": str(a), "right": str(b), "error": e} for a, b, e in report.unreadable],
        },
    )
    for left, right, error in report.unreadable[:20]:
        log.warning("cache: left out %s %s: %s", left, right, error)
    log.info(
        "cache: %d of %d pairs at %dx%d in %s (%d unreadable, listed in %s)",
        len(report.pairs),
        len(pairs),
        params.data.height,
        params.data.width,
        PAIR_CACHE,
        len(report.unreadable),
        CACHE_REPORT,
    )


def train(params: Params, variant: str, seed: str) -> None:
    """Train one loss variant with one seed; write its model, training summary and dvclive curves."""
    from .train import train_variant

    run = checked_run(params, variant, seed)
    t = params.train
    if t.launcher == "torchrun" and "LOCAL_RANK" not in os.environ:
        # Re-run this stage under torchrun; its ranks come back here with LOCAL_RANK set.
        import subprocess

        cmd = [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--standalone",
            f"--nproc_per_node={t.nproc}",
            "stages/train.py",
            variant,
            seed,
        ]
        log.info("train %s: %s", run, " ".join(cmd))
        if subprocess.run(cmd).returncode != 0:
            raise MsdepthError(
                f"train {run}: torchrun with {t.nproc} processes failed (see the ranks' errors above)"
            )
        return
    pairs = load_pair_list(CACHED_PAIRS)  # the pairs the cache holds, in its order
    images = load_pair_cache(PAIR_CACHE, len(pairs), params.data.height, params.data.width)
    result = train_variant(
        params,
        variant,
        pairs,
        model_path(run),
        checkpoint_path(run),
        live_dir=Path("plots") / "train" / run,
        cache=images,
        seed=params.seed(seed),
        summary_path=Path("metrics") / "train" / f"{run}.json",
        timing_path=Path("logs") / "train" / f"{run}.json",
    )
    resumed = f", resumed from epoch {result.resumed_from_epoch}" if result.resumed_from_epoch else ""
    log.info(
        "train %s: %d steps%s; %.0f s of training, %.0f s in this run (%.1f examples/s)",
        run,
        result.steps,
        resumed,
        result.seconds,
        result.seconds_this_run,
        result.examples_per_second,
    )


def infer(params: Params, variant: str, seed: str) -> None:
    """Left disparities of every evaluation frame, at the network's input size."""
    from .infer import predict_disparities
    from .train import load_model

    run = checked_run(params, variant, seed)
    torch_threads(params)
    model, meta = load_model(model_path(run))
    frames = read_eval_index(INDEX_DIR / "eval_frames.csv")
    disp = predict_disparities(
        model, [Path(p) for p in frames["left"]], meta["height"], meta["width"], params.eval.post_process
    )
    save_npy(run_dir(run) / "disparities.npy", disp)


def torch_threads(params: Params) -> None:
    import torch

    torch.set_num_threads(params.train.threads)


def depth(params: Params, variant: str, seed: str) -> None:
    """Disparities (fraction of width) -> metric depth at each frame's GT resolution."""
    run = checked_run(params, variant, seed)
    path = run_dir(run) / "disparities.npy"
    if not path.exists():
        raise DataError(f"{path}: no disparities for run {run!r}")
    frames = load_frames(read_eval_index(INDEX_DIR / "eval_frames.csv"))
    save_npz(run_dir(run) / "depth.npz", **depth_maps(np.load(path), frames))


def headline(suite: str, summary: dict) -> dict[str, float] | None:
    """The few numbers of a suite's summary that a reader compares (first cap): what
    ``dvc metrics show`` and ``dvc metrics diff`` list, one small file per run and suite. The
    full summary stays beside it as a plain output."""
    cap = next(k for k in summary if k.startswith("cap"))
    if suite == "full":
        m = summary[cap]
        out = {"abs_rel": m["abs_rel"], "rmse": m["rmse"], "a1": m["a1"]}
        if "image_dependence" in summary:
            out["variation"] = summary["image_dependence"]["variation_ratio"]
        return out
    if suite == "roi":
        m = summary[cap]["overall"]
        out = {"roi_abs_rel": m["abs_rel"], "roi_a1": m["a1"]}
        if cap in summary.get("masks", {}):
            out["mask_abs_rel"] = summary["masks"][cap]["overall"]["abs_rel"]
        return out
    return None


def _write_suite(suite: str, run: str, summary: dict, table) -> None:
    write_json(Path("metrics") / suite / f"{run}.json", summary)
    top = headline(suite, summary)
    if top is not None:
        write_json(Path("metrics") / "headline" / suite / f"{run}.json", top)
    with atomic_path(Path("metrics") / suite / f"{run}.csv") as tmp:
        table.to_csv(tmp, index=False, float_format="%.6g")


def _run_suite(params: Params, suite: str, run: str, pred: dict, frames, boxes) -> None:
    fn = SUITES[suite]
    summary, table = (
        fn(pred, frames, params.eval) if suite == "full" else fn(pred, frames, boxes, params.eval)
    )
    _write_suite(suite, run, summary, table)


def evaluate(params: Params, suite: str, variant: str, seed: str) -> None:
    """Run one evaluation suite on one run's depth maps."""
    if suite not in SUITES:
        raise ConfigError(f"unknown evaluation suite {suite!r}; known: {sorted(SUITES)}")
    run = checked_run(params, variant, seed)
    frames = load_frames(read_eval_index(INDEX_DIR / "eval_frames.csv"))
    boxes = kitti.read_rois(INDEX_DIR / "rois.csv") if suite != "full" else None
    _run_suite(params, suite, run, read_depth_maps(run_dir(run) / "depth.npz"), frames, boxes)


def baselines(params: Params) -> None:
    """The image-blind baselines, through the same depth conversion and suites as the variants.

    Their training GT is ``disp_02`` (synthetic) or the Velodyne scans (real KITTI); drives with
    neither are named and left out. With no GT at all the baselines are skipped, not failed: each
    leaves a ``{"skipped": reason}`` JSON (and a one-row CSV) that ``compare`` reports as missing.
    """
    pairs = load_pair_list(INDEX_DIR / "train_pairs.txt")
    gt = baselines_mod.training_gt([left for left, _ in pairs])
    for drive, count in gt.missing.items():
        log.warning(
            "baselines: %s: %d training frame(s) with neither disp_02/data/<frame>.png nor "
            "velodyne_points/data/<frame>.bin, left out",
            drive,
            count,
        )
    if gt.maps is None:
        reason = f"no training frame has GT (disp_02 or a Velodyne scan) in {len(gt.missing)} drive(s)"
        log.warning("baselines: %s: %s not built", reason, " and ".join(BASELINES))
        for run in BASELINES:
            for suite in SUITES:
                write_json(Path("metrics") / suite / f"{run}.json", {baselines_mod.SKIPPED: reason})
                write_text(Path("metrics") / suite / f"{run}.csv", f"{baselines_mod.SKIPPED}\n{reason}\n")
                if suite in ("full", "roi"):  # the headline files are declared DVC metrics too
                    write_json(
                        Path("metrics") / "headline" / suite / f"{run}.json", {baselines_mod.SKIPPED: reason}
                    )
        return
    used, (h, w) = len(gt.maps), gt.maps.shape[1:]
    subset = f" (an evenly spaced {used} of {gt.available}: memory budget)" if used < gt.available else ""
    resampled = f", {gt.resampled} resampled from other sizes" if gt.resampled else ""
    log.info(
        "baselines: training GT of %d frames%s at %dx%d%s: %s", used, subset, h, w, resampled, gt.sources
    )
    frames = load_frames(read_eval_index(INDEX_DIR / "eval_frames.csv"))
    boxes = kitti.read_rois(INDEX_DIR / "rois.csv")
    for run, disp in baselines_mod.baseline_disparities(gt.maps, len(frames)).items():
        pred = depth_maps(disp, frames)
        for suite in SUITES:
            _run_suite(params, suite, run, pred, frames, boxes)


def compare(params: Params) -> None:
    """One table of every variant (mean over its seeds) and baseline, as Markdown and JSON.

    A baseline the baselines stage could not build is listed as missing, with the reason.
    """
    missing = {
        b: reason
        for b in BASELINES
        if (reason := baselines_mod.skipped_reason("metrics", b, SUITES)) is not None
    }
    built = tuple(b for b in BASELINES if b not in missing)
    groups = {**variant_runs(params), **{b: [b] for b in built}}

    runs = [r for group in groups.values() for r in group]
    suites = load_suite_metrics("metrics", runs)
    tables = load_unit_tables("metrics", runs)
    stats = paired_statistics(tables, groups, params.compare, params.eval.caps)
    caps = [f"cap{c:g}" for c in params.eval.caps]
    dependence = image_dependence(suites, tables, groups, "prior", params.eval.caps[0])
    result, md = build_comparison(
        group_metrics(suites, groups),
        list(params.variants),
        built,
        stats,
        seed_spread(suites, groups, caps),
        params.train.seeds,
        dependence,
        groups,
        missing_baselines=missing,
    )
    write_json(Path("metrics") / "compare.json", result)
    write_text(Path("metrics") / "compare.md", md)
    write_json(Path("metrics") / "headline" / "mean.json", mean_headline(suites, groups))


def mean_headline(suites: dict, groups: dict[str, list[str]]) -> dict:
    """Per variant (and baseline) the headline numbers averaged over its runs, with the
    seed-to-seed sd of abs_rel: the one file to read in ``dvc exp show`` across experiments."""
    out = {}
    for group, runs in groups.items():
        full = [headline("full", suites["full"][r]) for r in runs]
        roi = [headline("roi", suites["roi"][r]) for r in runs]
        abs_rel = [h["abs_rel"] for h in full]
        out[group] = {
            "abs_rel": float(np.mean(abs_rel)),
            "roi_abs_rel": float(np.mean([h["roi_abs_rel"] for h in roi])),
        }
        if len(runs) > 1:
            out[group]["abs_rel_sd"] = float(np.std(abs_rel, ddof=1))
    return out


def figures(params: Params) -> None:
    """The dissertation's figures (disparities, ROI depth and gradients, curves, error scatter)."""
    from .figures import make_figures

    # The first seed's run of each variant: the figures show predictions, not an average of
    # them; the training curves show every seed's.
    groups = variant_runs(params)
    paths = make_figures(
        {v: runs[0] for v, runs in groups.items()},
        Path("plots") / "figures",
        eval_cfg=params.eval,
        curves=groups,
    )
    log.info("figures: %s", ", ".join(p.name for p in paths))


def run_stage(fn: Callable[..., None], *args: str, params_path: str | os.PathLike = "params.yaml") -> int:
    """Load params, run one stage function, report errors as one line; returns the exit code."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s", stream=sys.stderr)
    started = time.perf_counter()
    try:
        inspect.signature(fn).bind(None, *args)
    except TypeError:
        names = list(inspect.signature(fn).parameters)[1:]
        print(f"usage: {fn.__name__} {' '.join(n.upper() for n in names)}", file=sys.stderr)
        return 2
    try:
        fn(load_params(params_path), *args)
    except MsdepthError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    log.info(
        "%s%s done in %.1f s",
        fn.__name__,
        f" {' '.join(args)}" if args else "",
        time.perf_counter() - started,
    )
    return 0
