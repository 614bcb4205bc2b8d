"""Malformed checkpoints and state dicts are one line naming the file; non-finite weights are refused
at load and at save (issue 42, case 13)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import torch

from msdepth.config.params import Params, params_from_dict
from msdepth.errors import MsdepthError
from msdepth.networks.resnet import ResNetEncoder, load_pretrained
from msdepth.networks.serialization import load_weights_file, save_weights_file
from msdepth.training.train import TrainingError, TrainOptions, TrainOutputs, train_variant

H, W = 32, 64


def _params() -> Params:
    return params_from_dict(
        {
            "data": {"height": H, "width": W},
            "model": {"width_multiplier": 0.0625},
            "train": {"epochs": 1, "batch_size": 4, "threads": 1},
            "msssim": {"levels": 3},
        }
    )


@pytest.fixture(scope="module")
def checkpoint(pairs, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The checkpoint of a complete one-epoch run."""
    tmp = tmp_path_factory.mktemp("run")
    train_variant(
        _params(), "ssim", pairs, TrainOutputs(tmp / "model.pt", tmp / "ck.pt"), TrainOptions(progress=False)
    )
    return tmp / "ck.pt"


def _first_float(state: dict) -> str:
    return next(k for k, v in state.items() if v.is_floating_point())


def _no_criterion(state: dict) -> None:
    del state["criterion"]


def _wrong_shape(state: dict) -> None:
    name = _first_float(state["model"])
    state["model"][name] = torch.zeros(3, 3)


def _bad_rng(state: dict) -> None:
    state["torch_rng"] = torch.zeros(3, dtype=torch.uint8)


def _negative_epoch(state: dict) -> None:
    state["epoch"] = -5


def _nan_weights(state: dict) -> None:
    name = _first_float(state["model"])
    state["model"][name] = torch.full_like(state["model"][name], float("nan"))


@pytest.mark.parametrize(
    ("damage", "expected"),
    [
        (_no_criterion, "a malformed checkpoint (no criterion entry)"),
        (_wrong_shape, "in loading state_dict for MonodepthVGG: size mismatch for encoder."),
        (_bad_rng, "a malformed checkpoint ("),
        (_negative_epoch, "a malformed checkpoint (epoch -5 and step"),
        (_nan_weights, "refused to load: model."),
    ],
)
def test_a_malformed_checkpoint_is_one_line_naming_it(
    pairs, checkpoint: Path, tmp_path: Path, damage, expected
) -> None:
    # Was: KeyError, RuntimeError tracebacks, a negative epoch taken, and a NaN model written as "done".
    state = load_weights_file(checkpoint, what="checkpoint")
    damage(state)
    bad = tmp_path / "ck.pt"
    torch.save(state, bad)  # not save_weights_file: that refuses NaN weights
    model = tmp_path / "model.pt"
    with pytest.raises(TrainingError) as err:
        train_variant(_params(), "ssim", pairs, TrainOutputs(model, bad), TrainOptions(progress=False))
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"{bad}: ") and expected in message, message
    assert "delete it to train this run anew" in message
    assert not model.exists()


def test_non_finite_weights_are_not_saved(checkpoint: Path, tmp_path: Path) -> None:
    state = load_weights_file(checkpoint, what="checkpoint")
    _nan_weights(state)
    with pytest.raises(
        MsdepthError, match=r"model\.pt: not written: model\.\S+ holds NaN or infinite values"
    ):
        save_weights_file(tmp_path / "model.pt", state)
    assert list(tmp_path.iterdir()) == []
    shutil.copy(checkpoint, tmp_path / "ok.pt")  # a finite state still loads
    assert load_weights_file(tmp_path / "ok.pt", what="checkpoint")["epoch"] == 1


def test_a_pretrained_state_dict_with_an_integer_key_or_nan_weights_is_one_line(tmp_path: Path) -> None:
    encoder = ResNetEncoder()
    state = dict(encoder.state_dict())
    torch.save({**state, 3: torch.zeros(1)}, tmp_path / "int.pt")
    with pytest.raises(
        MsdepthError, match=r"int\.pt: not a torchvision resnet18 state dict \(a key that is not"
    ):
        load_pretrained(encoder, tmp_path / "int.pt")
    name = _first_float(state)
    torch.save({**state, name: torch.full_like(state[name], float("inf"))}, tmp_path / "inf.pt")
    with pytest.raises(MsdepthError, match=rf"inf\.pt: refused to load: {name} holds NaN or infinite"):
        load_pretrained(encoder, tmp_path / "inf.pt")
