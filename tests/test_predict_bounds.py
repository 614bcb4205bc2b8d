"""predict's memory bounds (issue 42, cases 4, 6 and 7): a sparse huge image fails alone, video
frames pass the pixel limit before any is decoded, and batches are planned by pixels, not by count."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import save_tiny_model

from msdepth.__main__ import main
from msdepth.cli import predict as predict_module
from msdepth.data.imagefile import BATCH_PIXEL_BUDGET, batches_by_pixels


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return save_tiny_model(tmp_path_factory.mktemp("model") / "model.pt")


def _image(path: Path, h: int = 48, w: int = 128) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), np.random.default_rng(0).integers(0, 256, (h, w, 3), np.uint8))


def video(path: Path, width: int, height: int, frames: int = 2) -> Path:
    """A tiny MJPG .avi of ``frames`` frames of ``width`` x ``height`` px."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 5, (width, height))
    assert writer.isOpened()
    for i in range(frames):
        writer.write(np.full((height, width, 3), 40 * i, np.uint8))
    writer.release()
    return path


def _errors(err: str) -> list[str]:
    assert "Traceback" not in err
    return [line for line in err.splitlines() if line.startswith("error:")]


def test_video_frames_over_the_pixel_limit_are_refused_before_decoding(
    tiny: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Case 7: `predict big.avi --max-megapixels 1` processed two 12 MP frames and exited 0.
    clip = video(tmp_path / "big.avi", 320, 240)  # 0.077 megapixels, over a limit of 0.05
    argv = ["predict", str(clip), "--model", str(tiny), "--out", str(tmp_path / "o"), "--quiet"]
    assert main([*argv, "--max-megapixels", "0.05"]) == 1
    errors = _errors(capsys.readouterr().err)
    assert errors == [
        # the image reader's own check and words (imagefile.check_pixel_limit), the file and option added
        f"error: {clip}: the video declares 320 x 240 px (0.0768 megapixels), over the limit of 0.05 "
        "megapixels (raise it with --max-megapixels)"
    ]
    assert not (tmp_path / "o" / "big").exists()
    assert main([*argv, "--max-megapixels", "0.1"]) == 0
    assert sorted(p.name for p in (tmp_path / "o" / "big").glob("*_disp.png")) == [
        "000000_disp.png",
        "000001_disp.png",
    ]


def test_a_sparse_huge_image_fails_alone_and_the_folder_goes_on(
    tiny: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Case 4: a sparse 2 GB b.png (4 KB on disk) took 2.4 GB RSS; the other images must still be done.
    _image(tmp_path / "in" / "a.png")
    _image(tmp_path / "in" / "c.png")
    with open(tmp_path / "in" / "b.png", "wb") as file:
        file.truncate(2 * 2**30)
    out = tmp_path / "o"
    assert main(["predict", str(tmp_path / "in"), "--model", str(tiny), "--out", str(out), "--quiet"]) == 1
    errors = _errors(capsys.readouterr().err)
    assert len(errors) == 1 and errors[0].startswith(
        f"error: {tmp_path / 'in' / 'b.png'}: image: the file is 2,048 MiB"
    )
    assert errors[0].endswith("nothing of it was read (raise it with --max-megapixels)")
    assert sorted(p.name for p in out.glob("*_disp.png")) == ["a_disp.png", "c_disp.png"]


def test_batches_close_at_the_pixel_budget() -> None:
    sizes = [10, 10, 10, 40, 5, 5, 5, 5]
    got = list(batches_by_pixels(sizes, lambda n: n, max_count=3, budget=25))
    assert got == [[10, 10, 10], [40], [5, 5, 5], [5]]
    # nothing of the next batch is drawn before a batch is handed over
    drawn: list[int] = []
    for batch in batches_by_pixels((drawn.append(n) or n for n in [30, 1]), lambda n: n, 8, budget=25):
        assert drawn[-1] == batch[-1]


def test_predict_batches_large_frames_alone(tiny: Path, tmp_path: Path, monkeypatch) -> None:
    # Case 6: the default --batch-size 8 held eight decoded 120-megapixel images at once.
    for name in "abcd":
        _image(tmp_path / "in" / f"{name}.png")
    sizes: list[int] = []
    real = predict_module._network_batch

    def spy(model, images, *args):  # noqa: ANN001, ANN202 - the wrapped function's own signature
        sizes.append(len(images))
        return real(model, images, *args)

    monkeypatch.setattr(predict_module, "_network_batch", spy)
    monkeypatch.setattr(
        predict_module,
        "batches_by_pixels",
        lambda items, pixels, count: batches_by_pixels(items, pixels, count, budget=2 * 48 * 128),
    )
    options = predict_module.PredictOptions(progress=False)
    assert predict_module.predict(tmp_path / "in", tiny, tmp_path / "o", options).written == 4
    assert sizes == [2, 2] and BATCH_PIXEL_BUDGET == 32_000_000


@pytest.mark.parametrize("command", ["predict", "export-onnx"])
def test_network_sides_over_the_model_bound_are_refused(
    tiny: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    # --height/--width 100000 would have run (or traced) the network at 10^10 px.
    _image(tmp_path / "in" / "a.png")
    head = ["predict", str(tmp_path / "in")] if command == "predict" else ["export-onnx"]
    out = tmp_path / ("o" if command == "predict" else "m.onnx")
    argv = [*head, "--model", str(tiny), "--out", str(out), "--height", "100000", "--width", "100000"]
    assert main(argv) == 1
    errors = _errors(capsys.readouterr().err)
    assert len(errors) == 1 and "4096 px a side" in errors[0]
