"""What the train stage needs around :func:`msdepth.training.train.train_variant`: the frame
sequences of the monocular modes and the line that sums a run up."""

from __future__ import annotations

from msdepth.config.params import Params
from msdepth.data.layout import layout
from msdepth.data.sequences import SequenceSample, training_sequences
from msdepth.errors import MsdepthError
from msdepth.training.train import TrainResult


def monocular_sequences(params: Params) -> list[SequenceSample] | None:
    """Monodepth2's M / MS (``train.mode`` mono | mono_stereo): the samples of the rendered
    sequences of ``data.kitti.mono_split``; None in stereo mode, which trains on the pairs."""
    t = params.train
    if t.mode == "stereo":
        return None
    paths = layout(params)
    if paths.mono_split is None:  # the config accepts the modes only with rendered sequences
        raise MsdepthError(f"train.mode {t.mode}: data.source {params.data.source} has no sequences")
    return training_sequences(paths.mono_split, paths.raw_root, t.source_frames, t.mode == "mono_stereo")


def result_line(result: TrainResult) -> str:
    """The steps, the epoch it resumed from and the time of a training run, in one line."""
    resumed = f", resumed from epoch {result.resumed_from_epoch}" if result.resumed_from_epoch else ""
    return (
        f"{result.steps} steps{resumed}; {result.seconds:.0f} s of training, "
        f"{result.seconds_this_run:.0f} s in this run ({result.examples_per_second:.1f} examples/s)"
    )
