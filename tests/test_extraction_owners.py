"""One KITTI archive cannot replace another's files (issue 42, case 11): a member that would replace
a file another archive wrote, or a file no archive wrote, is refused in one line with nothing
changed; the KITTI download refuses a stereo folder's tree (data.source: folder)."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import pytest

from msdepth.data import owners
from msdepth.download import extraction
from msdepth.errors import DataError

CALIB = "2011_09_26/calib_cam_to_cam.txt"
FRAME = "2011_09_26/2011_09_26_drive_0001_sync/image_02/data/0000000000.png"


def _zip(path: Path, members: dict[str, str]) -> Path:
    with zipfile.ZipFile(path, "w") as zf:
        for name, text in members.items():
            zf.writestr(name, text)
    return path


def _tree(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("member", [CALIB, FRAME])
def test_a_later_archive_cannot_replace_an_earlier_ones_file(tmp_path: Path, member: str) -> None:
    # Case 11: a later archive replaced 2011_09_26/calib_cam_to_cam.txt and an image of an already
    # extracted drive, whose marker still said complete.
    raw = tmp_path / "raw"
    first = _zip(tmp_path / "2011_09_26_calib.zip", {CALIB: "real calibration\n", FRAME: "real frame"})
    assert extraction.extract(first, raw)
    before = _tree(raw)
    later = _zip(tmp_path / "2011_09_26_drive_0002_sync.zip", {"2011_09_26/new.txt": "x", member: "forged"})
    with pytest.raises(DataError) as err:
        extraction.extract(later, raw)
    assert str(err.value) == (
        f"{later}: member {member!r} would replace {raw / member} (written by 2011_09_26_calib.zip); "
        "refusing to extract, nothing was changed"
    )
    assert _tree(raw) == before  # not even the new member, nor a marker


def test_a_file_no_archive_wrote_is_not_replaced(tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    (raw / "2011_09_26").mkdir(parents=True)
    (raw / CALIB).write_text("the user's own\n")
    archive = _zip(tmp_path / "c.zip", {CALIB: "forged"})
    with pytest.raises(DataError, match=r"c.zip: member .* \(a file no KITTI archive wrote here\)"):
        extraction.extract(archive, raw)
    assert (raw / CALIB).read_text() == "the user's own\n"
    assert sorted(p.name for p in raw.iterdir()) == ["2011_09_26"]


def test_the_jpeg_a_png_member_becomes_is_checked_too(tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    (raw / "2011_09_26").mkdir(parents=True)
    (raw / "2011_09_26" / "a.jpg").write_bytes(b"the user's")
    archive = _zip(tmp_path / "d.zip", {"2011_09_26/a.png": "png"})
    with pytest.raises(DataError, match=r"member '2011_09_26/a.jpg' would replace"):
        extraction.extract(archive, raw, jpeg=True)


def test_an_archive_may_replace_its_own_files_and_its_marker_lists_them(tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    archive = _zip(tmp_path / "c.zip", {CALIB: "v1"})
    assert extraction.extract(archive, raw)
    marker = raw / ".c.zip.complete"
    assert json.loads(marker.read_text())["files"] == [CALIB]
    assert extraction._file_owners(raw) == {CALIB: "c.zip"}
    # A run killed mid-move: the pending record still says whose the moved files are.
    marker.rename(raw / ".c.zip.pending")
    assert extraction.extract(_zip(archive, {CALIB: "v2"}), raw)
    assert (raw / CALIB).read_text() == "v2" and not (raw / ".c.zip.pending").exists()


@pytest.mark.parametrize("mark", owners.FOLDER_MARKS)
def test_the_kitti_download_refuses_a_stereo_folder(tmp_path: Path, mark: str) -> None:
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / mark).write_text("focal_px: 700\n")
    with pytest.raises(DataError) as err:
        owners.check_kitti_root(tmp_path / "mine")
    assert str(err.value) == (
        f"{tmp_path / 'mine'}: holds a stereo folder (data.source: folder) ({mark}): KITTI needs a "
        "data.root of its own (e.g. data/kitti); nothing was written"
    )
