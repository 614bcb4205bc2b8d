"""KITTI 2015 as an extra evaluation set (eval_sets' kitti2015): its layout beside a synthetic training
set, its GT (disp_occ_0), obj_map's cars as the exact class ``car``, bad trees refused in one line,
and the suites on the shared two-frame sample (``../shared/real-samples/kitti2015-training``; those
tests skip where it is absent)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from msdepth.config.params import Params
from msdepth.data import kitti
from msdepth.data.eval_sets import KITTI2015_GT, _build_kitti2015_index, build_set_index
from msdepth.data.layout import KITTI2015_SET, layout
from msdepth.errors import DataError
from msdepth.evaluation.results import score_set
from msdepth.evaluation.suites import load_frames
from msdepth.io import write_png

SAMPLE = Path(__file__).resolve().parents[1].parent / "shared" / "real-samples" / "kitti2015-training"
needs_sample = pytest.mark.skipif(not SAMPLE.is_dir(), reason=f"{SAMPLE} absent (a clone without ../shared)")
WIDTH = 1242  # a KITTI width: Monodepth's focal 721.5377 px, baseline 0.54 m


def tiny_set(root: Path, frames: tuple[str, ...] = ("000000_10",), obj_map: bool = True) -> None:
    """A KITTI 2015 training layout of flat frames: GT 20 px everywhere but 10 px on a car filling
    the lower half, which obj_map marks (instance 1)."""
    for frame in frames:
        for folder in ("image_2", "image_3"):
            (root / folder).mkdir(parents=True, exist_ok=True)
            write_png(root / folder / f"{frame}.png", np.full((8, WIDTH, 3), 100, np.uint8))
        disp = np.full((8, WIDTH), 20.0, np.float32)
        disp[4:] = 10.0
        (root / KITTI2015_GT).mkdir(parents=True, exist_ok=True)
        kitti.write_disparity(root / KITTI2015_GT / f"{frame}.png", disp)
        if obj_map:
            (root / "obj_map").mkdir(parents=True, exist_ok=True)
            ids = np.zeros((8, WIDTH), np.uint8)
            ids[4:] = 1
            write_png(root / "obj_map" / f"{frame}.png", ids)


def scored(tmp_path: Path, monkeypatch, root: Path, depth: float) -> dict:
    """The kitti2015 set of ``root`` scored with a constant ``depth``: its full-image summary."""
    frames = load_frames(_build_kitti2015_index(root))
    monkeypatch.chdir(tmp_path)  # score_set writes below metrics/ of the working folder
    pred = {f.name: np.full(f.shape, depth, np.float32) for f in frames}
    score_set(Params(), "kitti2015", "constant", pred, frames, scaled=False)
    path = next((tmp_path / "metrics" / "sets" / "kitti2015").rglob("constant.json"))
    return json.loads(path.read_text())


def test_the_set_scores_obj_maps_cars_as_the_class_car(tmp_path, monkeypatch):
    """Depth at the background's GT (20 px): abs_rel 0 there; on the car (GT 10 px, predicted 20 px)
    depth is half the GT's, abs_rel 0.5, D1 100 %, EPE 10 px; the whole frame half of that."""
    tiny_set(tmp_path / "set")
    summary = scored(tmp_path, monkeypatch, tmp_path / "set", 721.5377 * 0.54 / 20)
    car = summary["masks"]["cap80"]["by_class"]["car"]
    assert car["abs_rel"] == pytest.approx(0.5, abs=1e-3)
    assert summary["masks"]["stereo"]["car"]["d1"] == pytest.approx(100.0)
    assert summary["masks"]["stereo"]["car"]["epe"] == pytest.approx(10.0, abs=0.05)
    assert summary["cap80"]["abs_rel"] == pytest.approx(0.25, abs=1e-3)


def test_a_frame_without_obj_map_is_scored_without_classes(tmp_path):
    tiny_set(tmp_path / "set", obj_map=False)
    index = _build_kitti2015_index(tmp_path / "set")
    assert list(index["obj_map"]) == [""] and list(index["gt_kind"]) == ["disparity"]
    (frame,) = load_frames(index)
    assert frame.class_map is None


def test_bad_trees_are_refused_naming_the_file(tmp_path):
    with pytest.raises(DataError, match=r"no image_2/ folder"):
        _build_kitti2015_index(tmp_path)
    tiny_set(tmp_path, frames=("000000_10", "000001_10"))
    (tmp_path / "image_3" / "000001_10.png").unlink()
    with pytest.raises(DataError, match=r"image_3/000001_10\.png: missing"):
        _build_kitti2015_index(tmp_path)
    write_png(tmp_path / "image_3" / "000001_10.png", np.full((8, 100, 3), 100, np.uint8))
    with pytest.raises(DataError, match=r"000001_10\.png"):
        _build_kitti2015_index(tmp_path)


def test_the_set_sits_beside_the_rendered_frames_and_in_a_kitti_tree(tmp_path):
    """Beside a synthetic training set, the user's tree goes below data.root/kitti2015_stereo (the
    renderer owns kitti2015/); with data.source kitti it is the downloaded kitti2015/ itself."""
    params = Params()
    params = dataclasses.replace(params, eval=dataclasses.replace(params.eval, extra_sets=("kitti2015",)))
    params.eval.validate("eval", params)
    root = Path(params.data.root)
    assert layout(params).kitti2015_set_root == root / KITTI2015_SET / "training"
    assert layout(params).kitti2015_set_root != layout(params).kitti2015_root / "training"
    data = dataclasses.replace(params.data, source="kitti", root=str(tmp_path))
    kitti_params = dataclasses.replace(params, data=data)
    assert layout(kitti_params).kitti2015_set_root == tmp_path / "kitti2015" / "training"
    tiny_set(tmp_path / "kitti2015" / "training")
    assert list(build_set_index(kitti_params, "kitti2015")["frame"]) == ["000000_10"]


@needs_sample
def test_the_suites_run_on_the_shared_kitti2015_frames(tmp_path, monkeypatch):
    index = _build_kitti2015_index(SAMPLE)
    assert list(index["frame"]) == ["000000_10", "000001_10"]
    assert list(index["focal"]) == [721.5377, 721.5377] and list(index["obj_map"]) == ["", ""]
    summary = scored(tmp_path, monkeypatch, SAMPLE, 20.0)
    assert summary["images"] == 2 and np.isfinite(summary["cap80"]["abs_rel"])


def test_the_sets_boxes_are_obj_maps_cars_and_the_users_scored_as_objects(tmp_path, monkeypatch):
    """rois stage on the set: the obj_map's car (min size 2 px here) plus the user's windshield box
    (data.kitti.rois_csv); scored at the background's depth, the car box (GT 10 px, predicted 20 px)
    has abs_rel 0.5, D1 100 %, EPE 10 px, the windshield (on the background) 0; the exact car mask
    the same 0.5. A box on a frame the set lacks is refused naming the CSV; the Eigen sets get none."""
    from msdepth.config.params import params_from_dict
    from msdepth.data.rois import set_roi_boxes, write_set_rois

    tiny_set(tmp_path / "set")
    index = _build_kitti2015_index(tmp_path / "set")
    csv = tmp_path / "boxes.csv"
    csv.write_text("image,class,x0,y0,x1,y1\n000000_10,windshield,100,0,200,4\n")
    params = params_from_dict({"data": {"kitti": {"roi_min_size": 2, "rois_csv": str(csv)}}})
    rois = tmp_path / "set_rois" / "kitti2015.csv"
    boxes = write_set_rois(params, "kitti2015", index, rois)
    assert boxes[["class", "x0", "y0", "x1", "y1"]].values.tolist() == [
        ["car", 0, 4, WIDTH, 8],
        ["windshield", 100, 0, 200, 4],
    ]
    assert rois.with_suffix(".png").is_file()
    frames = load_frames(index)
    monkeypatch.chdir(tmp_path)
    pred = {f.name: np.full(f.shape, 721.5377 * 0.54 / 20, np.float32) for f in frames}
    score_set(params, "kitti2015", "constant", pred, frames, scaled=False, rois=rois)
    roi = json.loads((tmp_path / "metrics" / "sets" / "kitti2015" / "roi" / "constant.json").read_text())
    car, glass = roi["cap80"]["by_class"]["car"], roi["cap80"]["by_class"]["windshield"]
    assert car["abs_rel"] == pytest.approx(0.5, abs=1e-3) and car["d1"] == pytest.approx(1.0)
    assert car["epe"] == pytest.approx(10.0, abs=0.05) and glass["abs_rel"] == pytest.approx(0.0, abs=1e-4)
    assert roi["masks"]["cap80"]["by_class"]["car"]["abs_rel"] == pytest.approx(0.5, abs=1e-3)
    csv.write_text("image,class,x0,y0,x1,y1\n000009_10,sign,0,0,4,4\n")
    with pytest.raises(DataError, match=r"boxes\.csv: row 2: image '000009_10' is not an evaluation frame"):
        set_roi_boxes(params, "kitti2015", index)
    assert set_roi_boxes(params, "eigen", index).empty


def test_a_set_without_boxes_writes_the_explicit_no_rois_summary(tmp_path, monkeypatch):
    """An empty ROI file (the Eigen sets', or KITTI 2015 without obj_map or CSV): the ROI suite's
    summary says so, its headline is {"rois": 0}; the file is named in the reason."""
    from msdepth.data.rois import write_set_rois

    tiny_set(tmp_path / "set", obj_map=False)
    index = _build_kitti2015_index(tmp_path / "set")
    rois = tmp_path / "set_rois" / "kitti2015.csv"
    assert write_set_rois(Params(), "kitti2015", index, rois).empty
    monkeypatch.chdir(tmp_path)
    frames = load_frames(index)
    score_set(Params(), "kitti2015", "prior", {f.name: np.ones(f.shape, np.float32) for f in frames}, frames,
              rois=rois)  # fmt: skip
    summary = json.loads((tmp_path / "metrics" / "sets" / "kitti2015" / "roi" / "prior.json").read_text())
    assert summary["rois"] == 0 and "lists no box on set kitti2015" in summary["no_rois"]
    head = tmp_path / "metrics" / "headline" / "sets" / "kitti2015" / "roi" / "prior.json"
    assert json.loads(head.read_text()) == {"rois": 0}
