"""Bounds before bytes (issue 42, cases 4 and 5): an image file's size and header are checked before
its body is read, and a JPEG of more scans than any real one is refused before it is decoded."""

from __future__ import annotations

import resource
import struct
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from msdepth.data import imagefile, kitti
from msdepth.errors import DataError, PixelLimitError


def _peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


def _sparse(path: Path, size: int, head: bytes = b"") -> Path:
    """A file of ``size`` bytes that takes a few KB on disk: ``head``, then a hole."""
    with open(path, "wb") as file:
        file.write(head)
        file.truncate(size)
    return path


def repeated_scans(repeats: int) -> bytes:
    """A valid progressive JPEG whose last scan is repeated ``repeats`` times (libjpeg decodes each)."""
    image = np.full((64, 96, 3), 128, np.uint8)
    image[::8] = 0
    data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes()
    last = data.rfind(b"\xff\xda")
    return data[:-2] + data[last:-2] * repeats + b"\xff\xd9"


def test_a_sparse_2_gb_png_is_refused_without_reading_it(tmp_path: Path) -> None:
    # Case 4: a sparse 2 GB b.png (4 KB on disk) reached 2.4 GB RSS (here 2.1 GB, 23 s) before it
    # was refused; now it is refused from its size alone.
    path = _sparse(tmp_path / "b.png", 2 * 2**30)
    before = _peak_rss_mib()
    with pytest.raises(PixelLimitError, match=r"b.png: image: the file is 2,048 MiB, more than any image "):
        kitti.read_image(path)
    assert _peak_rss_mib() - before < 64


def test_a_huge_file_under_the_bound_is_refused_after_its_header(tmp_path: Path) -> None:
    # A real PNG header declaring 100 x 100 px, then 500 MB of hole: the header bounds the file.
    small = cv2.imencode(".png", np.zeros((100, 100, 3), np.uint8))[1].tobytes()
    path = _sparse(tmp_path / "c.png", 500 * 2**20, small)
    before = _peak_rss_mib()
    with pytest.raises(
        DataError, match=r"c.png: image: the file is 500 MiB, more than its header's 100 x 100 px"
    ):
        kitti.read_image(path)
    assert _peak_rss_mib() - before < 64


def test_the_file_bound_follows_the_pixel_limit(tmp_path: Path) -> None:
    path = _sparse(tmp_path / "d.png", imagefile._max_file_bytes(1000) + 1)
    with pytest.raises(PixelLimitError, match="within the limit of 0.001 megapixels"):
        kitti.read_image(path, max_pixels=1000)


def test_a_jpeg_frame_header_after_large_app_segments_is_found_by_seeking(tmp_path: Path) -> None:
    # Three 64 KB APP segments before the frame header: past the first 64 KiB read.
    image = np.random.default_rng(0).integers(0, 256, (20, 30, 3), np.uint8)
    data = cv2.imencode(".jpg", image)[1].tobytes()
    app = b"\xff\xe5" + struct.pack(">H", 65535) + b"\x00" * 65533
    (tmp_path / "e.jpg").write_bytes(data[:2] + app * 3 + data[2:])
    with open(tmp_path / "e.jpg", "rb") as file:
        assert imagefile._header_size(file) == (30, 20)
    assert kitti.read_image(tmp_path / "e.jpg").shape == (20, 30, 3)


def test_a_tiff_directory_at_the_end_is_read_by_seeking(tmp_path: Path) -> None:
    image = np.random.default_rng(0).integers(0, 256, (20, 30, 3), np.uint8)
    assert cv2.imwrite(str(tmp_path / "f.tif"), image)
    with open(tmp_path / "f.tif", "rb") as file:
        assert imagefile._header_size(file) == (30, 20)


def test_a_jpeg_of_5000_repeated_scans_is_refused_before_decoding(tmp_path: Path) -> None:
    # Case 5: a 200 KB file of 5,000 repeated scans took 48 s in predict and was accepted.
    (tmp_path / "p.jpg").write_bytes(repeated_scans(5000))
    with pytest.raises(
        DataError, match=rf"p.jpg: image: JPEG with more than {imagefile.MAX_JPEG_SCANS} scans"
    ):
        kitti.read_image(tmp_path / "p.jpg")


def test_a_progressive_jpeg_of_real_scan_count_is_read(tmp_path: Path) -> None:
    (tmp_path / "q.jpg").write_bytes(repeated_scans(0))
    assert kitti.read_image(tmp_path / "q.jpg").shape == (64, 96, 3)


def test_a_jpeg_of_repeated_scans_under_the_count_bound_is_refused_as_corrupt(tmp_path: Path) -> None:
    # Case 5's file with 50 repeats (under MAX_JPEG_SCANS) was decoded with exit code 0 and libjpeg's
    # bare "Inconsistent progression sequence" warning on stderr: a bogus progression is corrupt data.
    (tmp_path / "p.jpg").write_bytes(repeated_scans(50))
    with pytest.raises(DataError, match=r"p.jpg: image: corrupt JPEG \(libjpeg: Inconsistent progression"):
        kitti.read_image(tmp_path / "p.jpg")


def _jpeg_after_its_frame_header(body: bytes) -> bytes:
    """A JPEG's start, its frame header (a 1,000 x 1,000 px baseline frame), then ``body``."""
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 11, 8, 1000, 1000, 1) + b"\x01\x11\x00"
    return b"\xff\xd8" + sof + body


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + b"\x00" * 4  # the walk reads no CRC


def test_a_jpeg_of_more_markers_than_the_bound_is_refused_without_walking_them() -> None:
    # Issue 56: a 73 MB 1 MP JPEG of empty comment segments (18 million markers) took 14 s to walk,
    # to be refused by OpenCV; one marker more than the bound is refused by the walk.
    comments = b"\xff\xfe\x00\x02" * imagefile.MAX_JPEG_MARKERS
    with pytest.raises(DataError, match=r"^corrupt JPEG: more than 4,096 markers"):
        imagefile._jpeg_size(_jpeg_after_its_frame_header(comments + b"\xff\xd9"))
    # one fewer (the frame header is one) is walked to its end
    fewer = comments[: 4 * (imagefile.MAX_JPEG_MARKERS - 2)]
    assert imagefile._jpeg_size(_jpeg_after_its_frame_header(fewer + b"\xff\xd9")) == (1000, 1000)


def test_a_png_of_more_chunks_than_the_bound_is_refused_without_walking_them() -> None:
    # Issue 56: 72 MB of empty chunks (6 million) took 3.3 s to walk; the bound is one chunk a KiB of
    # the file on average, plus 4,096.
    ihdr = _png_chunk(b"IHDR", struct.pack(">IIBBBBB", 1000, 1000, 8, 0, 0, 0, 0))
    chunks = _png_chunk(b"zzZz", b"") * (imagefile.PNG_CHUNKS_BASE + 100)
    data = b"\x89PNG\r\n\x1a\n" + ihdr + chunks + _png_chunk(b"IEND", b"")
    with pytest.raises(DataError, match=r"^corrupt PNG: more than 4,145 chunks"):
        imagefile.png_size(data)
    # image data in 8 KiB chunks, as libpng writes it: 8 times under the bound
    idat = _png_chunk(b"IDAT", bytes(8192)) * 2000
    assert imagefile.png_size(b"\x89PNG\r\n\x1a\n" + ihdr + idat + _png_chunk(b"IEND", b"")) == (1000, 1000)


@pytest.mark.parametrize(
    "body",
    [b"\xff" * 16_000_000 + b"\xd9", b"\xff\xda\x00\x02" + b"\xff\x00" * 8_000_000 + b"\xff\xd9"],
    ids=["fill-bytes", "stuffed-bytes-in-a-scan"],
)
def test_runs_of_0xff_are_searched_not_walked(body: bytes) -> None:
    # 16 MB of fill bytes, or of 0xFF 0x00 in a scan: a Python loop over each 0xFF took seconds; the
    # regex engine finds the next marker (the result is the same: the walk reaches the end).
    started = time.perf_counter()
    assert imagefile._jpeg_size(_jpeg_after_its_frame_header(body)) == (1000, 1000)
    assert time.perf_counter() - started < 1.0
