"""Download, verify and unpack the KITTI raw archives: resumable, retrying, parallel, atomic.

The shipped list (``data_lists/kitti_archives_to_download.txt``) names 66 archives of a few GB
each on a public S3 bucket. Over a slow or flaky link a download must survive resets and
restarts without starting over, and a killed run must never leave something that a later run
takes for complete:

- :func:`download` streams to ``<archive>.part`` and resumes it with an HTTP ``Range`` request;
  the final name appears only when the size is right. The size is declared (HEAD and GET must
  agree), nothing past it is kept, and an attempt slower than :data:`MIN_RATE` is cut off.
- :func:`_verify_zip` reads every member (CRC check); ``manifest.json`` in the download folder
  records the sha256 of each archive once verified, and later runs compare against it.
- :func:`extract` unpacks into a temp folder beside the destination, moves it into place and
  writes a completion marker last. A member that would replace a folder by a file (or a file by
  a folder) that is already there, from another archive, is refused.
- Only https is fetched unless plain http is allowed (``allow_http``, for a trusted mirror), and a
  redirect never leaves https, nor goes to another scheme. Each entry must name a plain ``<name>.zip``.
  Before anything is unpacked, every member is checked: no path outside the destination, no
  dot-name at the top (where completion markers live), no symlink or device, and the declared
  sizes must fit the disk and stay within :data:`MAX_EXPANSION` times the archive (a zip bomb
  is refused undecompressed).
- :func:`fetch_all` does all of that for many archives in parallel and reports per archive:
  :func:`plan` checks the list, then :func:`fetch` or :func:`dry_run` runs it, all with one
  :class:`FetchOptions`. A host that cannot be reached at all (no name resolution, connection
  refused, no route) is not retried: the first such error stops every archive with one line
  (:class:`NetworkUnreachable`).
- :func:`select_needed` picks the archives that the chosen split lists need (their drives and
  those days' calibration archives), :func:`_select_archives` a count or named drives of a list.

Standard library only (``urllib``, ``zipfile``, ``hashlib``); tqdm for progress bars.
"""

from __future__ import annotations

import errno
import glob
import http.client
import os
import re
import shutil
import socket
import stat
import tempfile
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
import zipfile
import zlib
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

from tqdm import tqdm

from msdepth.errors import DataError
from msdepth.io import atomic_temps, write_json
from msdepth.readers import file_sha256, read_bounded, read_json_file

# The host every entry of the shipped list starts with; entries are kept relative to it so that a
# mirror (or a test server) can be used by passing another base URL to fetch_all.
KITTI_BASE_URL = "https://s3.eu-central-1.amazonaws.com/avg-kitti/"

MANIFEST_NAME = "manifest.json"
CHUNK_SIZE = 1 << 20  # 1 MiB reads: few syscalls, and a progress bar that still moves
MAX_BACKOFF_S = 60.0
JPEG_QUALITY = 92  # Monodepth's conversion (ImageMagick -quality 92, 4:2:0 chroma like OpenCV's)
USER_AGENT = "msdepth-kitti-download"
# Declared uncompressed bytes per archive byte above which an archive is refused as a zip bomb.
# KITTI's archives are PNG images (already deflated: ~1x), velodyne float32 scans and a few text
# files: ~1-3x. Deflate itself tops out near 1030x, reached by highly repetitive data (zeros), so
# 100x leaves honest archives a 30x margin and stops the cheap bombs; the disk-space check bounds
# anything below it. zipfile never writes more than a member's declared size (it cuts the output
# there and checks the CRC), so the declared sizes are what extraction can write.
MAX_EXPANSION = 100
# An attempt that brings fewer than MIN_RATE bytes/s over RATE_WINDOW_S seconds is cut off and
# counts as a failed retry even though it made progress: a server dripping bytes (or a stalled
# link) never trips the per-read timeout. 10 KiB/s is ~1/1000 of a home link; a 4 GB archive
# at that rate would still take 5 days. Lower FetchOptions.min_rate for a slower link.
MIN_RATE = 10 * 1024
RATE_WINDOW_S = 60.0
# What the list readers read at most (msdepth.readers.read_bounded: a FIFO would block a plain read
# forever, a huge file would be read whole). The archive list: the shipped one is 66 URLs, 7 KB;
# the bound holds ~10,000 of them. The split lists: msdepth.data.kitti.MAX_LIST_BYTES, which the
# index stage reads the same lists with (test_reader_bounds holds the two equal); not imported from
# there so that the download imports neither OpenCV nor pandas.
MAX_ARCHIVE_LIST_BYTES = 1 << 20
MAX_SPLIT_LIST_BYTES = 64 << 20

# Errors worth another try: the network or the server, not the request. HTTPError (a subclass of
# URLError) is sorted by status in _open before it can reach this tuple.
_TRANSIENT_ERRORS = (
    ConnectionError,
    TimeoutError,
    socket.timeout,
    urllib.error.URLError,
    http.client.HTTPException,
)
# Errors that say the host cannot be reached at all (no network, a wrong host name, nothing
# listening): retrying them per archive only multiplies the wait, as every archive shares the host.
_UNREACHABLE_ERRNOS = (errno.ENETUNREACH, errno.EHOSTUNREACH, errno.ENETDOWN)
# 408 Request Timeout and 429 Too Many Requests say "try again later" by definition; other 4xx
# (404, 403, ...) will not change on a retry.
_RETRYABLE_4XX = (408, 429)


class _Transient(Exception):
    """A failed attempt worth retrying (5xx, short read, inconsistent range answer)."""


class _TooSlow(_Transient):
    """An attempt below the minimum rate: retried, but counted as a failure even with progress."""


class NetworkUnreachable(DataError):
    """The server cannot be reached at all (name resolution failed, connection refused, no route):
    not retried, and it stops :func:`fetch_all` as a whole."""


def _unreachable(reason: object) -> bool:
    return isinstance(reason, (socket.gaierror, ConnectionRefusedError)) or (
        isinstance(reason, OSError) and reason.errno in _UNREACHABLE_ERRNOS
    )


class DownloadError(DataError):
    """One or more archives of :func:`fetch_all` failed; ``report`` holds the per-archive result."""

    def __init__(self, message: str, report: dict[str, Any]) -> None:
        super().__init__(message)
        self.report = report


@dataclass(frozen=True)
class FetchOptions:
    """How archives are fetched: one object, shared by every :func:`fetch_all` call of a run.

    ``jobs`` archives at a time; ``dry_run`` writes nothing (:func:`dry_run`); ``jpeg`` converts
    the PNGs on extraction (:func:`extract`); ``progress`` shows bars; ``retries``, ``backoff``
    (seconds, doubled per retry) and ``timeout`` (seconds per read) as :func:`download` uses them;
    an attempt slower than ``min_rate`` bytes/s over ``rate_window`` seconds is cut off (see
    :data:`MIN_RATE`); ``allow_http`` lets plain http through, for a mirror you trust
    (:func:`_check_url`).
    """

    jobs: int = 4
    dry_run: bool = False
    jpeg: bool = False
    progress: bool = True
    retries: int = 5
    backoff: float = 1.0
    timeout: float = 30.0
    min_rate: float = MIN_RATE
    rate_window: float = RATE_WINDOW_S
    allow_http: bool = False


# --------------------------------------------------------------------------- archive lists


def _list_text(path: Path, kind: str, max_bytes: int) -> str:
    """The UTF-8 text of the list file ``path`` (an empty file is ""), read through
    :func:`msdepth.readers.read_bounded`; each refusal one DataError line naming the file."""
    try:
        return read_bounded(path, kind, max_bytes, allow_empty=True).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from None


def parse_archive_list(path: str | os.PathLike) -> list[str]:
    """Read an archive list: one URL (or URL path) of a ``.zip`` per line.

    Blank lines and ``#`` comment lines are skipped. Entries under :data:`KITTI_BASE_URL` are returned
    relative to it (``raw_data/2011_09_26_calib.zip``); other absolute URLs are kept as they are.
    """
    path = Path(path)
    lines = _list_text(path, "archive list", MAX_ARCHIVE_LIST_BYTES).splitlines()
    names: list[str] = []
    seen: dict[str, int] = {}
    for number, line in enumerate(lines, 1):
        entry = line.strip()
        if not entry or entry.startswith("#"):
            continue
        if any(c.isspace() for c in entry) or not entry.endswith(".zip"):
            raise DataError(
                f"{path}:{number}: expected one URL of a .zip archive per line, got {line.strip()[:200]!r}"
            )
        if entry.startswith(KITTI_BASE_URL):
            entry = entry[len(KITTI_BASE_URL) :]
        problem = _entry_problem(entry)
        if problem:
            raise DataError(f"{path}:{number}: archive {entry!r}: {problem}")
        name = _archive_filename(entry)
        if name in seen:
            # Two entries would download to the same file, concurrently.
            raise DataError(f"{path}:{number}: archive {name} is listed twice (first on line {seen[name]})")
        seen[name] = number
        names.append(entry)
    if not names:
        raise DataError(f"{path}: no archives listed")
    return names


def _archive_filename(name: str) -> str:
    """The file name an archive entry downloads to (last component of its URL path)."""
    return PurePosixPath(urllib.parse.urlsplit(name).path).name


def _entry_problem(entry: str) -> str | None:
    """Why ``entry`` of an archive list cannot be fetched safely, or None.

    Its file name is what the download folder, the manifest and the completion marker are keyed
    by, so it must be a plain ``<name>.zip``: not empty, ``.`` or ``..`` (which would name the
    download folder or its parent), not a dot-file, and not hidden behind a query or fragment
    (``x/?.zip`` ends in ``.zip`` but names the folder ``x/``).
    """
    if "?" in entry or "#" in entry:
        return "has a query or fragment ('?' or '#'); list the archive's own URL"
    name = _archive_filename(entry)
    if name.startswith(".") or not name.endswith(".zip"):
        return "names no archive file (the URL path must end in <name>.zip)"
    return None


def _date_of(filename: str) -> str:
    """``2011_09_26`` for both ``2011_09_26_calib.zip`` and ``2011_09_26_drive_0001_sync.zip``."""
    return filename[:10]


def _select_archives(names: Sequence[str], subset: int | str | Iterable[str] | None = None) -> list[str]:
    """Pick the archives to fetch from a parsed list, in list order.

    ``subset`` is ``None`` or ``"all"`` (everything), an int ``N`` (the first N drive archives), or
    drive names (``2011_09_26_drive_0001``, with or without ``_sync`` / ``.zip``). The calibration
    archives of the selected drives' days are added, since a drive is unusable without them.
    """
    if subset is None or subset == "all":
        return list(names)
    drives = [n for n in names if "_drive_" in _archive_filename(n)]
    if isinstance(subset, bool) or not isinstance(subset, (int, str, Iterable)):
        raise DataError(f"archive subset: expected 'all', a count or drive names, got {subset!r}")
    if isinstance(subset, int):
        if subset < 0:
            raise DataError(f"archive subset: the number of drives must be >= 0, got {subset}")
        chosen = set(drives[:subset])
    else:
        if isinstance(subset, str):
            subset = [subset]
        by_drive = {_drive_of(_archive_filename(n)): n for n in names}
        wanted = [_drive_of(str(s).strip()) for s in subset]
        unknown = [w for w in wanted if w not in by_drive]
        if unknown:
            raise DataError(f"archive subset: not in the archive list: {', '.join(unknown)}")
        chosen = {by_drive[w] for w in wanted}
    days = {_date_of(_archive_filename(n)) for n in chosen}
    calib = {
        n
        for n in names
        if _archive_filename(n).endswith("_calib.zip") and _date_of(_archive_filename(n)) in days
    }
    return [n for n in names if n in chosen or n in calib]


def _drive_of(filename: str) -> str:
    """``2011_09_26_drive_0001`` for ``2011_09_26_drive_0001_sync.zip`` (and for ``..._sync``)."""
    return filename.removesuffix(".zip").removesuffix("_sync")


def _few(items: Sequence[str], limit: int = 3) -> str:
    """``a, b, c`` or ``a, b, c and 4 more``: a list that keeps an error message on one line."""
    shown = ", ".join(items[:limit])
    return shown + (f" and {len(items) - limit} more" if len(items) > limit else "")


def _count(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def _joined(words: Sequence[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def _split_drives(path: str | os.PathLike) -> list[str]:
    """The raw drives a split list names (``2011_09_26_drive_0001``), in the order first named.

    Both list formats are read: image pairs (``<date>/<drive>_sync/image_02/data/<n>.jpg`` and its
    right image: Godard's and Eigen's lists) and Monodepth2's ``<date>/<drive>_sync <frame> l``
    lines. The drive is the ``<drive>_sync`` folder below the date; a line naming none is a
    DataError naming the file and line (the lists' other checks are the index stage's).
    """
    path = Path(path)
    lines = _list_text(path, "split", MAX_SPLIT_LIST_BYTES).splitlines()
    drives: dict[str, None] = {}
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        named = [
            _drive_of(parts[1])
            for token in line.split()
            if len(parts := token.split("/")) >= 2 and parts[1].endswith("_sync")
        ]
        if not named:
            raise DataError(
                f"{path}:{number}: names no raw drive (expected paths '<date>/<drive>_sync/...'), "
                f"got {line.strip()[:200]!r}"
            )
        drives.update(dict.fromkeys(named))
    if not drives:
        raise DataError(f"{path}: split file lists no frame")
    return list(drives)


@dataclass(frozen=True)
class Selection:
    """The raw archives to fetch (:func:`select_needed`) and how they were chosen."""

    archives: list[str]  # in archive-list order: drives and their days' calibration archives
    drives: int  # drive archives among them
    calibrations: int  # calibration archives among them
    needed: int  # drives the splits name
    listed: int  # drive archives in the archive list
    sources: tuple[str, ...]  # what named them: "the train split", "eigen", ...
    restriction: str = ""  # "drives" (data.kitti.drives) or "drive_count", if one applied
    unneeded: tuple[str, ...] = ()  # drives of data.kitti.drives that no split names (not fetched)

    def describe(self, label: str = "KITTI raw") -> str:
        """One line: e.g. ``KITTI raw: 46 drives named by the train split and eigen (of 61 in
        the archive list) + 5 calibration archives``."""
        named = f"named by {_joined(self.sources)}"
        calib = f" + {_count(self.calibrations, 'calibration archive')}"
        if self.restriction == "drive_count":
            head = (
                f"the first {self.drives} of the {_count(self.needed, 'drive')} {named} "
                f"(data.kitti.drive_count; {self.listed} in the archive list)"
            )
        elif self.restriction == "drives":
            head = (
                f"{_count(self.drives, 'drive')} of data.kitti.drives, of the {self.needed} {named} "
                f"({self.listed} in the archive list)"
            )
        else:
            head = f"{_count(self.drives, 'drive')} {named} (of {self.listed} in the archive list)"
        line = f"{label}: {head}{calib}"
        if self.unneeded:
            line += f"; in data.kitti.drives but named by no split, so not fetched: {_few(self.unneeded)}"
        return line


def select_needed(
    names: Sequence[str],
    splits: dict[str, str | os.PathLike],
    subset: int | str | Iterable[str] | None = None,
    *,
    archive_list: str | os.PathLike = "the archive list",
) -> Selection:
    """The archives that the split lists ``splits`` (what names them, e.g. ``"the train split"``
    or ``"eigen"`` -> list file; read by :func:`_split_drives`) need, in the order of ``names``:
    the drives they name and the calibration archives of those drives' days.

    A split naming a drive that ``names`` lacks is a DataError naming the split file and (a few
    of) the drives. ``subset`` restricts further, as in :func:`_select_archives` and with its
    errors: a count takes the first N of the needed drives, drive names keep those of them the
    splits need (the others are reported in :attr:`Selection.unneeded`, not fetched).
    """
    drive_of = {n: _drive_of(_archive_filename(n)) for n in names if "_drive_" in _archive_filename(n)}
    listed = set(drive_of.values())
    wanted: dict[str, None] = {}
    for source, path in splits.items():
        drives = _split_drives(path)
        unknown = [d for d in drives if d not in listed]
        if unknown:
            raise DataError(
                f"{path} ({source}): names {len(unknown)} drive(s) not in {archive_list}: {_few(unknown)}"
            )
        wanted.update(dict.fromkeys(drives))
    needed = [n for n, d in drive_of.items() if d in wanted]
    restricted = _select_archives(names, subset)  # its checks and errors for the subset
    unneeded: list[str] = []
    if subset is None or subset == "all":
        chosen, restriction = needed, ""
    elif isinstance(subset, int):
        chosen, restriction = needed[:subset], "drive_count"
    else:
        kept = set(restricted)
        chosen, restriction = [n for n in needed if n in kept], "drives"
        unneeded = [drive_of[n] for n in restricted if n in drive_of and drive_of[n] not in wanted]
    archives = _select_archives(names, [drive_of[n] for n in chosen]) if chosen else []
    return Selection(
        archives=archives,
        drives=len(chosen),
        calibrations=len(archives) - len(chosen),
        needed=len(needed),
        listed=len(drive_of),
        sources=tuple(splits),
        restriction=restriction,
        unneeded=tuple(unneeded),
    )


# --------------------------------------------------------------------------- HTTP


def _check_url(url: str, allow_http: bool = False) -> None:
    """Refuse a URL that is not https (or, with ``allow_http``, http): over plain http anyone on
    the path can swap an archive, and the manifest would then record the swapped bytes as good."""
    scheme = urllib.parse.urlsplit(url).scheme.lower()
    if scheme == "https" or (scheme == "http" and allow_http):
        return
    if scheme == "http":
        raise DataError(
            f"{url}: plain http is refused (the archive would travel unauthenticated); use https, or "
            "allow http for a mirror you trust (data.kitti.allow_http: true)"
        )
    raise DataError(f"{url}: not an https URL{' (or http)' if allow_http else ''}; refusing to fetch it")


class NoDowngradeRedirect(urllib.request.HTTPRedirectHandler):
    """Follow redirects to http(s) URLs with a host, never from https to anything else: a
    redirect must not undo the https check, which applies to the URL that is actually requested,
    nor lead to another scheme (urllib would follow one to ``ftp://``). ``followed`` keeps the
    last target, so that an unreachable one is reported as the redirect's fault, not the mirror's.
    """

    followed = ""

    def redirect_request(self, req, fp, code, msg, headers, newurl):  # noqa: ANN001 - urllib's signature
        old, new = urllib.parse.urlsplit(req.full_url), urllib.parse.urlsplit(newurl)
        problem = None
        if old.scheme.lower() == "https" and new.scheme.lower() != "https":
            problem = "which is not https; refusing the downgrade"
        elif new.scheme.lower() not in ("http", "https"):
            problem = "which is not an http(s) URL; refusing to follow it"
        elif not new.hostname:
            problem = "which names no host; refusing to follow it"
        if problem:
            fp.close()
            raise DataError(f"{req.full_url}: redirected to {newurl}, {problem}")
        self.followed = newurl
        return super().redirect_request(req, fp, code, msg, headers, newurl)


def _open(
    url: str, timeout: float, *, method: str = "GET", offset: int = 0, allow_http: bool = False
) -> http.client.HTTPResponse | urllib.error.HTTPError:
    """Send one request; return the response, or raise DataError (permanent) / _Transient.

    A 416 (range past the end) is returned like a response: the caller decides what it means.
    A URL that :func:`_check_url` refuses, a redirect that :class:`NoDowngradeRedirect` refuses,
    or a redirect to a host that cannot be reached, is a DataError (that archive's alone).
    """
    _check_url(url, allow_http)
    headers = {"User-Agent": USER_AGENT}
    if offset:
        headers["Range"] = f"bytes={offset}-"
    redirects = NoDowngradeRedirect()
    try:
        # build_opener puts the handler in place of urllib's default redirect handler; the rest
        # (proxies from the environment, TLS verification) is what urlopen uses.
        opener = urllib.request.build_opener(redirects)
        return opener.open(urllib.request.Request(url, method=method, headers=headers), timeout=timeout)
    except urllib.error.HTTPError as exc:
        if exc.code == 416:
            return exc
        exc.close()
        if exc.code >= 500 or exc.code in _RETRYABLE_4XX:
            raise _Transient(f"HTTP {exc.code} {exc.reason}") from None
        raise DataError(f"{url}: HTTP {exc.code} {exc.reason}") from None
    except urllib.error.URLError as exc:
        # A socket-level reason (reset, timeout) may pass; a plain message such as "unknown url
        # type" is a typo in the list or the base URL and will not, nor will an unreachable host.
        if _unreachable(exc.reason) and redirects.followed:
            raise DataError(
                f"{url}: redirected to {redirects.followed}, which cannot be reached ({_describe(exc)})"
            ) from None
        if _unreachable(exc.reason):
            host = urllib.parse.urlsplit(url).hostname
            raise NetworkUnreachable(
                f"{url}: cannot reach {host} ({_describe(exc)}): no network, or a wrong host in the URL"
            ) from None
        if isinstance(exc.reason, OSError):
            raise
        raise DataError(f"{url}: {exc.reason}") from None
    except ValueError as exc:  # no scheme at all
        raise DataError(f"{url}: {exc}") from None


def _content_range(value: str | None) -> tuple[int | None, int | None]:
    """``bytes 100-199/200`` -> (100, 200); ``bytes */200`` -> (None, 200); unknown parts None."""
    # ASCII digits only, at most 20 (int() takes other Unicode digits, and refuses 4,300 of them).
    match = re.fullmatch(r"\s*bytes\s+(?:([0-9]{1,20})-[0-9]{1,20}|\*)/([0-9]{1,20}|\*)\s*", value or "")
    if not match:
        return None, None
    start, total = match.groups()
    return (int(start) if start else None), (int(total) if total and total != "*" else None)


def _int_header(url: str, value: str | None, name: str = "Content-Length") -> int | None:
    """Header ``name``'s byte count, None if absent; DataError if it is anything but ASCII digits
    (``²`` passes str.isdigit(), and int() then raises)."""
    if value is None or not value.strip():
        return None
    if not re.fullmatch(r"[0-9]{1,20}", value.strip()):
        raise DataError(f"{url}: the server's {name} {value[:40]!r} is not a byte count; refusing it")
    return int(value)


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return 0


class _Overlong(DataError):
    """The server sent more than the size it declared: the download is refused, not retried."""


def _attempt(
    url: str,
    part: Path,
    expected: int | None,
    options: FetchOptions,
    bar: tqdm,
    on_bytes: Callable[[int], None] | None,
) -> int:
    """One GET, resuming ``part`` where it ends; returns the file's size.

    The size is the one the answer declares (Content-Length of a 200, Content-Range of a 206),
    which must agree with ``expected`` (HEAD's) where both are known; one of them must be, and
    no byte past it is kept. Raises _Transient (or a network error) when the transfer should be
    retried from where it is, DataError when the server contradicts itself, declares no size or
    sends more than it declared (the ``.part`` is then removed).
    """
    offset = _size(part)
    response = _open(url, options.timeout, offset=offset, allow_http=options.allow_http)
    with response:
        if response.status == 416:
            return _whole(response, part, offset, expected)
        offset, mode, declared = _start(url, response, part, offset)
        total = _agreed_size(url, declared, expected)
        bar.reset(total=total)
        bar.update(offset)
        try:
            with open(part, mode) as out:
                _copy(url, response, out, offset, total, options, bar, on_bytes)
                out.flush()
                os.fsync(out.fileno())  # the rename that follows must not publish unwritten bytes
        except _Overlong:
            part.unlink(missing_ok=True)
            raise
    received = _size(part)
    if received != total:
        # http.client returns b"" rather than raising when the peer closes before Content-Length.
        raise _Transient(f"short read: have {received} of {total} bytes")
    return total


def _whole(response: urllib.error.HTTPError, part: Path, offset: int, expected: int | None) -> int:
    """A 416 (nothing past ``offset``): ``part`` is whole (a run killed between its last write and
    the rename), or longer than the file, and then it starts over from 0."""
    _, declared = _content_range(response.headers.get("Content-Range"))
    total = declared if declared is not None else expected
    if total is not None and total == offset and expected in (None, total):
        return total
    part.write_bytes(b"")
    raise _Transient(f"range {offset}- not satisfiable (size {total}); restarting from 0")


def _start(url: str, response: Any, part: Path, offset: int) -> tuple[int, str, int | None]:
    """Where a 200 or 206 answer's body goes: (its offset in ``part``, file mode, declared size)."""
    if response.status == 206:
        start, total = _content_range(response.headers.get("Content-Range"))
        if start != offset:
            part.write_bytes(b"")
            raise _Transient(f"asked for bytes {offset}-, got a range starting at {start}; restarting from 0")
        return offset, "ab", total
    # 200: the server ignored the Range header and sends the whole file. Appending it to the
    # partial file would corrupt it, so start again from byte 0.
    return 0, "wb", _int_header(url, response.headers.get("Content-Length"))


def _agreed_size(url: str, declared: int | None, expected: int | None) -> int:
    """The size a download stops at: the answer's, which must be HEAD's (``expected``) if both
    are known. Neither known is refused: a stream without a length would never be cut off."""
    if declared is not None and expected is not None and declared != expected:
        raise DataError(f"{url}: the server declares {declared} bytes, its HEAD said {expected}; refusing it")
    if declared is None and expected is None:
        raise DataError(
            f"{url}: the server declares no size (no Content-Length); refusing an unbounded download"
        )
    return declared if declared is not None else expected


def _copy(
    url: str,
    response: Any,
    out: Any,
    offset: int,
    total: int,
    options: FetchOptions,
    bar: tqdm,
    on_bytes: Callable[[int], None] | None,
) -> None:
    """Copy the body into ``out`` (which holds ``offset`` bytes) up to ``total`` bytes: more is
    _Overlong; fewer than ``options.min_rate`` bytes/s over a ``rate_window`` is _TooSlow."""
    room, window_start, window_bytes = total - offset, time.monotonic(), 0
    while True:
        # read1 hands over what has arrived, so bytes received before a reset are kept (read()
        # would loop for the full chunk and lose them with the exception). Network errors
        # propagate to download()'s retry loop.
        chunk = response.read1(CHUNK_SIZE)
        if not chunk:
            return
        if len(chunk) > room:
            raise _Overlong(
                f"{url}: the server sent more than the {total} bytes it declared; refusing the rest"
            )
        room -= len(chunk)
        out.write(chunk)
        bar.update(len(chunk))
        if on_bytes is not None:
            on_bytes(len(chunk))
        window_bytes += len(chunk)
        elapsed = time.monotonic() - window_start
        if elapsed >= options.rate_window:
            if window_bytes < options.min_rate * elapsed:
                raise _TooSlow(f"slower than {options.min_rate:g} B/s over {options.rate_window:g} s")
            window_start, window_bytes = time.monotonic(), 0


def download(
    url: str,
    dest: Path,
    options: FetchOptions = FetchOptions(),
    *,
    expected_size: int | None = None,
    on_bytes: Callable[[int], None] | None = None,
) -> Path:
    """Fetch ``url`` to ``dest``, resuming ``dest.part`` across failures; return ``dest``.

    Connection errors, resets, timeouts, 5xx and short reads are retried with exponential
    back-off, each time resuming with a ``Range`` request; ``options.retries`` bounds the
    consecutive attempts that brought no new bytes (an attempt that made progress resets the
    count, so a long download over a flaky link is not abandoned for having been interrupted
    often), or that were cut off below ``options.min_rate``. 4xx answers fail at once.

    The size is the one the server declares (Content-Length / Content-Range), which must equal
    ``expected_size`` (HEAD's, as :func:`fetch` passes it) if given; a download whose size
    neither gives is refused, and nothing past the size is kept. Only a complete ``.part`` is
    renamed to ``dest``, so an existing ``dest`` is taken as complete. ``on_bytes`` is called
    with each chunk's length (for an overall count). Only https is fetched, http too with
    ``options.allow_http`` (:func:`_check_url`); nothing is written for a refused URL.
    """
    dest = Path(dest)
    if dest.exists():
        return dest
    _check_url(url, options.allow_http)
    dest.parent.mkdir(parents=True, exist_ok=True)
    part = dest.with_suffix(dest.suffix + ".part")
    with tqdm(
        desc=dest.name,
        unit="B",
        unit_scale=True,
        unit_divisor=1024,
        leave=False,
        disable=not options.progress,
    ) as bar:
        _retrying(url, part, expected_size, options, bar, on_bytes)
    os.replace(part, dest)
    return dest


def _retrying(
    url: str,
    part: Path,
    expected: int | None,
    options: FetchOptions,
    bar: tqdm,
    on_bytes: Callable[[int], None] | None,
) -> None:
    """:func:`_attempt` until ``part`` is complete, with back-off, or a DataError."""
    failures = 0
    while True:
        before = _size(part)
        try:
            _attempt(url, part, expected, options, bar, on_bytes)
            return
        except (_Transient, *_TRANSIENT_ERRORS) as exc:
            progressed = _size(part) > before and not isinstance(exc, _TooSlow)
            failures = 0 if progressed else failures + 1
            if failures > options.retries:
                raise DataError(
                    f"{url}: download failed after {options.retries} retries: {_describe(exc)}"
                ) from None
            time.sleep(min(options.backoff * 2 ** max(failures - 1, 0), MAX_BACKOFF_S))
        except OSError as exc:  # the local side: disk full, permissions
            raise DataError(f"{part}: cannot write the download of {url} ({exc})") from None


def _describe(exc: BaseException) -> str:
    if isinstance(exc, urllib.error.URLError) and not isinstance(exc, urllib.error.HTTPError):
        return f"{type(exc.reason).__name__}: {exc.reason}"
    return f"{type(exc).__name__}: {exc}" if not isinstance(exc, _Transient) else str(exc)


def _remote_size(url: str, options: FetchOptions = FetchOptions()) -> int | None:
    """Content-Length of ``url`` from a HEAD request (None if the server does not say)."""
    for attempt in range(options.retries + 1):
        try:
            with _open(url, options.timeout, method="HEAD", allow_http=options.allow_http) as response:
                return _int_header(url, response.headers.get("Content-Length"))
        except (_Transient, *_TRANSIENT_ERRORS) as exc:
            if attempt == options.retries:
                raise DataError(
                    f"{url}: HEAD failed after {options.retries} retries: {_describe(exc)}"
                ) from None
            time.sleep(min(options.backoff * 2**attempt, MAX_BACKOFF_S))
    raise AssertionError("unreachable")


# --------------------------------------------------------------------------- verification


def _verify_zip(path: str | os.PathLike) -> None:
    """Check that ``path`` is a readable zip whose every member decompresses with the right CRC.

    This is ``ZipFile.testzip()``'s loop, but catching every way a damaged member fails (a bad
    deflate stream raises zlib.error, which testzip lets through without the member's name).
    Members that :func:`_check_members` refuses fail first, before anything is decompressed.
    """
    path = Path(path)
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as exc:
        raise DataError(f"{path}: not a readable zip archive (central directory: {exc})") from None
    with zf:
        members = zf.infolist()
        if not members:
            raise DataError(f"{path}: zip archive has no members")
        _check_members(zf, path)  # a zip bomb is not even decompressed
        for info in members:
            try:
                with zf.open(info) as member:
                    while member.read(CHUNK_SIZE):
                        pass
            except (zipfile.BadZipFile, zlib.error, EOFError, OSError, NotImplementedError) as exc:
                raise DataError(f"{path}: member {info.filename} is corrupt ({exc})") from None


class Manifest:
    """``manifest.json``: sha256 and size of each archive, recorded when first verified.

    Shared by the download threads; every change is written at once (atomically), so an
    interrupted run keeps what it verified.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._lock = threading.Lock()
        self.archives: dict[str, dict[str, Any]] = {}
        if path.exists():
            try:
                data = read_json_file(path, "download manifest")
                self.archives = dict(data["archives"])
            except DataError as exc:
                raise DataError(f"{exc}; delete it to re-verify every archive") from None
            except (KeyError, TypeError, ValueError) as exc:
                raise DataError(
                    f"{path}: not a download manifest ({exc}); delete it to re-verify every archive"
                ) from None

    def get(self, name: str) -> dict[str, Any] | None:
        with self._lock:
            return self.archives.get(name)

    def record(self, name: str, entry: dict[str, Any] | None) -> None:
        """Set (or with None, drop) the entry of archive ``name`` and write the file."""
        with self._lock:
            if entry is None:
                self.archives.pop(name, None)
            else:
                self.archives[name] = entry
            write_json(self.path, {"archives": dict(sorted(self.archives.items()))})


def _set_aside(path: Path) -> Path:
    """Move a bad archive to ``<name>.corrupt`` (kept for inspection) so the next run refetches it."""
    if not path.is_file() or path.is_symlink():  # only what download() wrote: never a folder
        raise DataError(f"{path}: not a downloaded archive (a folder or link?); leaving it alone")
    corrupt = path.with_name(path.name + ".corrupt")
    os.replace(path, corrupt)
    return corrupt


def _verify_archive(path: Path, manifest: Manifest, url: str = "") -> None:
    """Compare ``path`` with its manifest record, or verify it and record it if it has none.

    A mismatch or a damaged zip moves the archive aside (see :func:`_set_aside`), drops its
    record and raises DataError naming it.
    """
    entry = manifest.get(path.name)
    if entry is not None:
        size, sha = _size(path), file_sha256(path, "archive")
        if size != entry.get("size") or sha != entry.get("sha256"):
            corrupt = _set_aside(path)
            manifest.record(path.name, None)
            raise DataError(
                f"{path}: size {size} / sha256 {sha[:12]}... differ from {manifest.path.name}'s record "
                f"({entry.get('size')} / {str(entry.get('sha256'))[:12]}...); moved to {corrupt.name}, "
                "the next run fetches it again"
            )
        return
    try:
        _verify_zip(path)
    except DataError as exc:
        corrupt = _set_aside(path)
        raise DataError(f"{exc}; moved to {corrupt.name}, the next run fetches it again") from None
    manifest.record(path.name, {"size": _size(path), "sha256": file_sha256(path, "archive"), "url": url})


# --------------------------------------------------------------------------- extraction


def _marker(zip_path: Path, dest_dir: Path) -> Path:
    return dest_dir / f".{zip_path.name}.complete"


def _pending(zip_path: Path, dest_dir: Path) -> Path:
    """The record of the files an extraction is moving into place, written before the first move
    and replaced by the completion marker after the last: a run killed midway still owns them."""
    return dest_dir / f".{zip_path.name}.pending"


def _file_owners(dest_dir: Path) -> dict[str, str]:
    """Which archive wrote each file under ``dest_dir`` (relative POSIX path -> archive name), from
    the ``files`` of its completion markers and pending records. Markers written before the list
    was kept own nothing: their files are treated as files no archive wrote."""
    owners: dict[str, str] = {}
    records = [*dest_dir.glob(".*.zip.complete"), *dest_dir.glob(".*.zip.pending")]
    for record in sorted(records):
        try:
            data = read_json_file(record, "download record")
        except DataError:
            continue  # unreadable: owns nothing, so its files are refused rather than replaced
        files = data.get("files") if isinstance(data, dict) else None
        archive = record.name[1:].rsplit(".", 1)[0]
        for name in files if isinstance(files, list) else []:
            if isinstance(name, str):
                owners.setdefault(name, archive)
    return owners


def _replacement(zip_path: Path, member: str, target: Path, owners: dict[str, str]) -> str | None:
    """Why ``member`` may not replace the existing ``target``, or None: another archive wrote it, or
    no archive did (a user's file, a folder source's); this archive's own file may be replaced."""
    owner = owners.get(member)
    if owner == zip_path.name:
        return None
    whose = f"written by {owner}" if owner else "a file no KITTI archive wrote here"
    return f"member {member!r} would replace {target} ({whose})"


def _check_replacements(zf: zipfile.ZipFile, zip_path: Path, dest_dir: Path, jpeg: bool = False) -> None:
    """Refuse, before anything is extracted, an archive whose member would replace a file under
    ``dest_dir`` that this archive did not write (:func:`_file_owners`); with ``jpeg`` the JPEG a PNG
    member becomes is checked too. :func:`_publish` checks the extracted tree again, under the lock."""
    if not dest_dir.is_dir():
        return
    owners = _file_owners(dest_dir)
    for info in zf.infolist():
        if info.is_dir():
            continue
        names = [info.filename]
        if jpeg and info.filename.lower().endswith(".png"):
            names.append(info.filename[:-4] + ".jpg")
        for name in names:
            target = dest_dir / name
            problem = target.is_file() and _replacement(zip_path, name, target, owners)
            if problem:
                raise DataError(f"{zip_path}: {problem}; refusing to extract, nothing was changed")


def _check_members(zf: zipfile.ZipFile, zip_path: Path) -> int:
    """Refuse an archive with a member that must not be unpacked; return the declared total size.

    Refused: a path outside the destination (``..``, absolute, a drive letter or a leading
    backslash: zip-slip), a dot-name at the top (it could forge another archive's completion
    marker, ``.<archive>.complete``, or meet a temp folder), a symbolic link, device, fifo or
    socket (the Unix mode in the high bits of ``external_attr``), and declared sizes above
    :data:`MAX_EXPANSION` times the archive's.
    """
    total = 0
    for info in zf.infolist():
        name = info.filename
        parts = re.split(r"[\\/]", name)
        if name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", name) or ".." in parts:
            raise DataError(
                f"{zip_path}: member {name!r} points outside the extraction folder; refusing to extract"
            )
        top = next((p for p in parts if p not in ("", ".")), "")  # zipfile drops "" and "." parts
        if top.startswith("."):
            raise DataError(
                f"{zip_path}: member {name!r} is a top-level dot-file (completion markers and temp "
                "folders are named so); refusing to extract"
            )
        kind = stat.S_IFMT(info.external_attr >> 16)
        if kind not in (0, stat.S_IFREG, stat.S_IFDIR):  # 0: no Unix mode (e.g. written on Windows)
            what = "a symbolic link" if kind == stat.S_IFLNK else "a device, fifo or socket"
            raise DataError(f"{zip_path}: member {name!r} is {what}; refusing to extract")
        total += info.file_size
    size = _size(zip_path)
    if total > MAX_EXPANSION * max(size, 1):
        raise DataError(
            f"{zip_path}: members declare {_human(total)} uncompressed, {total / max(size, 1):.0f}x the "
            f"archive's {_human(size)} (more than {MAX_EXPANSION}x: a zip bomb?); refusing to extract"
        )
    return total


def _check_free_space(zip_path: Path, dest_dir: Path, needed: int) -> None:
    """Refuse to start an extraction that cannot fit: the declared sizes against the free space."""
    probe = dest_dir
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    free = shutil.disk_usage(probe).free
    if needed > free:
        raise DataError(
            f"{zip_path}: needs {_human(needed)} to extract but {probe} has {_human(free)} free; "
            "refusing to start"
        )


def _to_jpeg(root: Path, quality: int) -> None:
    """Replace every 8-bit PNG under ``root`` with a JPEG of ``quality``, as Monodepth did.

    16-bit PNGs (depth or disparity maps) are left alone: JPEG would destroy their values.
    """
    import cv2  # only needed for the optional conversion

    from msdepth.data.imagefile import decode, read_file

    for png in sorted(root.rglob("*.png")):
        try:  # the one image reader: size and header bounded before the file is read and decoded
            image = decode(read_file(png), cv2.IMREAD_UNCHANGED)
        except (OSError, DataError) as exc:
            raise DataError(f"{png}: {getattr(exc, 'strerror', None) or exc}") from None
        if image.dtype != "uint8":
            continue
        if not cv2.imwrite(str(png.with_suffix(".jpg")), image, [cv2.IMWRITE_JPEG_QUALITY, quality]):
            raise DataError(f"{png}: OpenCV could not write its JPEG")
        png.unlink()


# One extraction at a time moves its tree into place, so that the check for collisions and the
# moves see the same tree: two same-day archives finishing together both found no day folder and
# both renamed theirs there (ENOTEMPTY / EISDIR for the second, 2 of 40 trials).
_MOVE_LOCK = threading.Lock()


def _publish(zip_path: Path, tmp: Path, dest_dir: Path) -> list[str]:
    """Move the extracted tree ``tmp`` into ``dest_dir`` and return its files (relative POSIX
    paths), unless a member would replace a folder with a file or a file with a folder there, or a
    file this archive did not write (:func:`_replacement`): refused whole, before any move."""
    files = sorted(p.relative_to(tmp).as_posix() for p in tmp.rglob("*") if not p.is_dir())
    with _MOVE_LOCK:
        collision = _collision(tmp, dest_dir, tmp)
        owners = _file_owners(dest_dir)
        replaced = (
            _replacement(zip_path, f, dest_dir / f, owners) for f in files if (dest_dir / f).is_file()
        )
        problem = collision or next((r for r in replaced if r), None)
        if problem:
            raise DataError(f"{zip_path}: {problem}; refusing to extract, nothing was changed")
        write_json(_pending(zip_path, dest_dir), {"archive": zip_path.name, "files": files})
        _move_into(tmp, dest_dir)
    return files


def _collision(src: Path, dst: Path, root: Path) -> str | None:
    """The first entry of ``src`` whose kind (file or folder) differs from what ``dst`` holds in
    its place, described from ``root``; None if there is none."""
    for entry in sorted(src.iterdir()):
        target = dst / entry.name
        if not (target.exists() or target.is_symlink()):
            continue
        member = entry.relative_to(root).as_posix()
        if entry.is_dir() and target.is_dir():
            found = _collision(entry, target, root)
            if found:
                return found
        elif entry.is_dir():
            return f"member {member!r} is a folder but {target} is a file already"
        elif target.is_dir():
            return f"member {member!r} is a file but {target} is a folder already"
    return None


def _move_into(src: Path, dst: Path) -> None:
    """Move the tree ``src`` into ``dst``: a folder new to ``dst`` appears by one atomic rename;
    one that exists already (a day folder shared by several archives) is merged into, also one
    that appeared since it was looked at. A file replaces the file of the same name (the same
    archive extracted again)."""
    for entry in sorted(src.iterdir()):
        target = dst / entry.name
        if entry.is_dir():
            if not target.is_dir() and _renamed(entry, target):
                continue
            _move_into(entry, target)
        else:
            os.replace(entry, target)


def _renamed(src: Path, dst: Path) -> bool:
    """Rename the folder ``src`` to ``dst``; False if ``dst`` is a folder with something in it."""
    try:
        os.rename(src, dst)
    except OSError as exc:
        if exc.errno in (errno.ENOTEMPTY, errno.EEXIST):
            return False
        raise
    return True


def extract(
    zip_path: str | os.PathLike,
    dest_dir: str | os.PathLike,
    *,
    jpeg: bool = False,
    jpeg_quality: int = JPEG_QUALITY,
) -> bool:
    """Unpack ``zip_path`` into ``dest_dir`` atomically; False if it was already unpacked.

    The members go to a temp folder beside the destination first (same file system, so the final
    move is a rename); the completion marker ``.<archive>.complete`` is written last, so a
    half-extracted drive is never taken as complete and is simply redone. With ``jpeg`` the PNGs
    are converted to JPEG (``jpeg_quality``) before anything is moved into place.

    Nothing at all is written (not even ``dest_dir``) for an archive that :func:`_check_members`
    or :func:`_check_replacements` refuses or whose declared size exceeds the free space at
    ``dest_dir``, and nothing is moved into place for one with a member that would replace a
    folder by a file, a file by a folder, or a file this archive did not write (:func:`_publish`):
    that is another archive's, whose marker would still say complete, or the user's. The marker
    lists the files the archive wrote (:func:`_file_owners`).
    """
    zip_path, dest_dir = Path(zip_path), Path(dest_dir)
    marker = _marker(zip_path, dest_dir)
    if marker.exists():
        return False
    try:
        zf = zipfile.ZipFile(zip_path)
    except (zipfile.BadZipFile, OSError) as exc:
        raise DataError(f"{zip_path}: not a readable zip archive ({exc})") from None
    with zf:
        _check_free_space(zip_path, dest_dir, _check_members(zf, zip_path))
        _check_replacements(zf, zip_path, dest_dir, jpeg)
        tmp = None
        try:
            dest_dir.mkdir(parents=True, exist_ok=True)
            for stale in dest_dir.glob(f".{glob.escape(zip_path.name)}.*.tmp"):
                shutil.rmtree(stale, ignore_errors=True)  # left by a killed run
            tmp = Path(tempfile.mkdtemp(prefix=f".{zip_path.name}.", suffix=".tmp", dir=dest_dir))
            members = zf.infolist()
            for info in members:
                try:
                    zf.extract(info, tmp)
                except (zipfile.BadZipFile, zlib.error, EOFError) as exc:
                    raise DataError(f"{zip_path}: member {info.filename} is corrupt ({exc})") from None
            if jpeg:
                _to_jpeg(tmp, jpeg_quality)
            files = _publish(zip_path, tmp, dest_dir)
            record = {"archive": zip_path.name, "members": len(members), "jpeg": jpeg, "files": files}
            write_json(marker, record)
            _pending(zip_path, dest_dir).unlink(missing_ok=True)
        except OSError as exc:  # disk full, permissions: name the archive, not just a member path
            raise DataError(f"{zip_path}: extraction into {dest_dir} failed ({exc})") from None
        finally:
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)
    return True


# --------------------------------------------------------------------------- everything


@dataclass(frozen=True)
class Plan:
    """What one :func:`fetch_all` call fetches (:func:`plan`): archive file name -> URL, the
    folders the archives and their contents go to, and the dry run's headings."""

    urls: dict[str, str]
    download_dir: Path
    extract_dir: Path
    label: str = ""  # heads the dry run's total line, e.g. "KITTI raw"
    header: str = ""  # printed before the dry run's lines, e.g. how the archives were chosen

    def archive(self, name: str) -> Path:
        """Where archive ``name`` is downloaded to."""
        return self.download_dir / name

    def marker(self, name: str) -> Path:
        """The completion marker :func:`extract` writes for archive ``name``."""
        return _marker(self.archive(name), self.extract_dir)


def plan(
    base_url: str,
    names: Sequence[str],
    download_dir: str | os.PathLike,
    extract_dir: str | os.PathLike,
    *,
    allow_http: bool = False,
    label: str = "",
    header: str = "",
) -> Plan:
    """Resolve ``names`` (URL paths relative to ``base_url``, as :func:`parse_archive_list`
    returns them; absolute URLs are used as they are) and check them before anything is fetched.

    Every entry must name a plain ``<name>.zip`` (no query or fragment, see
    :func:`_entry_problem`), every URL must be https, or http with ``allow_http``
    (:func:`_check_url`), and no two entries may download to the same file: the first entry
    refused is a DataError, and nothing is asked or written. One bad entry stops the whole list:
    the list itself is wrong, and its other entries are suspect too.
    """
    if not base_url.endswith("/"):
        base_url += "/"  # urljoin would otherwise drop the last component of the base
    for name in names:
        problem = _entry_problem(name)
        if problem:
            raise DataError(f"archive {name!r}: {problem}")
    urls = {_archive_filename(n): urllib.parse.urljoin(base_url, n) for n in names}
    if len(urls) != len(names):
        raise DataError("fetch_all: two archives in the list share a file name")
    for url in urls.values():
        _check_url(url, allow_http)
    return Plan(urls, Path(download_dir), Path(extract_dir), label, header)


def fetch_all(
    base_url: str,
    names: Sequence[str],
    download_dir: str | os.PathLike,
    extract_dir: str | os.PathLike,
    options: FetchOptions = FetchOptions(),
    *,
    label: str = "",
    header: str = "",
) -> dict[str, Any]:
    """Download, verify and extract the archives ``names`` (:func:`plan` resolves and checks
    them against ``base_url``), or with ``options.dry_run`` say what that would do.

    :func:`fetch` does the work and :func:`dry_run` the dry run (headed by ``label``, after the
    line ``header`` if given); this returns their report.
    """
    planned = plan(
        base_url, names, download_dir, extract_dir, allow_http=options.allow_http, label=label, header=header
    )
    return dry_run(planned, options) if options.dry_run else fetch(planned, options)


def fetch(planned: Plan, options: FetchOptions = FetchOptions()) -> dict[str, Any]:
    """Download, verify and extract the planned archives, ``options.jobs`` at a time.

    An archive already downloaded and matching the manifest is not fetched again; one already
    extracted is not extracted again. One archive's failure does not stop the others; at the end a
    :class:`DownloadError` (a DataError) lists the failures and carries the report. The report:
    ``fetched``, ``skipped`` (already there and verified), ``extracted``, ``failed`` (name ->
    reason), ``bytes_downloaded``.

    Each archive to download is asked its size with a HEAD first, and the GET must agree with it
    (:func:`download`). A host that cannot be reached at all stops everything with one
    :class:`NetworkUnreachable`: before anything is written when there is something to fetch
    (one HEAD request probes the host first), or at the first such error later (the network went
    away mid-run). A redirect to a host that cannot be reached fails that archive alone.
    """
    to_download = [
        name
        for name in planned.urls
        if not planned.archive(name).exists() and not planned.marker(name).exists()
    ]
    if to_download:  # a complete tree needs no network: probe only when something must be fetched
        _probe(planned.urls[to_download[0]], options)
    planned.download_dir.mkdir(parents=True, exist_ok=True)
    # A run killed while writing the manifest or a marker left its temp; no thread writes yet.
    for path in [planned.download_dir / MANIFEST_NAME, *map(planned.marker, planned.urls)]:
        for tmp in atomic_temps(path):
            tmp.unlink()
    run = _Fetching(planned, options, Manifest(planned.download_dir / MANIFEST_NAME))
    unreachable: list[NetworkUnreachable] = []
    with tqdm(
        total=len(planned.urls), desc="KITTI archives", unit="archive", disable=not options.progress
    ) as bar:
        with ThreadPoolExecutor(max_workers=max(1, options.jobs)) as pool:
            futures = {pool.submit(run.one, name): name for name in planned.urls}
            for future in as_completed(futures):
                name = futures[future]
                try:
                    future.result()
                except NetworkUnreachable as exc:  # every other archive would fail the same way
                    unreachable.append(exc)
                except DataError as exc:
                    run.report["failed"][name] = str(exc)
                except Exception as exc:  # noqa: BLE001 - one archive's surprise must not hide the others' results
                    run.report["failed"][name] = f"{type(exc).__name__}: {exc}"
                bar.update(1)
    return _fetched(run.report, len(planned.urls), unreachable)


class _Fetching:
    """One :func:`fetch` under way: the report its threads fill in, and the stop that the first
    unreachable host sets (the archives not started then stay so)."""

    def __init__(self, planned: Plan, options: FetchOptions, manifest: Manifest) -> None:
        self.plan, self.options, self.manifest = planned, options, manifest
        self.report: dict[str, Any] = {
            "fetched": [],
            "skipped": [],
            "extracted": [],
            "failed": {},
            "bytes_downloaded": 0,
        }
        self.lock = threading.Lock()
        self.stop = threading.Event()

    def _add(self, key: str, name: str) -> None:
        with self.lock:
            self.report[key].append(name)

    def _count(self, nbytes: int) -> None:
        with self.lock:
            self.report["bytes_downloaded"] += nbytes

    def one(self, name: str) -> None:
        """Fetch, verify and extract archive ``name`` (nothing once the stop is set)."""
        if self.stop.is_set():
            return
        try:
            self._one(name)
        except NetworkUnreachable:
            self.stop.set()
            raise

    def _one(self, name: str) -> None:
        url, archive, marker = self.plan.urls[name], self.plan.archive(name), self.plan.marker(name)
        if not archive.exists() and marker.exists():
            # Extracted by an earlier run and the archive deleted since (to save space): done.
            self._add("skipped", name)
            return
        present = archive.exists()
        if not present:  # HEAD's size bounds the GET: a stream without a length is cut off there
            size = _remote_size(url, self.options)
            download(url, archive, self.options, expected_size=size, on_bytes=self._count)
        try:
            _verify_archive(archive, self.manifest, url)
        except DataError:
            # The archive was set aside: forget its extraction too, so that the next run fetches
            # and unpacks it again rather than taking the deleted archive for "extracted, removed".
            # Its files stay its own (the marker becomes its pending record), so that extraction may
            # replace them and no other archive may.
            if marker.exists():
                os.replace(marker, _pending(archive, self.plan.extract_dir))
            raise
        self._add("skipped" if present else "fetched", name)
        if extract(archive, self.plan.extract_dir, jpeg=self.options.jpeg):
            self._add("extracted", name)


def _fetched(report: dict[str, Any], archives: int, unreachable: list[NetworkUnreachable]) -> dict[str, Any]:
    """The report of a finished :func:`fetch`, or the error that ends it."""
    for key in ("fetched", "skipped", "extracted"):
        report[key].sort()
    if unreachable:
        done = len(report["fetched"]) + len(report["skipped"])
        raise NetworkUnreachable(f"{unreachable[0]}; stopped with {done} of {archives} archive(s) complete")
    if report["failed"]:
        lines = "\n".join(f"  {name}: {reason}" for name, reason in sorted(report["failed"].items()))
        raise DownloadError(f"{len(report['failed'])} of {archives} archive(s) failed:\n{lines}", report)
    return report


def _probe(url: str, options: FetchOptions) -> None:
    """One HEAD request to ``url``: NetworkUnreachable if its host cannot be reached at all.

    Any other answer or error is left to the download itself, which retries or reports it.
    """
    try:
        with _open(url, options.timeout, method="HEAD", allow_http=options.allow_http):
            pass
    except NetworkUnreachable:
        raise
    except (DataError, _Transient, *_TRANSIENT_ERRORS):
        pass


def dry_run(planned: Plan, options: FetchOptions = FetchOptions()) -> dict[str, Any]:
    """What :func:`fetch` would do, with sizes from HEAD requests; writes nothing.

    Prints one line per archive (complete, downloaded, to fetch, to resume), after the line
    ``planned.header`` if given, and a total headed by ``planned.label``. Nothing is printed
    before every HEAD has answered, so a host that cannot be reached leaves only its one-line
    error (NetworkUnreachable, at its first HEAD).

    Returns ``complete`` (extracted), ``downloaded`` (there, still to verify and extract),
    ``skipped`` (both), ``to_fetch`` (name -> size, None if the server does not say), ``resume``
    (name -> bytes already in its ``.part``), ``failed`` and ``total_bytes`` (what would be
    downloaded). An archive whose HEAD fails is a DownloadError listing it, after the lines.
    """
    report, missing = _present(planned)
    _ask_sizes(planned, options, missing, report)
    report["total_bytes"] = sum(
        max(nbytes - report["resume"].get(name, 0), 0)
        for name, nbytes in report["to_fetch"].items()
        if nbytes
    )
    _print_dry_run(planned, report)
    if report["failed"]:
        lines = "\n".join(f"  {name}: {reason}" for name, reason in sorted(report["failed"].items()))
        raise DownloadError(
            f"{len(report['failed'])} of {len(planned.urls)} archive(s) cannot be fetched:\n{lines}", report
        )
    return report


def _present(planned: Plan) -> tuple[dict[str, Any], list[str]]:
    """The dry run's report of what is already on disk, and the archives still to fetch."""
    report: dict[str, Any] = {
        "dry_run": True,
        "complete": [],
        "downloaded": [],
        "skipped": [],
        "to_fetch": {},
        "resume": {},
        "failed": {},
        "total_bytes": 0,
    }
    missing = []
    for name in planned.urls:
        archive = planned.archive(name)
        if planned.marker(name).exists():
            report["complete"].append(name)
        elif archive.exists():
            report["downloaded"].append(name)
        else:
            missing.append(name)
            part = _size(archive.with_suffix(archive.suffix + ".part"))
            if part:
                report["resume"][name] = part
    report["skipped"] = sorted(report["complete"] + report["downloaded"])
    return report, missing


def _ask_sizes(planned: Plan, options: FetchOptions, missing: list[str], report: dict[str, Any]) -> None:
    """HEAD each missing archive, ``options.jobs`` at a time, into ``to_fetch`` or ``failed``."""
    stop = threading.Event()  # set at the first NetworkUnreachable: every other HEAD would fail too

    def size(name: str) -> int | None:
        if stop.is_set():
            return None
        try:
            return _remote_size(planned.urls[name], options)
        except NetworkUnreachable:
            stop.set()
            raise

    with ThreadPoolExecutor(max_workers=max(1, options.jobs)) as pool:
        futures = [(n, pool.submit(size, n)) for n in missing]
        for name, future in futures:
            try:
                report["to_fetch"][name] = future.result()
            except NetworkUnreachable:  # not one archive's failure: the whole dry run's
                raise
            except DataError as exc:
                report["failed"][name] = str(exc)


def _print_dry_run(planned: Plan, report: dict[str, Any]) -> None:
    """The dry run's lines: the header, one line per archive, the total."""
    if planned.header:
        print(planned.header)
    for name in planned.urls:
        print(f"  {name:<34} {_dry_run_status(name, report)}")
    unknown = sum(s is None for s in report["to_fetch"].values())
    downloaded = len(report["downloaded"])
    print(
        f"{planned.label + ': ' if planned.label else ''}would fetch {len(report['to_fetch'])} archive(s), "
        f"{_human(report['total_bytes'])}{f' (+{unknown} of unknown size)' if unknown else ''}; "
        f"{len(report['complete'])} already complete"
        f"{f', {downloaded} downloaded and not yet extracted' if downloaded else ''}"
    )


def _dry_run_status(name: str, report: dict[str, Any]) -> str:
    """One archive's line of the dry run: what a real run would do with it."""
    if name in report["complete"]:
        return "complete (downloaded and extracted)"
    if name in report["downloaded"]:
        return "downloaded; would be verified and extracted"
    if name in report["failed"]:
        return "cannot be fetched (below)"
    nbytes, part = report["to_fetch"][name], report["resume"].get(name, 0)
    if nbytes is None:
        return "to fetch, size unknown"
    if part:
        return f"to fetch {_human(max(nbytes - part, 0))} of {_human(nbytes)} ({_human(part)} in its .part)"
    return f"to fetch, {_human(nbytes)}"


def dry_run_total(reports: Sequence[dict[str, Any]]) -> str:
    """The grand total line of several dry runs (e.g. the raw archives and KITTI 2015)."""
    fetch = sum(len(r["to_fetch"]) for r in reports)
    total = sum(r["total_bytes"] for r in reports)
    complete = sum(len(r["complete"]) for r in reports)
    downloaded = sum(len(r["downloaded"]) for r in reports)
    return (
        f"dry run, in all: would fetch {fetch} archive(s), {_human(total)}; {complete} already complete"
        f"{f', {downloaded} downloaded and not yet extracted' if downloaded else ''}; nothing was written"
    )


def _human(nbytes: int) -> str:
    size = float(nbytes)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if size < 1024 or unit == "GiB":
            return f"{size:.1f} {unit}" if unit != "B" else f"{nbytes} B"
        size /= 1024
    raise AssertionError("unreachable")
