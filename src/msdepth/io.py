"""Atomic file writing, the writers built on it, and the output policy.

Every writer (:func:`write_json`, :func:`write_text`, :func:`write_png`, :func:`save_npy`,
:func:`save_npz`) goes through :func:`atomic_path`, which yields a temporary path in the
destination folder and renames it over the final name only when the block succeeds: an output is
either complete under its final name or absent.

The output policy (:class:`OutputPolicy`, :func:`output_file_policy`) decides what a command may
write into a user's folder: never an input, and no existing file it did not write itself (its
manifest lists those it did).

Every reader of an input file opens it with :func:`open_regular` (or reads it whole with
:func:`read_bounded`): a regular file only, its size checked against its kind's limit before any
byte is read, each refusal one DataError naming the file.
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import json
import os
import re
import stat
import struct
import sys
import tempfile
import threading
import zlib
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any, BinaryIO, Callable, Iterator

from msdepth.errors import DataError, MsdepthError, OutputError

if TYPE_CHECKING:  # numpy is imported by the writers that need it: the params reader opens its file
    import numpy as np  # here (open_regular) and imports neither numpy nor torch (test_stages)


def _file_mode() -> int:
    # os.umask can only be read by setting it: done once at import, not per write, because the
    # umask is process-wide and the downloader writes from several threads.
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


_FILE_MODE = _file_mode()


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
        _written(path)  # complete under its name: now listed as the command's own
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


def file_sha256(path: str | os.PathLike, kind: str = "input") -> str:
    """The sha256 hex digest of the file at ``path``, read through :func:`open_regular` (any size;
    a FIFO, a device or a socket is refused before a byte is read, so hashing never blocks); a
    DataError names a path that is missing, a folder, not a regular file or unreadable."""
    digest = hashlib.sha256()
    with open_regular(path, kind, allow_empty=True) as f:
        try:
            while block := f.read(1 << 20):  # hashlib.file_digest needs Python 3.11
                digest.update(block)
        except OSError as exc:
            raise DataError(f"{path}: cannot read this {kind} file ({exc.strerror or exc})") from None
    return digest.hexdigest()


# Bounded reading: every reader of an input file (images, PFM, .npy, Velodyne scans, calibration and
# list files, JSON tables) opens it through open_regular, so each refusal below is written once.


def _size_text(nbytes: int) -> str:
    return f"{nbytes:,} bytes" if nbytes < 1 << 20 else f"{nbytes / 2**20:,.0f} MiB"


def not_regular_file(mode: int) -> str | None:
    """Why a file of ``st_mode`` ``mode`` is not a regular file ("a folder, not a file", "not a
    regular file (a FIFO, a device or a socket)"), None if it is one: the one classification of
    :func:`open_regular` and of the params' checks of named files.

    Example:
        >>> import stat
        >>> not_regular_file(stat.S_IFREG | 0o644) is None, not_regular_file(stat.S_IFDIR | 0o755)
        (True, 'a folder, not a file')
    """
    if stat.S_ISDIR(mode):
        return "a folder, not a file"
    if not stat.S_ISREG(mode):
        return "not a regular file (a FIFO, a device or a socket)"
    return None


def open_regular(
    path: str | os.PathLike,
    kind: str,
    max_bytes: int | None = None,
    *,
    allow_empty: bool = False,
    prefix: str | None = None,
    follow_symlinks: bool = True,
) -> BinaryIO:
    """``path`` open for reading (binary), once it is known to be a regular file of at most
    ``max_bytes`` (its size taken with fstat on the open file, before any byte is read) and, unless
    ``allow_empty``, not empty.

    Every refusal is one DataError, ``<path>: <problem>`` (``prefix`` replaces ``<path>: ``, for a
    reader whose caller names the file): no such file, a folder, not a regular file (a FIFO, a
    device or a socket: reading one could block forever or never end), a symbolic link loop or any
    other error of the open, over ``max_bytes``, empty. ``kind`` names the file in it ("PFM").
    ``follow_symlinks=False``: a symbolic link at ``path`` is refused, never followed (a file the
    project wrote itself, which a link could redirect to someone else's).
    """
    head = f"{path}: " if prefix is None else prefix
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | (0 if follow_symlinks else os.O_NOFOLLOW)
    try:  # O_NONBLOCK: opening a FIFO that no one writes returns at once, and fstat refuses it
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise DataError(f"{head}no such {kind} file") from None
    except OSError as exc:  # a symbolic link loop, a name too long, no permission
        if not follow_symlinks and os.path.islink(path):
            raise DataError(
                f"{head}a symbolic link, not the {kind} file itself; it is not followed"
            ) from None
        raise DataError(f"{head}cannot open this {kind} file ({exc.strerror or exc})") from None
    info = os.fstat(fd)
    problem = not_regular_file(info.st_mode)
    if problem is not None:
        problem += "" if stat.S_ISDIR(info.st_mode) else "; nothing was read"
    elif max_bytes is not None and info.st_size > max_bytes:
        problem = (
            f"the file is {_size_text(info.st_size)}, over the limit of {_size_text(max_bytes)} for {kind} "
            "files; nothing of it was read"
        )
    elif info.st_size == 0 and not allow_empty:
        problem = f"the {kind} file is empty (0 bytes)"
    if problem is not None:
        os.close(fd)
        raise DataError(head + problem)
    os.set_blocking(fd, True)
    return os.fdopen(fd, "rb")


def read_bounded(
    path: str | os.PathLike,
    kind: str,
    max_bytes: int,
    *,
    allow_empty: bool = False,
    prefix: str | None = None,
    follow_symlinks: bool = True,
) -> bytes:
    """The bytes of the regular file ``path``, of at most ``max_bytes`` (:func:`open_regular`, whose
    refusals these are); a file that changed size while it was read is refused too."""
    head = f"{path}: " if prefix is None else prefix
    opened = open_regular(
        path, kind, max_bytes, allow_empty=allow_empty, prefix=prefix, follow_symlinks=follow_symlinks
    )
    with opened as file:
        size = os.fstat(file.fileno()).st_size
        try:  # the size, not the limit, is asked for: read() allocates what it is asked for first
            data = file.read(size + 1)
        except OSError as exc:  # an I/O error: still one line naming the file
            raise DataError(f"{head}cannot read this {kind} file ({exc.strerror or exc})") from None
    if len(data) != size:
        raise DataError(f"{head}the {kind} file changed size while it was read ({size:,} bytes before)")
    return data


# Limits of the files the pipeline itself writes and reads back, against a hostile stand-in (a
# FIFO, a folder, a huge file) at an output's path. compare.json is ~0.3 MB, a KITTI-sized
# per-ROI table tens of MB, Eigen's 697 disparity maps at 256 x 512 float32 365 MB.
MAX_JSON_BYTES = 256 << 20
MAX_TABLE_BYTES = 1 << 30
MAX_ARRAY_BYTES = 64 << 30


def read_text_file(path: str | os.PathLike, kind: str, max_bytes: int = MAX_JSON_BYTES) -> str:
    """The UTF-8 text of the regular file ``path`` (:func:`read_bounded`); one DataError line
    naming the file when it is refused or not UTF-8."""
    try:
        return read_bounded(path, kind, max_bytes, allow_empty=True).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: this {kind} file is not UTF-8 text (byte {exc.start})") from None


def read_json_file(path: str | os.PathLike, kind: str, max_bytes: int = MAX_JSON_BYTES) -> Any:
    """The JSON value in the regular file ``path`` (:func:`read_text_file`); one DataError line
    naming the file when it is refused or not JSON (nesting too deep for the parser included).

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as d:
        ...     _ = Path(d, "m.json").write_text('{"abs_rel": 0.1}')
        ...     read_json_file(Path(d, "m.json"), "metrics")
        {'abs_rel': 0.1}
    """
    text = read_text_file(path, kind, max_bytes)
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise DataError(f"{path}: this {kind} file is not JSON ({str(exc).splitlines()[0][:200]})") from None


def read_json_object(path: str | os.PathLike, kind: str, hint: str = "") -> dict:
    """The JSON object in ``path`` (:func:`read_json_file`); one DataError line naming the file
    when it is missing (with ``hint``: what would write it), refused, not JSON or not an object.

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as d:
        ...     try:
        ...         read_json_object(Path(d, "compare.json"), "comparison", "run `dvc repro compare` first")
        ...     except DataError as exc:
        ...         print(str(exc).split("/")[-1])
        compare.json: missing; run `dvc repro compare` first
    """
    if not os.path.lexists(path):
        raise DataError(f"{path}: missing{'; ' + hint if hint else ''}")
    data = read_json_file(path, kind)
    if not isinstance(data, dict):
        raise DataError(f"{path}: expected a JSON object, got {type(data).__name__}")
    return data


# A table the pipeline writes averages 5 to 8 bytes a cell; pandas holds 8 bytes a cell (a float, or
# a pointer to a string) plus its strings. A file of empty or one-character cells would take 4 to 11
# times its size: the parsed table may hold at most this multiple of the file's bytes, and is parsed
# in chunks of about _TABLE_CHUNK_CELLS cells (2 MiB of floats) whose memory is summed as they come.
MAX_TABLE_GROWTH = 2
MAX_TABLE_COLUMNS = 10_000  # the widest table the pipeline writes has under 100
_TABLE_CHUNK_CELLS = 1 << 18


def read_table_file(path: str | os.PathLike, kind: str, max_bytes: int = MAX_TABLE_BYTES, **options: Any):
    """``pandas.read_csv`` of the regular file ``path`` of at most ``max_bytes`` (``options`` go to
    read_csv); one DataError line naming the file when it is refused or not a table.

    Parsed in chunks of rows straight from the file, their memory summed as they come
    (:func:`_table_bytes`): a table of more than :data:`MAX_TABLE_COLUMNS` columns, or that would
    hold more than :data:`MAX_TABLE_GROWTH` times its file's bytes (plus 1 MiB), is refused, so peak
    memory stays a small multiple of the file's size."""
    import pandas as pd  # here: most commands never read a table

    with open_regular(path, kind, max_bytes, allow_empty=True) as file:
        size = os.fstat(file.fileno()).st_size
        columns = _header_columns(file, options.get("sep", options.get("delimiter", ",")))
        if columns > MAX_TABLE_COLUMNS:
            raise DataError(
                f"{path}: its header has {columns:,} columns, over the {MAX_TABLE_COLUMNS:,} "
                f"of a {kind} table"
            )
        budget, chunks, held = MAX_TABLE_GROWTH * size + (1 << 20), [], 0
        rows = max(1, _TABLE_CHUNK_CELLS // columns)
        try:
            with pd.read_csv(_SizedReader(file, size), chunksize=rows, **options) as reader:
                for chunk in reader:
                    held += _table_bytes(chunk)
                    if held > budget:
                        raise DataError(
                            f"{path}: this {kind} table takes over {_size_text(held)} in memory, more than "
                            f"{MAX_TABLE_GROWTH}x its file ({_size_text(size)}): "
                            "not a table the pipeline writes"
                        )
                    chunks.append(chunk)
        except pd.errors.EmptyDataError:
            return pd.DataFrame()
        except (ValueError, UnicodeDecodeError, OSError) as exc:  # ParserError is a ValueError
            raise DataError(
                f"{path}: not a readable {kind} table ({str(exc).splitlines()[0][:200]})"
            ) from None
    return (
        chunks[0] if len(chunks) == 1 else pd.concat(chunks, ignore_index=True) if chunks else pd.DataFrame()
    )


def _header_columns(file: BinaryIO, sep: Any) -> int:
    """The columns of the table's first line (at most 1 MiB of it is read), the file rewound; 1 when
    ``sep`` is not one character (a pattern)."""
    line = file.readline(1 << 20)
    file.seek(0)
    if not isinstance(sep, str) or len(sep) != 1:
        return 1
    return line.count(sep.encode("utf-8", "replace")) + 1


def _table_bytes(frame: Any) -> int:
    """The bytes a parsed DataFrame chunk holds: its arrays, plus each distinct string object once
    (pandas shares one object among equal strings of a chunk, which ``memory_usage(deep=True)``
    counts once per cell)."""
    import pandas as pd

    total = int(frame.memory_usage(index=True, deep=False).sum())
    for i, dtype in enumerate(frame.dtypes):
        if pd.api.types.is_object_dtype(dtype) or pd.api.types.is_string_dtype(dtype):
            seen = {id(value): value for value in frame.iloc[:, i].to_numpy(dtype=object)}
            total += sum(sys.getsizeof(value) for value in seen.values())
    return total


class _SizedReader:
    """A binary file read as at most ``size`` bytes (its size when it was opened): a file that grows
    while pandas reads it is not read past the size its limit was checked against."""

    def __init__(self, file: BinaryIO, size: int) -> None:
        self.file, self.left = file, size

    def read(self, n: int = -1) -> bytes:
        """Up to ``n`` bytes (all that is left for a negative ``n``), never past the opened size."""
        n = self.left if n is None or n < 0 else min(n, self.left)
        data = self.file.read(n)
        self.left -= len(data)
        return data

    def __iter__(self) -> Iterator[bytes]:
        return iter(self.readline, b"")

    def readline(self, n: int = -1) -> bytes:
        """One line, never past the opened size."""
        data = self.file.readline(self.left if n is None or n < 0 else min(n, self.left))
        self.left -= len(data)
        return data


def read_npy_header(file: BinaryIO, size: int, where: str) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, fortran order, dtype) of the ``.npy`` stream ``file`` of ``size`` bytes, read up to
    its data: refused in one DataError naming ``where`` unless the header parses, holds no pickled
    objects and declares exactly the bytes that follow (a 128-byte header can declare terabytes).

    Example:
        >>> import io, numpy as np
        >>> buffer = io.BytesIO(); np.save(buffer, np.zeros((2, 3), np.uint8))
        >>> _ = buffer.seek(0); read_npy_header(buffer, len(buffer.getvalue()), "a.npy")
        ((2, 3), False, dtype('uint8'))
    """
    import numpy as np

    try:
        version = np.lib.format.read_magic(file)
        read = (
            np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        )
        shape, fortran, dtype = read(file)
    except (OSError, ValueError, SyntaxError) as exc:
        raise DataError(f"{where}: not a readable .npy array ({' '.join(str(exc).split())[:200]})") from None
    if dtype.hasobject:
        raise DataError(f"{where}: an .npy array of Python objects is refused (it would unpickle)")
    needed = dtype.itemsize * int(np.prod(shape, dtype=np.int64))
    if needed != size - file.tell():
        raise DataError(
            f"{where}: its header declares {dtype} {shape} ({needed} bytes) but it holds {size - file.tell()}"
        )
    return shape, fortran, dtype


def _npy_array(file: BinaryIO, size: int, where: str) -> np.ndarray:
    """The array of an ``.npy`` stream of ``size`` bytes, its header checked before any allocation
    (:func:`read_npy_header`), read into the one buffer the array keeps, 4 MiB at a time (a
    ``read(n)`` of a zip member builds ``n`` bytes, then copies them)."""
    import numpy as np

    shape, fortran, dtype = read_npy_header(file, size, where)
    needed = size - file.tell()
    data = bytearray(needed)  # bytearray, not bytes: the array is writable, as np.load's is
    view, got = memoryview(data), 0
    while got < needed:
        step = file.readinto(view[got : got + (4 << 20)])
        if not step:
            raise DataError(f"{where}: the .npy data ended early ({got} of {needed} bytes)")
        got += step
    return np.frombuffer(data, dtype).reshape(shape, order="F" if fortran else "C")


# A file whose size is over this and of which under 1/_SPARSE_RATIO is on disk is sparse: its holes
# read as zeros the pipeline never wrote (a 1.5 GiB .npy in 4 KB), and reading it allocates its size.
_SPARSE_MIN_BYTES = 64 << 20
_SPARSE_RATIO = 8
# What the pipeline's .npz files (np.savez_compressed of float depth maps, ~1.1x) may inflate to, per
# byte of the file: deflate reaches ~1,000x on zeros, so a bomb of a few MB would declare gigabytes.
MAX_INFLATE_RATIO = 64


def _check_not_sparse(file: BinaryIO, where: str, kind: str) -> None:
    """DataError naming ``where`` when the open ``file`` is sparse (:data:`_SPARSE_RATIO`)."""
    info = os.fstat(file.fileno())
    on_disk = getattr(info, "st_blocks", None)
    if (
        on_disk is not None
        and info.st_size > _SPARSE_MIN_BYTES
        and on_disk * 512 * _SPARSE_RATIO < info.st_size
    ):
        raise DataError(
            f"{where}: a sparse {kind} file ({_size_text(info.st_size)}, {_size_text(on_disk * 512)} "
            "on disk): not one the pipeline wrote; nothing was read"
        )


def read_npy_file(path: str | os.PathLike, kind: str, max_bytes: int = MAX_ARRAY_BYTES) -> np.ndarray:
    """The array in the regular ``.npy`` file ``path`` of at most ``max_bytes``: a sparse file is
    refused and the header checked against the file's size before the data is read; each refusal
    one DataError naming the file."""
    with open_regular(path, kind, max_bytes) as file:
        _check_not_sparse(file, str(path), kind)
        return _npy_array(file, os.fstat(file.fileno()).st_size, str(path))


def read_npz_file(
    path: str | os.PathLike, kind: str, max_bytes: int = MAX_ARRAY_BYTES
) -> dict[str, np.ndarray]:
    """``{name: array}`` of the regular ``.npz`` file ``path``: at most ``max_bytes`` on disk, not
    sparse, and its members as the zip headers declare them (each member's npy header then checked
    against its declared size) summed to at most ``max_bytes`` and :data:`MAX_INFLATE_RATIO` times the
    file: a zip bomb is refused before anything inflates; each member read as :func:`read_npy_file`
    reads a file. Each refusal one DataError naming the file."""
    import zipfile

    with open_regular(path, kind, max_bytes) as file:
        _check_not_sparse(file, str(path), kind)
        size = os.fstat(file.fileno()).st_size
        try:
            with zipfile.ZipFile(file) as archive:
                members = archive.infolist()
                _check_members(path, members, min(max_bytes, MAX_INFLATE_RATIO * size))
                out = {}
                for m in members:
                    with archive.open(m) as member:
                        out[m.filename[: -len(".npy")]] = _npy_array(
                            member, m.file_size, f"{path}[{m.filename}]"
                        )
                return out
        except (zipfile.BadZipFile, OSError, EOFError, zlib.error, NotImplementedError) as exc:
            raise DataError(f"{path}: not a readable .npz archive ({exc})") from None


def _check_members(path: str | os.PathLike, members: list, limit: int) -> None:
    """DataError naming ``path`` when the zip ``members`` declare more than ``limit`` bytes inflated,
    or one is not an ``.npy``."""
    declared = sum(m.file_size for m in members)
    if declared > limit:
        raise DataError(
            f"{path}: its members declare {_size_text(declared)} inflated, over the {_size_text(limit)} "
            f"this file may hold ({MAX_INFLATE_RATIO}x its size at most); nothing was inflated"
        )
    if any(not m.filename.endswith(".npy") for m in members):
        raise DataError(f"{path}: not an .npz of arrays (a member is not .npy)")


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


# The output policy: every command that writes into a user's folder (predict, optimum, export-onnx,
# export-folder, the studies) claims each output path through an OutputPolicy before writing it.
MANIFEST_PREFIX = ".msdepth-"  # the manifest of command C is "<output folder>/.msdepth-C"
# A manifest lists file names, one a line: ~40 bytes each, so this is over a million outputs, read
# whole in well under a second; anything larger is not a manifest the policy wrote.
MAX_MANIFEST_BYTES = 64 << 20


def _manifest_line(name: str) -> str:
    """One manifest line for ``name``, a file the command wrote completely: a JSON string in ASCII,
    so any character of a file name (a newline, U+2028, a byte that is not UTF-8 as Python's
    surrogate escape) stays on its one line."""
    return json.dumps(name, ensure_ascii=True) + "\n"


def _pending_line(name: str) -> str:
    """The manifest line of ``name`` claimed and not yet written: ``{"pending": name}``. Never
    trusted as the command's own file (a run killed before writing it leaves it), it only lets the
    next run remove that write's temp file; the end of the run drops it (:meth:`OutputPolicy.settle`)."""
    return json.dumps({"pending": name}, ensure_ascii=True) + "\n"


def _manifest_bytes(path: Path) -> bytes | None:
    """The manifest's bytes (None if there is none), read only from a regular file of bounded size
    and never through a symbolic link (:func:`read_bounded`)."""
    if not os.path.lexists(path):
        return None
    try:
        return read_bounded(
            path, "output manifest", MAX_MANIFEST_BYTES, allow_empty=True, follow_symlinks=False
        )
    except DataError as exc:  # an output-policy refusal: the file is in the way, not bad input
        raise OutputError(f"{exc}; it is not a manifest msdepth wrote: remove it") from None


def _manifest_entry(line: str) -> tuple[str, bool] | None:
    """``(name, written)`` of one manifest line, None if it is not one."""
    if line[0] in '"{':
        try:
            value = json.loads(line)
        except (ValueError, RecursionError):
            return None
        if isinstance(value, str):
            name, written = value, True
        elif isinstance(value, dict) and list(value) == ["pending"] and isinstance(value["pending"], str):
            name, written = value["pending"], False
        else:
            return None
    else:  # a plain line: a name as the manifests of earlier versions wrote it
        name, written = line, True
    relative = PurePosixPath(name)
    if not name or "\x00" in name or relative.is_absolute() or ".." in relative.parts:
        return None
    return name, written


def _manifest_entries(path: str | os.PathLike) -> list[tuple[str, bool]]:
    """``(name, written)`` per manifest line, in file order (split on ``\\n`` only); a missing
    manifest has none. OutputError (one line) for a manifest that is a symlink, not a regular file,
    too large, or has a line that is not a manifest line (:func:`_manifest_line`, :func:`_pending_line`
    or a plain name), so a file put there is never taken for a list of the command's own files."""
    return _parse_manifest(Path(path), _manifest_bytes(Path(path)) or b"")


def _parse_manifest(path: Path, data: bytes) -> list[tuple[str, bool]]:
    entries = []
    for number, raw in enumerate(data.split(b"\n"), 1):
        if raw:
            entry = _manifest_entry(raw.decode("utf-8", errors="surrogateescape"))
            if entry is None:
                raise OutputError(f"{path}: line {number} is not an output manifest line; remove the file")
            entries.append(entry)
    return entries


def _read_manifest(path: str | os.PathLike) -> set[str]:
    """The names a manifest lists as written (not those only pending); see :func:`_manifest_entries`."""
    return {name for name, written in _manifest_entries(path) if written}


def resolved(path: str | os.PathLike) -> Path:
    """``Path(path).resolve()``; OutputError (one line) for a symlink loop in it (a RuntimeError, or
    an OSError on newer Pythons, from resolve)."""
    try:
        return Path(path).resolve()
    except (RuntimeError, OSError) as exc:
        raise OutputError(f"{path}: a symbolic link loop in this path ({exc})") from None


def _nearest_existing(path: Path) -> Path:
    while not path.exists() and path.parent != path:
        path = path.parent
    return path


# Names claimed and not yet written, by resolved path: atomic_path records each in its policy's
# manifest once it is renamed into place. _LIVE: the policies whose run has not been settled.
_LOCK = threading.Lock()
_AWAITED: dict[Path, tuple["OutputPolicy", str]] = {}
_LIVE: dict[int, "OutputPolicy"] = {}


def _written(path: Path) -> None:
    """Record ``path``, just renamed into place, in the manifest of the policy that claimed it."""
    if not _AWAITED:
        return
    try:
        key = Path(path).resolve()
    except (RuntimeError, OSError):
        return
    with _LOCK:
        entry = _AWAITED.pop(key, None)
    if entry is not None:
        entry[0]._record(entry[1])


def settle_outputs() -> None:
    """Settle every policy of this process (:meth:`OutputPolicy.settle`); run at exit. An error is
    one line on stderr: the run's outputs are written, only the manifest keeps pending lines."""
    for policy in list(_LIVE.values()):
        try:
            policy.settle()
        except (MsdepthError, OSError) as exc:
            print(f"error: {exc}", file=sys.stderr)


atexit.register(settle_outputs)


class OutputPolicy:
    """What ``msdepth <command>`` may write under ``out_dir``: never an input, the model or the
    manifest, no existing file the command did not write itself (those it wrote are listed in
    ``out_dir/.msdepth-<command>``), and no path twice in one run (two inputs, one output).

    The manifest lists a name only once its file is complete: a claim records it as pending, the
    rename of :func:`atomic_path` as written, and :meth:`settle` (at the end of the run) drops the
    pending ones never written and the names whose files are gone. ``inputs``: files never to
    replace; ``input_dirs``: folders the output folder may not be or hold. Raises OutputError (one
    line) when ``out_dir`` is the filesystem root, an input folder, holds one or is not a folder, or
    its manifest is not one.
    """

    def __init__(
        self,
        out_dir: str | os.PathLike,
        command: str,
        inputs: tuple[str | os.PathLike, ...] = (),
        input_dirs: tuple[str | os.PathLike, ...] = (),
    ) -> None:
        self.out_dir, self.command = Path(out_dir), command
        self.manifest = self.out_dir / f"{MANIFEST_PREFIX}{command}"
        self.protected = {resolved(p): Path(p) for p in inputs}
        self.claimed: dict[Path, str] = {}  # resolved output -> the input it is the output of
        self.pending: dict[str, Path] = {}  # name -> resolved path, claimed and not yet written
        self.created = False  # whether this run created the manifest
        _check_output_folder(self.out_dir)
        out_resolved = resolved(self.out_dir)
        self._check_folder(out_resolved, input_dirs)
        entries = _manifest_entries(self.manifest)
        self.ours = {name for name, written in entries if written}
        # A run killed mid-write left the temp of an output it had listed (written or pending):
        # remove those only.
        self._remove_temps({name for name, _ in entries}, out_resolved)

    def _check_folder(self, out_resolved: Path, input_dirs: tuple[str | os.PathLike, ...]) -> None:
        """OutputError (one line) when the output folder is the filesystem root, an input folder or
        a folder holding one: checked before any input is listed, so that ``--out /`` is refused at
        once (its inputs, all inside it, were left out as outputs: "no images", after the listing)."""
        if out_resolved == Path(out_resolved.anchor):
            raise OutputError(
                f"{self.out_dir}: the filesystem root, not an output folder; choose a folder for the outputs"
            )
        for folder in input_dirs:
            if not Path(folder).is_dir():
                continue
            folder_resolved = resolved(folder)
            if out_resolved == folder_resolved:
                raise OutputError(
                    f"{self.out_dir}: the output folder is the input folder {folder}, whose files the "
                    "outputs could replace and a later run would read as inputs; choose another output folder"
                )
            if folder_resolved.is_relative_to(out_resolved):
                raise OutputError(
                    f"{self.out_dir}: the output folder holds the input folder {folder}, whose files would "
                    "be left out as outputs; choose an output folder outside it"
                )

    def _name(self, path: Path) -> str:
        return path.relative_to(self.out_dir).as_posix()

    def _remove_temps(self, names: set[str], out_resolved: Path) -> None:
        """Remove the temps (:func:`atomic_temps`) of ``names``, listing only the folders that hold them."""
        folders: dict[Path, set[str]] = {}
        for name in names:
            path = self.out_dir / name
            folders.setdefault(path.parent, set()).add(path.name)
        for folder, finals in folders.items():
            try:
                if not folder.is_dir() or not folder.resolve().is_relative_to(out_resolved):
                    continue
                temps = [
                    p for p in folder.iterdir() if (m := _ANY_TEMP.fullmatch(p.name)) and m["final"] in finals
                ]
            except (RuntimeError, OSError):
                continue
            for p in temps:
                if p.is_file() and not p.is_symlink():
                    p.unlink(missing_ok=True)

    def protect(self, inputs: list[Path]) -> None:
        """Add input files that no output may replace."""
        self.protected.update((resolved(p), Path(p)) for p in inputs)

    def prepare(self) -> None:
        """Create the output folder; OutputError (one line) if it cannot be created or written."""
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(
                f"{self.out_dir}: cannot create the output folder ({exc.strerror or exc})"
            ) from None
        if not os.access(self.out_dir, os.W_OK | os.X_OK):
            raise OutputError(f"{self.out_dir}: the output folder is not writable")

    def claim(self, paths: list[Path], source: str | os.PathLike) -> None:
        """Check that every path, an output of ``source``, may be written, and list the new ones in
        the manifest as pending (each is listed as written once :func:`atomic_path` renames it into
        place); OutputError naming the first that may not, with nothing written."""
        paths = [Path(p) for p in paths]
        for path in paths:
            self._check(path, str(source))
        new = {}
        for path in paths:
            key, name = resolved(path), self._name(path)
            self.claimed[key] = str(source)
            if name not in self.ours and name not in self.pending:
                new[name] = key
        if new:
            self.prepare()
            self._append("".join(_pending_line(name) for name in new))
            with _LOCK:
                self.pending.update(new)
                _AWAITED.update((key, (self, name)) for name, key in new.items())
        _LIVE[id(self)] = self  # settled at the end of the run (settle_outputs)

    def _append(self, text: str) -> None:
        """Append ``text`` to the manifest, a regular file (never through a symlink)."""
        flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK
        existed = os.path.lexists(self.manifest)
        try:
            fd = os.open(self.manifest, flags, 0o666)
        except OSError as exc:
            raise OutputError(
                f"{self.manifest}: cannot write this output manifest ({exc.strerror or exc})"
            ) from None
        with os.fdopen(fd, "ab") as f:
            if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                raise OutputError(f"{self.manifest}: the output manifest is not a regular file; remove it")
            f.write(text.encode("ascii"))
        self.created = self.created or not existed

    def _record(self, name: str) -> None:
        """List ``name``, now written completely, as the command's own."""
        with _LOCK:
            if self.pending.pop(name, None) is None:
                return
        self.ours.add(name)
        try:
            self._append(_manifest_line(name))
        except OutputError:  # settle() records it by its file, which exists
            self.pending[name] = resolved(self.out_dir / name)

    def settle(self) -> None:
        """End the run's record: a pending name whose file now exists (one a subprocess wrote) is
        listed as written, the others are dropped, and so are names whose files are gone; the
        manifest is rewritten with one line per name, in the order they were first claimed."""
        with _LOCK:
            pending, self.pending = self.pending, {}
            for key in pending.values():
                if _AWAITED.get(key, (None,))[0] is self:
                    del _AWAITED[key]
            _LIVE.pop(id(self), None)
        data = _manifest_bytes(self.manifest)
        if data is None:  # never created, or the folder is gone
            return
        entries = _parse_manifest(self.manifest, data)  # read again: another policy may share it
        written = {name for name, ok in entries if ok} | set(pending)
        # Claim order; a pending line another policy's settle dropped meanwhile goes last.
        names = [n for n in dict.fromkeys([*(n for n, _ in entries), *pending]) if n in written]
        text = "".join(_manifest_line(n) for n in names if os.path.lexists(self.out_dir / n))
        if not text and self.created:
            self.manifest.unlink()
        elif text.encode("ascii") != data:
            with atomic_path(self.manifest) as tmp:
                tmp.write_text(text, encoding="ascii")

    def _check(self, path: Path, source: str) -> None:
        key = resolved(path)
        if key in self.protected:
            raise OutputError(f"{path}: an output would replace the input {self.protected[key]}")
        if key == resolved(self.manifest) or not key.parent.is_relative_to(resolved(self.out_dir)):
            raise OutputError(f"{path}: not a path msdepth {self.command} may write (outside {self.out_dir})")
        if key in self.claimed and self.claimed[key] != source:
            raise OutputError(f"{source}: same output name as {self.claimed[key]} ({path}); rename one")
        if path.is_dir():
            raise OutputError(f"{path}: a folder where msdepth {self.command} writes a file")
        name = self._name(path)
        if (path.exists() or path.is_symlink()) and name not in self.ours and name not in self.pending:
            raise OutputError(
                f"{path}: exists and was not written by msdepth {self.command} (not listed in "
                f"{self.manifest}); move it or choose another --out"
            )


def _check_output_folder(out_dir: str | os.PathLike) -> None:
    """OutputError (one line) when ``out_dir`` exists and is not a folder, or lies under a file."""
    out_dir = Path(out_dir)
    existing = _nearest_existing(out_dir)
    if existing == out_dir and not out_dir.is_dir():
        raise OutputError(f"{out_dir}: exists and is not a folder; the output must be a folder")
    if existing != out_dir and not existing.is_dir():
        raise OutputError(f"{out_dir}: cannot create the output folder under the file {existing}")


def output_file_policy(
    out: str | os.PathLike, command: str, inputs: tuple[str | os.PathLike, ...] = ()
) -> OutputPolicy:
    """The policy of a command that writes the one file ``out`` (export-onnx), ``out`` checked (claim
    it before writing): OutputError (one line) if ``out`` is a folder, an input, or a file the
    command did not write."""
    out = Path(out)
    if out.is_dir():
        raise OutputError(f"{out}: a folder; --out names the file to write")
    policy = OutputPolicy(out.parent, command, inputs)
    policy._check(out, str(inputs[0]) if inputs else str(out))
    policy.prepare()
    for stale in atomic_temps(out):  # left by a writer of ``out`` killed mid-write (only that form)
        stale.unlink()
    return policy


def claim_output_file(out: str | os.PathLike | None, command: str, source: str | os.PathLike) -> bool:
    """Claim the one file ``out`` that a study writes, before its minutes of work: True when ``out``
    is None or may be written (listed in the folder's manifest); False after one line on stderr when
    it may not (a folder, an input, or a file the command did not write), for the caller to exit 1."""
    if out is None:
        return True
    try:
        output_file_policy(out, command).claim([Path(out)], source)
    except OutputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return False
    return True
