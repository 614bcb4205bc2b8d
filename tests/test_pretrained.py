"""`model.pretrained` is tracked by content: the pretrained stage's record (a dep of train), the
checkpoint fingerprint, and a resume that never reads the weights file."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import sys
from pathlib import Path

import pytest
import torch
from conftest import project, require_dvc, run_checked, stage

import msdepth.training.train as train_mod
from msdepth.config.params import Params, params_from_dict
from msdepth.errors import ConfigError, DataError
from msdepth.networks.resnet import ResNetEncoder
from msdepth.pipeline.paths import PRETRAINED, run_stage
from msdepth.pipeline.pretrained import recorded_sha256, write_record
from msdepth.readers import file_sha256
from msdepth.training.train import (
    TrainingError,
    TrainOptions,
    TrainOutputs,
    _load_pretrained_encoders,
    build_model,
    train_variant,
)

# A resnet18 run that may load torchvision weights (ResNet-18's width; sides multiples of 32).
RESNET = {"data": {"height": 64, "width": 64}, "model": {"architecture": "resnet18", "width_multiplier": 1.0}}
NONE_RECORD = '{\n  "path": "",\n  "sha256": null\n}\n'


def _resnet_params(pretrained: Path) -> Params:
    return params_from_dict({**RESNET, "model": {**RESNET["model"], "pretrained": str(pretrained)}})


def test_the_record_is_the_path_and_content_hash_and_changes_only_with_them(tmp_path: Path) -> None:
    out = tmp_path / "record.json"
    assert write_record("", out) and out.read_text() == NONE_RECORD  # unset: always these bytes
    assert not write_record("", out)
    weights = tmp_path / "w.pth"
    weights.write_bytes(b"A")
    assert write_record(str(weights), out)
    assert json.loads(out.read_text()) == {"path": str(weights), "sha256": hashlib.sha256(b"A").hexdigest()}
    assert not write_record(str(weights), out)  # the same content: not rewritten (nor its mtime)
    weights.write_bytes(b"B")  # replaced under the same name
    assert write_record(str(weights), out) and recorded_sha256(str(weights), out) == file_sha256(weights)


def test_the_train_stage_reads_the_hash_back_or_stops_in_one_line(tmp_path: Path) -> None:
    record = tmp_path / "record.json"
    assert recorded_sha256("", record) is None  # unset: the record is not even read
    with pytest.raises(DataError, match=r"record.json: missing; run `dvc repro pretrained`"):
        recorded_sha256("w.pth", record)
    write_record("", record)
    with pytest.raises(DataError, match=r"record.json: records '', not model.pretrained 'w.pth'; run"):
        recorded_sha256("w.pth", record)
    record.write_text("{")
    unreadable = r"record.json: this pretrained record file is not JSON \(.*\); run `dvc repro pretrained`"
    with pytest.raises(DataError, match=unreadable):
        recorded_sha256("w.pth", record)


def test_hashing_a_missing_folder_or_unreadable_file_is_one_data_error(tmp_path: Path, monkeypatch) -> None:
    with pytest.raises(DataError, match=r"absent.pth: no such weights file$"):
        file_sha256(tmp_path / "absent.pth", "weights")
    (tmp_path / "folder.pth").mkdir()
    with pytest.raises(DataError, match=r"folder.pth: a folder, not a file$"):
        file_sha256(tmp_path / "folder.pth")
    denied = tmp_path / "denied.pth"
    denied.write_bytes(b"A")
    _deny(monkeypatch, denied.name)  # chmod does not stop root, who may run the tests
    with pytest.raises(DataError, match=r"denied.pth: cannot open this input file \(Permission denied\)$"):
        file_sha256(denied)


def test_hashing_a_fifo_is_refused_at_once(tmp_path: Path) -> None:
    """A FIFO as model.pretrained: the hash would wait forever for a writer; validate_params and the
    hash each refuse it in one line, without opening it for a blocking read."""
    fifo = tmp_path / "weights.pth"
    os.mkfifo(fifo)
    with pytest.raises(DataError, match=r"weights.pth: not a regular file \(a FIFO, a device or a socket\)"):
        file_sha256(fifo, "weights")
    raw = {**RESNET, "model": {**RESNET["model"], "pretrained": str(fifo)}}
    with pytest.raises(
        ConfigError, match=r"^model\.pretrained: not a regular file \(a FIFO, a device or a socket\): "
    ):
        params_from_dict(raw)


def _deny(monkeypatch, name: str) -> None:
    """Opening a file called ``name`` fails as an unreadable file's would."""
    real_open = os.open

    def open_(path, *args, **kwargs):
        if Path(path).name == name:
            raise PermissionError(13, "Permission denied")
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(os, "open", open_)


def test_the_pretrained_stage_writes_the_record_or_stops_in_one_line(
    tmp_path: Path, monkeypatch, capsys
) -> None:
    pretrained = stage("pretrained").pretrained
    monkeypatch.chdir(tmp_path)
    Path("params.yaml").write_text("{}\n")  # model.pretrained: "", the default
    assert run_stage(pretrained) == 0 and PRETRAINED.read_text() == NONE_RECORD
    PRETRAINED.unlink()
    Path("resnet18.pth").write_bytes(b"A")
    for target, message in [
        ("absent.pth", "params.yaml: model.pretrained: no such file: absent.pth"),  # validate_params' check
        ("resnet18.pth", "model.pretrained: resnet18.pth: cannot open this weights file (Permission denied)"),
    ]:
        model = {**RESNET["model"], "pretrained": target}
        Path("params.yaml").write_text(json.dumps({**RESNET, "model": model}))
        with monkeypatch.context() as patch:
            _deny(patch, "resnet18.pth")
            assert run_stage(pretrained) == 1
        assert capsys.readouterr().err == f"error: {message}\n"
        assert not PRETRAINED.exists()
    assert run_stage(pretrained) == 0
    assert json.loads(PRETRAINED.read_text())["sha256"] == hashlib.sha256(b"A").hexdigest()


def test_the_fingerprint_hashes_the_content_not_the_path(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(train_mod, "_code_digest", lambda: "fixed")
    a, b = tmp_path / "a.pth", tmp_path / "b.pth"
    a.write_bytes(b"A")
    b.write_bytes(b"A")
    at_a, at_b = _resnet_params(a), _resnet_params(b)
    first = train_mod.fingerprint(at_a, "ssim", 8, 0, file_sha256(a))
    assert train_mod.fingerprint(at_b, "ssim", 8, 0, file_sha256(b)) == first  # moved: still resumed
    a.write_bytes(b"B")  # replaced under the same name: trained anew
    assert train_mod.fingerprint(at_a, "ssim", 8, 0, file_sha256(a)) != first
    assert train_mod.fingerprint(params_from_dict(RESNET), "ssim", 8, 0) != first  # from scratch
    with pytest.raises(TrainingError, match="model.pretrained is set: the fingerprint needs its content"):
        train_mod.fingerprint(at_a, "ssim", 8, 0)


def test_weights_changed_since_they_were_hashed_are_refused(tmp_path: Path) -> None:
    weights = tmp_path / "resnet18.pth"
    weights.write_bytes(b"B")
    model = build_model(params_from_dict({**RESNET, "model": {"architecture": "resnet18"}}))
    with pytest.raises(
        TrainingError, match=r"resnet18.pth: content changed since it was hashed \(sha256 0000"
    ):
        _load_pretrained_encoders(weights, model, None, sha256="0" * 64)


def test_a_fresh_run_loads_the_weights_and_a_resume_never_reads_them(pairs, tmp_path: Path, monkeypatch):
    # A narrow encoder's state dict, the config's ResNet-18 width check left out (dataclasses.replace):
    # the run then costs what test_train.py's do.
    base = params_from_dict(
        {
            "data": {"height": 64, "width": 64},
            "model": {"architecture": "resnet18", "width_multiplier": 0.0625},
            "train": {"epochs": 2, "batch_size": 4, "threads": 1},
        }
    )
    weights = tmp_path / "resnet18.pth"
    torch.manual_seed(3)
    torch.save(ResNetEncoder(width_multiplier=0.0625).state_dict(), weights)
    params = dataclasses.replace(base, model=dataclasses.replace(base.model, pretrained=str(weights)))
    digest, loads = file_sha256(weights), []
    real_load, real_save = train_mod.load_pretrained, train_mod._save_checkpoint
    monkeypatch.setattr(
        train_mod, "load_pretrained", lambda enc, path: (loads.append(path), real_load(enc, path))
    )

    def save_then_die(path, state):
        real_save(path, state)
        raise KeyboardInterrupt  # killed right after the first epoch's checkpoint

    def train(**kwargs):
        outputs = TrainOutputs(tmp_path / "m.pt", tmp_path / "ck.pt")
        return train_variant(params, "ssim", pairs, outputs, TrainOptions(progress=False, **kwargs))

    monkeypatch.setattr(train_mod, "_save_checkpoint", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        train(pretrained_sha256=digest)
    assert loads == [str(weights)]  # the fresh start
    monkeypatch.setattr(train_mod, "_save_checkpoint", real_save)
    shutil.move(weights, tmp_path / "moved.pth")
    assert train(pretrained_sha256=digest).resumed_from_epoch == 1 and loads == [str(weights)]
    # Without the recorded hash the file is hashed here, so even a resume needs it: one line.
    with pytest.raises(DataError, match=r"resnet18.pth: no such weights file$"):
        train()


@pytest.mark.slow
def test_replacing_the_weights_under_the_same_name_makes_train_stale(tmp_path: Path) -> None:
    """The real dvc.yaml with stand-ins for train's inputs and outputs committed (no training): once
    the pretrained stage has recorded the new content, train@ssim-0's one changed dep is its record
    (the exact status: everything else is as committed)."""
    require_dvc()
    weights = tmp_path / "resnet18.pth"
    weights.write_bytes(b"A")
    patch = {**RESNET, "model": {**RESNET["model"], "pretrained": str(weights)}, "train": {"seeds": [0]}}
    (tmp_path / "work").mkdir()
    work = project(tmp_path / "work", patch)
    for name in ("data/cache/train_pairs.txt", "data/cache/train_pairs.npy", "data/synthetic/x"):
        (work / name).parent.mkdir(parents=True, exist_ok=True)
        (work / name).write_text("an input\n")
    for name in ("models/ssim/seed0/model.pt", "plots/train/ssim/seed0/x", "metrics/train/ssim/seed0.json"):
        (work / name).parent.mkdir(parents=True, exist_ok=True)
        (work / name).write_text("an output\n")
    dvc = [sys.executable, "-m", "dvc"]
    run_checked([*dvc, "repro", "--quiet", "pretrained"], work)
    run_checked([*dvc, "commit", "--force", "--quiet", "train@ssim-0"], work)
    weights.write_bytes(b"B")
    run_checked([*dvc, "repro", "--quiet", "pretrained"], work)  # `dvc repro` runs it before train
    status = json.loads(run_checked([*dvc, "status", "--json", "train@ssim-0"], work))
    assert status == {"train@ssim-0": [{"changed deps": {str(PRETRAINED): "modified"}}]}
