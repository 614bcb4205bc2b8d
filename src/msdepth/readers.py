"""Bounded reading: every reader of an input file opens it with :func:`open_regular` (or reads it
whole with :func:`read_bounded`): a regular file only, its size checked against its kind's limit
before any byte is read, each refusal one DataError naming the file. On it: the readers of the
files the pipeline writes and reads back (text, JSON, tables, ``.npy`` and ``.npz`` arrays), each
holding at most a small multiple of what the file may legitimately hold, and :func:`file_sha256`.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
import sys
import zlib
from typing import TYPE_CHECKING, Any, BinaryIO, Iterator

from msdepth.errors import DataError

if TYPE_CHECKING:  # numpy is imported by the readers that need it: the params reader opens its file
    import numpy as np  # here (open_regular) and imports neither numpy nor torch (test_stages)


def size_text(nbytes: int) -> str:
    """``nbytes`` as bytes below 1 MiB, else as MiB (the refusals' sizes)."""
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
            f"the file is {size_text(info.st_size)}, over the limit of {size_text(max_bytes)} for {kind} "
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


# Python holds a JSON value in 30 to 70 bytes (an empty object 64, a float 24 plus its pointer); the
# pipeline's JSON files spend 16 bytes or more on each. A file averaging under this many bytes per
# value ("[{},{},...]": 3) would take over 20x its size parsed, and is refused before parsing.
MIN_JSON_BYTES_PER_VALUE = 4


def json_value_bound(data: bytes | str) -> int:
    """An upper bound on the values of the JSON text ``data``: its commas, braces and brackets (one
    each, strings' own included), counted without parsing.

    Example:
        >>> json_value_bound(b'[{}, {"a": [1, 2]}]')
        6
    """
    if isinstance(data, str):
        return data.count(",") + data.count("{") + data.count("[")
    return data.count(b",") + data.count(b"{") + data.count(b"[")


def check_json_density(data: bytes | str, where: str, min_bytes: int = MIN_JSON_BYTES_PER_VALUE) -> None:
    """A DataError naming ``where`` when the JSON text ``data`` may hold more than one value per
    ``min_bytes`` bytes (:func:`json_value_bound`, 4 KiB of slack): parsed, it would take many times
    its size in memory."""
    values = json_value_bound(data)
    if values * min_bytes > len(data) + 4096:
        raise DataError(
            f"{where}: up to {values:,} JSON values in {len(data):,} bytes, over one per {min_bytes} "
            "bytes: not a file the pipeline writes; nothing was parsed"
        )


def read_json_file(path: str | os.PathLike, kind: str, max_bytes: int = MAX_JSON_BYTES) -> Any:
    """The JSON value in the regular file ``path`` (:func:`read_text_file`); one DataError line
    naming the file when it is refused, denser in values than the pipeline writes
    (:func:`check_json_density`) or not JSON (nesting too deep for the parser included).

    Example:
        >>> import tempfile
        >>> from pathlib import Path
        >>> with tempfile.TemporaryDirectory() as d:
        ...     _ = Path(d, "m.json").write_text('{"abs_rel": 0.1}')
        ...     read_json_file(Path(d, "m.json"), "metrics")
        {'abs_rel': 0.1}
    """
    text = read_text_file(path, kind, max_bytes)
    check_json_density(text, str(path))
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise DataError(f"{path}: this {kind} file is not JSON ({str(exc).splitlines()[0][:200]})") from None


def read_json_object(path: str | os.PathLike, kind: str, hint: str = "") -> dict:
    """The JSON object in ``path`` (:func:`read_json_file`); one DataError line naming the file
    when it is missing (with ``hint``: what would write it), refused, not JSON or not an object.

    Example:
        >>> import tempfile
        >>> from pathlib import Path
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
                            f"{path}: this {kind} table takes over {size_text(held)} in memory, more than "
                            f"{MAX_TABLE_GROWTH}x its file ({size_text(size)}): "
                            "not a table the pipeline writes"
                        )
                    chunks.append(chunk)
        except (
            ValueError,
            UnicodeDecodeError,
            OSError,
            pd.errors.EmptyDataError,
        ) as exc:  # ParserError: a ValueError
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
            f"{where}: a sparse {kind} file ({size_text(info.st_size)}, {size_text(on_disk * 512)} "
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
            f"{path}: its members declare {size_text(declared)} inflated, over the {size_text(limit)} "
            f"this file may hold ({MAX_INFLATE_RATIO}x its size at most); nothing was inflated"
        )
    if any(not m.filename.endswith(".npy") for m in members):
        raise DataError(f"{path}: not an .npz of arrays (a member is not .npy)")


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
