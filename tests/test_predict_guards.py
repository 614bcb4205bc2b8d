"""`msdepth predict` never replaces a file it did not write, never reads its own outputs as inputs,
and refuses options and model outputs that would give a wrong result with exit code 0 (issue 27,
items 2, 4 and 10)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from msdepth.__main__ import main
from msdepth.io import atomic_path
from msdepth.networks.vgg import MonodepthVGG

NET_H, NET_W = 32, 96


def _save(path: Path, model: MonodepthVGG) -> Path:
    state = {"model": model.state_dict(), "criterion": {}, "width_multiplier": 0.0625}
    torch.save({**state, "height": NET_H, "width": NET_W, "variant": "tiny"}, path)
    return path


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    return _save(tmp_path_factory.mktemp("model") / "model.pt", MonodepthVGG(0.0625).eval())


def _image(path: Path, value: int) -> bytes:
    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(value)
    cv2.imwrite(str(path), cv2.resize(rng.integers(0, 256, (6, 16, 3), dtype=np.uint8), (128, 48)))
    return path.read_bytes()


def run(*args: object) -> int:
    return main(["predict", *map(str, args), "--quiet"])


def test_output_folder_equal_to_the_input_folder_is_refused(tiny: Path, tmp_path: Path, capsys) -> None:
    # Item 2: `predict p --out p` overwrote the user's p/scene_disp.png with exit code 0.
    users = _image(tmp_path / "p" / "scene_disp.png", 2)
    _image(tmp_path / "p" / "scene.png", 1)
    assert run(tmp_path / "p", "--model", tiny, "--out", tmp_path / "p") == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the output folder is the input folder" in err[0]
    assert (tmp_path / "p" / "scene_disp.png").read_bytes() == users
    assert sorted(p.name for p in (tmp_path / "p").iterdir()) == ["scene.png", "scene_disp.png"]


def test_output_folder_inside_the_input_is_skipped_on_the_next_run(
    tiny: Path, tmp_path: Path, capsys
) -> None:
    # Item 2: with --out p/depth, a second run predicted its own outputs into p/depth/depth/.
    _image(tmp_path / "p" / "scene.png", 1)
    out = tmp_path / "p" / "depth"
    assert run(tmp_path / "p", "--model", tiny, "--out", out) == 0
    first = {p.name: p.read_bytes() for p in out.iterdir()}
    assert run(tmp_path / "p", "--model", tiny, "--out", out) == 0  # its own outputs may be rewritten
    assert {p.name: p.read_bytes() for p in out.iterdir()} == first
    assert sorted(first) == [".msdepth-predict", "scene_depth.png", "scene_disp.npy", "scene_disp.png"]
    assert "wrote the outputs of 1 of 1 frame(s)" in capsys.readouterr().err


def test_the_next_run_removes_the_temp_a_killed_run_left_and_nothing_else(tiny: Path, tmp_path: Path) -> None:
    # Item 12: a run killed mid-write (kill -9) left .0016.ply.aizb060n.ply in --out for good.
    _image(tmp_path / "in" / "sub" / "0016.png", 1)
    out = tmp_path / "out"
    assert run(tmp_path / "in", "--model", tiny, "--out", out, "--ply", "binary") == 0
    first = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    # As a run killed while writing the point cloud leaves it (its name listed in the manifest).
    writer = atomic_path(out / "sub" / "0016.ply", suffix=".ply")  # kept referenced: collected, it cleans up
    killed = writer.__enter__()
    killed.write_bytes(b"ply\nhalf a point cloud")
    users = [
        out / "sub" / name for name in (".0016.ply.aizb060n.ply", ".0016.ply.msdepth-tmp-aizb060n.ply.bak")
    ]
    users.append(out / "sub" / ".mine.ply.msdepth-tmp-aizb060n.ply")  # not an output predict listed
    for path in users:
        path.write_text("a user's file")
    assert run(tmp_path / "in", "--model", tiny, "--out", out, "--ply", "binary") == 0
    assert not killed.exists()
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == {
        **first,
        **{p: b"a user's file" for p in users},
    }


def test_a_file_predict_did_not_write_is_never_replaced(tiny: Path, tmp_path: Path, capsys) -> None:
    users = _image(tmp_path / "out" / "a_disp.png", 3)  # the user's own file, in the output folder
    _image(tmp_path / "in" / "a.png", 1)
    _image(tmp_path / "in" / "b.png", 2)
    assert run(tmp_path / "in", "--model", tiny, "--out", tmp_path / "out") == 1
    err = capsys.readouterr().err
    line = (
        f"error: {tmp_path / 'in' / 'a.png'}: {tmp_path / 'out' / 'a_disp.png'}: exists and was not written"
    )
    assert line + " by msdepth predict" in err
    assert (tmp_path / "out" / "a_disp.png").read_bytes() == users
    assert not (tmp_path / "out" / "a_disp.npy").exists()  # nothing of that frame is written
    assert (tmp_path / "out" / "b_disp.png").exists()  # the other frame is


def test_an_output_that_would_replace_the_input_image_is_refused(tiny: Path, tmp_path: Path, capsys) -> None:
    # A single image named like an output of itself: x_disp.png's outputs go beside it, not over it,
    # but "x" written to the folder holding x_disp.png would; the manifest check catches the rest.
    source = _image(tmp_path / "x.png", 1)
    assert run(tmp_path / "x.png", "--model", tiny, "--out", tmp_path, "--disp-format", "npy") == 0
    assert (tmp_path / "x.png").read_bytes() == source
    _image(tmp_path / "y_disp.png", 2)
    before = (tmp_path / "y_disp.png").read_bytes()
    _image(tmp_path / "y.png", 4)
    assert run(tmp_path / "y.png", "--model", tiny, "--out", tmp_path) == 1
    assert (tmp_path / "y_disp.png").read_bytes() == before
    assert "y_disp.png: exists and was not written by msdepth predict" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("flag", "value"),
    [("--cx", "nan"), ("--cy", "inf"), ("--focal", "inf"), ("--baseline", "inf"), ("--baseline", "nan")],
)
def test_non_finite_camera_options_are_refused(
    tiny: Path, tmp_path: Path, capsys, flag: str, value: str
) -> None:
    # Item 10: accepted, giving an empty or NaN point cloud and depth with exit code 0.
    _image(tmp_path / "a.png", 1)
    assert run(tmp_path / "a.png", "--model", tiny, "--out", tmp_path / "out", flag, value) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0] == f"error: invalid prediction option(s): {flag[2:]}={float(value)!r}"
    assert not (tmp_path / "out").exists()


def test_a_model_with_nan_weights_is_refused_at_load(tmp_path: Path, capsys) -> None:
    # Issue 42 case 13: non-finite weights are refused when the file is loaded, in one line.
    torch.manual_seed(0)
    model = MonodepthVGG(0.0625).eval()
    with torch.no_grad():
        for weight in model.parameters():
            weight.fill_(float("nan"))
    path = _save(tmp_path / "nan.pt", model)
    _image(tmp_path / "a.png", 1)
    assert run(tmp_path / "a.png", "--model", path, "--out", tmp_path / "out") == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {path}: refused to load: model.") and "NaN" in err[0]
    assert not (tmp_path / "out").exists()


def test_a_model_whose_output_is_nan_fails_the_frame(tiny: Path, tmp_path: Path, capsys, monkeypatch) -> None:
    # Item 10: the colour map of a NaN disparity was written and the exit code was 0. Finite weights
    # can still overflow, so the output is checked too.
    import msdepth.cli.predict as predict_module

    def nan_output(model, images, post_process):
        return np.full((images.shape[0], images.shape[2], images.shape[3]), np.nan, np.float32)

    monkeypatch.setattr(predict_module, "network_disparity", nan_output)
    _image(tmp_path / "a.png", 1)
    assert run(tmp_path / "a.png", "--model", tiny, "--out", tmp_path / "out") == 1
    err = capsys.readouterr().err
    assert "a.png: the model's output has NaN or infinite values" in err
    assert not list((tmp_path / "out").glob("a*"))


def test_max_megapixels_refuses_a_large_image_and_keeps_the_rest(tiny: Path, tmp_path: Path, capsys) -> None:
    # Item 4: the limit is an option; a refused frame does not stop the folder.
    _image(tmp_path / "in" / "small.png", 1)
    cv2.imwrite(str(tmp_path / "in" / "large.png"), np.zeros((200, 300, 3), np.uint8))
    assert run(tmp_path / "in", "--model", tiny, "--out", tmp_path / "out", "--max-megapixels", "0.01") == 1
    err = capsys.readouterr().err
    assert "large.png: image: the header declares 300 x 200 px" in err
    assert (tmp_path / "out" / "small_disp.png").exists()
    assert not (tmp_path / "out" / "large_disp.png").exists()


@pytest.mark.parametrize(
    "error",
    [
        MemoryError(),
        RuntimeError("DefaultCPUAllocator: can't allocate memory: you tried to allocate 9600000000 bytes"),
    ],
    ids=["MemoryError", "torch-cpu-allocator"],
)
def test_running_out_of_memory_fails_the_batch_not_the_run(
    tiny: Path, tmp_path: Path, capsys, monkeypatch, error: Exception
) -> None:
    # Item 4: a MemoryError escaped the per-frame handler and ended the run with a traceback.
    import msdepth.cli.predict as predict_module

    real = predict_module.network_disparity
    calls = []

    def first_batch_runs_out(model, tensor, post_process):
        calls.append(len(tensor))
        if len(calls) == 1:
            raise error
        return real(model, tensor, post_process)

    monkeypatch.setattr(predict_module, "network_disparity", first_batch_runs_out)
    for name in ("a", "b", "c"):
        _image(tmp_path / "in" / f"{name}.png", 1)
    assert run(tmp_path / "in", "--model", tiny, "--out", tmp_path / "out", "--batch-size", "2") == 1
    err = capsys.readouterr().err
    assert f"error: {tmp_path / 'in' / 'a.png'}: out of memory while predicting it in a batch of 2" in err
    assert "b.png: out of memory" in err and calls == [2, 1]
    assert (tmp_path / "out" / "c_disp.png").exists() and not (tmp_path / "out" / "a_disp.png").exists()
