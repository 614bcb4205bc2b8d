"""Hostile and unusual image files (issue 27, items 3, 4, 10 and 11): the declared size is checked
before decoding, a corrupt JPEG is refused, the EXIF orientation is applied, and valid files with
data after the image are read."""

from __future__ import annotations

import io
import re
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from msdepth.data import imagefile, kitti
from msdepth.data.pairs import build_pair_cache
from msdepth.errors import DataError, PixelLimitError


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_declaring(width: int, height: int, idat: bytes = b"") -> bytes:
    """A well-formed PNG whose IHDR declares ``width`` x ``height`` RGB px, with ``idat`` as its data."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    idat = idat or zlib.compress(b"\x00" * 1000)
    return b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", idat) + _chunk(b"IEND", b"")


def _jpeg(image: np.ndarray) -> bytes:
    return cv2.imencode(".jpg", image)[1].tobytes()


def _noise(h: int, w: int) -> np.ndarray:
    return np.random.default_rng(0).integers(0, 256, (h, w, 3), dtype=np.uint8)


def test_png_declaring_50000_squared_is_one_data_error(tmp_path: Path) -> None:
    # Item 3: OpenCV raised cv2.error ("pixels <= CV_IO_MAX_IMAGE_PIXELS"), which nothing caught.
    (tmp_path / "huge.png").write_bytes(png_declaring(50_000, 50_000))
    with pytest.raises(DataError, match=r"huge.png: image: the header declares 50000 x 50000 px"):
        kitti.read_image(tmp_path / "huge.png")


def test_decompression_bomb_is_refused_before_decoding(tmp_path: Path) -> None:
    # Item 4: 16,000 x 16,000 px of zeros deflate to 730 KB; decoding took 1.5 GB (7 GB in predict).
    # Here 12,000 x 12,000 (144 megapixels, over the 120 limit) of one repeated row: 0.4 MB.
    row = b"\x00" * (1 + 3 * 12_000)
    packer = zlib.compressobj(9)
    idat = b"".join(packer.compress(row) for _ in range(12_000)) + packer.flush()
    (tmp_path / "bomb.png").write_bytes(png_declaring(12_000, 12_000, idat))
    with pytest.raises(DataError, match=r"bomb.png: .*144 megapixels\), over the limit of 120 megapixels"):
        kitti.read_image(tmp_path / "bomb.png")


def test_the_pixel_limit_can_be_raised_and_lowered(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "a.png"), _noise(40, 50))
    assert kitti.read_image(tmp_path / "a.png", max_pixels=2000).shape == (40, 50, 3)
    with pytest.raises(DataError, match="40 px .*over the limit of 0.00199"):
        kitti.read_image(tmp_path / "a.png", max_pixels=1999)


@pytest.mark.parametrize(
    ("width", "height", "limit", "expected"),
    [
        (12_000, 12_000, 120_000_000, "declares 12000 x 12000 px (144 megapixels), over the limit of 120 "),
        (300, 200, 10_000, "declares 300 x 200 px (0.06 megapixels), over the limit of 0.01 megapixels"),
        (1280, 960, 1_000_000, "declares 1280 x 960 px (1.229 megapixels), over the limit of 1 megapixels"),
        (100_000, 100_000, 120_000_000, "(10000 megapixels)"),
    ],
)
def test_one_pixel_limit_check_and_message(width: int, height: int, limit: int, expected: str) -> None:
    # One check for images and video frames (issue 42): predict's video check repeated it with its
    # own words and rounding ("0 megapixels" over a limit of 0.01 came from the image's).
    assert imagefile.check_pixel_limit(width, height, width * height) == (width, height)
    with pytest.raises(PixelLimitError) as err:
        imagefile.check_pixel_limit(width, height, min(limit, width * height - 1), "the video")
    assert str(err.value).startswith("the video declares") and "\n" not in str(err.value)
    if width * height > limit:
        with pytest.raises(PixelLimitError, match=re.escape(expected)):
            imagefile.check_pixel_limit(width, height, limit)
    with pytest.raises(DataError, match=r"^the header declares an empty image \(0 x 5 px\)$"):
        imagefile.check_pixel_limit(0, 5, limit)


def test_predict_checks_video_frames_with_the_image_reader_s_check() -> None:
    # The duplicate is gone: predict words no pixel limit of its own.
    source = (Path(__file__).parents[1] / "src/msdepth/cli/predict.py").read_text()
    assert "check_pixel_limit(" in source and "over the limit of" not in source


@pytest.mark.parametrize(
    "suffix", [".png", ".jpg", ".bmp", ".tif", ".webp", ".ppm", ".pgm"], ids=lambda s: s.lstrip(".")
)
def test_declared_size_matches_opencv_for_every_supported_format(suffix: str) -> None:
    from msdepth.data import imagefile

    image = _noise(37, 53)[..., :1] if suffix == ".pgm" else _noise(37, 53)
    data = cv2.imencode(suffix, image)[1].tobytes()
    assert imagefile._declared_size(data) == (53, 37)


def test_cache_leaves_out_the_huge_pair_and_keeps_the_good_one(tmp_path: Path) -> None:
    # Item 3: the cache stage crashed on the cv2.error instead of leaving the pair out.
    for name in ("l.png", "r.png"):
        cv2.imwrite(str(tmp_path / name), _noise(16, 32))
    (tmp_path / "huge.png").write_bytes(png_declaring(50_000, 50_000))
    pairs = [(tmp_path / "huge.png", tmp_path / "r.png"), (tmp_path / "l.png", tmp_path / "r.png")]
    report = build_pair_cache(pairs, 8, 16, tmp_path / "cache.npy", progress=False)
    assert report.pairs == pairs[1:]
    assert [(a, b) for a, b, _ in report.unreadable] == pairs[:1]
    assert "50000 x 50000 px" in report.unreadable[0][2]


def test_exif_orientation_is_applied(tmp_path: Path) -> None:
    # Item 10: stored 128 wide x 48 high with orientation 6 (rotate 90 degrees clockwise to view):
    # was predicted sideways, 48 x 128 read as (48, 128).
    from PIL import Image

    stored = np.zeros((48, 128, 3), np.uint8)
    stored[:, :16] = 255  # a white band on the left, which becomes the top once rotated
    picture = Image.fromarray(stored)
    exif = picture.getexif()
    exif[0x0112] = 6
    buffer = io.BytesIO()
    picture.save(buffer, "JPEG", exif=exif.tobytes(), quality=95)
    (tmp_path / "phone.jpg").write_bytes(buffer.getvalue())
    img = kitti.read_image(tmp_path / "phone.jpg")
    assert img.shape == (128, 48, 3)
    assert img[:12].mean() > 240 and img[20:].mean() < 15


def test_jpeg_corrupt_mid_scan_is_refused(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    # Item 10: a restart marker where none belongs: libjpeg only warned and OpenCV returned grey blocks.
    data = bytearray(_jpeg(_noise(96, 128)))
    data[len(data) // 2 : len(data) // 2 + 2] = b"\xff\xd0"
    (tmp_path / "bad.jpg").write_bytes(bytes(data))
    with pytest.raises(DataError, match=r"bad.jpg: image: corrupt JPEG \(libjpeg: Corrupt JPEG data"):
        kitti.read_image(tmp_path / "bad.jpg")
    assert "Corrupt JPEG" not in capfd.readouterr().err  # reported once, in the error, not also raw


def test_a_good_jpeg_after_a_bad_one_still_reads(tmp_path: Path) -> None:
    data = bytearray(_jpeg(_noise(96, 128)))
    data[len(data) // 2 : len(data) // 2 + 2] = b"\xff\xd0"
    (tmp_path / "bad.jpg").write_bytes(bytes(data))
    (tmp_path / "good.jpg").write_bytes(_jpeg(_noise(96, 128)))
    with pytest.raises(DataError):
        kitti.read_image(tmp_path / "bad.jpg")
    assert kitti.read_image(tmp_path / "good.jpg").shape == (96, 128, 3)


def test_jpeg_with_a_motion_photo_video_after_it_is_read(tmp_path: Path) -> None:
    # Item 11: the end-of-image marker had to be in the last 64 bytes: "truncated JPEG".
    image = _noise(48, 64)
    trailer = b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 40  # holds 0xFF 0xD9 too
    (tmp_path / "motion.jpg").write_bytes(_jpeg(image) + trailer)
    (tmp_path / "plain.jpg").write_bytes(_jpeg(image))
    np.testing.assert_array_equal(
        kitti.read_image(tmp_path / "motion.jpg"), kitti.read_image(tmp_path / "plain.jpg")
    )


def test_png_with_data_after_iend_is_read(tmp_path: Path) -> None:
    # Item 11: IEND had to be the file's last bytes: "truncated PNG (no IEND chunk at the end)".
    image = _noise(48, 64)
    (tmp_path / "t.png").write_bytes(cv2.imencode(".png", image)[1].tobytes() + b"MPF trailer" * 20)
    np.testing.assert_array_equal(kitti.read_image(tmp_path / "t.png"), image[..., ::-1])


@pytest.mark.parametrize("cut", [1, 2, 100])
def test_jpeg_cut_short_is_still_truncated(tmp_path: Path, cut: int) -> None:
    data = _jpeg(_noise(48, 64))
    (tmp_path / "cut.jpg").write_bytes(data[:-cut])
    with pytest.raises(DataError, match="cut.jpg: image: truncated JPEG"):
        kitti.read_image(tmp_path / "cut.jpg")


def test_unknown_format_is_refused_before_opencv_sees_it(tmp_path: Path) -> None:
    # OpenCV would decode a Radiance HDR named .png; its cost is not checked, so it is refused.
    (tmp_path / "x.png").write_bytes(cv2.imencode(".hdr", np.ones((4, 4, 3), np.float32))[1].tobytes())
    with pytest.raises(DataError, match="x.png: image: cannot decode it: not a PNG, JPEG"):
        kitti.read_image(tmp_path / "x.png")
