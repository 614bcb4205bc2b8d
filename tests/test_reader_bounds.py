"""Every reader of an input file, fed the same hostile set (issue 56, deliverable 2): a FIFO, a
folder, a symbolic link loop, a sparse file one byte over its kind's limit, a truncated file, an
empty file and garbage. Each answer is one line naming the file (a MsdepthError), given at once (a
FIFO never blocks) and without reading what the file declares (a sparse file costs a stat).

The readers share one opening (:func:`msdepth.readers.open_regular`); this test is what holds each of them
to it, so a new reader goes into :data:`READERS` with its limit."""

from __future__ import annotations

import contextlib
import json
import os
import struct
import time
import tracemalloc
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
from conftest import unblocking

from msdepth.cli import experiments
from msdepth.config.params import MAX_PARAMS_BYTES, read_params_file
from msdepth.config.params_yaml import MAX_DATA_FILE_BYTES
from msdepth.data import eval_sets, folder, ground_truth, imagefile, kitti, pfm
from msdepth.download import lists
from msdepth.errors import DataError, MsdepthError
from msdepth.evaluation import pose
from msdepth.io import _encode_png


@dataclass(frozen=True)
class Reader:
    """One reader: the file name it reads, a good file, the largest size it reads, how to call it,
    how many bytes to cut for a truncated file, and whether an empty file is a valid one."""

    name: str
    filename: str
    good: bytes
    max_bytes: int
    read: Callable[[Path], Any]
    cut: int = 3
    empty_ok: bool = False


def _npy(array: np.ndarray) -> bytes:
    header = f"{{'descr': '{array.dtype.str}', 'fortran_order': False, 'shape': {array.shape}, }}".encode()
    header += b" " * (-(10 + len(header) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + array.tobytes()


_CALIB = b"S_rect_02: 6 4\nR_rect_00: 1 0 0 0 1 0 0 0 1\nP_rect_02: 1 0 3 0 0 1 2 0 0 0 1 0\n"
_VELO_TO_CAM = "R: 1 0 0 0 1 0 0 0 1\nT: 0 0 0\n"
_POSES = b"1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0.5 0 1 0 0 0 0 1 0.25\n"

READERS = [
    Reader(
        "image",
        "a.png",
        _encode_png(np.arange(24, dtype=np.uint8).reshape(4, 6)),
        imagefile._max_file_bytes(imagefile.MAX_IMAGE_PIXELS),
        kitti.read_image,
    ),
    Reader("PFM", "d.pfm", b"Pf\n2 2\n-1.0\n" + np.ones(4, "<f4").tobytes(), pfm.MAX_PFM_BYTES, pfm.read_pfm),
    Reader(
        "npy GT",
        "d.npy",
        _npy(np.ones((2, 3), "<f4")),
        ground_truth.MAX_NPY_BYTES,
        lambda p: ground_truth.read_gt_depth("npy_depth", p, focal=1.0, baseline=1.0),
    ),
    Reader(
        "Velodyne scan",
        "0000000000.bin",
        np.ones((3, 4), "<f4").tobytes(),
        kitti.MAX_VELODYNE_BYTES,
        kitti.read_velodyne,
        empty_ok=True,  # a scan of no points
    ),
    # the raw day's calibration: the file named here, beside a good calib_velo_to_cam.txt
    Reader(
        "calibration",
        "calib_cam_to_cam.txt",
        _CALIB,
        kitti.MAX_CALIB_BYTES,
        lambda p: kitti.read_raw_calib(p.parent),
        cut=30,
    ),
    Reader(
        "split list",
        "split.txt",
        b"l0.png r0.png\nl1.png r1.png\n",
        kitti.MAX_LIST_BYTES,
        kitti.read_split,
        8,
    ),
    Reader(
        "camera",
        "camera.yaml",
        b"focal_px: 700\nwidth_px: 1400\nbaseline_m: 0.1\n",
        MAX_DATA_FILE_BYTES,
        folder._read_camera,
        cut=16,
    ),
    Reader(
        "params",
        "params.yaml",
        b"train: {epochs: 3}\n",
        MAX_PARAMS_BYTES,
        read_params_file,
        empty_ok=True,  # an empty params file is the defaults
    ),
    Reader(
        "dvc exp show --json",
        "show.json",
        json.dumps([{"rev": "workspace", "name": None, "data": {}}]).encode(),
        experiments.MAX_JSON_BYTES,
        experiments.read_json,
    ),
    Reader(
        "ROI CSV",
        "rois.csv",
        b"image,class,x0,y0,x1,y1\n000000_10,car,0,0,4,4\n",
        kitti.MAX_ROI_BYTES,
        kitti.read_rois,
    ),
    Reader("poses", "poses.txt", _POSES, pose.MAX_POSES_BYTES, pose._read_poses, cut=6),  # 11 numbers left
    Reader(
        "benchmark split",
        "eigen_benchmark_test_files.txt",
        b"2011_09_26/2011_09_26_drive_0002_sync 69 l\n",
        kitti.MAX_LIST_BYTES,
        eval_sets._read_benchmark_split,
    ),
    Reader(
        "archive list",
        "archives.txt",
        b"# KITTI raw\nraw_data/2011_09_26_calib.zip\n",
        lists.MAX_ARCHIVE_LIST_BYTES,
        lists.parse_archive_list,
    ),
    Reader(
        "download's split list",
        "train_files.txt",
        b"2011_09_26/2011_09_26_drive_0001_sync 1 l\n",
        lists.MAX_SPLIT_LIST_BYTES,
        lists._split_drives,
        cut=33,  # "2011_09_26" is left: names no drive
    ),
]
CASES = ["fifo", "folder", "symlink-loop", "over-limit", "truncated", "empty", "garbage"]


def _plant(case: str, reader: Reader, path: Path) -> None:
    """The hostile ``case`` at ``path``."""
    if case == "fifo":
        os.mkfifo(path)
    elif case == "folder":
        path.mkdir()
    elif case == "symlink-loop":
        (path.parent / "loop").symlink_to(path)
        path.symlink_to(path.parent / "loop")
    elif case == "over-limit":
        with open(path, "wb") as f:  # sparse: no block of it is written
            f.truncate(reader.max_bytes + 1)
    elif case == "truncated":
        path.write_bytes(reader.good[: -reader.cut])
    elif case == "empty":
        path.write_bytes(b"")
    else:  # garbage: an odd length, not a whole number of anything
        path.write_bytes(np.random.default_rng(0).integers(0, 256, 1001, dtype=np.uint8).tobytes())


def _folder_for(tmp_path: Path, reader: Reader) -> Path:
    day = tmp_path / "day"
    day.mkdir()
    (day / "calib_velo_to_cam.txt").write_text(_VELO_TO_CAM)
    return day / reader.filename


@pytest.mark.parametrize("reader", READERS, ids=[r.name for r in READERS])
def test_each_reader_reads_its_good_file(tmp_path: Path, reader: Reader) -> None:
    path = _folder_for(tmp_path, reader)
    path.write_bytes(reader.good)
    reader.read(path)


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("reader", READERS, ids=[r.name for r in READERS])
def test_each_reader_refuses_the_hostile_set_in_one_line(tmp_path: Path, reader: Reader, case: str) -> None:
    path = _folder_for(tmp_path, reader)
    _plant(case, reader, path)
    tracemalloc.start()
    started = time.perf_counter()
    try:
        with unblocking(path) if case == "fifo" else contextlib.nullcontext():
            reader.read(path)
    except MsdepthError as exc:
        error: MsdepthError | None = exc
    else:
        error = None
    seconds = time.perf_counter() - started
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    if error is None:
        assert case == "empty" and reader.empty_ok, f"{reader.name}: {case} was accepted"
        return
    message = str(error)
    assert "\n" not in message and str(path) in message and len(message) < 400, message
    # a FIFO answers at once (unblocking releases a blocked open after 1 s); nothing big is read
    assert seconds < 0.9 and peak < 16 << 20, (message, seconds, peak)


def test_the_download_reads_split_lists_with_the_index_stages_bound() -> None:
    # download.lists keeps its own constant (importing msdepth.data.kitti would load OpenCV and pandas):
    # this holds the two equal.
    assert lists.MAX_SPLIT_LIST_BYTES == kitti.MAX_LIST_BYTES


@pytest.mark.parametrize("case", ["fifo", "folder", "missing"])
def test_the_png_signature_check_refuses_what_is_not_a_file_in_one_line(tmp_path: Path, case: str) -> None:
    # read_label_map checks the signature after decoding: a FIFO swapped in meanwhile blocked open().
    path = tmp_path / "labels.png"
    if case == "fifo":
        os.mkfifo(path)
    elif case == "folder":
        path.mkdir()
    with unblocking(path) if case == "fifo" else contextlib.nullcontext(), pytest.raises(DataError) as err:
        imagefile.is_png(path)
    message = str(err.value)
    assert message.startswith(f"{path}: ") and "\n" not in message, message
