"""Readers and writers of KITTI's on-disk formats: round trips, every DataError case, real samples."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from msdepth.data import kitti
from msdepth.data.sequences import SplitEntry, _read_mono_split
from msdepth.errors import DataError
from msdepth.io import write_png

SHARED = Path(__file__).resolve().parents[2] / "shared"
REAL = SHARED / "real-samples" / "kitti-object-pair"

RAW_CALIB = """calib_time: 09-Jan-2012 13:57:47
corner_dist: 9.950000e-02
S_02: 1.392000e+03 5.120000e+02
K_02: 9.597910e+02 0.000000e+00 6.960217e+02 0.000000e+00 9.569251e+02 2.241806e+02 0.000000e+00 0.000000e+00 1.000000e+00
S_rect_02: 1.242000e+03 3.750000e+02
P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01 0.000000e+00 7.215377e+02 1.728540e+02 2.163791e-01 0.000000e+00 0.000000e+00 1.000000e+00 2.745884e-03
P_rect_03: 7.215377e+02 0.000000e+00 6.095593e+02 -3.395242e+02 0.000000e+00 7.215377e+02 1.728540e+02 2.199936e+00 0.000000e+00 0.000000e+00 1.000000e+00 2.729905e-03
"""


def _rgb(h: int = 12, w: int = 20, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


# ---------------------------------------------------------------------------------- images


def test_image_round_trip_keeps_rgb_order(tmp_path: Path) -> None:
    img = _rgb()
    img[0, 0] = (255, 0, 0)
    write_png(tmp_path / "a.png", img)
    back = kitti.read_image(tmp_path / "a.png")
    assert back.dtype == np.uint8 and back.shape == img.shape
    np.testing.assert_array_equal(back, img)
    assert tuple(back[0, 0]) == (255, 0, 0)


def test_read_image_reads_jpeg(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "a.jpg"), _rgb())
    assert kitti.read_image(tmp_path / "a.jpg").shape == (12, 20, 3)


def test_read_image_missing_file(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="nope.png.*no such"):
        kitti.read_image(tmp_path / "nope.png")


def test_read_image_zero_bytes(tmp_path: Path) -> None:
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(DataError, match="empty.png.*0 bytes"):
        kitti.read_image(tmp_path / "empty.png")


def test_read_image_truncated_png(tmp_path: Path) -> None:
    write_png(tmp_path / "full.png", _rgb(64, 64))
    data = (tmp_path / "full.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match="cut.png.*truncated"):
        kitti.read_image(tmp_path / "cut.png")


def test_read_image_truncated_jpeg(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "full.jpg"), _rgb(64, 64))
    data = (tmp_path / "full.jpg").read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match="cut.jpg.*truncated"):
        kitti.read_image(tmp_path / "cut.jpg")


def test_read_image_not_an_image(tmp_path: Path) -> None:
    (tmp_path / "junk.png").write_bytes(b"this is not a png at all")
    with pytest.raises(DataError, match="junk.png.*decode"):
        kitti.read_image(tmp_path / "junk.png")


@pytest.mark.parametrize(
    "image, expected",
    [
        (np.full((8, 8), 100, np.uint8), 100),  # grey: repeated into R, G and B
        (np.full((8, 8, 3), 100 * 257, np.uint16), 100),  # 16-bit: scaled to 8 bits
        (np.full((8, 8, 4), 100, np.uint8), 100),  # BGRA: the alpha channel dropped
    ],
    ids=["grey", "16-bit", "rgba"],
)
def test_read_image_converts_grey_16_bit_and_alpha(tmp_path: Path, image: np.ndarray, expected: int) -> None:
    # These were refused ("expected an 8-bit 3-channel image"), though a conversion serves the user.
    cv2.imwrite(str(tmp_path / "x.png"), image)
    img = kitti.read_image(tmp_path / "x.png")
    assert img.dtype == np.uint8 and img.shape == (8, 8, 3)
    np.testing.assert_array_equal(img, np.full((8, 8, 3), expected, np.uint8))


# ------------------------------------------------------------------------------ disparity


def test_disparity_round_trip(tmp_path: Path) -> None:
    disp = np.array([[0.0, 1.0, 12.3456], [100.0, 0.001, 300.0]], np.float32)
    kitti.write_disparity(tmp_path / "d.png", disp)
    raw = cv2.imread(str(tmp_path / "d.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.ndim == 2
    assert raw[0, 0] == 0 and raw[0, 1] == 256 and raw[1, 0] == 25600
    assert raw[1, 1] == 1  # a tiny valid disparity stays valid
    assert raw[1, 2] == 65535  # clipped
    back = kitti.read_disparity(tmp_path / "d.png")
    assert back.dtype == np.float32
    assert abs(back[0, 2] - 12.3456) <= 1 / 512
    assert back[0, 0] == 0


@pytest.mark.parametrize("bad", [np.float32(-1.0), np.float32(np.nan)])
def test_write_disparity_rejects_negative_and_nan(tmp_path: Path, bad: np.float32) -> None:
    with pytest.raises(DataError, match="d.png"):
        kitti.write_disparity(tmp_path / "d.png", np.array([[1.0, bad]], np.float32))


@pytest.mark.parametrize(
    "image", [np.zeros((8, 8), np.uint8), np.zeros((8, 8, 3), np.uint16)], ids=["uint8", "3-channel"]
)
def test_read_disparity_rejects_wrong_type(tmp_path: Path, image: np.ndarray) -> None:
    cv2.imwrite(str(tmp_path / "d.png"), image)
    with pytest.raises(DataError, match="d.png.*16-bit single-channel"):
        kitti.read_disparity(tmp_path / "d.png")


def test_read_disparity_zero_bytes_and_missing(tmp_path: Path) -> None:
    (tmp_path / "d.png").write_bytes(b"")
    with pytest.raises(DataError, match="d.png"):
        kitti.read_disparity(tmp_path / "d.png")
    with pytest.raises(DataError, match="missing.png"):
        kitti.read_disparity(tmp_path / "missing.png")


def test_obj_map_round_trip_and_wrong_type(tmp_path: Path) -> None:
    ids = np.zeros((6, 9), np.uint8)
    ids[1:3, 2:5] = 1
    ids[4, 7] = 2
    write_png(tmp_path / "o.png", ids)
    np.testing.assert_array_equal(kitti.read_obj_map(tmp_path / "o.png"), ids)
    write_png(tmp_path / "o16.png", ids.astype(np.uint16))
    with pytest.raises(DataError, match="o16.png.*8-bit single-channel"):
        kitti.read_obj_map(tmp_path / "o16.png")


# ------------------------------------------------------------------------------- calibration


def test_read_calib_raw_format(tmp_path: Path) -> None:
    (tmp_path / "calib_cam_to_cam.txt").write_text(RAW_CALIB)
    calib = kitti.read_calib(tmp_path / "calib_cam_to_cam.txt")
    assert "calib_time" not in calib  # non-numeric values are skipped
    assert calib["S_rect_02"].tolist() == [1242.0, 375.0]
    assert calib["P_rect_02"].shape == (12,)
    focal, baseline = kitti.stereo_from_calib(calib)
    assert focal == pytest.approx(721.5377)
    assert baseline == pytest.approx((44.85728 + 339.5242) / 721.5377)


def test_read_calib_object_format(tmp_path: Path) -> None:
    p2 = " ".join(map(str, [700.0, 0, 600, 0, 0, 700, 180, 0, 0, 0, 1, 0]))
    p3 = " ".join(map(str, [700.0, 0, 600, -378, 0, 700, 180, 0, 0, 0, 1, 0]))
    (tmp_path / "calib.txt").write_text(f"P2: {p2}\nP3: {p3}\n\nR0_rect: 1 0 0 0 1 0 0 0 1\n")
    focal, baseline = kitti.stereo_from_calib(kitti.read_calib(tmp_path / "calib.txt"))
    assert (focal, baseline) == (pytest.approx(700.0), pytest.approx(0.54))


def test_calib_errors(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="none.txt.*no such"):
        kitti.read_calib(tmp_path / "none.txt")
    (tmp_path / "words.txt").write_text("calib_time: yesterday\nhello world\n")
    with pytest.raises(DataError, match="words.txt.*no numeric"):
        kitti.read_calib(tmp_path / "words.txt")
    with pytest.raises(DataError, match="P_rect_02"):
        kitti.stereo_from_calib({"K_02": np.eye(3).ravel()})
    with pytest.raises(DataError, match="12 values"):
        kitti.stereo_from_calib({"P2": np.ones(9), "P3": np.ones(9)})


@pytest.mark.parametrize(
    ("p2", "p3", "problem"),
    [
        ("1e-300 0 80 0", "1e-300 0 80 -1e-300", r"focal length must be 1 to 100000 px, got 1e-300"),
        ("200 0 80 0", "200 0 80 -1e-300", r"baseline of 5e-303 m, outside 0.001 to 10 m"),
        ("200 0 80 0", "200 0 80 -1e9", r"baseline of 5e\+06 m"),
        ("200 0 80 0", "200 0 80 108", r"baseline of -0.54 m"),
    ],
)
def test_a_calibration_outside_a_rigs_physical_range_is_one_line(
    tmp_path: Path, p2: str, p3: str, problem: str
) -> None:
    """Issue 68: KITTI calibrations get camera files' ranges (a focal of 1e-300 was indexed)."""
    path = tmp_path / "000001.txt"
    path.write_text(f"P2: {p2} 0 200 24 0 0 0 1 0\nP3: {p3} 0 200 24 0 0 0 1 0\n")
    with pytest.raises(DataError, match=problem) as err:
        kitti.focal_and_baseline(160, path)
    assert str(path) in str(err.value)


def test_focal_and_baseline(tmp_path: Path) -> None:
    assert kitti.focal_and_baseline(1242) == (721.5377, 0.54)
    assert kitti.focal_and_baseline(1224, tmp_path / "ignored.txt") == (707.0493, 0.54)
    (tmp_path / "c.txt").write_text(RAW_CALIB)
    focal, baseline = kitti.focal_and_baseline(414, tmp_path / "c.txt")
    assert focal == pytest.approx(721.5377) and baseline == pytest.approx(0.5327, abs=1e-3)
    with pytest.raises(DataError, match="width 414 is not a KITTI.*missing.txt"):
        kitti.focal_and_baseline(414, tmp_path / "missing.txt")
    with pytest.raises(DataError, match="width 414"):
        kitti.focal_and_baseline(414)


# ---------------------------------------------------------------------------------- splits


def test_split_round_trip_and_blank_lines(tmp_path: Path) -> None:
    pairs = [("a/image_02/data/0.jpg", "a/image_03/data/0.jpg"), ("b/l.png", "b/r.png")]
    kitti.write_split(tmp_path / "s.txt", pairs)
    assert kitti.read_split(tmp_path / "s.txt") == pairs
    (tmp_path / "gaps.txt").write_text("\nl1 r1\n   \nl2 r2\n\n")
    assert kitti.read_split(tmp_path / "gaps.txt") == [("l1", "r1"), ("l2", "r2")]


def test_split_errors(tmp_path: Path) -> None:
    (tmp_path / "bad.txt").write_text("l1 r1\n\nonly_one_path\n")
    with pytest.raises(DataError, match=r"bad.txt:3: expected 'left right'"):
        kitti.read_split(tmp_path / "bad.txt")
    (tmp_path / "three.txt").write_text("l r extra\n")
    with pytest.raises(DataError, match=r"three.txt:1:"):
        kitti.read_split(tmp_path / "three.txt")
    (tmp_path / "empty.txt").write_text("\n\n")
    with pytest.raises(DataError, match="empty.txt.*no pairs"):
        kitti.read_split(tmp_path / "empty.txt")
    with pytest.raises(DataError, match="missing.txt.*no such"):
        kitti.read_split(tmp_path / "missing.txt")
    with pytest.raises(DataError, match="whitespace"):
        kitti.write_split(tmp_path / "w.txt", [("a b", "c")])


def test_shipped_split_lists_parse() -> None:
    lists = Path(__file__).resolve().parents[1] / "data_lists"  # the copies the pipeline uses
    train = kitti.read_split(lists / "kitti_train_files.txt")
    assert len(train) == 29000 and train[0][0].endswith(".jpg")
    assert len(kitti.read_split(lists / "kitti_val_files.txt")) == 1159
    assert len(kitti.read_split(lists / "kitti_stereo_2015_test_files.txt")) == 200
    zhou = _read_mono_split(lists / "eigen_zhou_train_files.txt")  # Monodepth2's, for train.mode mono
    assert len(zhou) == 39810 and zhou[0] == SplitEntry("2011_09_26/2011_09_26_drive_0022_sync", 473, "r")
    if (SHARED / "kitti").is_dir():  # unchanged copies of the reference lists
        for name in ("kitti_train_files.txt", "kitti_val_files.txt", "kitti_stereo_2015_test_files.txt"):
            assert (lists / name).read_bytes() == (SHARED / "kitti" / name).read_bytes()
        zhou_source = SHARED / "kitti" / "monodepth2_splits" / "eigen_zhou_train_files.txt"
        assert (lists / "eigen_zhou_train_files.txt").read_bytes() == zhou_source.read_bytes()


def test_resolve_image_prefers_existing_file(tmp_path: Path) -> None:
    folder = tmp_path / "d" / "image_02" / "data"
    folder.mkdir(parents=True)
    (folder / "0.png").write_bytes(b"x")
    assert kitti.resolve_image(tmp_path, "d/image_02/data/0.jpg") == folder / "0.png"
    (folder / "1.jpg").write_bytes(b"x")
    assert kitti.resolve_image(tmp_path, "d/image_02/data/1.jpg") == folder / "1.jpg"
    assert kitti.resolve_image(tmp_path, "d/image_02/data/1.png") == folder / "1.jpg"
    (folder / "2.jpg").write_bytes(b"x")
    (folder / "2.png").write_bytes(b"x")
    assert kitti.resolve_image(tmp_path, "d/image_02/data/2.jpg") == folder / "2.jpg"  # as listed
    assert kitti.resolve_image(tmp_path, "d/image_02/data/3.jpg") is None


# ------------------------------------------------------------------------------------ ROIs


def _rois() -> pd.DataFrame:
    return pd.DataFrame(
        {
            "image": ["000000_10", "000007_10"],
            "class": ["car", "sign"],
            "x0": [0, 10],
            "y0": [5, 2],
            "x1": [40, 16],
            "y1": [30, 9],
        }
    )


def test_rois_round_trip_keeps_frame_names(tmp_path: Path) -> None:
    kitti.write_rois(tmp_path / "r.csv", _rois())
    back = kitti.read_rois(tmp_path / "r.csv")
    assert list(back.columns) == list(kitti.ROI_COLUMNS)
    assert back["image"].tolist() == ["000000_10", "000007_10"]
    assert back[["x0", "y0", "x1", "y1"]].dtypes.map(lambda t: t == np.int64).all()
    pd.testing.assert_frame_equal(back, _rois())


def test_empty_roi_table_round_trips(tmp_path: Path) -> None:
    kitti.write_rois(tmp_path / "r.csv", pd.DataFrame(columns=list(kitti.ROI_COLUMNS)))
    assert len(kitti.read_rois(tmp_path / "r.csv")) == 0


@pytest.mark.parametrize(
    ("row", "message"),
    [
        ("000000_10,car,1.5,0,4,4", "integers"),
        ("000000_10,car,a,0,4,4", "integers"),
        ("000000_10,car,,0,4,4", "integers"),
        ("000000_10,car,4,0,4,4", "x1 > x0"),
        ("000000_10,car,0,5,4,2", "y1 > y0"),
        ("000000_10,car,-1,0,4,4", "negative"),
        ("000000_10,bus,0,0,4,4", "class 'bus'"),
    ],
)
def test_bad_roi_rows(tmp_path: Path, row: str, message: str) -> None:
    (tmp_path / "r.csv").write_text("image,class,x0,y0,x1,y1\n000001_10,car,0,0,4,4\n" + row + "\n")
    with pytest.raises(DataError, match=f"r.csv: row 3: .*{message}"):
        kitti.read_rois(tmp_path / "r.csv")


def test_roi_file_errors(tmp_path: Path) -> None:
    (tmp_path / "cols.csv").write_text("image,class,x0,y0,x1\n0,car,0,0,4\n")
    with pytest.raises(DataError, match=r"cols.csv: missing ROI column.*y1"):
        kitti.read_rois(tmp_path / "cols.csv")
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(DataError, match="empty.csv"):
        kitti.read_rois(tmp_path / "empty.csv")
    with pytest.raises(DataError, match="none.csv.*no such"):
        kitti.read_rois(tmp_path / "none.csv")
    (tmp_path / "wide.csv").write_text("image,class,x0,y0,x1,y1\n0,car,0,0,4,4\n0,car,0,0,4,4,5,6\n")
    with pytest.raises(DataError) as err:  # pandas' tokenizer error ends with a newline
        kitti.read_rois(tmp_path / "wide.csv")
    assert str(err.value) == (
        f"{tmp_path / 'wide.csv'}: not a readable ROI CSV: Error tokenizing data. C error: Expected 6 fields "
        "in line 3, saw 8"
    )
    bad = _rois()
    bad.loc[1, "class"] = "tree"
    with pytest.raises(DataError, match="out.csv: row 3"):
        kitti.write_rois(tmp_path / "out.csv", bad)
    assert not (tmp_path / "out.csv").exists()


def test_kitti2015_paths() -> None:
    paths = kitti.kitti2015_paths(Path("/k"), "000042_10", gt="disp_occ_0")
    assert paths == {
        "left": Path("/k/training/image_2/000042_10.png"),
        "right": Path("/k/training/image_3/000042_10.png"),
        "disp": Path("/k/training/disp_occ_0/000042_10.png"),
        "obj_map": Path("/k/training/obj_map/000042_10.png"),
        "calib": Path("/k/training/calib_cam_to_cam/000042.txt"),
        "class_map": Path("/k/training/class_map/000042_10.png"),  # the synthetic set's only
    }
    assert kitti.kitti2015_paths(Path("/k"), "000042_10")["disp"].parent.name == "disp_noc_0"


# ---------------------------------------------------------------------------- real samples


def test_real_left_image() -> None:
    if not REAL.is_dir():
        pytest.skip("../shared/real-samples is not available")
    left = kitti.read_image(REAL / "left.png")
    assert left.shape == (375, 1242, 3) and left.dtype == np.uint8
    assert kitti.focal_and_baseline(left.shape[1]) == (721.5377, 0.54)


def test_real_calibration() -> None:
    if not REAL.is_dir():
        pytest.skip("../shared/real-samples is not available")
    calib = kitti.read_calib(REAL / "calib.txt")
    assert {"P2", "P3", "R0_rect", "Tr_velo_to_cam"} <= set(calib)
    focal, baseline = kitti.stereo_from_calib(calib)
    assert focal == pytest.approx(721.5377)
    assert baseline == pytest.approx(0.5327, abs=5e-4)
