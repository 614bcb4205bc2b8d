"""The index stage on a KITTI-format tree: what it finds, reports, and refuses."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from msdepth import render
from msdepth.config.params import params_from_dict
from msdepth.data import kitti
from msdepth.data.eval_index import read_eval_index
from msdepth.data.indexing import build_indexes
from msdepth.errors import DataError
from msdepth.io import write_png

SYN = {"seed": 5, "drives": 2, "train_pairs": 6, "eval_frames": 3, "height": 48, "width": 160}


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("kitti")
    render.generate(
        params_from_dict({"data": {"synthetic": SYN}}).data.synthetic, root, progress=False, workers=1
    )
    return root


@pytest.fixture()
def tree(pristine: Path, tmp_path: Path):
    root = tmp_path / "kitti"
    shutil.copytree(pristine, root)
    params = params_from_dict({"data": {"root": str(root), "synthetic": SYN}})
    return root, params, tmp_path / "index"


def test_index_of_a_complete_tree(tree) -> None:
    root, params, out = tree
    report = build_indexes(params, out)
    assert (
        report["train_pairs_found"] == report["train_pairs_listed"] == 6
        and report["train_pairs_missing"] == []
    )
    frames = read_eval_index(out / "eval_frames.csv")
    assert list(frames["frame"]) == ["000000_10", "000001_10", "000002_10"]
    assert np.allclose(frames["focal"], 721.5377 * 160 / 1242) and np.allclose(frames["baseline"], 0.54)


def test_missing_training_images_are_reported_not_fatal(tree) -> None:
    root, params, out = tree
    gone = sorted((root / "raw").rglob("image_03/data/*.png"))[1]
    gone.unlink()
    report = build_indexes(params, out)
    assert report["train_pairs_found"] == 5 and len(report["train_pairs_missing"]) == 1
    assert gone.relative_to(root / "raw").as_posix() in report["train_pairs_missing"][0]
    assert json.loads((out / "report.json").read_text()) == report


def test_empty_split_is_a_clear_error(tree) -> None:
    root, params, out = tree
    (root / "train_files.txt").write_text("")
    with pytest.raises(DataError, match="train_files.txt: split file lists no pairs"):
        build_indexes(params, out)


def test_missing_evaluation_gt_names_the_frame(tree) -> None:
    root, params, out = tree
    (root / "kitti2015" / "training" / "disp_noc_0" / "000001_10.png").unlink()
    with pytest.raises(DataError, match=r"1 evaluation frame\(s\) missing .*000001_10"):
        build_indexes(params, out)


@pytest.mark.parametrize("what", ["right image", "disp_noc_0 GT"])
def test_views_or_gt_of_another_size_name_both_files(tree, what: str) -> None:
    root, params, out = tree
    training = root / "kitti2015" / "training"
    if what == "right image":
        bad = training / "image_3" / "000002_10.png"
        write_png(bad, np.zeros((40, 160, 3), np.uint8))
    else:
        bad = training / "disp_noc_0" / "000002_10.png"
        kitti.write_disparity(bad, np.ones((48, 150), np.float32))
    with pytest.raises(
        DataError, match=rf"image_2/000002_10.png is \(48, 160\) but its {what} .*000002_10.png is"
    ):
        build_indexes(params, out)


def test_an_index_of_an_older_format_is_refused_with_the_way_out(tmp_path: Path) -> None:
    """Indexes are DVC outputs: a changed index format re-runs the index stage, so an older file
    (here one with KITTI 2015's ``disp`` column, before every set shared one format) is an error
    that says so, not a guess."""
    path = tmp_path / "eval_frames.csv"
    path.write_text("frame,left,right,disp,obj_map,focal,baseline\n000000_10,l.png,r.png,d.png,,721.5,0.54\n")
    with pytest.raises(
        DataError, match=r"missing columns \['calib', 'class_map', 'crop', 'gt', 'gt_kind'\].*index stage"
    ):
        read_eval_index(path)
