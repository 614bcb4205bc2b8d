"""`data.source: kitti` end to end: `dvc repro` downloads KITTI-shaped archives from a local
HTTP server, extracts them, indexes the shipped-style splits, finds car ROIs in obj_map and runs
every stage, baselines, comparison and figures included. No test touches the internet.

The archives hold exactly what KITTI's do (see :mod:`kitti_mirror`): raw drives without the
synthetic set's ``disp_02``, so the baselines' training GT must come from the Velodyne scans as
on real KITTI. One mirror is built from the renderer's output, one from the real sample in
``../shared`` (skipped without it).
"""

from __future__ import annotations

import contextlib
import functools
import http.server
import json
import sys
import threading
import zipfile
from pathlib import Path
from typing import Iterator

import kitti_mirror
import pytest
from conftest import UP_TO_DATE, dvc_status, project, run_checked

from msdepth import render
from msdepth.config.params import SyntheticConfig
from msdepth.download.lists import KITTI_BASE_URL
from msdepth.reporting.figures import STAGE_FIGURES

# The tests here run DVC on copied projects: the second tier (`-m slow`).
pytestmark = pytest.mark.slow

SYN = SyntheticConfig(seed=4, drives=2, train_pairs=12, eval_frames=3, height=48, width=160)
REAL = Path(__file__).resolve().parents[2] / "shared" / "real-samples" / "kitti-object-pair"
# What KITTI's archives never hold: the synthetic set's own files.
SYNTHETIC_ONLY = ("disp_02", "class_map", "rois.csv", "synthetic.json", "train_files.txt", "test_files.txt")


def _zip_tree(zip_path: Path, root: Path, members: list[Path]) -> None:
    zip_path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(zip_path, "w") as zf:
        for member in members:
            for f in sorted(member.rglob("*")) if member.is_dir() else [member]:
                if f.is_file():
                    zf.write(f, f.relative_to(root).as_posix())


def _archives(tree: Path, served: Path) -> list[str]:
    """Zip a KITTI-shaped ``tree`` as KITTI ships it: per day a calibration archive, per drive an
    archive, and data_scene_flow.zip. Returns the raw archives' URLs relative to the base URL."""
    raw, urls = tree / "raw", []
    for day in sorted(p for p in raw.iterdir() if p.is_dir()):
        calib = sorted(day.glob("calib_*.txt"))
        assert [p.name for p in calib] == [
            "calib_cam_to_cam.txt",
            "calib_imu_to_velo.txt",
            "calib_velo_to_cam.txt",
        ]
        _zip_tree(served / "raw_data" / f"{day.name}_calib.zip", raw, calib)
        urls.append(f"raw_data/{day.name}_calib.zip")
        for drive in sorted(day.glob("*_sync")):
            name = drive.name.removesuffix("_sync")
            assert sorted(p.name for p in drive.iterdir()) == [
                "image_00",
                "image_01",
                "image_02",
                "image_03",
                "oxts",
                "velodyne_points",
            ]
            _zip_tree(served / "raw_data" / name / f"{drive.name}.zip", raw, [drive])
            urls.append(f"raw_data/{name}/{drive.name}.zip")
    scene = tree / "kitti2015"
    _zip_tree(served / "data_scene_flow.zip", scene, [scene / "training", scene / "testing"])
    return urls


@contextlib.contextmanager
def _serve(directory: Path) -> Iterator[str]:
    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args: object) -> None:
            pass

    handler = functools.partial(Quiet, directory=str(directory))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()


def _kitti_params(base_url: str, lists: Path, **kitti: object) -> dict:
    return {
        "data": {
            "source": "kitti",
            "root": "data/kitti",
            "kitti": {
                "base_url": base_url,
                "allow_http": True,  # the local mirror speaks plain http
                "archive_list": str(lists / "archives.txt"),
                "jobs": 2,
                "train_split": str(lists / "train.txt"),
                "eval_split": str(lists / "eval.txt"),
                "eigen_split": str(lists / "eigen.txt"),
                **kitti,
            },
        }
    }


def _check_run(work: Path, archives: int) -> str:
    """What every KITTI run must show: all archives fetched, nothing synthetic-only on disk, the
    baselines built from the scans, the comparison and the figures. Returns compare.md."""
    manifest = json.loads((work / "data" / "downloads" / "manifest.json").read_text())
    assert len(manifest["archives"]) == archives + 1  # raw archives and data_scene_flow.zip
    data = work / "data" / "kitti"
    assert not [p for name in SYNTHETIC_ONLY for p in data.rglob(name)]
    assert list(data.glob("raw/*/*_sync/velodyne_points/data/*.bin"))
    for suite in ("full", "roi", "gradients"):
        for run in ("msssim/seed0", "ssim/seed0", "constant", "prior"):
            assert "cap80" in json.loads((work / "metrics" / suite / f"{run}.json").read_text()), (suite, run)
    for run in ("msssim/seed0", "ssim/seed0", "constant", "prior"):  # the Eigen split, LiDAR GT
        assert "cap80" in json.loads(
            (work / "metrics" / "sets" / "eigen" / "full" / f"{run}.json").read_text()
        )
    md = (work / "metrics" / "compare.md").read_text()
    assert "Baselines (image-blind, from training GT): constant, prior." in md and "Missing" not in md
    assert "| prior |" in md and "| constant |" in md
    assert sorted(p.name for p in (work / "plots" / "figures").iterdir()) == sorted(STAGE_FIGURES)
    assert dvc_status(work) == UP_TO_DATE
    return md


@pytest.fixture(scope="module")
def mirror(tmp_path_factory):
    """The renderer's output as KITTI ships it, on 127.0.0.1: archives, data_scene_flow.zip, lists."""
    tree = tmp_path_factory.mktemp("tree")
    render.generate(SYN, tree, progress=False, workers=1)
    kitti_tree = tmp_path_factory.mktemp("kitti")
    kitti_mirror.mirror_from_synthetic(tree, kitti_tree)
    served = tmp_path_factory.mktemp("served")
    urls = _archives(kitti_tree, served)
    lists = tmp_path_factory.mktemp("lists")
    (lists / "archives.txt").write_text("".join(KITTI_BASE_URL + u + "\n" for u in urls))
    (lists / "train.txt").write_text((tree / "train_files.txt").read_text())
    (lists / "eval.txt").write_text(
        (tree / "kitti2015" / "test_files.txt").read_text().replace(".png", ".jpg")
    )
    # An Eigen-format list of a few raw frames with scans, in Monodepth's .jpg names.
    (lists / "eigen.txt").write_text(
        "".join(
            line.replace(".png", ".jpg") + "\n"
            for line in (tree / "train_files.txt").read_text().splitlines()[:3]
        )
    )
    with _serve(served) as base_url:
        yield base_url, lists, len(urls)


def test_kitti_source_runs_every_stage(mirror, tmp_path: Path) -> None:
    base_url, lists, archives = mirror
    work = project(tmp_path, _kitti_params(base_url, lists, roi_min_size=4, roi_min_valid=0.2))
    run_checked([sys.executable, "-m", "dvc", "repro", "--quiet"], work)
    _check_run(work, archives)
    report = json.loads((work / "data" / "index" / "report.json").read_text())
    assert report["source"] == "kitti" and report["train_pairs_found"] == SYN.train_pairs
    assert report["eval_frames"] == SYN.eval_frames  # the .jpg names resolved to the .png files
    rois = (work / "data" / "index" / "rois.csv").read_text().splitlines()
    assert len(rois) > 1 and all(",car," in line for line in rois[1:])  # cars from obj_map
    assert (work / "data" / "index" / "rois.png").stat().st_size > 1000
    _check_monocular(work, lists)


def _check_monocular(work: Path, lists: Path) -> None:
    """`dvc exp run -S train.mode=mono` on the fetched drives: a Monodepth2 split of the listed
    frames (those without both neighbours skipped), and pose ATE on an odometry-shaped copy of
    one drive's frames placed below data.root (``odometry/``), as a user unpacks KITTI's."""
    frames = sorted(
        (line.split()[0].split("/image_02/")[0], int(Path(line.split()[0]).stem))
        for line in (lists / "train.txt").read_text().splitlines()
    )
    (lists / "mono.txt").write_text("".join(f"{d} {n} l\n" for d, n in frames))
    drive, _ = frames[0]
    odometry = work / "data" / "kitti" / "odometry"
    shots = sorted((work / "data" / "kitti" / "raw" / drive / "image_02" / "data").glob("*.png"))
    for n, shot in enumerate(shots):
        (odometry / "sequences" / "09" / "image_2").mkdir(parents=True, exist_ok=True)
        (odometry / "sequences" / "09" / "image_2" / f"{n:06d}.png").write_bytes(shot.read_bytes())
    poses = [f"1 0 0 0 0 1 0 0 0 0 1 {0.8 * n:g}\n" for n in range(len(shots))]
    (odometry / "poses").mkdir()
    (odometry / "poses" / "09.txt").write_text("".join(poses))
    mono = ["-S", "train.mode=mono", "-S", f"data.kitti.mono_split={lists / 'mono.txt'}"]
    # One run's chain (its training, inference and full-image suite) is enough here.
    run_checked([sys.executable, "-m", "dvc", "exp", "run", "--quiet", *mono, "eval_full@ssim-0"], work)
    summary = json.loads((work / "metrics" / "train" / "ssim" / "seed0.json").read_text())
    assert summary["pose"]["snippets"] == len(shots) - 1 and list(summary["pose"]["sequences"]) == ["09"]
    full = json.loads((work / "metrics" / "full" / "ssim" / "seed0.json").read_text())
    assert "median_scaling" in full["cap80"]  # up to scale: evaluated median-scaled, as Monodepth2


# Hand-drawn boxes on the real left image (the rear window of the dark hatchback, the side
# windows of the near car), as a user adds windshield/glass boxes beside the obj_map cars.
REAL_USER_ROIS = (
    "image,class,x0,y0,x1,y1\n000000_10,windshield,775,192,865,232\n000000_10,glass,935,215,1110,300\n"
)


@pytest.mark.skipif(not REAL.is_dir(), reason="../shared/real-samples is not available")
def test_real_kitti_files_run_every_stage(tmp_path: Path) -> None:
    """The real pair, scan and calibration as one raw drive (the pair repeated) and a KITTI 2015
    frame whose GT is the projected scan: 1242 x 375 images, sparse GT, calibration converted to
    the raw format, no KITTI 2015 calibration (Monodepth's focal table covers 1242 px)."""
    frames = 8
    kitti_tree = tmp_path / "kitti"
    kitti_mirror.mirror_from_real(REAL, kitti_tree, train_frames=frames)
    urls = _archives(kitti_tree, tmp_path / "served")
    lists = tmp_path / "lists"
    lists.mkdir()
    (lists / "archives.txt").write_text("".join(KITTI_BASE_URL + u + "\n" for u in urls))
    drive = "2011_09_26/2011_09_26_drive_0001_sync"
    (lists / "train.txt").write_text(
        "".join(
            f"{drive}/image_02/data/{i:010d}.jpg {drive}/image_03/data/{i:010d}.jpg\n" for i in range(frames)
        )
    )
    (lists / "eval.txt").write_text("training/image_2/000000_10.jpg training/image_3/000000_10.jpg\n")
    (lists / "eigen.txt").write_text(
        f"{drive}/image_02/data/0000000000.jpg {drive}/image_03/data/0000000000.jpg\n"
    )
    (lists / "rois.csv").write_text(REAL_USER_ROIS)
    with _serve(tmp_path / "served") as base_url:
        # One scan's GT is sparse (3-9 % of a car's box; KITTI 2015's fitted car models are denser).
        params = _kitti_params(
            base_url, lists, roi_min_size=16, roi_min_valid=0.03, rois_csv=str(lists / "rois.csv")
        )
        (tmp_path / "work").mkdir()
        work = project(tmp_path / "work", params)
        run_checked([sys.executable, "-m", "dvc", "repro", "--quiet"], work)
    md = _check_run(work, len(urls))
    (tmp_path / "compare.md").write_text(md)  # kept beside the run for a reader of the test's tmp dir
    report = json.loads((work / "data" / "index" / "report.json").read_text())
    assert report["train_pairs_found"] == frames and report["eval_frames"] == 1
    rois = (work / "data" / "index" / "rois.csv").read_text()
    assert rois.count(",car,") == 4 and ",windshield," in rois and ",glass," in rois
    # The prior of eight copies of the scan, evaluated on that scan's GT: the scan -> disparity ->
    # depth round trip of training and evaluation agree but for the GT PNG's 1/256 px steps.
    full = json.loads((work / "metrics" / "full" / "prior.json").read_text())
    assert 0 < full["cap80"]["abs_rel"] < 0.01
    # The same on the Eigen path: the raw scan itself as GT, projected by the index's calibration,
    # inside Garg's crop (measured 0.0135: the prior, built at the training GT's resampled size and
    # resized back, blurs the near objects that fill the crop; a wrong focal, baseline or
    # projection would be off by far more).
    eigen = json.loads((work / "metrics" / "sets" / "eigen" / "full" / "prior.json").read_text())
    assert eigen["images"] == 1 and 0 < eigen["cap80"]["abs_rel"] < 0.02
