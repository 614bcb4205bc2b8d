"""Monodepth2's split files of KITTI raw frames (``drive frame side`` per line) and their sequences.

A line such as ``2011_09_26/2011_09_26_drive_0022_sync 473 r`` names the frame
``<raw root>/2011_09_26/2011_09_26_drive_0022_sync/image_03/data/0000000473.png`` (``l`` = camera
2, ``r`` = camera 3; ``.jpg`` is accepted as well, see :func:`msdepth.data.kitti.resolve_image`).
Its source frames are the frames at the given offsets in the same drive and camera, and its stereo
partner the same frame of the other camera. Frames whose file or a neighbour's is missing are
skipped and counted, as Monodepth2's lists leave out a drive's first and last frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from ..errors import DataError
from .kitti import list_lines, resolve_image

CAMERAS = {"l": "image_02", "r": "image_03"}
OTHER_SIDE = {"l": "r", "r": "l"}


@dataclass(frozen=True)
class SplitEntry:
    """One line of a Monodepth2 split: drive folder (relative to the raw root), frame index, side."""

    drive: str
    frame: int
    side: str


@dataclass(frozen=True)
class SequenceSample:
    """A target frame, its source frames by offset, and its stereo partner (None if absent)."""

    target: Path
    sources: dict[int, Path]
    stereo: Path | None


@dataclass
class SequenceIndex:
    """The usable samples of a split, and how many of its lines were skipped and why."""

    samples: list[SequenceSample] = field(default_factory=list)
    missing_frame: int = 0  # the target frame's file is not on disk
    missing_neighbour: int = 0  # a source frame (or, when required, the stereo partner) is not


def read_mono_split(path: str | Path) -> list[SplitEntry]:
    """The entries of a Monodepth2 split file; a DataError names the file and line of a bad one."""
    entries = []
    for number, line, fields in list_lines(path, "no such split file"):
        if len(fields) != 3 or fields[2] not in CAMERAS or not fields[1].isdigit():
            raise DataError(
                f"{path}:{number}: expected 'drive frame side' (side l or r, frame a non-negative "
                f"integer), got {line.strip()!r}"
            )
        drive = fields[0].rstrip("/")
        if not drive or ".." in Path(drive).parts or Path(drive).is_absolute():
            raise DataError(f"{path}:{number}: drive {fields[0]!r} must be a folder below the raw root")
        entries.append(SplitEntry(drive, int(fields[1]), fields[2]))
    if not entries:
        raise DataError(f"{path}: split file lists no frames")
    return entries


def frame_path(raw_root: Path, drive: str, frame: int, side: str) -> Path | None:
    """The file of one KITTI raw frame (``.png`` or ``.jpg``), or None if it is not on disk."""
    if frame < 0:
        return None
    return resolve_image(Path(raw_root), f"{drive}/{CAMERAS[side]}/data/{frame:010d}.png")


def index_sequences(
    raw_root: str | Path,
    entries: Sequence[SplitEntry],
    offsets: Sequence[int] = (-1, 1),
    stereo: bool = False,
) -> SequenceIndex:
    """The samples of ``entries`` whose target and source frames (and, with ``stereo``, the stereo
    partner) are on disk below ``raw_root``; the others are counted in the result."""
    if 0 in offsets or not offsets:
        raise ValueError(f"index_sequences: offsets must be non-zero, got {list(offsets)}")
    index = SequenceIndex()
    for entry in entries:
        target = frame_path(Path(raw_root), entry.drive, entry.frame, entry.side)
        if target is None:
            index.missing_frame += 1
            continue
        sources = {o: frame_path(Path(raw_root), entry.drive, entry.frame + o, entry.side) for o in offsets}
        partner = frame_path(Path(raw_root), entry.drive, entry.frame, OTHER_SIDE[entry.side])
        if any(p is None for p in sources.values()) or (stereo and partner is None):
            index.missing_neighbour += 1
            continue
        index.samples.append(SequenceSample(target, sources, partner))  # type: ignore[arg-type]
    return index
