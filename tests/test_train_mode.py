"""train.mode and train.source_frames: stereo by default, the monocular modes only with frame sequences."""

from __future__ import annotations

import pytest

from msdepth.config import TrainConfig, fingerprint_fields, params_from_dict
from msdepth.errors import ConfigError


def test_stereo_is_the_default_and_leaves_the_fingerprint_alone() -> None:
    train = params_from_dict({}).train
    assert train.mode == "stereo" and train.source_frames == (-1, 1)
    # Added after checkpoints existed: at their defaults they are not hashed.
    assert not {"mode", "source_frames"} & set(fingerprint_fields(TrainConfig()))
    assert params_from_dict({"train": {"mode": "stereo", "source_frames": [-1, 1]}}).train == train


@pytest.mark.parametrize(
    ("train", "message"),
    [
        (
            {"mode": "mono"},
            "train.mode: 'mono' trains on frame sequences: set data.synthetic.seq",
        ),
        (
            {"mode": "mono_stereo"},
            "train.mode: 'mono_stereo' trains on frame sequences: set data",
        ),
        ({"mode": "stereo_mono"}, "train.mode: 'stereo_mono' is not one of"),
        ({"source_frames": [-1, 0, 1]}, "train.source_frames: must be distinct non-zero offsets"),
        ({"source_frames": [1, 1]}, "train.source_frames: must be distinct non-zero offsets"),
        ({"source_frames": [-2, 2]}, "train.source_frames: applies to train.mode mono and mono_stereo only"),
    ],
)
def test_bad_values_are_one_config_error(train: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        params_from_dict({"train": train})


@pytest.mark.parametrize("mode", ["mono", "mono_stereo"])
def test_monocular_modes_need_rendered_sequences(mode: str) -> None:
    sequences = {"synthetic": {"sequence_length": 3}}
    train = params_from_dict({"data": sequences, "train": {"mode": mode, "source_frames": [-1, 1]}}).train
    assert train.mode == mode
    with pytest.raises(ConfigError, match="data.synthetic.sequence_length >= 3"):
        params_from_dict({"data": {**sequences, "source": "kitti"}, "train": {"mode": mode}})
