"""train.mode and train.source_frames: stereo by default, the monocular modes only with frame sequences."""

from __future__ import annotations

import pytest

from msdepth.config.params import TrainConfig, fingerprint_fields, params_from_dict
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
            "train.mode: 'mono' trains on frame sequences: KITTI's raw drives (data.source kitti) or",
        ),
        (
            {"mode": "mono_stereo"},
            "train.mode: 'mono_stereo' trains on frame sequences: KITTI's raw drives",
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
def test_monocular_modes_need_rendered_or_kitti_sequences(mode: str) -> None:
    sequences = {"synthetic": {"sequence_length": 3}}
    train = params_from_dict({"data": sequences, "train": {"mode": mode, "source_frames": [-1, 1]}}).train
    assert train.mode == mode
    # KITTI's raw drives are sequences: Monodepth2's eigen_zhou split names their frames.
    kitti = params_from_dict({"data": {"source": "kitti"}, "train": {"mode": mode}})
    assert kitti.data.kitti.mono_split == "data_lists/eigen_zhou_train_files.txt"
    with pytest.raises(ConfigError, match="data.synthetic.sequence_length >= 3"):
        params_from_dict({"data": {"source": "synthetic"}, "train": {"mode": mode}})
    with pytest.raises(ConfigError, match="here data.source is folder"):
        folder = {"source": "folder", "root": "f"}
        params_from_dict({"data": folder, "eval": {"extra_sets": []}, "train": {"mode": mode}})


@pytest.mark.parametrize("sequences", [["9/../x"], ["../09"], [""]])
def test_odometry_sequences_are_numbers_not_paths(sequences: list[str]) -> None:
    with pytest.raises(ConfigError, match="odometry_sequences: must be KITTI odometry sequence numbers"):
        params_from_dict({"data": {"kitti": {"odometry_sequences": sequences}}})
