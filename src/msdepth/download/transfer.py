"""HTTP: one archive downloaded, resumable and retrying.

:func:`download` streams to ``<archive>.part`` and resumes it with an HTTP ``Range`` request; the final
name appears only when the size is right. The size is declared (HEAD and GET must agree), nothing
past it is kept, and an attempt slower than :data:`MIN_RATE` is cut off. Only https is fetched unless
plain http is allowed (``allow_http``, for a trusted mirror), and a redirect never leaves https, nor
goes to another scheme. A host that cannot be reached at all (no name resolution, connection
refused, no route) is not retried: :class:`NetworkUnreachable`.

Standard library only (``urllib``); tqdm for progress bars."""

from __future__ import annotations

import errno
import http.client
import os
import re
import socket
import time
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from msdepth.download.sizes import CHUNK_SIZE, file_size
from msdepth.errors import DataError

MAX_BACKOFF_S = 60.0
USER_AGENT = "msdepth-kitti-download"
# An attempt that brings fewer than MIN_RATE bytes/s over RATE_WINDOW_S seconds is cut off and
# counts as a failed retry even though it made progress: a server dripping bytes (or a stalled
# link) never trips the per-read timeout. 10 KiB/s is ~1/1000 of a home link; a 4 GB archive
# at that rate would still take 5 days. Lower FetchOptions.min_rate for a slower link.
MIN_RATE = 10 * 1024
RATE_WINDOW_S = 60.0

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
    not retried, and it stops :func:`fetching.fetch_all` as a whole."""


def _unreachable(reason: object) -> bool:
    return isinstance(reason, (socket.gaierror, ConnectionRefusedError)) or (
        isinstance(reason, OSError) and reason.errno in _UNREACHABLE_ERRNOS
    )


@dataclass(frozen=True)
class FetchOptions:
    """How archives are fetched: one object, shared by every :func:`fetching.fetch_all` call of a run.

    ``jobs`` archives at a time; ``dry_run`` writes nothing (:func:`fetching.dry_run`); ``jpeg`` converts
    the PNGs on extraction (:func:`extraction.extract`); ``progress`` shows bars; ``retries``, ``backoff``
    (seconds, doubled per retry) and ``timeout`` (seconds per read) as :func:`download` uses them;
    an attempt slower than ``min_rate`` bytes/s over ``rate_window`` seconds is cut off (see
    :data:`MIN_RATE`); ``allow_http`` lets plain http through, for a mirror you trust
    (:func:`check_url`).
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


def check_url(url: str, allow_http: bool = False) -> None:
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
    A URL that :func:`check_url` refuses, a redirect that :class:`NoDowngradeRedirect` refuses,
    or a redirect to a host that cannot be reached, is a DataError (that archive's alone).
    """
    check_url(url, allow_http)
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
    offset = file_size(part)
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
    received = file_size(part)
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
    ``expected_size`` (HEAD's, as :func:`fetching.fetch` passes it) if given; a download whose size
    neither gives is refused, and nothing past the size is kept. Only a complete ``.part`` is
    renamed to ``dest``, so an existing ``dest`` is taken as complete. ``on_bytes`` is called
    with each chunk's length (for an overall count). Only https is fetched, http too with
    ``options.allow_http`` (:func:`check_url`); nothing is written for a refused URL.
    """
    dest = Path(dest)
    if dest.exists():
        return dest
    check_url(url, options.allow_http)
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
        before = file_size(part)
        try:
            _attempt(url, part, expected, options, bar, on_bytes)
            return
        except (_Transient, *_TRANSIENT_ERRORS) as exc:
            progressed = file_size(part) > before and not isinstance(exc, _TooSlow)
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


def remote_size(url: str, options: FetchOptions = FetchOptions()) -> int | None:
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


def probe(url: str, options: FetchOptions) -> None:
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
