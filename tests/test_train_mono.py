"""train.mode mono and mono_stereo: Monodepth2's training on rendered frame sequences."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
import torch

from msdepth import render
from msdepth.config.params import SyntheticConfig, params_from_dict
from msdepth.data import sequences
from msdepth.data.layout import MONO_SPLIT, layout
from msdepth.errors import DataError, MsdepthError
from msdepth.training.train import TrainOptions, TrainOutputs, load_model, train_variant

H, W = 64, 192  # the pose network's ResNet-18 needs sides of 64 px or more
RENDER = {"seed": 3, "drives": 1, "train_pairs": 6, "eval_frames": 1, "height": 64, "width": 192}


@pytest.fixture(scope="module")
def raw(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("sequences")
    cfg = SyntheticConfig(**RENDER, sequence_length=6)
    render.generate(cfg, root, progress=False, workers=1, lidar=False)
    return root


def _params(mode: str, **train):
    return params_from_dict(
        {
            "data": {"height": H, "width": W, "synthetic": {**RENDER, "sequence_length": 6}},
            "model": {"width_multiplier": 0.0625},
            "train": {"epochs": 1, "batch_size": 2, "threads": 1, "mode": mode, **train},
        }
    )


def _samples(raw: Path, stereo: bool) -> list[sequences.SequenceSample]:
    entries = sequences._read_mono_split(raw / MONO_SPLIT)
    return sequences._index_sequences(raw / "raw", entries, stereo=stereo).samples


@pytest.mark.parametrize("mode", ["mono", "mono_stereo"])
def test_trains_and_writes_the_model_and_summary(raw: Path, tmp_path: Path, mode: str) -> None:
    samples = _samples(raw, mode == "mono_stereo")
    assert len(samples) == 8  # frames 1..4, both cameras
    params = _params(mode, augment=True)
    summary = tmp_path / "summary.json"
    result = train_variant(
        params,
        "ssim",
        [],
        TrainOutputs(tmp_path / "model.pt", tmp_path / "ck.pt", summary_path=summary),
        TrainOptions(progress=False, sequences=samples),
    )
    assert result.steps == 4
    losses = json.loads(summary.read_text())["final_losses"]
    assert set(losses) == {"total", "appearance", "smoothness", "automask"}
    assert all(torch.isfinite(torch.tensor(v)) for v in losses.values())
    model, meta = load_model(tmp_path / "model.pt")
    assert meta["variant"] == "ssim" and model(torch.rand(1, 3, H, W))[0].shape == (1, 2, H, W)
    assert "pose" in torch.load(tmp_path / "ck.pt", weights_only=True)


def test_loss_decreases_over_steps(raw: Path, tmp_path: Path) -> None:
    """On the same batch again and again (batch = the whole set), the loss goes down."""
    samples = _samples(raw, False)[:2]
    params = _params("mono", epochs=6, batch_size=2, learning_rate=1e-3)
    outputs = TrainOutputs(tmp_path / "m.pt", tmp_path / "ck.pt")
    train_variant(params, "ssim", [], outputs, TrainOptions(progress=False, sequences=samples))
    history = torch.load(tmp_path / "ck.pt", weights_only=True)["history"]
    totals = [entry["total"] for entry in history]
    assert totals[-1] < totals[0], totals


def test_same_params_same_bytes(raw: Path, tmp_path: Path) -> None:
    samples = _samples(raw, True)
    for run in ("a", "b"):
        (tmp_path / run).mkdir()
        train_variant(
            _params("mono_stereo", augment=True),
            "ssim",
            [],
            TrainOutputs(tmp_path / run / "m.pt", tmp_path / run / "ck.pt"),
            TrainOptions(progress=False, sequences=samples),
        )
    assert (tmp_path / "a" / "m.pt").read_bytes() == (tmp_path / "b" / "m.pt").read_bytes()


def test_mono_without_sequences_is_one_error(tmp_path: Path) -> None:
    outputs = TrainOutputs(tmp_path / "m.pt", tmp_path / "ck.pt")
    with pytest.raises(MsdepthError, match="train.mode mono trains on frame sequences"):
        train_variant(_params("mono"), "ssim", [], outputs, TrainOptions(progress=False))


def test_the_layout_names_the_rendered_split(raw: Path, tmp_path: Path) -> None:
    """What the train stage reads in the monocular modes: the split below data.root, its frames."""
    params = _params("mono_stereo")
    paths = layout(dataclasses.replace(params, data=dataclasses.replace(params.data, root=str(raw))))
    assert paths.mono_split == raw / MONO_SPLIT
    samples = sequences.training_sequences(paths.mono_split, paths.raw_root, (-1, 1), stereo=True)
    assert samples == _samples(raw, True)
    with pytest.raises(DataError, match=r"no usable frame .*\(0 missing, 8 without a neighbour\)"):
        sequences.training_sequences(paths.mono_split, paths.raw_root, (-3, 3), stereo=False)
