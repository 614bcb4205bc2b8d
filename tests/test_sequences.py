"""Monodepth2 split files over a tiny KITTI raw tree that the test writes."""

from __future__ import annotations

from pathlib import Path

import pytest

from msdepth.data.sequences import SplitEntry, _index_sequences, _read_mono_split
from msdepth.errors import DataError

DRIVE = "2011_09_26/2011_09_26_drive_0001_sync"
OTHER = "2011_09_26/2011_09_26_drive_0002_sync"


def _tree(root: Path) -> None:
    """Drive 1: left frames 0-4 (png), right frames 0-3 (jpg); drive 2: left frames 5-6."""
    for drive, camera, frames, ext in (
        (DRIVE, "image_02", range(5), "png"),
        (DRIVE, "image_03", range(4), "jpg"),
        (OTHER, "image_02", (5, 6), "png"),
    ):
        folder = root / drive / camera / "data"
        folder.mkdir(parents=True, exist_ok=True)
        for f in frames:
            (folder / f"{f:010d}.{ext}").write_bytes(b"x")


def test_read_split(tmp_path: Path) -> None:
    split = tmp_path / "train_files.txt"
    split.write_text(f"{DRIVE} 1 l\n\n{OTHER}/ 6 r\n")
    assert _read_mono_split(split) == [SplitEntry(DRIVE, 1, "l"), SplitEntry(OTHER, 6, "r")]


@pytest.mark.parametrize(
    ("line", "message"),
    [
        (f"{DRIVE} 1", "expected 'drive frame side'"),
        (f"{DRIVE} 1 x", "expected 'drive frame side'"),
        (f"{DRIVE} -1 l", "expected 'drive frame side'"),
        ("../elsewhere 1 l", "must be a folder below the raw root"),
        ("/abs/drive 1 l", "must be a folder below the raw root"),
    ],
)
def test_bad_lines_name_file_and_line(tmp_path: Path, line: str, message: str) -> None:
    split = tmp_path / "split.txt"
    split.write_text(f"{DRIVE} 1 l\n{line}\n")
    with pytest.raises(DataError, match=rf"split\.txt:2: .*{message}"):
        _read_mono_split(split)


def test_empty_or_missing_split_is_refused(tmp_path: Path) -> None:
    (tmp_path / "empty.txt").write_text("\n")
    with pytest.raises(DataError, match="empty.txt: split file lists no frames"):
        _read_mono_split(tmp_path / "empty.txt")
    with pytest.raises(DataError, match="absent.txt: no such split file"):
        _read_mono_split(tmp_path / "absent.txt")


def test_frames_without_both_neighbours_are_skipped_and_counted(tmp_path: Path) -> None:
    _tree(tmp_path)
    entries = [
        SplitEntry(DRIVE, 0, "l"),  # no frame -1
        SplitEntry(DRIVE, 1, "l"),  # ok
        SplitEntry(DRIVE, 3, "l"),  # ok
        SplitEntry(DRIVE, 4, "l"),  # no frame 5 in this drive (drive 2's frame 5 does not count)
        SplitEntry(DRIVE, 9, "l"),  # no such frame
        SplitEntry(DRIVE, 2, "r"),  # ok, right camera, jpg
        SplitEntry(OTHER, 6, "l"),  # no frame 7
    ]
    index = _index_sequences(tmp_path, entries)
    assert (index.missing_frame, index.missing_neighbour) == (1, 3)
    targets = [s.target.relative_to(tmp_path).as_posix() for s in index.samples]
    assert targets == [
        f"{DRIVE}/image_02/data/0000000001.png",
        f"{DRIVE}/image_02/data/0000000003.png",
        f"{DRIVE}/image_03/data/0000000002.jpg",
    ]
    first = index.samples[0]
    assert {o: p.name for o, p in first.sources.items()} == {-1: "0000000000.png", 1: "0000000002.png"}
    assert first.stereo == tmp_path / DRIVE / "image_03" / "data" / "0000000001.jpg"


def test_stereo_partner_required_in_mono_stereo(tmp_path: Path) -> None:
    _tree(tmp_path)
    entries = [SplitEntry(DRIVE, 3, "l"), SplitEntry(DRIVE, 2, "l")]  # right frame 3 exists, 4 not needed
    assert len(_index_sequences(tmp_path, entries, stereo=True).samples) == 2
    late = [SplitEntry(DRIVE, 3, "l")]
    # With offsets (-2, +1) frame 3 needs 1 and 4: present; its partner (right 3) is present too.
    assert len(_index_sequences(tmp_path, late, offsets=(-2, 1), stereo=True).samples) == 1
    # Left frame 4's partner (right 4) is missing: skipped in stereo, kept without.
    entry = [SplitEntry(DRIVE, 4, "l")]
    assert _index_sequences(tmp_path, entry, offsets=(-1,), stereo=True).missing_neighbour == 1
    assert _index_sequences(tmp_path, entry, offsets=(-1,)).samples[0].stereo is None
    with pytest.raises(ValueError, match="non-zero"):
        _index_sequences(tmp_path, entry, offsets=(0,))
