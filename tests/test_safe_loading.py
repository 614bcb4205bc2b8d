"""A shared model or checkpoint file must not run code: crafted pickles through every loader.

Each attack file is a dict saved with ``torch.save`` whose pickle calls a function when it is
loaded (``__reduce__``): it touches a marker file. Through ``msdepth predict``, the infer stage
and a training resume the marker must never appear, and the error is one line naming the file.
"""

from __future__ import annotations

import os
import pathlib
import pickle
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import PAIR_H, PAIR_W, stage

from msdepth.config.params import params_from_dict
from msdepth.errors import MsdepthError
from msdepth.io import write_png
from msdepth.networks.serialization import load_weights_file
from msdepth.networks.vgg import MonodepthVGG
from msdepth.pipeline.paths import run_stage
from msdepth.training.train import TrainingError, TrainOptions, TrainOutputs, load_model, train_variant

ROOT = Path(__file__).resolve().parents[1]
H, W = PAIR_H, PAIR_W  # the size of conftest.py's training pairs


class Touch:
    """Unpickled, this calls ``Path.touch(marker)``: code that a file must not be able to run."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return pathlib.Path.touch, (pathlib.Path(self.marker),)


class System:
    """The classic payload: a shell command."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return os.system, (f"touch '{self.marker}'",)


def poisoned_model(path: Path, marker: Path, payload: type = Touch) -> Path:
    """A model file that works (a real network's weights) and runs the payload when unpickled."""
    torch.manual_seed(0)
    state = {
        "model": MonodepthVGG(0.0625).state_dict(),
        "criterion": {},
        "width_multiplier": 0.0625,
        "height": H,
        "width": W,
        "variant": payload(marker),
        "seed": 0,
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(state, path)
    return path


def _one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


@pytest.mark.parametrize("payload", [Touch, System])
def test_the_attack_files_are_real(tmp_path: Path, payload: type) -> None:
    """An unrestricted torch.load of the crafted file runs its code (what the tests below guard)."""
    marker = tmp_path / "ran"
    torch.load(poisoned_model(tmp_path / "model.pt", marker, payload), weights_only=False)
    assert marker.exists()


@pytest.mark.parametrize("payload", [Touch, System])
def test_load_weights_file_refuses_code_and_names_it(tmp_path: Path, payload: type) -> None:
    marker, path = tmp_path / "ran", poisoned_model(tmp_path / "model.pt", tmp_path / "ran", payload)
    with pytest.raises(MsdepthError) as err:
        load_weights_file(path)
    message = _one_line(str(err.value))
    assert message.startswith(f"{path}: refused to load: the file needs code to be unpickled")
    assert ("posix.system" if payload is System else "pathlib.Path") in message
    assert "retrain it with `dvc repro`" in message
    assert not marker.exists()


def test_predict_cli_refuses_a_poisoned_model(tmp_path: Path) -> None:
    """``python -m msdepth predict --model``: exit 1, one line naming the model, no code run, no output."""
    marker, model = tmp_path / "ran", poisoned_model(tmp_path / "shared" / "model.pt", tmp_path / "ran")
    image = tmp_path / "a.png"
    write_png(image, np.full((H, W, 3), 128, np.uint8))
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "msdepth",
            "predict",
            str(image),
            "--model",
            str(model),
            "--out",
            str(tmp_path / "out"),
            "--device",
            "cpu",
            "--quiet",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 1
    line = _one_line(result.stderr)
    assert line.startswith(f"error: {model}: refused to load: the file needs code") and "weights_only" in line
    assert not marker.exists() and not (tmp_path / "out").exists()


def test_infer_stage_refuses_a_poisoned_model(tmp_path: Path, monkeypatch, capsys) -> None:
    """The infer stage (stages/infer.py: run_stage(infer, VARIANT, SEED)) on a poisoned models/ file."""
    monkeypatch.chdir(tmp_path)
    shutil.copy(ROOT / "params.yaml", tmp_path / "params.yaml")
    marker = tmp_path / "ran"
    model = poisoned_model(Path("models") / "ssim" / "seed0" / "model.pt", marker)
    assert run_stage(stage("infer").infer, "ssim", "0") == 1
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"error: {model}: refused to load: the file needs code to be unpickled")
    assert not marker.exists() and not Path("outputs").exists()


def test_training_refuses_to_resume_a_poisoned_checkpoint(pairs, tmp_path: Path) -> None:
    """A planted checkpoint is refused (not trained over) with a TrainingError naming it; deleting it,
    as the message says, trains anew, and the files that run writes load weights-only."""
    params = params_from_dict(
        {
            "data": {"height": H, "width": W},
            "model": {"width_multiplier": 0.0625},
            "train": {"epochs": 1, "batch_size": 4, "threads": 1},
            "msssim": {"levels": 3},
        }
    )
    marker, checkpoint, model = tmp_path / "ran", tmp_path / "ck.pt", tmp_path / "model.pt"
    torch.save({"fingerprint": Touch(marker), "epoch": 1}, checkpoint)
    with pytest.raises(TrainingError) as err:
        train_variant(params, "ssim", pairs, TrainOutputs(model, checkpoint), TrainOptions(progress=False))
    message = _one_line(str(err.value))
    assert message.startswith(f"{checkpoint}: refused to load: the file needs code to be unpickled")
    assert "checkpoint file written by msdepth" in message and "delete it to train this run anew" in message
    assert not marker.exists() and not model.exists()
    assert checkpoint.exists()  # left for inspection, not overwritten

    checkpoint.unlink()
    result = train_variant(
        params, "ssim", pairs, TrainOutputs(model, checkpoint), TrainOptions(progress=False)
    )
    assert result.resumed_from_epoch == 0
    assert load_weights_file(checkpoint, what="checkpoint")["epoch"] == 1
    assert load_model(model)[1]["variant"] == "ssim"


def _zip_without(path: Path, out: Path, suffix: str) -> Path:
    """A copy of the torch zip ``path`` without its member ending in ``suffix``."""
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            if not info.filename.endswith(suffix):
                dst.writestr(info, src.read(info))
    return out


def test_damaged_or_foreign_files_are_one_line_naming_them(tmp_path: Path) -> None:
    good = tmp_path / "good.pt"
    torch.save({"model": {"w": torch.zeros(2)}}, good)
    assert torch.equal(load_weights_file(good)["model"]["w"], torch.zeros(2))

    (tmp_path / "garbage.pt").write_bytes(b"<html>not found</html>")
    (tmp_path / "truncated.pt").write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    # The legacy (non-zip) format: a bare pickle, which msdepth never writes and is not unpickled.
    (tmp_path / "legacy.pt").write_bytes(pickle.dumps({"model": {}}))
    torch.save([torch.zeros(1)], tmp_path / "list.pt")
    cases = {
        "garbage.pt": "refused to load: not a model file written by msdepth (no zip archive",
        "truncated.pt": "refused to load: not a model file written by msdepth (no zip archive",
        "legacy.pt": "refused to load: not a model file written by msdepth (no zip archive",
        "no_pickle.pt": "cannot read the model file, it is corrupt (",
        "list.pt": "not a model file written by msdepth (it holds a list, not a dict)",
        "missing.pt": "no such model file",
    }
    _zip_without(good, tmp_path / "no_pickle.pt", "data.pkl")
    for name, expected in cases.items():
        path = tmp_path / name
        with pytest.raises(MsdepthError) as err:
            load_weights_file(path)
        message = _one_line(str(err.value))
        assert message.startswith(f"{path}: {expected}"), message


def test_a_model_file_without_the_network_is_named(tmp_path: Path) -> None:
    path = tmp_path / "model.pt"
    torch.save({"model": {}, "height": H}, path)
    missing = f"{path}: not a model file written by msdepth .no width_multiplier, width.$"
    with pytest.raises(MsdepthError, match=missing):
        load_model(path)
