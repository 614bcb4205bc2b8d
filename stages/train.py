"""Stage ``train@<variant>-<seed>``: train one loss variant with one seed."""

from __future__ import annotations

import json
import logging
import os
import sys
from pathlib import Path

from msdepth.config.params import Params
from msdepth.data.layout import layout
from msdepth.data.pairs import load_pair_cache, load_pair_list
from msdepth.data.sequences import SequenceSample, training_sequences
from msdepth.errors import MsdepthError
from msdepth.io import write_json
from msdepth.pipeline.paths import (
    CACHED_PAIRS,
    PAIR_CACHE,
    PRETRAINED,
    SeedArg,
    VariantArg,
    checked_run,
    checkpoint_path,
    model_path,
    run_stage,
)
from msdepth.pipeline.pretrained import recorded_sha256

log = logging.getLogger("msdepth")


def train(params: Params, variant: VariantArg, seed: SeedArg) -> None:
    """Train one loss variant with one seed; write its model, training summary and dvclive curves."""
    from msdepth.training.train import train_variant

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
    sequences = mono_sequences(params)
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
        sequences=sequences,
        # The pretrained stage's hash: the fingerprint's, so that a resume never reads the weights.
        pretrained_sha256=recorded_sha256(params.model.pretrained, PRETRAINED),
    )
    if sequences is not None and int(os.environ.get("RANK", "0")) == 0:
        add_pose_metrics(params, run, Path("metrics") / "train" / f"{run}.json")
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


def mono_sequences(params: Params) -> list[SequenceSample] | None:
    """Monodepth2's M / MS training frames: the samples of the rendered sequences (None in stereo)."""
    t = params.train
    if t.mode == "stereo":
        return None
    paths = layout(params)
    if paths.mono_split is None:  # the config accepts the modes only with rendered sequences
        raise MsdepthError(f"train.mode {t.mode}: data.source {params.data.source} has no sequences")
    return training_sequences(paths.mono_split, paths.raw_root, t.source_frames, t.mode == "mono_stereo")


def add_pose_metrics(params: Params, run: str, summary_path: Path) -> None:
    """A monocular run's pose ATE (msdepth.evaluation.pose), added to its training summary as ``pose``:
    on the rendered sequences, or on the KITTI odometry sequences that are on disk (each one's also
    under ``pose.sequences``; none is fetched, so with none there the summary has no ``pose``)."""
    from msdepth.evaluation.pose import odometry_ates, sequence_ates
    from msdepth.training.train import trained_pose_net

    net = trained_pose_net(params, checkpoint_path(run))
    paths, h, w = layout(params), params.data.height, params.data.width
    if params.data.source == "kitti":
        assert paths.odometry is not None  # the KITTI layout always names it
        pose = odometry_ates(net, paths.odometry, params.data.kitti.odometry_sequences, h, w)
        if not pose:
            log.info("train %s: no KITTI odometry poses below %s: pose not evaluated", run, paths.odometry)
            return
    else:
        pose = sequence_ates(net, paths.raw_root, params.data.synthetic.sequence_length, h, w)
    write_json(summary_path, {**json.loads(summary_path.read_text()), "pose": pose})
    for name, values in {"": pose, **pose.get("sequences", {})}.items():
        log.info(
            "train %s: pose ATE%s %.4f ± %.4f over %d snippets",
            run,
            f" of sequence {name}" if name else "",
            values["ate_mean"],
            values["ate_std"],
            values["snippets"],
        )


if __name__ == "__main__":
    sys.exit(run_stage(train, *sys.argv[1:]))
