"""Model files cannot make loading allocate without bound, slip past the zip check, or carry
metadata that runs away (issue 27, items 5, 6 and the state-dict message of 12)."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import pytest
import torch

from msdepth.errors import MsdepthError
from msdepth.networks.model_file import load_model
from msdepth.networks.serialization import load_weights_file
from msdepth.networks.vgg import MonodepthVGG

MULTIPLIER = 0.0625


def _state(**changes: object) -> dict:
    torch.manual_seed(0)
    state = {
        "model": MonodepthVGG(MULTIPLIER).state_dict(),
        "criterion": {},
        "width_multiplier": MULTIPLIER,
        "height": 32,
        "width": 96,
        "variant": "tiny",
        "seed": 0,
    }
    return {**state, **changes}


def _save(path: Path, state: dict) -> Path:
    torch.save(state, path)
    return path


class _Allocate:
    """Pickles as ``bytearray(size)``: a few bytes in the file, ``size`` bytes once unpickled."""

    def __init__(self, size: int) -> None:
        self.size = size

    def __reduce__(self) -> tuple:
        return bytearray, (self.size,)


def test_weights_only_bytearray_is_refused_before_unpickling(tmp_path: Path) -> None:
    # Item 5: weights-only builds bytearray(n): bytearray(3 GiB) took 3.4 GB RSS, and predict went on.
    path = _save(tmp_path / "m.pt", _state(variant=_Allocate(2**20)))
    assert torch.load(path, weights_only=True)["variant"] == bytearray(2**20)  # what torch alone does
    with pytest.raises(
        MsdepthError, match=r"m.pt: refused to load: .*it names (__builtin__|builtins).bytearray"
    ):
        load_weights_file(path)


def test_deflated_records_are_refused(tmp_path: Path) -> None:
    # Item 5: deflated records expanded without limit (a 1.5 MB file took 1.35 GB).
    plain = _save(tmp_path / "plain.pt", _state())
    with (
        zipfile.ZipFile(plain) as src,
        zipfile.ZipFile(tmp_path / "packed.pt", "w", zipfile.ZIP_DEFLATED) as dst,
    ):
        for info in src.infolist():
            dst.writestr(info.filename, src.read(info))
    assert torch.load(tmp_path / "packed.pt", weights_only=True)["height"] == 32  # torch reads it
    with pytest.raises(MsdepthError, match=r"packed.pt: refused to load: its zip record .* is compressed"):
        load_weights_file(tmp_path / "packed.pt")


def test_legacy_pickle_with_a_zip_appended_is_refused(tmp_path: Path) -> None:
    # Item 6: zipfile.is_zipfile finds the appended zip's directory; torch reads the first bytes and
    # takes its legacy loader. The file loaded and predicted with exit code 0.
    legacy = io.BytesIO()
    torch.save(_state(), legacy, _use_new_zipfile_serialization=False)
    appended = io.BytesIO()
    with zipfile.ZipFile(appended, "w") as archive:
        archive.writestr("x", b"x")
    (tmp_path / "m.pt").write_bytes(legacy.getvalue() + appended.getvalue())
    assert zipfile.is_zipfile(tmp_path / "m.pt")
    with pytest.raises(MsdepthError, match=r"m.pt: refused to load: .*no zip archive from its first byte"):
        load_weights_file(tmp_path / "m.pt")


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"width_multiplier": -32}, r"width_multiplier must be a number in \(0, 16\], got -32"),
        ({"width_multiplier": 0}, "width_multiplier must be a number"),
        ({"width_multiplier": "abc"}, "width_multiplier must be a number .* got 'abc'"),
        ({"width_multiplier": True}, "width_multiplier must be a number"),
        ({"width_multiplier": float("nan")}, "width_multiplier must be a number"),
        ({"height": 20000, "width": 20000}, "height must be a multiple of 8 from 32 to 4096 px, got 20000"),
        ({"width": 0}, "width must be a multiple of 8"),
        ({"width": "abc"}, "width must be a multiple of 8 .* got 'abc'"),
        ({"height": 33}, "height must be a multiple of 8"),
        ({"norm": 7}, "norm must be one of"),
        ({"extra": 1}, "unknown entry extra"),
        ({"model": [1, 2]}, "its 'model' entry is not a state dict of tensors"),
    ],
)
def test_bad_metadata_is_one_line(tmp_path: Path, changes: dict, message: str) -> None:
    # Item 5: -32, 0 or "abc" gave a traceback; 20000 x 20000 ran into a 4.8 GB allocation.
    path = _save(tmp_path / "m.pt", _state(**changes))
    with pytest.raises(MsdepthError, match=rf"m.pt: not a model file written by msdepth \({message}"):
        load_model(path)


def test_a_multiplier_that_disagrees_with_the_weights_names_the_shapes(tmp_path: Path) -> None:
    # Item 5 (3.0 with small weights would build a large network first) and item 12: the message was
    # cut to "Error(s) in loading state_dict for MonodepthVGG", without the keys or shapes.
    path = _save(tmp_path / "m.pt", _state(width_multiplier=3.0))
    with pytest.raises(MsdepthError) as err:
        load_model(path)
    message = str(err.value)
    assert "\n" not in message
    expected = f"{path}: its weights do not fit a vgg network of width_multiplier=3.0: shape of "
    assert message.startswith(expected)
    assert "encoder.0.1.0.weight (2, 2, 7, 7) (expected (96, 96, 7, 7)) and 57 more" in message


def test_missing_and_unexpected_keys_are_named(tmp_path: Path) -> None:
    weights = dict(MonodepthVGG(MULTIPLIER).state_dict())
    first = next(iter(weights))
    weights["extra.weight"] = weights.pop(first)
    path = _save(tmp_path / "m.pt", _state(model=weights))
    with pytest.raises(MsdepthError, match=rf"missing {first}; unexpected extra.weight$"):
        load_model(path)


def test_a_good_file_still_loads(tmp_path: Path) -> None:
    model, meta = load_model(_save(tmp_path / "m.pt", _state()))
    assert meta["height"] == 32 and not model.training
