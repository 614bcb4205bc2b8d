"""Each data source has a tree of its own: no stage deletes or writes into a tree another source made.

The hostile situations of switching data.source without switching data.root: the renderer over
an extracted KITTI (it would delete raw/ and kitti2015/), and KITTI's download into the
synthetic set (real drives share two drive names with the synthetic ones, whose disp_02/ would
then pass for their GT).
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
from pathlib import Path

import pytest
from conftest import run_script, stage

from msdepth.config.params import SyntheticConfig, params_from_dict
from msdepth.data import owners
from msdepth.errors import DataError
from msdepth.io import TEMP_MARK
from msdepth.render import generate

prepare_data = stage("prepare_data").prepare_data

ROOT = Path(__file__).resolve().parents[1]
TINY = SyntheticConfig(seed=3, drives=1, train_pairs=2, eval_frames=1, height=24, width=80)
DRIVE = "2011_09_26/2011_09_26_drive_0001_sync"  # a real drive name that the synthetic set uses too


def _files(root: Path) -> dict[str, str]:
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def _kitti_tree(root: Path, markers: bool = True) -> dict[str, str]:
    """An extracted KITTI (one drive, KITTI 2015), with the download's markers unless not ``markers``."""
    (root / "raw" / DRIVE / "image_02" / "data").mkdir(parents=True)
    (root / "raw" / DRIVE / "image_02" / "data" / "0000000000.png").write_bytes(b"a real KITTI frame")
    (root / "raw" / "2011_09_26" / "calib_cam_to_cam.txt").write_text("real calibration\n")
    (root / "kitti2015" / "training" / "image_2").mkdir(parents=True)
    (root / "kitti2015" / "training" / "image_2" / "000000_10.png").write_bytes(b"a KITTI 2015 frame")
    if markers:
        (root / "raw" / ".2011_09_26_drive_0001_sync.zip.complete").write_text("{}\n")
        (root / "kitti2015" / ".data_scene_flow.zip.complete").write_text("{}\n")
    return _files(root)


def test_renderer_refuses_an_extracted_kitti(tmp_path: Path) -> None:
    root = tmp_path / "data" / "kitti"
    before = _kitti_tree(root)
    with pytest.raises(
        DataError,
        match="^" + re.escape(f"{root}: holds KITTI's download (kitti2015/.data_scene_flow.zip.complete)"),
    ):
        generate(TINY, root, progress=False, workers=1)
    assert _files(root) == before


def test_renderer_refuses_a_tree_it_did_not_write(tmp_path: Path) -> None:
    """KITTI extracted by hand (no markers), or any other files: not the renderer's to delete."""
    root = tmp_path / "data" / "kitti"
    before = _kitti_tree(root, markers=False)
    with pytest.raises(
        DataError, match=rf"^{re.escape(str(root))}: holds files the synthetic renderer did not write"
    ):
        generate(TINY, root, progress=False, workers=1)
    assert _files(root) == before


def test_renderer_refuses_a_file_as_its_root(tmp_path: Path) -> None:
    (tmp_path / "data").write_text("a user's file")
    with pytest.raises(DataError, match="^" + re.escape(f"{tmp_path / 'data'}: is a file, not a folder")):
        generate(TINY, tmp_path / "data", progress=False, workers=1)
    assert (tmp_path / "data").read_text() == "a user's file"


def test_renderer_refuses_kitti_extracted_into_its_own_tree(tmp_path: Path) -> None:
    """Today's mixture (KITTI downloaded into the synthetic set) is no longer the renderer's alone."""
    root = tmp_path / "mixed"
    generate(TINY, root, progress=False, workers=1)
    (root / "raw" / ".2011_09_26_drive_0001_sync.zip.complete").write_text("{}\n")
    before = _files(root)
    with pytest.raises(DataError, match="holds KITTI's download"):
        generate(TINY, root, progress=False, workers=1)
    assert _files(root) == before


def test_renderer_replaces_its_own_tree_also_after_an_interruption(tmp_path: Path) -> None:
    root = tmp_path / "synthetic"
    generate(TINY, root, progress=False, workers=1)
    first = _files(root)
    assert owners.SUMMARY in first and owners.RENDERING not in first
    # Killed during a rerender: the summary not yet rewritten, a stale frame left behind.
    (root / owners.SUMMARY).unlink()
    (root / owners.RENDERING).write_text("")
    (root / "raw" / DRIVE / "stale.png").write_bytes(b"left by the killed render")
    generate(TINY, root, progress=False, workers=1)
    assert _files(root) == first


def test_renderer_removes_the_temp_files_a_killed_render_left(tmp_path: Path) -> None:
    """raw/ and kitti2015/ are replaced whole; at the root, only names of the writers' temp scheme go."""
    root = tmp_path / "synthetic"
    generate(TINY, root, progress=False, workers=1)
    first = _files(root)
    names = [p.name for p in root.iterdir() if p.is_file()] + [owners.RENDERING]
    temps = []
    for name in names:  # as io.atomic_path names them (mkstemp)
        fd, tmp = tempfile.mkstemp(prefix=f".{name}{TEMP_MARK}", suffix=Path(name).suffix, dir=root)
        os.close(fd)
        temps.append(Path(tmp))
    (root / "raw" / DRIVE / f".0000000001.png{TEMP_MARK}k1ll3d_9.png").write_bytes(b"half a frame")
    (root / ".rois.csv.keep-me").write_text("a user's file")
    generate(TINY, root, progress=False, workers=1)
    assert not [t for t in temps if t.exists()]
    assert _files(root) == {**first, ".rois.csv.keep-me": _files(root)[".rois.csv.keep-me"]}


def _kitti_params(root: Path, tmp_path: Path) -> object:
    """data.source kitti on ``root``, from a mirror that cannot be reached (nothing may be fetched)."""
    (tmp_path / "archives.txt").write_text("raw_data/2011_09_26_calib.zip\n")
    split = f"{DRIVE}/image_02/data/0000000000.png {DRIVE}/image_03/data/0000000000.png\n"
    (tmp_path / "train.txt").write_text(split)
    return params_from_dict(
        {
            "data": {
                "source": "kitti",
                "root": str(root),
                "kitti": {
                    "base_url": "http://127.0.0.1:9/",
                    "allow_http": True,
                    "archive_list": str(tmp_path / "archives.txt"),
                    "train_split": str(tmp_path / "train.txt"),
                    "download_dir": str(tmp_path / "downloads"),
                },
            },
            "eval": {"extra_sets": []},
        }
    )


@pytest.mark.parametrize("dry_run", [False, True])
def test_kitti_download_refuses_the_synthetic_tree(tmp_path: Path, dry_run: bool) -> None:
    root = tmp_path / "data" / "synthetic"
    generate(TINY, root, progress=False, workers=1)
    assert (root / "raw" / DRIVE / "disp_02").is_dir()  # what would pass for the real drive's GT
    before = _files(root)
    with pytest.raises(
        DataError, match=rf"^{re.escape(str(root))}: holds the synthetic set \(synthetic\.json\): KITTI needs"
    ):
        prepare_data(_kitti_params(root, tmp_path), dry_run=dry_run)
    assert _files(root) == before and not (tmp_path / "downloads").exists()


def test_kitti_download_refuses_an_interrupted_render(tmp_path: Path) -> None:
    root = tmp_path / "data" / "synthetic"
    root.mkdir(parents=True)
    (root / owners.RENDERING).write_text("")
    with pytest.raises(DataError, match=rf"holds the synthetic set \({owners.RENDERING}\)"):
        prepare_data(_kitti_params(root, tmp_path))


def test_the_stage_refuses_in_one_line_naming_the_root(tmp_path: Path) -> None:
    """data.source synthetic where KITTI was extracted: exit 1 and one line, also in a dry run."""
    before = _kitti_tree(tmp_path / "data" / "kitti")
    (tmp_path / "params.yaml").write_text("data: {source: synthetic, root: data/kitti}\n")
    for args in ([], ["--dry-run"]):
        proc = run_script("stages/prepare_data.py", *args, cwd=tmp_path)
        assert proc.returncode == 1, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and "data/kitti: holds KITTI's download" in lines[0], proc.stderr
    assert _files(tmp_path / "data" / "kitti") == before


def test_defaults_give_each_source_its_own_tree() -> None:
    """params.yaml's data.root is the synthetic set's own; KITTI's documented root differs."""
    params = params_from_dict({})
    assert params.data.source == "synthetic" and params.data.root == "data/synthetic"
    text = (ROOT / "params.yaml").read_text()
    assert "  root: data/synthetic " in text and "data/kitti (kitti)" in text
