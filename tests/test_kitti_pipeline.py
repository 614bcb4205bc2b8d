"""`data.source: kitti` end to end: `dvc repro` downloads KITTI-shaped archives from a local
HTTP server, extracts them, indexes the shipped-style splits, finds car ROIs in obj_map and runs
every stage through the evaluation suites. No test touches the internet."""

from __future__ import annotations

import functools
import http.server
import json
import sys
import threading
import zipfile
from pathlib import Path

import pytest
from test_pipeline_e2e import _project, _run

from msdepth.config import SyntheticConfig
from msdepth.data import synthetic
from msdepth.data.download import KITTI_BASE_URL

SYN = SyntheticConfig(seed=4, drives=2, train_pairs=12, eval_frames=3, height=48, width=160)


def _zip_tree(zip_path: Path, root: Path, members: list[Path]) -> None:
    zip_path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(zip_path, "w") as zf:
        for member in members:
            for f in sorted(member.rglob("*")) if member.is_dir() else [member]:
                if f.is_file():
                    zf.write(f, f.relative_to(root).as_posix())


@pytest.fixture(scope="module")
def mirror(tmp_path_factory):
    """A KITTI mirror on 127.0.0.1: raw drive and calibration archives, data_scene_flow.zip, lists."""
    tree = tmp_path_factory.mktemp("tree")
    synthetic.generate(SYN, tree, progress=False, workers=1)
    served = tmp_path_factory.mktemp("served")
    raw = tree / "raw"
    urls = []
    for day in sorted(p for p in raw.iterdir() if p.is_dir()):
        _zip_tree(served / "raw_data" / f"{day.name}_calib.zip", raw, [day / "calib_cam_to_cam.txt"])
        urls.append(f"raw_data/{day.name}_calib.zip")
        for drive in sorted(day.glob("*_sync")):
            name = drive.name.removesuffix("_sync")
            _zip_tree(served / "raw_data" / name / f"{drive.name}.zip", raw, [drive])
            urls.append(f"raw_data/{name}/{drive.name}.zip")
    _zip_tree(served / "data_scene_flow.zip", tree / "kitti2015", [tree / "kitti2015" / "training"])
    lists = tmp_path_factory.mktemp("lists")
    (lists / "archives.txt").write_text("".join(KITTI_BASE_URL + u + "\n" for u in urls))
    (lists / "train.txt").write_text((tree / "train_files.txt").read_text())
    (lists / "eval.txt").write_text(
        (tree / "kitti2015" / "test_files.txt").read_text().replace(".png", ".jpg")
    )
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(served))
    handler.log_message = lambda *a, **k: None
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_address[1]}/", lists, len(urls)
    server.shutdown()


def test_kitti_source_runs_every_stage(mirror, tmp_path: Path) -> None:
    base_url, lists, archives = mirror
    work = _project(
        tmp_path,
        {
            "data": {
                "source": "kitti",
                "kitti": {
                    "base_url": base_url,
                    "allow_http": True,  # the local mirror speaks plain http
                    "archive_list": str(lists / "archives.txt"),
                    "jobs": 2,
                    "train_split": str(lists / "train.txt"),
                    "eval_split": str(lists / "eval.txt"),
                    "roi_min_size": 4,
                    "roi_min_valid": 0.2,
                },
            }
        },
    )
    _run([sys.executable, "-m", "dvc", "repro", "--quiet"], work)
    manifest = json.loads((work / "data" / "downloads" / "manifest.json").read_text())
    assert len(manifest["archives"]) == archives + 1  # raw archives and data_scene_flow.zip
    report = json.loads((work / "data" / "index" / "report.json").read_text())
    assert report["source"] == "kitti" and report["train_pairs_found"] == SYN.train_pairs
    assert report["eval_frames"] == SYN.eval_frames  # the .jpg names resolved to the .png files
    rois = (work / "data" / "index" / "rois.csv").read_text().splitlines()
    assert len(rois) > 1 and all(",car," in line for line in rois[1:])  # cars from obj_map
    assert (work / "data" / "index" / "rois.png").stat().st_size > 1000
    for suite in ("full", "roi", "gradients"):
        data = json.loads((work / "metrics" / suite / "msssim" / "seed0.json").read_text())
        assert "cap80" in data
    assert _run([sys.executable, "-m", "dvc", "status", "--quiet"], work) == ""
