"""GT files that declare more than they hold (issue 27, item 12): one DataError naming the file,
before anything is allocated."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from msdepth.data import kitti
from msdepth.data.ground_truth import read_gt_depth
from msdepth.errors import DataError


def _npy_declaring(shape: tuple[int, ...], body: bytes = b"\x00" * 64) -> bytes:
    header = f"{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}".encode()
    header += b" " * (-(10 + len(header) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + body


@pytest.mark.parametrize("kind", ["npy_depth", "npy_disparity"])
def test_npy_declaring_a_terabyte_is_one_data_error(tmp_path: Path, kind: str) -> None:
    # Was: MemoryError, "Unable to allocate 3.64 TiB for an array with shape (1000000000000,)".
    (tmp_path / "gt.npy").write_bytes(_npy_declaring((1_000_000, 1_000_000)))
    with pytest.raises(
        DataError, match=r"gt.npy: its header declares float32 \(1000000, 1000000\) .* it holds 64"
    ):
        read_gt_depth(kind, tmp_path / "gt.npy", focal=700.0, baseline=0.5)


def test_npz_named_npy_is_one_data_error(tmp_path: Path) -> None:
    # Was: AttributeError: 'NpzFile' object has no attribute 'ndim'.
    np.savez(tmp_path / "gt.npz", a=np.ones((4, 4), np.float32))
    (tmp_path / "gt.npz").rename(tmp_path / "gt.npy")
    with pytest.raises(DataError, match=r"gt.npy: not a readable .npy array"):
        read_gt_depth("npy_depth", tmp_path / "gt.npy", focal=700.0, baseline=0.5)


def test_a_good_npy_still_reads(tmp_path: Path) -> None:
    depth = np.array([[1.0, 0.0], [np.nan, 2.5]], np.float32)
    np.save(tmp_path / "gt.npy", depth)
    np.testing.assert_array_equal(
        read_gt_depth("npy_depth", tmp_path / "gt.npy", focal=1.0, baseline=1.0), [[1.0, 0.0], [0.0, 2.5]]
    )
    (tmp_path / "short.npy").write_bytes(_npy_declaring((4, 4), body=b"\x00" * 63))
    with pytest.raises(DataError, match=r"short.npy: its header declares float32 \(4, 4\) \(64 bytes\)"):
        read_gt_depth("npy_depth", tmp_path / "short.npy", focal=1.0, baseline=1.0)


def _calib_day(day: Path, size: str) -> Path:
    day.mkdir(parents=True, exist_ok=True)
    numbers = " ".join(["1"] * 12)
    (day / "calib_cam_to_cam.txt").write_text(
        f"S_rect_02: {size}\nR_rect_00: 1 0 0 0 1 0 0 0 1\nP_rect_02: {numbers}\n"
    )
    (day / "calib_velo_to_cam.txt").write_text("R: 1 0 0 0 1 0 0 0 1\nT: 0 0 0\n")
    return day


def test_an_unbounded_s_rect_02_is_refused(tmp_path: Path) -> None:
    # Was: lidar_depth_map attempted a 298 GiB depth map.
    day = _calib_day(tmp_path / "day", "1e7 4e6")
    with pytest.raises(
        DataError, match=r"calib_cam_to_cam.txt: S_rect_02 must be a whole width and height from 1"
    ):
        kitti.read_raw_calib(day)
    with pytest.raises(ValueError, match="lidar_depth_map: shape must be"):
        kitti.lidar_depth_map(np.ones((1, 4)), np.eye(4), np.eye(3), np.eye(3, 4), (4_000_000, 10_000_000))
    assert kitti.read_raw_calib(_calib_day(tmp_path / "ok", "1242 375")).shape == (375, 1242)


@pytest.mark.parametrize(("body", "holds"), [(b"\x00" * 76, 76), (b"\x00" * 84, 84), (b"\x00" * 81, 81)])
def test_npy_gt_whose_body_is_not_exactly_its_shape_is_one_data_error(
    tmp_path: Path, body: bytes, holds: int
) -> None:
    # Issue 42, item 4: np.load ignored trailing bytes after the declared (4, 5) float32.
    (tmp_path / "gt.npy").write_bytes(_npy_declaring((4, 5), body))
    with pytest.raises(
        DataError, match=rf"gt.npy: its header declares float32 \(4, 5\) \(80 bytes\) but it holds {holds}"
    ):
        read_gt_depth("npy_depth", tmp_path / "gt.npy", focal=700.0, baseline=0.5)
    (tmp_path / "gt.npy").write_bytes(_npy_declaring((4, 5), b"\x00" * 80))
    assert read_gt_depth("npy_depth", tmp_path / "gt.npy", focal=700.0, baseline=0.5).shape == (4, 5)


@pytest.mark.parametrize(
    "case, words",
    [
        ("missing", r"no depth map of evaluation frame 'b'"),
        (
            "shape",
            r"frame 'b''s depth map is float32 \(4, 5\), expected a float map of its GT's size \(4, 6\)",
        ),
        ("dtype", r"frame 'b''s depth map is <U1 \(4, 6\), expected a float map"),
        ("nan", r"frame 'b''s depth map holds NaN or a depth <= 0"),
        ("negative", r"frame 'b''s depth map holds NaN or a depth <= 0"),
    ],
)
def test_a_tampered_depth_npz_is_one_line_naming_it_in_the_evaluate_stage(
    tmp_path: Path, monkeypatch, case: str, words: str
) -> None:
    """Issue 68: a depth.npz missing a frame, of the wrong shape or holding NaN gave 'unexpected
    KeyError / IndexError / ValueError' in the evaluate stage (msdepth.evaluation.results.score_run),
    without the file's name."""
    from msdepth.config.params import Params
    from msdepth.evaluation import results
    from msdepth.evaluation.suites import Frame
    from msdepth.io import save_npz

    frames = [Frame(name, np.full((4, 6), 10.0, np.float32), 700.0, 0.5) for name in ("a", "b")]
    maps = {f.name: np.full((4, 6), 12.0, np.float32) for f in frames}
    if case == "missing":
        del maps["b"]
    elif case == "shape":
        maps["b"] = maps["b"][:, :5]
    elif case == "dtype":
        maps["b"] = np.full((4, 6), "x")
    else:
        maps["b"][1, 2] = np.nan if case == "nan" else -1.0
    path = tmp_path / "outputs" / "ssim" / "seed0" / "depth.npz"
    save_npz(path, **maps)
    monkeypatch.chdir(tmp_path)  # where metrics/ would be written, were the file accepted
    monkeypatch.setattr(results, "read_eval_index", lambda path: None)
    monkeypatch.setattr(results, "load_frames", lambda index: frames)
    with pytest.raises(DataError, match=rf"^{path}: {words}") as err:
        results.score_run(Params(), "full", "ssim/seed0", path, tmp_path / "i.csv", tmp_path / "r.csv")
    assert "\n" not in str(err.value) and not (tmp_path / "metrics").exists()
