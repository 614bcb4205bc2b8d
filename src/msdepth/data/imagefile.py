"""Decoding image files with bounded cost: the header is read before any pixel is.

OpenCV allocates what a file declares before it reads the pixels: a 320-byte PNG declaring
50,000 x 50,000 px makes it raise, and a 730 KB PNG of 16,000 x 16,000 px took 7 GB. So the size
each format declares (PNG's IHDR, JPEG's SOF, BMP, TIFF, WebP, PNM headers) is read here from
the bytes and checked against a pixel limit first; a file in any other format is refused, as
its cost cannot be known in advance. The structure is walked too: a PNG's chunks up to IEND
and a JPEG's markers up to its end-of-image marker, so a truncated file is refused (OpenCV
fills it with grey rows) while data after the image (a phone's "motion photo" video, MPF
previews) is allowed. libjpeg reports corrupt entropy-coded data only as a warning on stderr
(and decodes grey blocks): that warning is caught and turned into a refusal.

A file is read only after its size and header pass (:func:`read_file`): its size on disk is
bounded by the pixel limit (:func:`_max_file_bytes`), its header (a PNG's IHDR, a JPEG's markers up
to the frame header, read by seeking, at most :data:`JPEG_HEADER_MARKERS` of them) declares at most
that many pixels, and its size is bounded again by the pixels it declares. So a sparse 2 GB file
named ``b.png`` (4 KB on disk) costs a stat and no read. A JPEG of more than
:data:`MAX_JPEG_SCANS` scans is refused before decoding: libjpeg decodes every scan again, so a
200 KB file of 5,000 repeated scans took 48 s.

Every problem is a DataError without the file name; callers prefix it.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
import threading
from typing import BinaryIO, Callable, Iterable, Iterator, TypeVar

import cv2
import numpy as np

from msdepth.errors import DataError, PixelLimitError
from msdepth.readers import open_regular

# 120 million pixels: a 108-megapixel phone photo (12,000 x 9,000) fits; predict on one peaks at
# about 4.3 GiB (measured, docs/user-guide.md "Security"). Raise it with read_image(max_pixels=...)
# or `msdepth predict --max-megapixels`.
MAX_IMAGE_PIXELS = 120_000_000
# The most bytes a real image file spends per pixel: 16-bit RGBA stored without compression (TIFF,
# PNG at level 0, PAM-like PNM). An ASCII PNM can spend more; it is refused past this bound.
MAX_BYTES_PER_PIXEL = 8
# What a file may hold beyond its pixels: EXIF, ICC profiles, MPF previews, a motion photo's video.
FILE_SLACK_BYTES = 64 * 2**20
# Progressive JPEGs of libjpeg, phones and cameras have at most about 20 scans (libjpeg's own
# progression has 10); libjpeg decodes each scan over the whole frame, so time grows with the count.
MAX_JPEG_SCANS = 100
JPEG_HEADER_MARKERS = 1024  # markers walked (by seeking, 4 bytes read each) to find the frame header
# The markers a whole JPEG's walk visits (the scans' entropy-coded data is searched in C, not walked):
# a real JPEG has tens (hundreds with 64 MiB of metadata in 64 KiB segments), and the header's walk
# already stops at JPEG_HEADER_MARKERS; a 73 MB file of empty comment segments took 14 s to walk.
MAX_JPEG_MARKERS = 4 * JPEG_HEADER_MARKERS
# The chunks a PNG's walk visits: at most one per PNG_BYTES_PER_CHUNK of the file on average, plus
# PNG_CHUNKS_BASE. Encoders write image data in chunks of 8 KiB (libpng) or more; 72 MB of empty
# chunks (6 million) took 3.3 s.
PNG_CHUNKS_BASE = 4096
PNG_BYTES_PER_CHUNK = 1024
_HEAD_BYTES = 64 * 1024  # read first: every header but a JPEG's or a TIFF's directory lies in it

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_JPEG_MAGIC = b"\xff\xd8"
_JPEG_SOF = set(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}  # frame headers (0xC4 etc. are tables)
_JPEG_STANDALONE = set(range(0xD0, 0xD8)) | {0x01}  # RSTn and TEM: no length field
_JPEG_FILL = re.compile(rb"\xff*")
_JPEG_MARKER_AFTER_SCAN = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")
_HEADER_LIMIT = 4096  # bytes of a PNM header searched for its size
# libjpeg's warnings that the data is corrupt (it decodes on, with grey blocks or a wrong picture);
# a repeated or out-of-order progressive scan is "Inconsistent progression sequence".
_LIBJPEG_ERRORS = (b"Corrupt JPEG data", b"Premature end of JPEG file", b"Inconsistent progression sequence")
_STDERR_LOCK = threading.Lock()


# The decoded pixels a batch of predict or optimum may hold: 32 megapixels (96 MB of RGB): eight
# KITTI frames (0.47 megapixels each) or three 12-megapixel photos; a larger image goes alone.
BATCH_PIXEL_BUDGET = 32_000_000

ReadAt = Callable[[int, int], bytes]
Item = TypeVar("Item")  # (position, count) -> at most count bytes from position


def _max_file_bytes(pixels: int) -> int:
    """The largest file accepted for an image of ``pixels`` pixels: :data:`MAX_BYTES_PER_PIXEL` a
    pixel, plus :data:`FILE_SLACK_BYTES` of metadata."""
    return MAX_BYTES_PER_PIXEL * pixels + FILE_SLACK_BYTES


def _u16(data: bytes, pos: int, order: str = "big") -> int:
    return int.from_bytes(data[pos : pos + 2], order)


def _u32(data: bytes, pos: int, order: str = "big") -> int:
    return int.from_bytes(data[pos : pos + 4], order)


def _png_header_size(data: bytes) -> tuple[int, int]:
    """(width, height) of a PNG's IHDR chunk, which must come first."""
    if len(data) < 33:  # signature, IHDR and its CRC
        raise DataError(f"truncated PNG: {len(data)} bytes, its header is cut off")
    if data[12:16] != b"IHDR":
        raise DataError("corrupt PNG: it does not start with an IHDR chunk")
    return _u32(data, 16), _u32(data, 20)


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) of a PNG after walking its chunks to IEND; DataError if they do not get there,
    or if there are more than :data:`PNG_CHUNKS_BASE` plus one per :data:`PNG_BYTES_PER_CHUNK` bytes.

    Walking the chunk headers costs microseconds; OpenCV allocates a chunk's declared length first.
    """
    size = _png_header_size(data)
    pos, most = len(_PNG_MAGIC), PNG_CHUNKS_BASE + len(data) // PNG_BYTES_PER_CHUNK
    for _ in range(most):
        if pos + 12 > len(data):  # 4 length + 4 type + data + 4 CRC
            break
        length, kind = _u32(data, pos), data[pos + 4 : pos + 8]
        if pos + 12 + length > len(data):
            raise DataError(
                f"truncated PNG: chunk {kind!r} at byte {pos} declares {length} bytes, past the end"
            )
        if kind == b"IEND":
            return size
        pos += 12 + length
    else:
        raise DataError(
            f"corrupt PNG: more than {most:,} chunks (one a KiB of the file, plus {PNG_CHUNKS_BASE:,}) "
            "before its end: refused, every chunk is walked"
        )
    raise DataError(f"truncated PNG: no IEND chunk (the chunks stop at byte {pos})")


def _jpeg_scan_end(data: bytes, pos: int) -> int:
    """The position of the first marker after entropy-coded data starting at ``pos``: the first 0xFF
    followed by neither 0x00 (a stuffed 0xFF byte), a restart marker 0xD0-0xD7 nor another 0xFF (a
    fill byte), found by the regex engine (a Python loop over 0xFF bytes took seconds for megabytes)."""
    found = _JPEG_MARKER_AFTER_SCAN.search(data, pos)
    if found is None:
        raise DataError("truncated JPEG (no end-of-image marker)")
    return found.start()


def _jpeg_size(data: bytes) -> tuple[int, int]:
    """(width, height) of a JPEG's frame header, after walking its markers to the end-of-image marker.

    Bytes after that marker (a motion photo's video, MPF previews) are allowed and ignored; more
    than :data:`MAX_JPEG_SCANS` scans (start-of-scan markers) or :data:`MAX_JPEG_MARKERS` markers
    are refused.
    """
    pos, size, scans = 2, None, 0
    for _ in range(MAX_JPEG_MARKERS):
        fill = _JPEG_FILL.match(data, pos).end()  # fill bytes: a run of 0xFF, the last one the marker's
        pos = max(pos, fill - 1)
        if pos + 2 > len(data):
            raise DataError("truncated JPEG (no end-of-image marker)")
        if data[pos] != 0xFF:
            raise DataError(f"corrupt JPEG: no marker at byte {pos}")
        marker = data[pos + 1]
        if marker == 0xD9:
            if size is None:
                raise DataError("corrupt JPEG: no frame header before the end-of-image marker")
            return size
        if marker in _JPEG_STANDALONE:
            pos += 2
            continue
        if pos + 4 > len(data):
            raise DataError("truncated JPEG (no end-of-image marker)")
        end = pos + 2 + _u16(data, pos + 2)
        if marker in _JPEG_SOF and end <= len(data) and end - pos >= 9:
            size = (_u16(data, pos + 7), _u16(data, pos + 5))
        if marker == 0xDA:
            scans += 1
            if scans > MAX_JPEG_SCANS:  # refused before libjpeg decodes them all again
                raise DataError(
                    f"JPEG with more than {MAX_JPEG_SCANS} scans (real progressive JPEGs have at most "
                    "about 20): refused, its decoding time grows with every scan"
                )
        pos = _jpeg_scan_end(data, end) if marker == 0xDA else end
    raise DataError(
        f"corrupt JPEG: more than {MAX_JPEG_MARKERS:,} markers (real JPEGs have at most a few hundred): "
        "refused, every marker is walked"
    )


def _pnm_size(data: bytes) -> tuple[int, int]:
    """Width and height of a PBM/PGM/PPM: the two numbers after the magic, '#' comments skipped."""
    head = data[:_HEADER_LIMIT]
    lines = [line.split(b"#", 1)[0] for line in head[2:].split(b"\n")]
    tokens = b" ".join(lines).split()
    if len(tokens) < 2 or not (tokens[0].isdigit() and tokens[1].isdigit()):
        raise DataError(f"corrupt PNM header (no width and height in its first {_HEADER_LIMIT} bytes)")
    return int(tokens[0]), int(tokens[1])


def _tiff_size(at: ReadAt) -> tuple[int, int]:
    """ImageWidth and ImageLength of a TIFF's first image file directory (which may lie anywhere)."""
    order = "little" if at(0, 2) == b"II" else "big"
    ifd = _u32(at(4, 4), 0, order)
    head = at(ifd, 2)
    count = _u16(head, 0, order) if len(head) == 2 else 0
    table = at(ifd + 2, 12 * count)  # at most 65,535 entries: 786 KB
    found: dict[int, int] = {}
    for entry in range(0, len(table) - 11, 12):
        tag, kind = _u16(table, entry, order), _u16(table, entry + 2, order)
        if tag in (256, 257):
            found[tag] = _u16(table, entry + 8, order) if kind == 3 else _u32(table, entry + 8, order)
    if len(found) < 2:
        raise DataError("corrupt TIFF: no ImageWidth and ImageLength in its first directory")
    return found[256], found[257]


def _webp_size(data: bytes) -> tuple[int, int]:
    kind = data[12:16]
    if kind == b"VP8 " and len(data) >= 30:
        return _u16(data, 26, "little") & 0x3FFF, _u16(data, 28, "little") & 0x3FFF
    if kind == b"VP8L" and len(data) >= 25:
        bits = _u32(data, 21, "little")
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if kind == b"VP8X" and len(data) >= 30:
        return int.from_bytes(data[24:27], "little") + 1, int.from_bytes(data[27:30], "little") + 1
    raise DataError("corrupt WebP: no VP8, VP8L or VP8X header")


def _jpeg_frame_size(at: ReadAt) -> tuple[int, int]:
    """(width, height) of a JPEG's frame header, found by walking its markers from the start with
    ``at`` (4 bytes read per marker, the segments between skipped); DataError if a scan, the end or
    :data:`JPEG_HEADER_MARKERS` markers come first."""
    pos = 2
    for _ in range(JPEG_HEADER_MARKERS):
        head = at(pos, 4)
        if len(head) < 2:
            raise DataError("truncated JPEG (no frame header)")
        if head[0] != 0xFF:
            raise DataError(f"corrupt JPEG: no marker at byte {pos}")
        marker = head[1]
        if marker == 0xFF or marker in _JPEG_STANDALONE:  # a fill byte, or a marker without length
            pos += 1 if marker == 0xFF else 2
            continue
        if marker in (0xD9, 0xDA):
            raise DataError("corrupt JPEG: no frame header before its first scan")
        frame = at(pos + 4, 5) if marker in _JPEG_SOF else b""
        if len(head) < 4 or (marker in _JPEG_SOF and len(frame) < 5):
            raise DataError("truncated JPEG (no frame header)")
        if marker in _JPEG_SOF:  # precision, then height and width
            return _u16(frame, 3), _u16(frame, 1)
        pos += 2 + _u16(head, 2)
    raise DataError(f"corrupt JPEG: no frame header in its first {JPEG_HEADER_MARKERS} markers")


def _other_size(data: bytes, at: ReadAt) -> tuple[int, int]:
    """(width, height) of a BMP, TIFF, WebP or PNM from its first bytes ``data`` (``at`` for the
    rest); DataError for any other format."""
    if data.startswith(b"BM") and len(data) >= 26:
        if _u32(data, 14, "little") == 12:  # OS/2 BITMAPCOREHEADER: 16-bit sizes
            return _u16(data, 18, "little"), _u16(data, 20, "little")
        width, height = (int.from_bytes(data[i : i + 4], "little", signed=True) for i in (18, 22))
        return abs(width), abs(height)  # a negative height means rows stored top-down
    if data[:4] in (b"II*\x00", b"MM\x00*") and len(data) >= 8:
        return _tiff_size(at)
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return _webp_size(data)
    if len(data) >= 2 and data[:1] == b"P" and data[1:2] in b"123456":
        return _pnm_size(data)
    raise DataError(
        "cannot decode it: not a PNG, JPEG, BMP, TIFF, WebP or PNM image (or its header is cut off)"
    )


def _declared_size(data: bytes) -> tuple[int, int]:
    """(width, height) that an image file's header declares, read without decoding any pixel.

    PNG, JPEG, BMP, TIFF, WebP and PNM (P1-P6); DataError for any other format, a header that is
    cut off or inconsistent, a truncated PNG/JPEG (see :func:`png_size`, :func:`_jpeg_size`).
    """
    if data.startswith(_PNG_MAGIC):
        return png_size(data)
    if data.startswith(_JPEG_MAGIC):
        return _jpeg_size(data)
    return _other_size(data, lambda pos, count: data[pos : pos + count])


def _header_size(file: BinaryIO) -> tuple[int, int]:
    """(width, height) that an open image file's header declares, reading only the header: the
    first 64 KiB, a JPEG's markers up to its frame header and a TIFF's first directory."""
    file.seek(0)
    head = file.read(_HEAD_BYTES)

    def at(pos: int, count: int) -> bytes:
        file.seek(pos)
        return file.read(count)

    if head.startswith(_PNG_MAGIC):
        return _png_header_size(head)
    if head.startswith(_JPEG_MAGIC):
        return _jpeg_frame_size(at)
    return _other_size(head, at)


def _check_declared_size(data: bytes, max_pixels: int = MAX_IMAGE_PIXELS) -> tuple[int, int]:
    """:func:`_declared_size`, and a DataError unless it is non-empty and at most ``max_pixels``."""
    return check_pixel_limit(*_declared_size(data), max_pixels)


def megapixels(pixels: int) -> str:
    """``pixels`` in megapixels, to 4 significant digits and never in exponent form: "144",
    "0.0768", "1.229", "10000"."""
    return f"{float(f'{pixels / 1e6:.4g}'):f}".rstrip("0").rstrip(".")


def check_pixel_limit(
    width: int, height: int, max_pixels: int, declared_by: str = "the header"
) -> tuple[int, int]:
    """The one pixel limit of every image and video frame, checked on the size ``declared_by``
    declares before anything is decoded (an image's header here, a video's container in predict):
    ``(width, height)``, or a DataError for an empty size and a PixelLimitError over ``max_pixels``.

    No option is named: each command that has one (predict's ``--max-megapixels``) adds it.
    """
    if width <= 0 or height <= 0:
        raise DataError(f"{declared_by} declares an empty image ({width} x {height} px)")
    if width * height > max_pixels:
        raise PixelLimitError(
            f"{declared_by} declares {width} x {height} px ({megapixels(width * height)} megapixels), "
            f"over the limit of {max_pixels / 1e6:g} megapixels"
        )
    return width, height


def _mib(nbytes: int) -> str:
    return f"{nbytes / 2**20:,.0f} MiB"


def read_file(path: str | os.PathLike, max_pixels: int = MAX_IMAGE_PIXELS) -> bytes:
    """The bytes of an image file, read only after its size and header pass the bounds.

    Before any read: the file's size against :func:`_max_file_bytes` of ``max_pixels`` (a
    PixelLimitError: raising the limit raises it). Then only the header (:func:`_header_size`): the
    size it declares against ``max_pixels``, and the file's size against :func:`_max_file_bytes` of
    the declared pixels. Only then the whole file, which :func:`decode` walks again.
    """
    # the bound is checked below, as a PixelLimitError that names the option raising it
    with open_regular(path, "image", prefix="") as file:
        size = os.fstat(file.fileno()).st_size
        if size > _max_file_bytes(max_pixels):
            raise PixelLimitError(
                f"the file is {_mib(size)}, more than any image within the limit of {max_pixels / 1e6:g} "
                f"megapixels takes ({_mib(_max_file_bytes(max_pixels))}: {MAX_BYTES_PER_PIXEL} bytes a "
                "pixel and 64 MiB of metadata); nothing of it was read"
            )
        width, height = check_pixel_limit(*_header_size(file), max_pixels)
        if size > _max_file_bytes(width * height):
            raise DataError(
                f"the file is {_mib(size)}, more than its header's {width} x {height} px can take "
                f"({_mib(_max_file_bytes(width * height))}); only its header was read"
            )
        file.seek(0)
        return file.read(size)


@contextlib.contextmanager
def _stderr_captured() -> Iterator[list[bytes]]:
    """Collect what C code writes to file descriptor 2 inside the block (libjpeg's warnings)."""
    captured: list[bytes] = []
    try:
        saved = os.dup(2)
    except OSError:  # no stderr at all: nothing to capture
        yield captured
        return
    with _STDERR_LOCK, tempfile.TemporaryFile() as sink:
        sys.stderr.flush()
        os.dup2(sink.fileno(), 2)
        try:
            yield captured
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            captured.append(sink.read())


def decode(data: bytes, flags: int = cv2.IMREAD_UNCHANGED, max_pixels: int = MAX_IMAGE_PIXELS) -> np.ndarray:
    """Decode an image file's bytes with OpenCV after :func:`_check_declared_size`.

    ``flags``: OpenCV's, e.g. ``IMREAD_COLOR`` (8-bit BGR, the EXIF orientation applied). Every
    failure is a DataError: the header checks, OpenCV's own errors, running out of memory, and a
    JPEG whose data libjpeg found corrupt.
    """
    _check_declared_size(data, max_pixels)
    is_jpeg = data.startswith(_JPEG_MAGIC)
    buffer = np.frombuffer(data, np.uint8)
    try:
        with _stderr_captured() if is_jpeg else contextlib.nullcontext([]) as captured:
            img = cv2.imdecode(buffer, flags)
    except cv2.error as exc:
        raise DataError(f"OpenCV cannot decode it ({str(exc).strip().splitlines()[-1]})") from None
    except MemoryError:
        raise DataError("out of memory while decoding it") from None
    warnings = b"".join(captured)
    problem = next((line for line in warnings.splitlines() if line.startswith(_LIBJPEG_ERRORS)), None)
    if problem is None and warnings:
        sys.stderr.write(warnings.decode("utf-8", "replace"))  # not ours to swallow
    if problem is not None:
        raise DataError(f"corrupt JPEG (libjpeg: {problem.decode('ascii', 'replace')})")
    if img is None:
        raise DataError("cannot decode it (corrupt or not an image)")
    return img


def batches_by_pixels(
    items: Iterable[Item], pixels: Callable[[Item], int], max_count: int, budget: int = BATCH_PIXEL_BUDGET
) -> Iterator[list[Item]]:
    """Consecutive batches of ``items``, each closed as soon as it holds ``max_count`` items or
    ``budget`` pixels (``pixels(item)`` each): a batch holds less than ``budget`` plus one item's
    pixels, and no item of the next batch is read before it is handed over (``items`` may decode
    lazily)."""
    batch: list[Item] = []
    total = 0
    for item in items:
        batch.append(item)
        total += pixels(item)
        if len(batch) >= max_count or total >= budget:
            yield batch
            batch, total = [], 0
    if batch:
        yield batch


def is_png(path: str | os.PathLike) -> bool:
    """Whether a file starts with PNG's signature (8 bytes read); a DataError line names a file that
    is not a regular one (:func:`msdepth.readers.open_regular`: a FIFO put in its place would block a
    plain open forever)."""
    with open_regular(path, "image", allow_empty=True) as file:
        return file.read(len(_PNG_MAGIC)) == _PNG_MAGIC


def file_pixels(path: str | os.PathLike) -> int:
    """The pixels an image file's header declares (:func:`_header_size`), 0 if it cannot be read: a
    plan's estimate only; the file is checked in full when it is read."""
    try:
        with open_regular(path, "image", prefix="") as file:
            width, height = _header_size(file)
    except (OSError, DataError):
        return 0
    return max(width, 0) * max(height, 0)
