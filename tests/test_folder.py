"""data.source folder: the PFM reader, the GT formats, the camera file, the index builders, the
config checks and the zero-ROI suites."""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from msdepth.config.params import ConfigError, params_from_dict
from msdepth.data import folder, kitti
from msdepth.data.ground_truth import read_gt_depth
from msdepth.data.layout import folder_layout
from msdepth.data.pfm import read_pfm, write_pfm
from msdepth.errors import DataError
from msdepth.evaluation.suites import NO_ROIS, Frame, evaluate_gradients, evaluate_roi, load_frames
from msdepth.io import write_png


def _read_gt(path: Path, *, focal: float, baseline: float, npy_is_disparity: bool = False) -> np.ndarray:
    """GT depth of a folder's GT file as the evaluation index reads it (folder.eval_rows)."""
    kind = folder.gt_kind(path, npy_is_disparity=npy_is_disparity)
    return read_gt_depth(kind, path, focal=focal, baseline=baseline)


# --------------------------------------------------------------------------- PFM, hand-built


def _pfm_bytes(magic: bytes, rows_top_first: list[list], little: bool, scale: float = 1.0) -> bytes:
    """A PFM file written by hand: the header, then the rows bottom first, packed one float at a time."""
    height, width = len(rows_top_first), len(rows_top_first[0])
    flat = [
        v for row in reversed(rows_top_first) for px in row for v in (px if isinstance(px, tuple) else (px,))
    ]
    order = "<" if little else ">"
    header = b"%s\n%d %d\n%s\n" % (magic, width, height, str(-scale if little else scale).encode())
    return header + struct.pack(f"{order}{len(flat)}f", *flat)


@pytest.mark.parametrize("little", [True, False])
def test_pfm_greyscale_both_byte_orders_rows_bottom_to_top(tmp_path: Path, little: bool):
    rows = [[1.0, 2.0, 3.0], [4.0, 5.5, float("inf")]]  # top row first
    path = tmp_path / "d.pfm"
    path.write_bytes(_pfm_bytes(b"Pf", rows, little))
    got = read_pfm(path)
    assert got.dtype == np.float32 and got.shape == (2, 3)
    np.testing.assert_array_equal(got, np.array(rows, np.float32))


def test_pfm_colour_is_three_channels(tmp_path: Path):
    rows = [[(1.0, 2.0, 3.0), (4.0, 5.0, 6.0)]]
    path = tmp_path / "c.pfm"
    path.write_bytes(_pfm_bytes(b"PF", rows, little=True))
    got = read_pfm(path)
    assert got.shape == (1, 2, 3)
    np.testing.assert_array_equal(got[0, 1], [4.0, 5.0, 6.0])
    # A colour PFM is no disparity map: the GT reader refuses it, naming the file.
    with pytest.raises(DataError, match=r"c\.pfm: a disparity map must have one channel"):
        _read_gt(path, focal=100.0, baseline=0.5)


def test_pfm_truncated_or_not_a_pfm_is_an_error_naming_the_file(tmp_path: Path):
    good = _pfm_bytes(b"Pf", [[1.0, 2.0], [3.0, 4.0]], little=True)
    (tmp_path / "cut.pfm").write_bytes(good[:-3])
    with pytest.raises(DataError, match=r"cut\.pfm: truncated PFM"):
        read_pfm(tmp_path / "cut.pfm")
    (tmp_path / "bad.pfm").write_bytes(b"P6\n2 2\n255\n" + bytes(12))
    with pytest.raises(DataError, match=r"bad\.pfm: not a PFM file"):
        read_pfm(tmp_path / "bad.pfm")


def test_write_pfm_round_trips(tmp_path: Path):
    disp = np.arange(12, dtype=np.float32).reshape(3, 4)
    for little in (True, False):
        write_pfm(tmp_path / "w.pfm", disp, little_endian=little)
        np.testing.assert_array_equal(read_pfm(tmp_path / "w.pfm"), disp)


# --------------------------------------------------------------------------- GT formats


def test_pfm_ground_truth_invalid_values_are_zero(tmp_path: Path):
    rows = [[10.0, float("inf"), float("nan")], [0.0, -1.0, 20.0]]
    (tmp_path / "g.pfm").write_bytes(_pfm_bytes(b"Pf", rows, little=True))
    depth = _read_gt(tmp_path / "g.pfm", focal=100.0, baseline=0.5)
    np.testing.assert_allclose(depth, [[5.0, 0, 0], [0, 0, 2.5]])
    assert depth.dtype == np.float32


def test_png_and_npy_ground_truth(tmp_path: Path):
    disp = np.array([[10.0, 0.0], [25.0, 50.0]], np.float32)
    kitti.write_disparity(tmp_path / "g.png", disp)
    np.testing.assert_allclose(
        _read_gt(tmp_path / "g.png", focal=100.0, baseline=0.5), [[5.0, 0], [2.0, 1.0]]
    )
    np.save(tmp_path / "d.npy", np.array([[3.0, np.inf], [-2.0, 7.5]]))
    np.testing.assert_allclose(_read_gt(tmp_path / "d.npy", focal=100.0, baseline=0.5), [[3.0, 0], [0, 7.5]])
    np.save(tmp_path / "p.npy", disp)
    np.testing.assert_allclose(
        _read_gt(tmp_path / "p.npy", focal=100.0, baseline=0.5, npy_is_disparity=True),
        [[5.0, 0], [2.0, 1.0]],
    )
    np.save(tmp_path / "rgb.npy", np.zeros((2, 2, 3)))
    with pytest.raises(DataError, match=r"rgb\.npy: GT must be a 2-D"):
        _read_gt(tmp_path / "rgb.npy", focal=1.0, baseline=1.0)
    (tmp_path / "g.exr").write_bytes(b"x")
    with pytest.raises(DataError, match=r"g\.exr: unknown GT format '\.exr'"):
        _read_gt(tmp_path / "g.exr", focal=1.0, baseline=1.0)


# --------------------------------------------------------------------------- camera


def test_camera_file_and_focal_rescaled_to_the_width(tmp_path: Path):
    (tmp_path / "camera.yaml").write_text("focal_px: 700\nwidth_px: 1400\nbaseline_m: 0.12\n")
    camera = folder._read_camera(tmp_path / "camera.yaml")
    assert camera.focal_at(1400) == 700.0 and camera.focal_at(700) == 350.0
    (tmp_path / "bad.yaml").write_text("focal_px: 700\nwidth: 1400\nbaseline_m: 0.12\n")
    with pytest.raises(DataError, match=r"bad\.yaml: .*missing \['width_px'\], unknown \['width'\]"):
        folder._read_camera(tmp_path / "bad.yaml")
    (tmp_path / "neg.yaml").write_text("focal_px: 700\nwidth_px: 1400\nbaseline_m: -1\n")
    with pytest.raises(DataError, match="baseline_m must be 0.001 to 10 m, got -1"):
        folder._read_camera(tmp_path / "neg.yaml")


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        # Issue 68: only > 0 was checked; width 1e-300 put focal 9.6e+304 into the index.
        ("focal_px: 1.0e-300", "focal_px must be 1 to 100000 px, got 1e-300"),
        ("focal_px: 2.0e+5", "focal_px must be 1 to 100000 px"),
        ("baseline_m: 1.0e+300", "baseline_m must be 0.001 to 10 m, got 1e+300"),
        ("baseline_m: 0.0001", "baseline_m must be 0.001 to 10 m"),
        ("width_px: 1.0e-300", "width_px must be 1 to 100000 px, got 1e-300"),
        ("width_px: 1400.5", "width_px must be a whole number of pixels, got 1400.5"),
        ("width_px: .nan", "width_px must be a number"),
    ],
)
def test_camera_values_outside_their_physical_range_are_one_line(
    tmp_path: Path, line: str, expected: str
) -> None:
    values = {"focal_px": "700", "width_px": "1400", "baseline_m": "0.12"}
    key, value = line.split(": ")
    values[key] = value
    path = tmp_path / "camera.yaml"
    path.write_text("".join(f"{k}: {v}\n" for k, v in values.items()))
    with pytest.raises(DataError) as err:
        folder._read_camera(path)
    message = str(err.value)
    assert message.startswith(f"{path}: ") and expected in message and "\n" not in message, message


def test_camera_values_at_their_range_ends_are_read(tmp_path: Path) -> None:
    path = tmp_path / "camera.yaml"
    path.write_text("focal_px: 1\nwidth_px: 100000\nbaseline_m: 10\n")
    assert folder._read_camera(path) == folder.Camera(1.0, 100000.0, 10.0)
    path.write_text("focal_px: 100000\nwidth_px: 1\nbaseline_m: 0.001\n")
    assert folder._read_camera(path) == folder.Camera(100000.0, 1.0, 0.001)


# --------------------------------------------------------------------------- index builders


def _image(path: Path, h: int = 8, w: int = 12, value: int = 100) -> None:
    write_png(path, np.full((h, w, 3), value, np.uint8))


def _folder(root: Path, names=("a", "b", "c", "d"), eval_lines: str | None = None) -> Path:
    for side in ("left", "right"):
        (root / side).mkdir(parents=True)
        for n in names:
            _image(root / side / f"{n}.png")
    (root / "gt").mkdir()
    kitti.write_disparity(root / "gt" / "c.png", np.full((8, 12), 4.0, np.float32))
    np.save(root / "gt" / "d.npy", np.full((8, 12), 2.0, np.float32))
    (root / "camera.yaml").write_text("focal_px: 24\nwidth_px: 24\nbaseline_m: 0.5\n")
    lines = "left/c.png right/c.png gt/c.png\nleft/d.png right/d.png gt/d.npy\nleft/b.png right/b.png\n"
    (root / "eval.txt").write_text(lines if eval_lines is None else eval_lines)
    return root


def _params(data_root: Path, **folder_keys) -> object:
    return params_from_dict(
        {
            "data": {"source": "folder", "root": str(data_root), "folder": folder_keys},
            "eval": {"extra_sets": []},
        }
    )


def test_training_pairs_leave_out_the_evaluation_frames(tmp_path: Path):
    root = _folder(tmp_path / "s")
    pairs, excluded = folder.build_train_pairs(folder_layout(_params(root)))
    assert [(p[0].name, p[1].parent.name) for p in pairs] == [("a.png", "right")]
    assert excluded == 3
    (root / "pairs.txt").write_text("left/a.png right/a.png\nleft/c.png right/c.png\n")
    pairs, excluded = folder.build_train_pairs(folder_layout(_params(root, pairs="pairs.txt")))
    assert [p[0].name for p in pairs] == ["a.png"] and excluded == 1


def test_a_missing_right_image_is_named(tmp_path: Path):
    root = _folder(tmp_path / "s")
    (root / "right" / "a.png").unlink()
    with pytest.raises(DataError, match=r"right/a\.png: no right image for .*left/a\.png"):
        folder.build_train_pairs(folder_layout(_params(root)))
    with pytest.raises(DataError, match=r"not a usable stereo folder.*right/a\.png: no right image"):
        folder.check_folder(folder_layout(_params(root)))


def test_evaluation_index_rows_kinds_camera_and_no_gt(tmp_path: Path):
    from msdepth.data.eval_index import EVAL_COLUMNS
    from msdepth.data.indexing import folder_eval_index

    root = _folder(tmp_path / "s")
    frames = folder_eval_index(_params(root))
    assert list(frames.columns) == list(EVAL_COLUMNS)
    assert list(frames["frame"]) == ["c", "d", "b"]
    assert list(frames["gt_kind"]) == ["disparity", "npy_depth", "none"]
    assert (frames["focal"] == 12.0).all() and (frames["baseline"] == 0.5).all()  # 24 px at 24 -> 12 at 12
    assert (frames["crop"] == "").all()
    loaded = load_frames(frames.astype({c: str for c in EVAL_COLUMNS if c not in ("focal", "baseline")}))
    np.testing.assert_allclose(loaded[0].gt_depth, 12.0 * 0.5 / 4.0)
    np.testing.assert_allclose(loaded[1].gt_depth, 2.0)
    assert loaded[2].shape == (8, 12) and not loaded[2].valid.any()  # listed, no GT: excluded later
    (root / "gt" / "c.png").unlink()
    with pytest.raises(DataError, match=r"gt/c\.png: no such GT file \(listed in .*eval\.txt\)"):
        folder_eval_index(_params(root))


@pytest.mark.parametrize("field", ["left", "right", "gt"])
@pytest.mark.parametrize("escape", ["../../outside/c.png", "ABSOLUTE", "left/../../outside/c.png"])
def test_an_evaluation_list_naming_a_file_outside_the_folder_is_one_line(
    tmp_path: Path, field: str, escape: str
) -> None:
    # Issue 68: eval.txt naming ../../outside/000001.png or an absolute path was indexed: DVC tracks
    # only the folder, so a change there would rerun nothing.
    from msdepth.data.indexing import folder_eval_index

    root = _folder(tmp_path / "a" / "s")
    (tmp_path / "outside").mkdir()
    _image(tmp_path / "outside" / "c.png")
    escape = str(tmp_path / "outside" / "c.png") if escape == "ABSOLUTE" else escape
    line = {"left": "left/c.png", "right": "right/c.png", "gt": "gt/c.png"}
    line[field] = escape
    (root / "eval.txt").write_text(f"{line['left']} {line['right']} {line['gt']}\n")
    for call in (folder_eval_index, lambda p: folder.check_folder(folder_layout(p))):
        with pytest.raises(DataError) as err:
            call(_params(root))
        message = str(err.value)
        assert f"{root / 'eval.txt'}:1: " in message and repr(escape) in message, message
        assert ("absolute path" if escape.startswith("/") else "out of the folder") in message
        assert "\n" not in message


@pytest.mark.parametrize("key", ["camera", "eval_list", "class_maps", "pairs", "rois_csv"])
def test_a_folder_key_naming_a_file_outside_the_folder_is_one_line(tmp_path: Path, key: str) -> None:
    root = _folder(tmp_path / "s")
    params = _params(root, **{key: "../elsewhere/x"})
    with pytest.raises(DataError, match=rf"^data\.folder\.{key}: the path '\.\./elsewhere/x' is a path out"):
        folder.check_folder(folder_layout(params))
    params = _params(root, **{key: str(tmp_path / "elsewhere")})
    with pytest.raises(DataError, match=rf"^data\.folder\.{key}: .* out of the folder"):
        folder.check_folder(folder_layout(params))


def test_a_pairs_list_naming_a_file_outside_the_folder_is_one_line(tmp_path: Path) -> None:
    root = _folder(tmp_path / "s")
    (root / "pairs.txt").write_text("left/a.png ../../x/a.png\n")
    with pytest.raises(DataError, match=r"pairs\.txt: the right image '\.\./\.\./x/a\.png' is a path out"):
        folder.build_train_pairs(folder_layout(_params(root, pairs="pairs.txt")))


def test_folder_indexes_write_the_pipeline_files(tmp_path: Path):
    from msdepth.data.indexing import _folder_indexes

    root = _folder(tmp_path / "s")
    report = _folder_indexes(_params(root), tmp_path / "index")
    assert report["train_pairs_found"] == 1 and report["eval_frames"] == 3
    assert report["eval_frames_without_gt"] == 1 and report["eval_frames_left_out_of_training"] == 3
    assert kitti.read_split(tmp_path / "index" / "train_pairs.txt") == [
        (str(root / "left" / "a.png"), str(root / "right" / "a.png"))
    ]
    assert json.loads((tmp_path / "index" / "report.json").read_text())["source"] == "folder"


def test_check_folder_lists_what_is_missing(tmp_path: Path):
    with pytest.raises(DataError, match="no such folder"):
        folder.check_folder(folder_layout(_params(tmp_path / "nope")))
    root = _folder(tmp_path / "s")
    assert folder.check_folder(folder_layout(_params(root))) == {
        "train_pairs": 1,
        "eval_frames": 3,
        "eval_frames_with_gt": 2,
    }
    (root / "camera.yaml").unlink()
    (root / "gt" / "d.npy").unlink()
    with pytest.raises(DataError, match=r"camera\.yaml: no camera file.*d\.npy: listed in"):
        folder.check_folder(folder_layout(_params(root)))


def test_config_checks_name_the_key(tmp_path: Path):
    with pytest.raises(ConfigError, match=r"eval\.extra_sets: .*set eval\.extra_sets: \[\]"):
        params_from_dict({"data": {"source": "folder"}})
    with pytest.raises(ConfigError, match=r"data\.folder\.root: must be empty .*set data\.root: elsewhere"):
        _params(tmp_path, root="elsewhere")
    with pytest.raises(ConfigError, match=r"data\.folder\.left: must name a folder"):
        _params(tmp_path, left="")
    with pytest.raises(ConfigError, match=r"unknown parameter\(s\) \['data\.folder\.lefts'\]"):
        _params(tmp_path, lefts="x")
    _params(tmp_path, left="", pairs="pairs.txt")  # a pair list needs no folders


# --------------------------------------------------------------------------- zero ROIs


def _no_rois() -> pd.DataFrame:
    return pd.DataFrame(
        {c: pd.Series(dtype=str if c in ("image", "class") else int) for c in kitti.ROI_COLUMNS}
    )


@pytest.mark.parametrize("suite", [evaluate_roi, evaluate_gradients])
def test_zero_rois_give_an_explicit_summary_and_a_header_only_table(suite, tmp_path: Path):
    from msdepth.config.params import EvalConfig
    from msdepth.evaluation.results import headline

    frame = Frame("f", np.full((4, 6), 10.0, np.float32), 100.0, 0.5)
    summary, table = suite({"f": np.full((4, 6), 9.0, np.float32)}, [frame], _no_rois(), EvalConfig())
    assert summary["rois"] == 0 and NO_ROIS in summary and not any(k.startswith("cap") for k in summary)
    assert table.empty and {"roi", "image", "class", "cap"} <= set(table.columns)
    table.to_csv(tmp_path / "t.csv", index=False)
    assert (tmp_path / "t.csv").read_text().count("\n") == 1  # the header line only
    assert headline("roi", summary) == {"rois": 0}
    assert headline("gradients", summary) is None


def test_compare_without_rois_says_the_roi_suites_were_skipped():
    from msdepth.analysis.comparison import comparison_data
    from msdepth.evaluation.metrics import METRICS
    from msdepth.reporting.comparison import ROIS_SKIPPED, build_comparison

    full = {"cap80": dict.fromkeys(METRICS, 0.5), "images": 2, "excluded_images": 0}
    none = {"rois": 0, NO_ROIS: "no ROIs"}
    suites = {"full": {"ssim": full}, "roi": {"ssim": none}, "gradients": {"ssim": none}}
    result, md = build_comparison(comparison_data(suites, ["ssim"], []))
    assert ROIS_SKIPPED in md and "## ROI" not in md and "Gradient" not in md
    assert "## Full image, cap 80 m" in md and result["roi"] == {} and result["rois_skipped"] == "no ROIs"


def test_means_without_rois_have_no_roi_number():
    """The compare stage's per-variant mean rows from a comparison without ROIs: full image only."""
    from msdepth.analysis.comparison import comparison_data, mean_rows
    from msdepth.evaluation.metrics import METRICS
    from msdepth.reporting.comparison import build_comparison

    full = {"cap80": dict.fromkeys(METRICS, 0.5), "images": 2, "excluded_images": 0}
    none = {"rois": 0, NO_ROIS: "no ROIs"}
    suites = {"full": {"ssim": full}, "roi": {"ssim": none}, "gradients": {"ssim": none}}
    result, _ = build_comparison(comparison_data(suites, ["ssim"], []))
    assert mean_rows(result, ["ssim"], "cap80") == {"ssim": {"abs_rel": 0.5, "a1": 0.5}}


@pytest.mark.parametrize(
    ("name", "why"),
    [
        (b"a b.png", "white space"),
        (b"a\nb.png", "white space"),
        (b"a\rb.png", "white space"),
        (b"a\tb.png", "white space"),
        (b"\xff\xfe.png", "not UTF-8"),
    ],
    ids=["space", "newline", "carriage-return", "tab", "not-utf8"],
)
def test_an_unlistable_image_name_is_one_line_naming_it_in_prepare_data_and_index(
    tmp_path: Path, name: bytes, why: str
) -> None:
    """Issue 68: a non-UTF-8 image name passed prepare_data, then the index stage gave 'unexpected
    UnicodeEncodeError'; a space, newline or carriage return refused the folder naming the stage's
    own output. Both stages now refuse such an image in one line naming it (escaped)."""
    from msdepth.data.indexing import _folder_indexes

    root = _folder(tmp_path / "s")
    for side in ("left", "right"):
        _image(Path(os.fsdecode(os.fsencode(root / side) + b"/" + name)))
    shown = repr(os.fsdecode(os.fsencode(root / "left") + b"/" + name))[1:-1]
    for stage in (
        lambda: folder.check_folder(folder_layout(_params(root))),
        lambda: _folder_indexes(_params(root), tmp_path / "index"),
    ):
        with pytest.raises(DataError) as err:
            stage()
        message = str(err.value)
        assert "\n" not in message and "\r" not in message, message
        assert shown in message and why in message and "rename it" in message, message
    assert not (tmp_path / "index").exists()
