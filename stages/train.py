"""Stage ``train@<variant>-<seed>``: train one loss variant with one seed."""

from __future__ import annotations

import logging
import sys

from msdepth.config.params import Params
from msdepth.data.pairs import load_pair_cache, load_pair_list
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
    train_plots_dir,
    train_summary_path,
    train_timing_path,
)
from msdepth.pipeline.pretrained import recorded_sha256

log = logging.getLogger("msdepth")


def train(params: Params, variant: VariantArg, seed: SeedArg) -> None:
    """Train one loss variant with one seed; write its model, training summary and dvclive curves."""
    from msdepth.evaluation.pose import add_pose_metrics
    from msdepth.training import distributed
    from msdepth.training.run import monocular_sequences, result_line
    from msdepth.training.train import TrainOptions, TrainOutputs, train_variant, trained_pose_net

    run = checked_run(params, variant, seed)
    if distributed.must_relaunch(params.train.launcher):  # its ranks come back here
        distributed.relaunch("stages/train.py", [variant, seed], params.train.nproc, f"train {run}")
        return
    pairs = load_pair_list(CACHED_PAIRS)  # the pairs the cache holds, in its order
    images = load_pair_cache(PAIR_CACHE, len(pairs), *params.image_size)
    sequences = monocular_sequences(params)
    result = train_variant(
        params,
        variant,
        pairs,
        TrainOutputs(
            model_path(run),
            checkpoint_path(run),
            live_dir=train_plots_dir(run),
            summary_path=train_summary_path(run),
            timing_path=train_timing_path(run),
        ),
        TrainOptions(
            cache=images,
            seed=params.seed(seed),
            sequences=sequences,
            # The pretrained stage's hash: the fingerprint's, so that a resume never reads the weights.
            pretrained_sha256=recorded_sha256(params.model.pretrained, PRETRAINED),
        ),
    )
    if sequences is not None and distributed.is_main_process():  # a monocular run: its pose net too
        net = trained_pose_net(params, checkpoint_path(run))
        add_pose_metrics(params, net, run, train_summary_path(run))
    log.info("train %s: %s", run, result_line(result))


if __name__ == "__main__":
    sys.exit(run_stage(train, *sys.argv[1:]))
