"""Exact classes scored over whole frames (issue 55): a stereo folder's class maps
(``data.folder.class_maps``: PNGs of labels named by ``classes.yaml``) and KITTI 2015's cars from
``obj_map``, through the full-image suite's exact-class summary (msdepth.evaluation.classes); a bad
class map is one line naming the file; the synthetic set's class maps stay with the ROI suite. The
KITTI 2015 test on real frames uses ``../shared/real-samples`` and skips where it is absent."""

from __future__ import annotations

import json
import re
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from msdepth.config.params import Params, params_from_dict
from msdepth.data import folder, kitti
from msdepth.data.eval_index import build_eval_index, read_eval_index, write_eval_index
from msdepth.data.ground_truth import read_frame_classes
from msdepth.data.indexing import _folder_indexes, folder_eval_index
from msdepth.data.layout import folder_layout
from msdepth.errors import DataError
from msdepth.evaluation.results import run_suite
from msdepth.evaluation.suites import load_frames
from msdepth.io import write_png
from msdepth.pipeline.paths import headline_path, suite_path

SAMPLE = Path(__file__).resolve().parents[1].parent / "shared" / "real-samples" / "kitti2015-training"
needs_sample = pytest.mark.skipif(not SAMPLE.is_dir(), reason=f"{SAMPLE} absent (a clone without ../shared)")

H, W = 8, 12
CLASSES = "1: transparent\n2: specular\n"


def _labels(frame: str) -> np.ndarray:
    """c: rows 0-3 transparent; d: columns 0-5 transparent, 6-11 specular."""
    labels = np.zeros((H, W), np.uint8)
    if frame == "c":
        labels[:4] = 1
    else:
        labels[:, :6], labels[:, 6:] = 1, 2
    return labels


def _folder(root: Path) -> Path:
    """A stereo folder: training frame a, evaluation frames c (GT 10 m) and d (GT 20 m), .npy depth
    GT, class maps in classes/. Camera 24 px at 24 px wide: 12 px at 12, baseline 0.5 m."""
    for side in ("left", "right"):
        (root / side).mkdir(parents=True)
        for name in "acd":
            write_png(root / side / f"{name}.png", np.full((H, W, 3), 100, np.uint8))
    (root / "gt").mkdir()
    np.save(root / "gt" / "c.npy", np.full((H, W), 10.0, np.float32))
    np.save(root / "gt" / "d.npy", np.full((H, W), 20.0, np.float32))
    (root / "camera.yaml").write_text("focal_px: 24\nwidth_px: 24\nbaseline_m: 0.5\n")
    (root / "eval.txt").write_text("left/c.png right/c.png gt/c.npy\nleft/d.png right/d.png gt/d.npy\n")
    (root / "classes").mkdir()
    (root / "classes" / "classes.yaml").write_text(CLASSES)
    for name in "cd":
        write_png(root / "classes" / f"{name}.png", _labels(name))
    return root


def _params(root: Path, class_maps: str = "classes") -> Params:
    folder_keys = {"class_maps": class_maps} if class_maps else {}
    return params_from_dict(
        {"data": {"source": "folder", "root": str(root), "folder": folder_keys}, "eval": {"extra_sets": []}}
    )


def _full_suite(params: Params, index: Path, pred: dict, tmp_path: Path, monkeypatch) -> tuple[dict, dict]:
    """The full-image suite run on ``pred`` as run ``constant``: its summary and headline."""
    frames = load_frames(read_eval_index(index))
    monkeypatch.chdir(tmp_path)  # run_suite writes below metrics/ of the working folder
    run_suite(params, "full", "constant", pred, frames, None)
    summary = json.loads(suite_path("full", "constant").read_text())
    return summary, json.loads(headline_path("full", "constant").read_text())


def test_a_folder_with_class_maps_is_scored_per_class(tmp_path, monkeypatch):
    """Frame c predicted 12 m on its transparent rows, 10 m (exact) elsewhere; d 15 m everywhere.
    transparent: abs_rel (0.2 + 0.25) / 2 = 0.225 (one whole-frame ROI per frame and class); EPE
    |12·0.5/10 - 12·0.5/12| = 0.1 px on c, |6/20 - 6/15| = 0.1 px on d; specular: d alone, 0.25.
    The whole frame: (0.1 + 0.25) / 2 = 0.175."""
    root = _folder(tmp_path / "set")
    params = _params(root)
    report = _folder_indexes(params, tmp_path / "index")
    assert report["eval_frames"] == 2
    index = read_eval_index(tmp_path / "index" / "eval_frames.csv")
    assert [Path(p).relative_to(root).as_posix() for p in index["class_map"]] == [
        "classes/c.png",
        "classes/d.png",
    ]
    pred = {
        "c": np.where(_labels("c") == 1, 12.0, 10.0).astype(np.float32),
        "d": np.full((H, W), 15.0, np.float32),
    }
    summary, headline = _full_suite(
        params, tmp_path / "index" / "eval_frames.csv", pred, tmp_path, monkeypatch
    )
    by_class = summary["masks"]["cap80"]["by_class"]
    assert by_class["transparent"]["abs_rel"] == pytest.approx(0.225, abs=1e-6)
    assert by_class["transparent"]["count"] == 2
    assert by_class["specular"]["abs_rel"] == pytest.approx(0.25, abs=1e-6)
    assert summary["masks"]["stereo"]["transparent"] == pytest.approx({"d1": 0.0, "epe": 0.1, "frames": 2})
    assert summary["cap80"]["abs_rel"] == pytest.approx(0.175, abs=1e-6)
    assert headline["transparent_abs_rel"] == pytest.approx(0.225, abs=1e-6)
    assert headline["specular_d1"] == 0.0


def test_a_folder_without_class_maps_keeps_its_summary(tmp_path, monkeypatch):
    root = _folder(tmp_path / "set")
    params = _params(root, class_maps="")
    write_eval_index(tmp_path / "eval_frames.csv", folder_eval_index(params))
    pred = {name: np.full((H, W), 10.0, np.float32) for name in "cd"}
    summary, headline = _full_suite(params, tmp_path / "eval_frames.csv", pred, tmp_path, monkeypatch)
    assert "masks" not in summary and set(headline) == {"abs_rel", "a1"}


def _png_declaring(width: int, height: int) -> bytes:
    """A valid-looking PNG whose header declares ``width`` x ``height`` px (no pixel data)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b"")


def _break(root: Path, case: str) -> str:
    """Spoil the folder's class maps one way; the expected message (a regex after the file's path)."""
    d = root / "classes" / "d.png"
    if case == "missing":
        d.unlink()
        return r"classes/d\.png: no such class map of frame 'd' \(data\.folder\.class_maps\)"
    if case == "size":
        write_png(d, np.zeros((H, W - 2), np.uint8))
        return r"left/d\.png is \(8, 12\) but its class map .*classes/d\.png is \(8, 10\)"
    if case == "label":
        labels = _labels("d")
        labels[0, 0] = 7
        write_png(d, labels)
        return r"classes/d\.png: label\(s\) \[7\] not in its classes file \(which names \[1, 2\]"
    if case == "jpeg":
        d.write_bytes(cv2.imencode(".jpg", _labels("d"))[1].tobytes())
        return r"classes/d\.png: class map: not a PNG"
    if case == "colour":
        write_png(d, np.zeros((H, W, 3), np.uint8))
        return r"classes/d\.png: expected an 8- or 16-bit single-channel class map"
    if case == "huge":
        d.write_bytes(_png_declaring(50_000, 50_000))
        return r"classes/d\.png: class map: the header declares 50000 x 50000 px .*over the limit"
    if case == "class":
        (root / "classes" / "classes.yaml").write_text("1: transparent\n2: mirror\n")
        return r"classes/classes\.yaml: label 2: unknown class 'mirror'; known: \['car', "
    if case == "class list":  # issue 68: unexpected TypeError: unhashable type: 'list'
        (root / "classes" / "classes.yaml").write_text("1: [transparent]\n2: specular\n")
        return r"classes/classes\.yaml: label 1: expected one class name, got \['transparent'\]; known: "
    if case == "class mapping":
        (root / "classes" / "classes.yaml").write_text("1: {transparent: 1}\n2: specular\n")
        return r"classes/classes\.yaml: label 1: expected one class name, got \{'transparent': 1\}; known: "
    (root / "classes" / "classes.yaml").unlink()
    return r"classes/classes\.yaml: no classes file"


@pytest.mark.parametrize(
    "case",
    [
        "missing",
        "size",
        "label",
        "jpeg",
        "colour",
        "huge",
        "class",
        "class list",
        "class mapping",
        "no classes",
    ],
)
def test_a_bad_class_map_is_one_line_naming_the_file(tmp_path, case):
    root = _folder(tmp_path / "set")
    expected = _break(root, case)
    with pytest.raises(DataError) as err:
        folder_eval_index(_params(root))
    message = str(err.value)
    assert "\n" not in message and len(message) < 400, message
    assert message.startswith(str(root)), message
    assert re.search(expected, message), message


@pytest.mark.parametrize("case", ["class list", "class mapping"])
def test_prepare_data_names_a_class_that_is_no_name(tmp_path, case):
    """prepare_data's check of the folder reads classes.yaml as the index does: one line naming it."""
    root = _folder(tmp_path / "set")
    expected = _break(root, case)
    with pytest.raises(DataError) as err:
        folder.check_folder(folder_layout(_params(root)))
    assert "\n" not in str(err.value) and re.search(expected, str(err.value)), err.value


def test_prepare_data_names_a_missing_class_map(tmp_path):
    root = _folder(tmp_path / "set")
    assert folder.check_folder(folder_layout(_params(root)))["eval_frames"] == 2
    (root / "classes" / "c.png").unlink()
    with pytest.raises(DataError, match=r"classes/c\.png: no class map for left/c\.png"):
        folder.check_folder(folder_layout(_params(root)))


# --------------------------------------------------------------------------- KITTI 2015's obj_map


def _kitti2015(root: Path, width: int = 1242, *, class_map: bool = False) -> Path:
    """A KITTI 2015 training tree of one frame ``000000_10``, 8 px high: GT 20 px, 40 px on the car
    (columns 0-99, obj_map instance 1); its split file. ``class_map``: the synthetic set's too (sign
    bit on the car's columns: a class map that does not hold the car)."""
    training = root / "training"
    for folder_name in ("image_2", "image_3"):
        write_png(training / folder_name / "000000_10.png", np.full((8, width, 3), 100, np.uint8))
    disp = np.full((8, width), 20.0, np.float32)
    disp[:, :100] = 40.0
    kitti.write_disparity(training / "disp_noc_0" / "000000_10.png", disp)
    objects = np.zeros((8, width), np.uint8)
    objects[:, :100] = 1
    write_png(training / "obj_map" / "000000_10.png", objects)
    if class_map:
        write_png(training / "class_map" / "000000_10.png", np.where(objects > 0, 8, 0).astype(np.uint8))
    split = root / "test_files.txt"
    split.write_text("training/image_2/000000_10.png training/image_3/000000_10.png\n")
    return split


def _kitti_index(root: Path, split: Path, gt: str = "disp_noc_0") -> Path:
    path = root / "eval_frames.csv"
    write_eval_index(path, build_eval_index(root, split, gt))
    return path


def test_obj_map_gives_kitti2015_frames_an_exact_car_class(tmp_path, monkeypatch):
    """Depth predicted at disparity 20 px everywhere: the car (GT 40 px) at twice its depth, abs_rel
    1.0, D1 100 %, EPE 20 px; the rest exact."""
    split = _kitti2015(tmp_path / "kitti2015")
    index = _kitti_index(tmp_path / "kitti2015", split)
    (frame,) = load_frames(read_eval_index(index))
    assert frame.whole_frame_classes and set(np.unique(frame.class_map)) == {0, kitti.CLASS_BITS["car"]}
    pred = {frame.name: np.full(frame.shape, frame.focal * frame.baseline / 20.0, np.float32)}
    summary, headline = _full_suite(Params(), index, pred, tmp_path, monkeypatch)
    assert summary["masks"]["cap80"]["by_class"]["car"]["abs_rel"] == pytest.approx(1.0, abs=1e-5)
    assert summary["masks"]["stereo"]["car"] == pytest.approx({"d1": 100.0, "epe": 20.0, "frames": 1})
    assert headline["car_abs_rel"] == pytest.approx(1.0, abs=1e-5) and headline["car_d1"] == 100.0


def test_the_synthetic_sets_class_map_keeps_obj_map_out_and_its_classes_in_their_boxes(tmp_path, monkeypatch):
    """A frame with a class map (the synthetic set's) reads it, not obj_map, and its classes stay
    with the ROI suite: the full-image summary is what it was (the default pipeline's outputs)."""
    split = _kitti2015(tmp_path / "kitti2015", class_map=True)
    index = _kitti_index(tmp_path / "kitti2015", split)
    row = read_eval_index(index).iloc[0]
    classes, whole_frame = read_frame_classes(row.gt_kind, row.class_map, row.obj_map)
    assert not whole_frame and set(np.unique(classes)) == {0, kitti.CLASS_BITS["sign"]}
    (frame,) = load_frames(read_eval_index(index))
    pred = {frame.name: np.full(frame.shape, 10.0, np.float32)}
    summary, headline = _full_suite(Params(), index, pred, tmp_path, monkeypatch)
    assert "masks" not in summary and set(headline) == {"abs_rel", "a1"}


@needs_sample
def test_obj_map_cars_on_the_shared_kitti2015_frames(tmp_path, monkeypatch):
    """The shared frames (no obj_map of their own) with a hand-made one: the car class is scored on
    real 375 x 1242 frames and their sparse GT; a prediction equal to the GT scores 0 there."""
    root = tmp_path / "kitti2015"
    frames = sorted(p.stem for p in (SAMPLE / "image_2").glob("*_10.png"))
    for folder_name in ("image_2", "image_3", "disp_occ_0"):
        (root / "training" / folder_name).mkdir(parents=True)
        for name in frames:
            (root / "training" / folder_name / f"{name}.png").symlink_to(SAMPLE / folder_name / f"{name}.png")
    (root / "training" / "obj_map").mkdir()
    for name in frames:
        objects = np.zeros((375, 1242), np.uint8)
        objects[200:300, 400:700] = 1  # the road ahead, where the LiDAR GT is dense
        write_png(root / "training" / "obj_map" / f"{name}.png", objects)
    split = root / "test_files.txt"
    split.write_text("".join(f"training/image_2/{n}.png training/image_3/{n}.png\n" for n in frames))
    index = _kitti_index(root, split, gt="disp_occ_0")
    loaded = load_frames(read_eval_index(index))
    assert [f.shape for f in loaded] == [(375, 1242)] * len(frames) and all(
        f.whole_frame_classes for f in loaded
    )
    pred = {f.name: np.where(f.valid, f.gt_depth, 10.0).astype(np.float32) for f in loaded}
    summary, _ = _full_suite(Params(), index, pred, tmp_path, monkeypatch)
    car = summary["masks"]["cap80"]["by_class"]["car"]
    assert car["count"] == len(frames) and car["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    assert summary["masks"]["stereo"]["car"]["d1"] == 0.0


def test_a_stereo_folder_is_an_extra_set_with_its_class_maps_and_boxes(tmp_path, monkeypatch):
    """eval.extra_sets' folder beside the synthetic training set: data.folder.root names the folder;
    its frames, class maps and data.folder.rois_csv boxes make the set's index and ROI file, scored
    as the folder source scores them (the numbers of the test above), each box a unit with D1/EPE.
    Without data.folder.root the params are refused naming the key."""
    from msdepth.data.eval_sets import build_set_index
    from msdepth.data.rois import write_set_rois
    from msdepth.errors import ConfigError
    from msdepth.evaluation.results import score_set

    root = _folder(tmp_path / "set")
    (root / "rois.csv").write_text("image,class,x0,y0,x1,y1\nc,glass,0,0,12,4\nd,glass,0,0,6,8\n")
    params = params_from_dict(
        {"data": {"folder": {"root": str(root), "class_maps": "classes", "rois_csv": "rois.csv"}},
         "eval": {"extra_sets": ["folder"]}}
    )  # fmt: skip
    assert params.data.source == "synthetic"
    index = build_set_index(params, "folder")
    assert list(index["frame"]) == ["c", "d"] and all(index["class_map"].str.endswith(".png"))
    rois = tmp_path / "set_rois" / "folder.csv"
    assert len(write_set_rois(params, "folder", index, rois)) == 2
    frames = load_frames(index)
    pred = {
        "c": np.where(_labels("c") == 1, 12.0, 10.0).astype(np.float32),
        "d": np.full((H, W), 15.0, np.float32),
    }
    monkeypatch.chdir(tmp_path)
    score_set(params, "folder", "constant", pred, frames, scaled=False, rois=rois)
    summary = json.loads((tmp_path / "metrics" / "sets" / "folder" / "full" / "constant.json").read_text())
    assert summary["masks"]["cap80"]["by_class"]["transparent"]["abs_rel"] == pytest.approx(0.225, abs=1e-6)
    roi = json.loads((tmp_path / "metrics" / "sets" / "folder" / "roi" / "constant.json").read_text())
    glass = roi["cap80"]["by_class"]["glass"]  # c's top rows at 12 m for 10 (0.2), d's left half 15 for 20
    assert glass["count"] == 2 and glass["abs_rel"] == pytest.approx(0.225, abs=1e-6)
    assert "d1" in glass and "epe" in glass
    with pytest.raises(ConfigError, match=r"^data\.folder\.root: must name the stereo folder"):
        params_from_dict({"eval": {"extra_sets": ["folder"]}})
