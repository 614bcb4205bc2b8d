"""The archive list and the split lists: which KITTI raw archives to fetch.

:func:`parse_archive_list` reads and checks the list of archives (one ``<name>.zip`` URL per line),
:func:`select_needed` picks the archives that the chosen split lists need (their drives and those
days' calibration archives), :func:`_select_archives` a count or named drives of a list."""

from __future__ import annotations

import os
import urllib.parse
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from msdepth.errors import DataError
from msdepth.readers import read_bounded

# The host every entry of the shipped list starts with; entries are kept relative to it so that a
# mirror (or a test server) can be used by passing another base URL to fetch_all.
KITTI_BASE_URL = "https://s3.eu-central-1.amazonaws.com/avg-kitti/"

# What the list readers read at most (msdepth.readers.read_bounded: a FIFO would block a plain read
# forever, a huge file would be read whole). The archive list: the shipped one is 66 URLs, 7 KB;
# the bound holds ~10,000 of them. The split lists: msdepth.data.kitti.MAX_LIST_BYTES, which the
# index stage reads the same lists with (test_reader_bounds holds the two equal); not imported from
# there so that the download imports neither OpenCV nor pandas.
MAX_ARCHIVE_LIST_BYTES = 1 << 20
MAX_SPLIT_LIST_BYTES = 64 << 20


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
        problem = entry_problem(entry)
        if problem:
            raise DataError(f"{path}:{number}: archive {entry!r}: {problem}")
        name = archive_filename(entry)
        if name in seen:
            # Two entries would download to the same file, concurrently.
            raise DataError(f"{path}:{number}: archive {name} is listed twice (first on line {seen[name]})")
        seen[name] = number
        names.append(entry)
    if not names:
        raise DataError(f"{path}: no archives listed")
    return names


def archive_filename(name: str) -> str:
    """The file name an archive entry downloads to (last component of its URL path)."""
    return PurePosixPath(urllib.parse.urlsplit(name).path).name


def entry_problem(entry: str) -> str | None:
    """Why ``entry`` of an archive list cannot be fetched safely, or None.

    Its file name is what the download folder, the manifest and the completion marker are keyed
    by, so it must be a plain ``<name>.zip``: not empty, ``.`` or ``..`` (which would name the
    download folder or its parent), not a dot-file, and not hidden behind a query or fragment
    (``x/?.zip`` ends in ``.zip`` but names the folder ``x/``).
    """
    if "?" in entry or "#" in entry:
        return "has a query or fragment ('?' or '#'); list the archive's own URL"
    name = archive_filename(entry)
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
    drives = [n for n in names if "_drive_" in archive_filename(n)]
    if isinstance(subset, bool) or not isinstance(subset, (int, str, Iterable)):
        raise DataError(f"archive subset: expected 'all', a count or drive names, got {subset!r}")
    if isinstance(subset, int):
        if subset < 0:
            raise DataError(f"archive subset: the number of drives must be >= 0, got {subset}")
        chosen = set(drives[:subset])
    else:
        if isinstance(subset, str):
            subset = [subset]
        by_drive = {_drive_of(archive_filename(n)): n for n in names}
        wanted = [_drive_of(str(s).strip()) for s in subset]
        unknown = [w for w in wanted if w not in by_drive]
        if unknown:
            raise DataError(f"archive subset: not in the archive list: {', '.join(unknown)}")
        chosen = {by_drive[w] for w in wanted}
    days = {_date_of(archive_filename(n)) for n in chosen}
    calib = {
        n
        for n in names
        if archive_filename(n).endswith("_calib.zip") and _date_of(archive_filename(n)) in days
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
    drive_of = {n: _drive_of(archive_filename(n)) for n in names if "_drive_" in archive_filename(n)}
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
