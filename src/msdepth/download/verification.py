"""A downloaded archive verified: every member's CRC read once (:func:`_verify_zip`), and
``manifest.json`` in the download folder recording the sha256 of each archive once verified, which
later runs compare against (:func:`verify_archive`)."""

from __future__ import annotations

import os
import threading
import zipfile
import zlib
from pathlib import Path
from typing import Any

from msdepth.download.extraction import check_members
from msdepth.download.sizes import CHUNK_SIZE, file_size
from msdepth.errors import DataError
from msdepth.io import write_json
from msdepth.readers import file_sha256, read_json_file

MANIFEST_NAME = "manifest.json"


def _verify_zip(path: str | os.PathLike) -> None:
    """Check that ``path`` is a readable zip whose every member decompresses with the right CRC.

    This is ``ZipFile.testzip()``'s loop, but catching every way a damaged member fails (a bad
    deflate stream raises zlib.error, which testzip lets through without the member's name).
    Members that :func:`extraction.check_members` refuses fail first, before anything is decompressed.
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
        check_members(zf, path)  # a zip bomb is not even decompressed
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


def verify_archive(path: Path, manifest: Manifest, url: str = "") -> None:
    """Compare ``path`` with its manifest record, or verify it and record it if it has none.

    A mismatch or a damaged zip moves the archive aside (see :func:`_set_aside`), drops its
    record and raises DataError naming it.
    """
    entry = manifest.get(path.name)
    if entry is not None:
        size, sha = file_size(path), file_sha256(path, "archive")
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
    manifest.record(path.name, {"size": file_size(path), "sha256": file_sha256(path, "archive"), "url": url})
