"""Readers say what they saw (issue 68, item 4's misleading lines): a 1-bit class map's real label,
a palette PNG called a palette, a symbolic link to a FIFO called one, PGM bytes named ``.png``
refused as KITTI GT, and a learning rate too small to move a float32 weight refused."""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from msdepth.config.params import params_from_dict
from msdepth.data import folder, kitti, kitti2012
from msdepth.data.ground_truth import read_label_class_map
from msdepth.errors import ConfigError, DataError

H, W = 4, 8


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _png(rows: list[bytes], depth: int, color_type: int, extra: bytes = b"") -> bytes:
    """A PNG of W x len(rows) px from packed ``rows`` (filter 0 added)."""
    ihdr = struct.pack(">IIBBBBB", W, len(rows), depth, color_type, 0, 0, 0)
    raw = b"".join(b"\x00" + row for row in rows)
    return (
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", ihdr)
        + extra
        + _chunk(b"IDAT", zlib.compress(raw))
        + _chunk(b"IEND", b"")
    )


def _one_bit_map(tmp_path: Path, classes: str) -> Path:
    # Labels 1 on the left half of each row (bits 11110000), 0 elsewhere.
    path = tmp_path / "classes" / "c.png"
    path.parent.mkdir()
    path.write_bytes(_png([b"\xf0"] * H, 1, 0))
    (path.parent / "classes.yaml").write_text(classes)
    return path


def test_a_one_bit_class_map_reads_its_labels(tmp_path: Path) -> None:
    # OpenCV scales a 1-bit 1 to 255: the map was refused as "label(s) [255] not in its classes file".
    path = _one_bit_map(tmp_path, "1: transparent\n")
    bits = read_label_class_map(path)
    expected = np.zeros((H, W), np.uint8)
    expected[:, :4] = kitti.CLASS_BITS["transparent"]
    np.testing.assert_array_equal(bits, expected)


def test_a_one_bit_class_map_names_its_real_label(tmp_path: Path) -> None:
    path = _one_bit_map(tmp_path, "2: transparent\n")
    with pytest.raises(DataError, match=r"c\.png: label\(s\) \[1\] not in its classes file"):
        read_label_class_map(path)


def test_a_palette_class_map_is_called_a_palette(tmp_path: Path) -> None:
    # It was "got uint8 with 3 channel(s)": OpenCV expands the palette to colours.
    path = tmp_path / "classes" / "c.png"
    path.parent.mkdir()
    palette = _chunk(b"PLTE", bytes([0, 0, 0, 255, 0, 0]))
    path.write_bytes(_png([bytes([0, 1] * (W // 2))] * H, 8, 3, palette))
    (path.parent / "classes.yaml").write_text("1: transparent\n")
    with pytest.raises(DataError) as err:
        read_label_class_map(path)
    assert "got a palette PNG" in str(err.value) and "channel(s)" not in str(err.value), err.value
    with pytest.raises(
        DataError, match=r"c\.png: expected an 8-bit single-channel class map, got a palette PNG"
    ):
        kitti.read_class_map(path)


def test_a_symbolic_link_to_a_fifo_is_called_one(tmp_path: Path) -> None:
    # It was "no such class map".
    os.mkfifo(tmp_path / "fifo")
    link = tmp_path / "c.png"
    link.symlink_to(tmp_path / "fifo")
    with pytest.raises(
        DataError, match=r"c\.png: a symbolic link to a FIFO, not a regular file \(class map\)$"
    ):
        folder._existing(link, "class map")
    (tmp_path / "gone.png").symlink_to(tmp_path / "nothing")
    with pytest.raises(DataError, match=r"gone\.png: a symbolic link to a missing file \(class map\)$"):
        folder._existing(tmp_path / "gone.png", "class map")
    with pytest.raises(DataError, match=r"none\.png: no such class map$"):
        folder._existing(tmp_path / "none.png", "class map")


def test_pgm_bytes_named_png_are_refused_as_kitti_gt(tmp_path: Path) -> None:
    # OpenCV decodes by content: a 16-bit PGM named .png was read as KITTI 2012 GT.
    gt = tmp_path / "disp_occ" / "000000_10.png"
    gt.parent.mkdir()
    gt.write_bytes(f"P5\n{W} {H}\n65535\n".encode() + np.full((H, W), 256, ">u2").tobytes())
    with pytest.raises(
        DataError, match=r"000000_10\.png: KITTI disparity map: not a PNG \(its bytes are a PGM\)"
    ):
        kitti2012.read_gt_disparity(gt)
    with pytest.raises(DataError, match=r"not a PNG \(its bytes are a PGM\)"):
        kitti.read_disparity(gt)


@pytest.mark.parametrize("key", ["optimum", "train"])
@pytest.mark.parametrize("value", [1e-320, 1e-12])
def test_a_learning_rate_too_small_to_move_a_weight_is_refused(key: str, value: float) -> None:
    with pytest.raises(ConfigError, match=rf"{key}\.learning_rate: must be in \[1e-09, 10\]"):
        params_from_dict({key: {"learning_rate": value}})
    params_from_dict({key: {"learning_rate": 1e-9}})
