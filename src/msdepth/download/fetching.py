"""Download, verify and unpack many KITTI raw archives: parallel, reported per archive.

The shipped list (``data_lists/kitti_archives_to_download.txt``) names 66 archives of a few GB each
on a public S3 bucket. Over a slow or flaky link a download must survive resets and restarts
without starting over, and a killed run must never leave something that a later run takes for
complete. :func:`fetch_all` does that for many archives in parallel: :func:`plan` checks the list,
then :func:`fetch` or :func:`dry_run` runs it, all with one :class:`transfer.FetchOptions`. Each
archive goes through :func:`transfer.download`, :func:`verification.verify_archive` and
:func:`extraction.extract`. A host that cannot be reached at all stops every archive with one line
(:class:`transfer.NetworkUnreachable`)."""

from __future__ import annotations

import os
import threading
import urllib.parse
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from msdepth.download.extraction import completion_marker, extract, pending_record
from msdepth.download.lists import archive_filename, entry_problem
from msdepth.download.sizes import file_size, human_size
from msdepth.download.transfer import (
    FetchOptions,
    NetworkUnreachable,
    check_url,
    download,
    probe,
    remote_size,
)
from msdepth.download.verification import MANIFEST_NAME, Manifest, verify_archive
from msdepth.errors import DataError
from msdepth.io import atomic_temps

_DEFAULTS = FetchOptions()  # one frozen default for the functions' ``options``


class DownloadError(DataError):
    """One or more archives of :func:`fetch_all` failed; ``report`` holds the per-archive result."""

    def __init__(self, message: str, report: dict[str, Any]) -> None:
        super().__init__(message)
        self.report = report


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
        """The completion marker :func:`extraction.extract` writes for archive ``name``."""
        return completion_marker(self.archive(name), self.extract_dir)


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
    """Resolve ``names`` (URL paths relative to ``base_url``, as :func:`lists.parse_archive_list`
    returns them; absolute URLs are used as they are) and check them before anything is fetched.

    Every entry must name a plain ``<name>.zip`` (no query or fragment, see
    :func:`lists.entry_problem`), every URL must be https, or http with ``allow_http``
    (:func:`transfer.check_url`), and no two entries may download to the same file: the first entry
    refused is a DataError, and nothing is asked or written. One bad entry stops the whole list:
    the list itself is wrong, and its other entries are suspect too.
    """
    if not base_url.endswith("/"):
        base_url += "/"  # urljoin would otherwise drop the last component of the base
    for name in names:
        problem = entry_problem(name)
        if problem:
            raise DataError(f"archive {name!r}: {problem}")
    urls = {archive_filename(n): urllib.parse.urljoin(base_url, n) for n in names}
    if len(urls) != len(names):
        raise DataError("fetch_all: two archives in the list share a file name")
    for url in urls.values():
        check_url(url, allow_http)
    return Plan(urls, Path(download_dir), Path(extract_dir), label, header)


def fetch_all(
    base_url: str,
    names: Sequence[str],
    download_dir: str | os.PathLike,
    extract_dir: str | os.PathLike,
    options: FetchOptions = _DEFAULTS,
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


def fetch(planned: Plan, options: FetchOptions = _DEFAULTS) -> dict[str, Any]:
    """Download, verify and extract the planned archives, ``options.jobs`` at a time.

    An archive already downloaded and matching the manifest is not fetched again; one already
    extracted is not extracted again. One archive's failure does not stop the others; at the end a
    :class:`DownloadError` (a DataError) lists the failures and carries the report. The report:
    ``fetched``, ``skipped`` (already there and verified), ``extracted``, ``failed`` (name ->
    reason), ``bytes_downloaded``.

    Each archive to download is asked its size with a HEAD first, and the GET must agree with it
    (:func:`transfer.download`). A host that cannot be reached at all stops everything with one
    :class:`transfer.NetworkUnreachable`: before anything is written when there is something to fetch
    (one HEAD request probes the host first), or at the first such error later (the network went
    away mid-run). A redirect to a host that cannot be reached fails that archive alone.
    """
    to_download = [
        name
        for name in planned.urls
        if not planned.archive(name).exists() and not planned.marker(name).exists()
    ]
    if to_download:  # a complete tree needs no network: probe only when something must be fetched
        probe(planned.urls[to_download[0]], options)
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
            size = remote_size(url, self.options)
            download(url, archive, self.options, expected_size=size, on_bytes=self._count)
        try:
            verify_archive(archive, self.manifest, url)
        except DataError:
            # The archive was set aside: forget its extraction too, so that the next run fetches
            # and unpacks it again rather than taking the deleted archive for "extracted, removed".
            # Its files stay its own (the marker becomes its pending record), so that extraction may
            # replace them and no other archive may.
            if marker.exists():
                os.replace(marker, pending_record(archive, self.plan.extract_dir))
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


def dry_run(planned: Plan, options: FetchOptions = _DEFAULTS) -> dict[str, Any]:
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
            part = file_size(archive.with_suffix(archive.suffix + ".part"))
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
            return remote_size(planned.urls[name], options)
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
        f"{human_size(report['total_bytes'])}{f' (+{unknown} of unknown size)' if unknown else ''}; "
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
        left = human_size(max(nbytes - part, 0))
        return f"to fetch {left} of {human_size(nbytes)} ({human_size(part)} in its .part)"
    return f"to fetch, {human_size(nbytes)}"


def dry_run_total(reports: Sequence[dict[str, Any]]) -> str:
    """The grand total line of several dry runs (e.g. the raw archives and KITTI 2015)."""
    fetch = sum(len(r["to_fetch"]) for r in reports)
    total = sum(r["total_bytes"] for r in reports)
    complete = sum(len(r["complete"]) for r in reports)
    downloaded = sum(len(r["downloaded"]) for r in reports)
    return (
        f"dry run, in all: would fetch {fetch} archive(s), {human_size(total)}; {complete} already complete"
        f"{f', {downloaded} downloaded and not yet extracted' if downloaded else ''}; nothing was written"
    )
