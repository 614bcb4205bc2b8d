"""The project's hand-drawn ROIs on the real KITTI 2015 frames (``data_lists/kitti2015_rois.csv``):
the reader's checks, the committed boxes, and their GT density as documented in
``studies/results/real/kitti2015_rois.md`` (that part skips when ../shared is absent)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from msdepth.config.params import EvalConfig
from msdepth.data import kitti
from msdepth.data.annotations import KITTI2015_SIZE, gt_density, read_annotation
from msdepth.errors import DataError
from msdepth.evaluation.suites import Frame, evaluate_roi

ROOT = Path(__file__).resolve().parents[1]
CSV = ROOT / "data_lists" / "kitti2015_rois.csv"
DOCUMENTED = ROOT / "studies" / "results" / "real" / "kitti2015_rois.md"
SAMPLES = ROOT.parent / "shared" / "real-samples" / "kitti2015-training"
HEADER = "image,class,x0,y0,x1,y1\n"


def test_committed_boxes_parse_and_lie_inside_the_frames() -> None:
    boxes = read_annotation(CSV)
    assert list(boxes.columns) == list(kitti.ROI_COLUMNS)
    assert set(boxes["image"]) == {"000000_10", "000001_10"}
    assert set(boxes["class"]) == set(kitti.ROI_CLASSES)  # every class drawn at least once
    h, w = KITTI2015_SIZE
    assert (w, h) == (1242, 375)
    assert (boxes["x0"] >= 0).all() and (boxes["y0"] >= 0).all()
    assert (boxes["x1"] <= w).all() and (boxes["y1"] <= h).all()
    assert (boxes["x1"] > boxes["x0"]).all() and (boxes["y1"] > boxes["y0"]).all()
    assert not boxes.duplicated().any()


@pytest.mark.parametrize(
    ("row", "problem"),
    [
        ("000000_10,car,10,20,1243,40", "lies outside the 1242x375 image"),
        ("000000_10,car,10,20,30,376", "lies outside the 1242x375 image"),
        ("000000_10,truck,10,20,30,40", "class 'truck' is not one of"),
        ("000000_10,car,10,20,30.5,40", "box coordinates must be integers"),
        ("000000_10,car,30,20,10,40", "empty box"),
    ],
)
def test_bad_rows_give_one_line_naming_the_file(tmp_path: Path, row: str, problem: str) -> None:
    path = tmp_path / "rois.csv"
    path.write_text(HEADER + "000000_10,sign,0,0,5,5\n" + row + "\n")
    with pytest.raises(DataError) as err:
        read_annotation(path)
    message = str(err.value)
    assert "\n" not in message and str(path) in message and problem in message
    assert "row 3" in message  # the CSV line of the bad row


def test_gt_density_by_hand() -> None:
    gt = np.zeros((4, 6), np.float32)
    gt[0, 0:3] = 5.0  # 3 of the first box's 2x3 pixels
    gt[3, 5] = np.nan  # NaN is no GT
    boxes = pd.DataFrame({"image": ["a", "a"], "class": ["car", "sign"], "x0": [0, 4], "y0": [0, 2]}).assign(
        x1=[3, 6], y1=[2, 4]
    )
    assert gt_density(boxes, {"a": gt}).tolist() == [0.5, 0.0]
    with pytest.raises(DataError, match="'b'"):
        gt_density(boxes.assign(image="b"), {"a": gt})


def documented_density() -> dict[int, float]:
    """CSV line -> GT density, from the study's table (line, frame, class, box, size, density)."""
    row = r"^\| (\d+) \| \d{6}_\d{2} \| \w+ \| [\d, ]+ \| \d+x\d+ \| ([\d.]+) \|"
    rows = re.findall(row, DOCUMENTED.read_text(), re.M)
    return {int(line): float(value) for line, value in rows}


def test_gt_density_is_as_documented() -> None:
    if not SAMPLES.is_dir():
        pytest.skip("../shared/real-samples is not available")
    boxes = read_annotation(CSV)
    gt = {n: kitti.read_disparity(SAMPLES / "disp_occ_0" / f"{n}.png") for n in boxes["image"].unique()}
    measured = gt_density(boxes, gt)
    documented = documented_density()
    assert sorted(documented) == [i + 2 for i in range(len(boxes))]  # one row per box, CSV lines
    assert np.allclose([documented[i + 2] for i in range(len(boxes))], measured, atol=5e-4)


def test_the_roi_suite_scores_them() -> None:
    """The boxes go into the ROI suite as they are: the GT as prediction scores 0 in every class,
    and the boxes without any GT are the ones left out."""
    cap = 1000.0  # beyond every GT depth (a few pixels lie past 80 m, which the cap would clamp)
    if not SAMPLES.is_dir():
        pytest.skip("../shared/real-samples is not available")
    boxes = read_annotation(CSV)
    names = sorted(boxes["image"].unique())
    frames = [
        Frame.from_disparity(n, kitti.read_disparity(SAMPLES / "disp_occ_0" / f"{n}.png"), 721.5377, 0.54)
        for n in names
    ]
    summary, per_roi = evaluate_roi(
        {f.name: f.gt_depth for f in frames}, frames, boxes, EvalConfig(caps=(cap,))
    )
    by_class = summary[f"cap{cap:g}"]["by_class"]
    assert set(by_class) == set(kitti.ROI_CLASSES)
    assert all(m["abs_rel"] == pytest.approx(0.0, abs=1e-6) for m in by_class.values())
    empty = gt_density(boxes, {f.name: f.gt_depth for f in frames}) == 0
    assert summary["excluded_rois"] == int(empty.sum()) > 0
    assert sorted(per_roi["roi"].unique()) == [i for i in range(len(boxes)) if not empty[i]]
