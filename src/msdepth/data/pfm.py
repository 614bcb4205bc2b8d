"""PFM (Portable Float Map) files: the disparity format of Scene Flow and Middlebury.

A PFM file is a text header and raw float32 samples::

    PF | Pf          colour (3 channels) | greyscale (1 channel)
    <width> <height>
    <scale>          its sign is the byte order: negative = little-endian, positive = big-endian
    <samples>        width * height * channels float32, rows from the BOTTOM of the image up

Written here from that description (no third-party reader).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from msdepth.data.imagefile import MAX_IMAGE_PIXELS
from msdepth.errors import DataError
from msdepth.io import atomic_path
from msdepth.readers import open_regular

# Three whitespace-separated header fields after the magic; "\r\n" (Windows line ends) or one other
# whitespace byte ends the scale, then the samples start (a binary sample may itself look like
# whitespace, so nothing more is skipped). The header is
# split into tokens within its first HEADER_LIMIT bytes: a regex over the whole file took
# quadratic time (a 32 KB header of digits, 18.6 s).
HEADER_LIMIT = 256
_WHITESPACE = b" \t\r\n\x0b\x0c"
_INTEGER = re.compile(rb"\d{1,9}")
# The largest PFM read: a one-channel map at the image pixel limit (a three-channel one up to a third
# of it); reading one takes twice its size (the samples, then the top-row-first copy).
MAX_PFM_BYTES = 4 * MAX_IMAGE_PIXELS + HEADER_LIMIT + 2
_SCALE = re.compile(rb"[-+]?[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?")


def _header(data: bytes) -> tuple[bytes, int, int, float, int] | None:
    """(magic, width, height, scale, where the byte ending the scale is), or None if the header is
    malformed."""
    head = data[: HEADER_LIMIT + 1]
    if head[:2] not in (b"PF", b"Pf"):
        return None
    pos, fields = 2, []
    for _ in range(3):
        start = pos
        while pos < len(head) and head[pos] in _WHITESPACE:
            pos += 1
        if pos == start:
            return None
        end = pos
        while end < len(head) and head[end] not in _WHITESPACE:
            end += 1
        fields.append(head[pos:end])
        pos = end
    if pos >= len(head) or pos >= HEADER_LIMIT:  # no whitespace byte ends the scale
        return None
    width, height, scale = fields
    if not (_INTEGER.fullmatch(width) and _INTEGER.fullmatch(height) and _SCALE.fullmatch(scale)):
        return None
    return head[:2], int(width), int(height), float(scale), pos


def read_pfm(path: str | os.PathLike) -> np.ndarray:
    """The samples of a PFM file as float32, top row first: ``(H, W)`` for ``Pf``, ``(H, W, 3)``
    for ``PF``. A malformed file, or a body not exactly width x height x channels float32 (short or
    with trailing bytes), is a DataError naming it; "\\r\\n" may end the header.

    Bounded: only a regular file of at most :data:`MAX_PFM_BYTES` is opened
    (:func:`msdepth.readers.open_regular`), its header is read first, and the body only once the file's
    size is exactly what the header declares (a 1 GiB sparse PFM took 4.1 GB to refuse)."""
    path = Path(path)
    try:
        with open_regular(path, "PFM", MAX_PFM_BYTES) as file:
            size = os.fstat(file.fileno()).st_size
            head = file.read(HEADER_LIMIT + 1)  # the header and the byte after its end, for "\r\n"
            shape, dtype, start = _checked_header(path, head, size)
            file.seek(start)
            body = np.empty(4 * int(np.prod(shape)), np.uint8)
            if file.readinto(body) != body.size:
                raise DataError(f"{path}: truncated PFM: the file shrank while it was read")
    except OSError as exc:
        raise DataError(f"{path}: cannot read the PFM file ({exc.strerror or exc})") from None
    return np.ascontiguousarray(body.view(dtype).reshape(shape)[::-1], dtype=np.float32)


def _checked_header(path: Path, head: bytes, size: int) -> tuple[tuple[int, ...], str, int]:
    """(shape, sample dtype, offset of the samples) of a PFM whose first bytes are ``head`` and whose
    size is ``size``; DataError unless the header is well formed and the samples fill the rest exactly."""
    header = _header(head)
    if header is None:
        raise DataError(
            f"{path}: not a PFM file (expects 'PF' or 'Pf', width height, scale within its first "
            f"{HEADER_LIMIT} bytes)"
        )
    magic, width, height, scale, end = header
    if width < 1 or height < 1:
        raise DataError(f"{path}: PFM size {width}x{height} is empty")
    if scale == 0:
        raise DataError(f"{path}: PFM scale is 0 (its sign gives the byte order)")
    channels = 3 if magic == b"PF" else 1
    count = width * height * channels
    # "\r\n" is always the line end: a lone "\r" before a sample starting with byte 0x0a is then one
    # byte short and refused, where the other reading would shift every sample of a cut CRLF file.
    start = end + 2 if head[end : end + 2] == b"\r\n" else end + 1
    body = size - start
    if body != 4 * count:
        what = "truncated PFM" if body < 4 * count else "PFM with trailing bytes"
        raise DataError(
            f"{path}: {what}: {width}x{height}x{channels} float32 need exactly {4 * count} bytes, "
            f"the file has {body} after its header"
        )
    shape = (height, width) if channels == 1 else (height, width, 3)
    return shape, "<f4" if scale < 0 else ">f4", start


def write_pfm(path: str | os.PathLike, image: np.ndarray, *, little_endian: bool = True) -> None:
    """Write a float ``(H, W)`` (``Pf``) or ``(H, W, 3)`` (``PF``) array as PFM, atomically."""
    image = np.asarray(image, dtype=np.float32)
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise DataError(f"{path}: a PFM holds (H, W) or (H, W, 3) samples, got shape {image.shape}")
    magic = b"Pf" if image.ndim == 2 else b"PF"
    header = magic + b"\n%d %d\n%s\n" % (image.shape[1], image.shape[0], b"-1.0" if little_endian else b"1.0")
    body = np.ascontiguousarray(image[::-1]).astype("<f4" if little_endian else ">f4").tobytes()
    with atomic_path(path, suffix=".pfm") as tmp:
        Path(tmp).write_bytes(header + body)
