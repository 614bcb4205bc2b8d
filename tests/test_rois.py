"""ROI extraction: car boxes from obj_map, merging and checking hand-drawn boxes, the contact sheet."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from msdepth import render
from msdepth.config.params import SyntheticConfig
from msdepth.data import kitti
from msdepth.data.eval_index import build_eval_index
from msdepth.data.rois import (
    HEADER_HEIGHT,
    LABEL_HEIGHT,
    PAD,
    _boxes_from_obj_map,
    _contact_sheet,
    _extract_rois,
    _letterbox,
)
from msdepth.errors import DataError
from msdepth.io import write_png

# Seed 3 gives 4 frames with 9 visible cars, 4 of them >= 16 px a side, one mostly hidden
# behind another, plus windshield, glass and sign boxes.
CFG = SyntheticConfig(seed=3, drives=1, train_pairs=1, eval_frames=4, height=96, width=320)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, pd.DataFrame]:
    root = tmp_path_factory.mktemp("rois")
    render.generate(CFG, root, progress=False, workers=1)
    k2015 = root / "kitti2015"
    return root, build_eval_index(k2015, k2015 / "test_files.txt", "disp_noc_0")


def _iou(a: tuple[int, ...], b: tuple[int, ...]) -> float:
    w = max(0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def _write_csv(path: Path, rows: list[tuple]) -> Path:
    pd.DataFrame(rows, columns=list(kitti.ROI_COLUMNS)).to_csv(path, index=False)
    return path


# --------------------------------------------------------------------------------------------
# boxes_from_obj_map on hand-made maps


def test_boxes_exact_and_filtered() -> None:
    obj = np.zeros((60, 100), np.uint8)
    gt = np.ones((60, 100), np.float32)
    obj[2:20, 5:21] = 7  # 16 x 18: exactly min_size wide -> kept
    obj[30:50, 40:55] = 3  # 15 px wide -> dropped by min_size
    obj[10:12, 60:62] = 200  # two blobs of one instance: the box spans both
    obj[40:45, 90:96] = 200
    obj[25:45, 0:20] = 9  # 20 x 20, but GT on 5 of its 20 rows (25 %) -> dropped by min_valid
    gt[25:45, 0:20] = 0
    gt[25:30, 0:20] = 1
    obj[0:20, 70:86] = 12  # GT on 6 of its 20 rows, exactly 30 % -> kept (the bound is inclusive)
    gt[6:20, 70:86] = 0
    assert _boxes_from_obj_map(obj, gt) == [(7, 5, 2, 21, 20), (12, 70, 0, 86, 20), (200, 60, 10, 96, 45)]
    # Looser thresholds bring the others back; ids stay sorted and non-contiguous.
    assert [b[0] for b in _boxes_from_obj_map(obj, gt, min_size=1, min_valid=0.0)] == [3, 7, 9, 12, 200]
    assert _boxes_from_obj_map(obj, gt, min_size=15, min_valid=0.2)[:2] == [
        (3, 40, 30, 55, 50),
        (7, 5, 2, 21, 20),
    ]


def test_boxes_edge_cases() -> None:
    obj = np.zeros((20, 20), np.uint8)
    assert _boxes_from_obj_map(obj, np.ones((20, 20))) == []  # background only
    obj[:, :] = 1  # a car filling the frame: the box is the whole image, x1/y1 exclusive
    assert _boxes_from_obj_map(obj, np.ones((20, 20)), min_size=20) == [(1, 0, 0, 20, 20)]
    gt_nan = np.full((20, 20), np.nan)  # NaN is no GT
    assert _boxes_from_obj_map(obj, gt_nan, min_size=1) == []
    with pytest.raises(DataError, match=r"\(20, 20\).*\(20, 21\)"):
        _boxes_from_obj_map(obj, np.ones((20, 21)))
    with pytest.raises(DataError, match="integer"):
        _boxes_from_obj_map(obj.astype(np.float32), np.ones((20, 20)))
    with pytest.raises(ValueError, match="min_valid"):
        _boxes_from_obj_map(obj, np.ones((20, 20)), min_valid=1.5)


# --------------------------------------------------------------------------------------------
# extract_rois on the synthetic set


@pytest.mark.parametrize("min_size", [16, 8])
def test_car_boxes_match_the_generator(tiny, min_size: int) -> None:
    # The generator's car box is the bounding box of the whole car's projected 3-D corners
    # (hidden parts included), clipped to the image, kept only if >= 50 % of it shows the car.
    # The obj_map box covers the visible pixels only, so it lies inside the generator's box
    # (equal up to a pixel of rounding for an unoccluded car), and the two agree (IoU > 0.5)
    # unless the car is mostly hidden; such a car (frame 3, 9x6 px) has no generator box and
    # is below both min_size values here.
    root, frames = tiny
    gen = kitti.read_rois(root / "rois.csv")
    gen = gen[gen["class"] == "car"]
    rois = _extract_rois(frames, min_size=min_size, progress=False)
    assert set(rois["class"]) == {"car"} and len(rois) == (4 if min_size == 16 else 8)
    for roi in rois.itertuples(index=False):
        box = (roi.x0, roi.y0, roi.x1, roi.y1)
        assert box[2] - box[0] >= min_size and box[3] - box[1] >= min_size
        cands = [tuple(g) for g in gen.loc[gen["image"] == roi.image, ["x0", "y0", "x1", "y1"]].to_numpy()]
        best = max(cands, key=lambda g: _iou(box, g))
        assert _iou(box, best) > 0.5, (roi, cands)
        assert best[0] <= box[0] and best[1] <= box[1] and box[2] <= best[2] and box[3] <= best[3], (
            box,
            best,
        )
    # Recall: every generator car box comfortably above min_size is found.
    for g in gen.itertuples(index=False):
        if min(g.x1 - g.x0, g.y1 - g.y0) >= min_size + 2:
            mine = rois.loc[rois["image"] == g.image, ["x0", "y0", "x1", "y1"]].to_numpy()
            assert any(_iou(tuple(m), (g.x0, g.y0, g.x1, g.y1)) > 0.5 for m in mine), g


def test_user_rows_are_merged_sorted_and_round_trip(tiny, tmp_path: Path) -> None:
    root, frames = tiny
    frames = frames.copy()
    frames.loc[1, "obj_map"] = ""  # a frame without obj_map: no car boxes, counted
    user = _write_csv(
        tmp_path / "hand.csv",
        [
            ("000003_10", "windshield", 27, 54, 59, 62),
            ("000000_10", "sign", 0, 0, CFG.width, CFG.height),  # the whole image is inside it
            ("000000_10", "car", 127, 47, 162, 75),  # the same as an automatic box: kept once
            ("000001_10", "car", 180, 45, 199, 60),  # a hand-drawn car where obj_map is missing
        ],
    )
    rois = _extract_rois(frames, user_csv=user, progress=False)
    report = rois.attrs["report"]
    assert report["frames"] == 4 and report["frames_without_obj_map"] == 1
    assert report["car_boxes_from_obj_map"] == 4 and report["user_boxes"] == 4 and report["rois"] == 7
    assert list(rois.columns) == list(kitti.ROI_COLUMNS)
    keys = list(rois[["image", "class", "x0", "y0"]].itertuples(index=False, name=None))
    assert keys == sorted(keys)
    assert rois[rois["image"] == "000001_10"]["class"].tolist() == ["car"]  # only the hand one
    assert ((rois["image"] == "000000_10") & (rois["x0"] == 127)).sum() == 1
    kitti.write_rois(tmp_path / "out.csv", rois)
    pd.testing.assert_frame_equal(kitti.read_rois(tmp_path / "out.csv"), rois, check_dtype=False)


@pytest.mark.parametrize(
    ("row", "problem"),
    [
        (("000009_10", "glass", 0, 0, 10, 10), r"'000009_10' is not an evaluation frame"),
        (("000002_10.png", "glass", 0, 0, 10, 10), r"did you mean '000002_10'"),
        (
            ("000002_10", "glass", 300, 0, CFG.width + 1, 10),
            rf"outside frame 000002_10's {CFG.width}x{CFG.height}",
        ),
        (("000002_10", "sign", 0, 90, 10, CFG.height + 1), "outside"),
        (("000002_10", "mirror", 0, 0, 10, 10), "not one of"),  # read_rois' own checks apply
    ],
)
def test_bad_user_rows_name_csv_and_row(tiny, tmp_path: Path, row: tuple, problem: str) -> None:
    _, frames = tiny
    user = _write_csv(tmp_path / "hand.csv", [("000000_10", "car", 0, 0, 5, 5), row])
    with pytest.raises(DataError, match=rf"hand\.csv: row 3: .*{problem}"):
        _extract_rois(frames, user_csv=user, progress=False)


def test_missing_user_csv_and_bad_obj_map(tiny, tmp_path: Path) -> None:
    _, frames = tiny
    with pytest.raises(DataError, match="nope.csv: no such ROI file"):
        _extract_rois(frames, user_csv=tmp_path / "nope.csv", progress=False)
    wrong = tmp_path / "obj.png"
    write_png(wrong, np.zeros((CFG.height, CFG.width - 1), np.uint8))
    bad = frames.copy()
    bad.loc[0, "obj_map"] = str(wrong)
    with pytest.raises(DataError, match=r"obj\.png: .*GT disparity"):
        _extract_rois(bad, progress=False)


def test_empty_result_is_an_empty_table(tiny, tmp_path: Path) -> None:
    _, frames = tiny
    rois = _extract_rois(frames, min_size=1000, progress=False)
    assert rois.empty and list(rois.columns) == list(kitti.ROI_COLUMNS)
    kitti.write_rois(tmp_path / "empty.csv", rois)
    assert kitti.read_rois(tmp_path / "empty.csv").empty


# --------------------------------------------------------------------------------------------
# Contact sheet


def test_contact_sheet_layout_and_content(tiny, tmp_path: Path) -> None:
    root, frames = tiny
    gen = kitti.read_rois(root / "rois.csv")  # car, windshield, glass and sign boxes
    per_class = gen["class"].value_counts()
    tile, columns, cap = 24, 3, 4  # 24 px: the bigger cars shrink, the small boxes grow
    out = _contact_sheet(gen, frames, tmp_path / "sheet.png", tile=tile, columns=columns, max_per_class=cap)
    sheet = kitti.read_image(out)
    cell_w, cell_h = tile + 2 * PAD, tile + LABEL_HEIGHT + 2 * PAD
    height = sum(HEADER_HEIGHT + math.ceil(min(n, cap) / columns) * cell_h for n in per_class)
    assert sheet.shape == (height, columns * cell_w, 3)
    assert sheet.std() > 20  # not blank
    # The first car cell holds the first car box's crop (classes in ROI_CLASSES order, car first).
    first = gen[gen["class"] == "car"].sort_values(["image", "x0", "y0"]).iloc[0]
    left = kitti.read_image(frames.set_index("frame").loc[first["image"], "left"])
    crop = left[first["y0"] : first["y1"], first["x0"] : first["x1"]]
    cell = sheet[HEADER_HEIGHT + PAD : HEADER_HEIGHT + PAD + tile, PAD : PAD + tile]
    np.testing.assert_array_equal(cell, _letterbox(crop, tile))
    # The label strip under it has text on it.
    assert (sheet[HEADER_HEIGHT + PAD + tile : HEADER_HEIGHT + cell_h, :cell_w] > 150).any()


def test_contact_sheet_empty_and_unknown_frame(tiny, tmp_path: Path) -> None:
    _, frames = tiny
    empty = _extract_rois(frames, min_size=1000, progress=False)
    sheet = cv2.imread(str(_contact_sheet(empty, frames, tmp_path / "empty.png", columns=2)))
    assert sheet.shape == (HEADER_HEIGHT, 2 * (96 + 2 * PAD), 3)
    rois = pd.DataFrame([("999999_10", "car", 0, 0, 4, 4)], columns=list(kitti.ROI_COLUMNS))
    with pytest.raises(DataError, match="999999_10"):
        _contact_sheet(rois, frames, tmp_path / "bad.png")
    assert not (tmp_path / "bad.png").exists()
