"""Atomic file writing and the writers built on it.

Every writer (:func:`write_json`, :func:`write_text`, :func:`write_png`, :func:`save_npy`,
:func:`save_npz`) goes through :func:`atomic_path`, which yields a temporary path in the
destination folder and renames it over the final name only when the block succeeds: an output is
either complete under its final name or absent. The PNG encoder is the project's own, so a
rendered tree's bytes depend on its pixels only.

Reading is :mod:`msdepth.readers`'s (bounded readers); what a command may write into a user's folder
is :mod:`msdepth.outputs`'s (the output policy).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import struct
import tempfile
import zlib
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator

from msdepth.errors import DataError

if TYPE_CHECKING:  # numpy is imported by the writers that need it
    import numpy as np


def _file_mode() -> int:
    # os.umask can only be read by setting it: done once at import, not per write, because the
    # umask is process-wide and the downloader writes from several threads.
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


_FILE_MODE = _file_mode()
# Called with each path atomic_path has renamed into place: msdepth.outputs registers the output
# policy's record of it there (the policy builds on these writers, not they on it).
_WRITTEN_HOOKS: list[Callable[[Path], None]] = []


def on_written(hook: Callable[[Path], None]) -> None:
    """Call ``hook(path)`` each time :func:`atomic_path` has renamed a complete file to ``path``."""
    _WRITTEN_HOOKS.append(hook)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temp path beside ``path``; rename it to ``path`` if the block exits cleanly.

    ``suffix`` defaults to the final name's suffix so that writers that pick a format by
    extension (OpenCV, numpy) see the right one.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.name}{TEMP_MARK}", suffix=path.suffix if suffix is None else suffix, dir=path.parent
    )
    os.close(fd)
    # mkstemp creates 0600; give the output the permissions a plain open() would.
    os.chmod(tmp, _FILE_MODE)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
        for hook in _WRITTEN_HOOKS:  # the output policy lists it as the command's own
            hook(path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


# atomic_path's temp names are ".<final name>.msdepth-tmp-<8 random characters><suffix>" (mkstemp's
# prefix, then 8 characters of tempfile's _RandomNameSequence alphabet, then the suffix): a form no
# user file has, so a stale temp is known by its name alone and only the project's own are removed.
TEMP_MARK = ".msdepth-tmp-"
_TEMP_RANDOM = "[a-z0-9_]{8}"
# The suffix is a Path.suffix (one dot, no other) or empty.
_ANY_TEMP = re.compile(r"\.(?P<final>.+)" + re.escape(TEMP_MARK) + _TEMP_RANDOM + r"(?P<suffix>\.[^.]+)?")


def atomic_temps(path: str | os.PathLike, suffix: str | None = None) -> list[Path]:
    """The temp files that :func:`atomic_path` for ``path`` (with the same ``suffix``) left beside it:
    a writer killed before its rename (``kill -9``) leaves ``.<name>.msdepth-tmp-<8 random chars><suffix>``.

    Only names of exactly that form count, so a caller that removes them removes nothing else.
    """
    path = Path(path)
    tail = path.suffix if suffix is None else suffix
    if not path.parent.is_dir():
        return []
    found = []
    for p in path.parent.iterdir():
        match = _ANY_TEMP.fullmatch(p.name)
        if match and match["final"] == path.name and (match["suffix"] or "") == tail and p.is_file():
            found.append(p)
    return sorted(found)


def temp_final_name(name: str) -> str | None:
    """The final name whose :func:`atomic_path` temp is named ``name``, None if ``name`` is not one.

    Example:
        >>> temp_final_name(".a.json.msdepth-tmp-abcd1234.json"), temp_final_name("a.json")
        ('a.json', None)
    """
    match = _ANY_TEMP.fullmatch(name)
    return match["final"] if match else None


def remove_stale_temps(folder: str | os.PathLike, ours: Callable[[Path], bool] | None = None) -> list[Path]:
    """Remove the temp files that writers killed before their rename (``kill -9``) left in ``folder``
    and below, and return them (sorted); a missing folder has none.

    Only regular files named as :func:`atomic_path` names its temps count (never a symlink or a
    folder), and with ``ours`` only those whose final path it accepts, so nothing the project did
    not write is removed. Call it when no writer is writing there: a live temp has the same name.
    """
    stale = []
    for parent, dirs, files in os.walk(folder):
        dirs.sort()
        for name in sorted(files):
            match = _ANY_TEMP.fullmatch(name)
            if match and (ours is None or ours(Path(parent, match["final"]))):
                stale.append(Path(parent, name))
    stale = [p for p in stale if p.is_file() and not p.is_symlink()]
    for p in stale:
        p.unlink(missing_ok=True)
    return stale


def write_json(path: str | os.PathLike, data: Any) -> None:
    """Write ``data`` as indented JSON, atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2, sort_keys=False) + "\n")


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write a text file atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


# One filter for every row and a fixed deflate level: the bytes depend only on the pixels and
# on zlib, not on the OpenCV/libpng build, so a rendered data tree hashes the same in DVC on
# every machine (OpenCV's encoder changes its output between releases). Level 1: as fast as
# OpenCV's encoder, files ~10 % larger; level 6 would take 3x longer for 3 % less.
_PNG_LEVEL = 1
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of a uint8 or uint16 gray/RGB ``(h, w[, 3])`` image (RGB order; KITTI's flow
    maps are 16-bit RGB).

    Deterministic: rows use PNG's "Up" filter (a row minus the row above, which suits smooth
    renders and 16-bit disparities alike) and deflate at a fixed level.
    """
    import numpy as np

    if image.dtype not in (np.uint8, np.uint16) or not (
        image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)
    ):
        raise DataError(f"PNG: expected uint8 or uint16 (h, w) / (h, w, 3), got {image.dtype} {image.shape}")
    color_type, depth = (0 if image.ndim == 2 else 2), 8 * image.dtype.itemsize
    h, w = image.shape[:2]
    if h == 0 or w == 0:
        raise DataError(f"PNG: empty image {image.shape}")
    rows = np.ascontiguousarray(image, dtype=image.dtype.newbyteorder(">")).view(np.uint8).reshape(h, -1)
    up = rows.copy()
    up[1:] -= rows[:-1]  # uint8 arithmetic wraps modulo 256, as the filter is defined
    scanlines = np.concatenate([np.full((h, 1), 2, np.uint8), up], axis=1)
    header = struct.pack(">IIBBBBB", w, h, depth, color_type, 0, 0, 0)
    return b"".join(
        (
            _PNG_SIGNATURE,
            _png_chunk(b"IHDR", header),
            _png_chunk(b"IDAT", zlib.compress(scanlines.tobytes(), _PNG_LEVEL)),
            _png_chunk(b"IEND", b""),
        )
    )


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write a uint8 or uint16 RGB/gray image as PNG, atomically (see :func:`_encode_png`)."""
    try:
        data = _encode_png(image)
    except DataError as err:
        raise DataError(f"{path}: {err}") from None
    with atomic_path(path, suffix=".png") as tmp:
        tmp.write_bytes(data)


def save_npy(path: str | os.PathLike, array: np.ndarray) -> None:
    """Write one array as ``.npy``, atomically."""
    import numpy as np

    with atomic_path(path, suffix=".npy") as tmp:
        np.save(tmp, array)


def save_npz(path: str | os.PathLike, **arrays: np.ndarray) -> None:
    """Write arrays to a compressed ``.npz`` atomically."""
    import numpy as np

    with atomic_path(path, suffix=".npz") as tmp:
        np.savez_compressed(tmp, **arrays)
