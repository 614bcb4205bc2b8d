"""Writing the synthetic set as a KITTI-format tree; :func:`generate` renders the whole set."""

from __future__ import annotations

import multiprocessing
import os
import shutil
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np
import pandas as pd

from msdepth.config.params import CameraConfig, SyntheticConfig, fingerprint_fields
from msdepth.data.kitti import (
    KITTI_BASELINE,
    read_raw_calib,
    velodyne_depth,
    write_disparity,
    write_rois,
    write_split,
    write_velodyne,
)
from msdepth.data.layout import MONO_SPLIT
from msdepth.data.owners import RENDERING, SUMMARY, check_synthetic_root
from msdepth.io import atomic_path, atomic_temps, write_json, write_png, write_text
from msdepth.render.frame import (
    EVAL,
    SEQUENCE_STEP,
    TRAIN,
    Frame,
    render_frame,
    sequence_frame,
    sequence_pose,
)
from msdepth.render.raycast import focal_for_width
from msdepth.render.velodyne_sim import calib_velo_to_cam_text

DATES = ("2011_09_26", "2011_09_28", "2011_09_29", "2011_09_30", "2011_10_03")
# The raw drive holding the evaluation frames with their LiDAR scans: training drives are numbered
# 1..drives, so this one cannot collide with them (generate refuses drives >= EVAL_DRIVE).
EVAL_DATE, EVAL_DRIVE = DATES[0], 9000
EIGEN_TEST_FILES = "eigen_test_files.txt"
EVAL_GT_OCC = "disp_occ_0"
EVAL_GT_NOC = "disp_noc_0"
# With data.synthetic.sequence_length: Monodepth2's split of the frames with both neighbours
# (``drive frame side``, msdepth.data.sequences), and each drive's camera 02 poses.
POSES = "poses.txt"


def calib_text(height: int, width: int, raw: bool = False) -> str:
    """A raw-data style ``calib_cam_to_cam.txt`` for the synthetic rig (cameras 02 and 03).

    ``raw``: the file of a raw day folder, which the raw-LiDAR GT is projected with. It also has
    ``R_rect_00`` (identity: the rig is rectified), and its principal points are in KITTI's
    MATLAB convention (1-based pixels, one more than the 0-based image centre), which the field's
    projection assumes when it takes ``round(u) - 1`` as the pixel (:func:`kitti.lidar_depth_map`):
    a point then lands on the pixel that shows it. The KITTI 2015 files (``raw=False``) keep the
    0-based centre; only the focal and baseline are read from them.
    """
    f = focal_for_width(width)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    if raw:
        cx, cy = cx + 1.0, cy + 1.0

    def row(key: str, values: Iterable[float]) -> str:
        return f"{key}: " + " ".join(f"{v:.12e}" for v in values) + "\n"

    text = "calib_time: 01-Jan-2017 00:00:00\ncorner_dist: 0.000000e+00\n"
    if raw:
        text += row("R_rect_00", np.eye(3).ravel())
    for cam, tx in (("02", 0.0), ("03", -KITTI_BASELINE)):
        text += row(f"S_{cam}", (width, height))
        text += row(f"K_{cam}", (f, 0, cx, 0, f, cy, 0, 0, 1))
        text += row(f"D_{cam}", (0, 0, 0, 0, 0))
        text += row(f"R_{cam}", np.eye(3).ravel())
        text += row(f"T_{cam}", (tx, 0, 0))
        text += row(f"S_rect_{cam}", (width, height))
        text += row(f"R_rect_{cam}", np.eye(3).ravel())
        text += row(f"P_rect_{cam}", (f, 0, cx, f * tx, 0, f, cy, 0, 0, 0, 1, 0))
    return text


def _drive_position(cfg: SyntheticConfig, index: int) -> tuple[int, int]:
    """``(drive index from 0, frame number in the drive)`` of training pair ``index``."""
    drive = index * cfg.drives // cfg.train_pairs
    first = -(-drive * cfg.train_pairs // cfg.drives)  # first index mapped to this drive
    return drive, index - first


def train_drive(cfg: SyntheticConfig, index: int) -> tuple[str, int]:
    """``(drive folder relative to raw/, frame number)`` of training pair ``index``."""
    drive, number = _drive_position(cfg, index)
    date = DATES[drive % len(DATES)]
    return f"{date}/{date}_drive_{drive + 1:04d}_sync", number


def _train_frame(cfg: SyntheticConfig, index: int) -> Frame:
    """Training pair ``index``: an independent frame, or with ``sequence_length`` frame
    ``number % sequence_length`` of its drive's sequence ``number // sequence_length``."""
    cars = (tuple(cfg.train_cars), tuple(cfg.train_car_depth))
    if not cfg.sequence_length:
        return render_frame(cfg.seed, TRAIN, index, cfg.height, cfg.width, cars=cars, sensor=cfg.camera)
    drive, number = _drive_position(cfg, index)
    run, position = (drive, number // cfg.sequence_length), number % cfg.sequence_length
    return sequence_frame(cfg.seed, run, position, cfg.height, cfg.width, cars=cars, sensor=cfg.camera)


def _write_train(job: tuple[SyntheticConfig, str, int]) -> tuple[str, str, np.ndarray]:
    """Write training pair ``index``; returns its two paths and its scene's camera rotation."""
    cfg, root, index = job
    frame = _train_frame(cfg, index)
    drive, number = train_drive(cfg, index)
    name = f"{number:010d}.png"
    raw = Path(root) / "raw"
    left, right = f"{drive}/image_02/data/{name}", f"{drive}/image_03/data/{name}"
    write_png(raw / left, frame.left)
    write_png(raw / right, frame.right)
    write_disparity(raw / drive / "disp_02" / "data" / name, frame.disp)
    return left, right, frame.rotation


def within_range(disp: np.ndarray, focal: float, max_depth: float) -> np.ndarray:
    """``disp`` with pixels deeper than ``max_depth`` metres set invalid (0); 0 = no limit.

    KITTI's GT comes from a LiDAR that returns nothing past ~80 m; a rendered road reaches the
    horizon (kilometres), which would otherwise dominate RMSE against predictions capped at 80 m.
    """
    if max_depth <= 0:
        return disp
    return np.where(disp >= focal * KITTI_BASELINE / max_depth, disp, 0).astype(disp.dtype)


def eval_pairs(
    cfg: SyntheticConfig, gt: str = EVAL_GT_NOC, sensor: CameraConfig | None = None
) -> Iterator[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
    """Each evaluation frame's name, views and GT disparity (``gt``: :data:`EVAL_GT_NOC` or
    :data:`EVAL_GT_OCC`), rendered in memory as :func:`generate` writes them but recorded by
    ``sensor`` (None: the ideal views), for comparing cameras on the same scenes."""
    for index in range(cfg.eval_frames):
        frame = render_frame(cfg.seed, EVAL, index, cfg.height, cfg.width, sensor=sensor)
        disp = within_range(frame.disp, frame.focal, cfg.gt_max_depth)
        if gt == EVAL_GT_NOC:
            disp = np.where(frame.noc, disp, 0).astype(disp.dtype)
        yield f"{index:06d}_10", frame.left, frame.right, disp


def eval_drive() -> str:
    """The raw drive folder (relative to ``raw/``) of the evaluation frames and their scans."""
    return f"{EVAL_DATE}/{EVAL_DATE}_drive_{EVAL_DRIVE:04d}_sync"


def _write_eval(
    job: tuple[SyntheticConfig, str, int, bool],
) -> tuple[list[tuple[str, str, int, int, int, int]], dict[str, int] | None]:
    """Write evaluation frame ``index``; returns its ROI rows and (with the LiDAR) its scan's counts."""
    cfg, root, index, lidar = job
    frame = render_frame(cfg.seed, EVAL, index, cfg.height, cfg.width, lidar=lidar, sensor=cfg.camera)
    name = f"{index:06d}_10"
    training = Path(root) / "kitti2015" / "training"
    write_png(training / "image_2" / f"{name}.png", frame.left)
    write_png(training / "image_3" / f"{name}.png", frame.right)
    disp = within_range(frame.disp, frame.focal, cfg.gt_max_depth)
    write_disparity(training / EVAL_GT_OCC / f"{name}.png", disp)
    write_disparity(training / EVAL_GT_NOC / f"{name}.png", np.where(frame.noc, disp, 0))
    write_png(training / "obj_map" / f"{name}.png", frame.obj_map)
    write_png(training / "class_map" / f"{name}.png", frame.class_map)
    write_text(training / "calib_cam_to_cam" / f"{index:06d}.txt", calib_text(cfg.height, cfg.width))
    rows = [(name, *box) for box in frame.rois]
    if not lidar:
        return rows, None
    # The same frame as a raw drive frame: images (copies of the files above), scan.
    raw = Path(root) / "raw"
    drive, number = raw / eval_drive(), f"{index:010d}"
    for src, cam in (("image_2", "image_02"), ("image_3", "image_03")):
        with atomic_path(drive / cam / "data" / f"{number}.png") as tmp:
            shutil.copyfile(training / src / f"{name}.png", tmp)
    scan_path = drive / "velodyne_points" / "data" / f"{number}.bin"
    write_velodyne(scan_path, frame.scan.points)
    gt = velodyne_depth(scan_path, read_raw_calib(raw / EVAL_DATE))  # as the evaluation reads it
    return rows, {"points": int(len(frame.scan.points)), "gt_pixels": int((gt > 0).sum())}


def _run(fn: Callable, jobs: list, workers: int, bar) -> list:
    """Map ``fn`` over ``jobs`` in order, in worker processes when ``workers > 1``."""
    if workers <= 1:
        results = []
        for job in jobs:
            results.append(fn(job))
            bar.update(1)
        return results
    # spawn: a forked child could inherit locks held by threads of torch/OpenCV in the parent.
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        results = []
        for result in pool.map(fn, jobs, chunksize=max(1, min(16, len(jobs) // (4 * workers)))):
            results.append(result)
            bar.update(1)
        return results


def generate(
    cfg: SyntheticConfig, root: Path, progress: bool = True, workers: int | None = None, lidar: bool = True
) -> dict:
    """Render the whole synthetic set under ``root`` in KITTI's layouts; returns a summary.

    Always regenerates from scratch (``root/raw`` and ``root/kitti2015`` are replaced), but only
    in a tree of its own: ``root`` must be empty, absent, or marked as the synthetic set's
    (:mod:`msdepth.data.owners`); any other tree, such as KITTI's, is refused (DataError). Every
    file is written atomically and the output depends only on ``cfg`` (byte-identical reruns).
    ``workers`` processes render in parallel (default: the CPUs available to this process).

    The evaluation frames are written twice: as KITTI 2015 frames ``NNNNNN_10`` and, with a
    simulated Velodyne scan each, as frames ``NNNNNNNNNN`` of the raw drive :func:`eval_drive`
    (same image bytes), listed in ``eigen_test_files.txt``. ``lidar=False`` skips the latter
    (for timing; nothing else changes).
    """
    root = Path(root)
    if cfg.drives >= EVAL_DRIVE:
        raise ValueError(f"at most {EVAL_DRIVE - 1} drives: drive {EVAL_DRIVE} holds the evaluation frames")
    if workers is None:
        workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    _clear(root)
    _write_calibration(cfg, root, lidar)
    pairs, evals = _render(cfg, root, workers, progress, lidar)
    summary = _write_lists(cfg, root, pairs, [rows for rows, _ in evals], lidar)
    if lidar and cfg.eval_frames:

        def spread(key: str) -> dict[str, float | int]:
            values = np.array([counts[key] for _, counts in evals], float)
            return {"mean": float(values.mean()), "min": int(values.min()), "max": int(values.max())}

        summary["lidar"] = {
            "drive": eval_drive(),
            "points_per_scan": spread("points"),
            "gt_pixels_per_frame": spread("gt_pixels"),  # lidar_depth_map at the evaluation size
        }
    write_json(root / SUMMARY, summary)
    (root / RENDERING).unlink()
    return summary


def _clear(root: Path) -> None:
    """Remove the previous render's trees and Eigen list, after checking that ``root`` is the
    renderer's own (:func:`~msdepth.data.owners.check_synthetic_root`, else DataError), and mark it
    as such until the summary is written (an interrupted render is then still known as its own).
    A killed render's temp files go too: in raw/ and kitti2015/ with them, at the root by name."""
    check_synthetic_root(root)
    write_text(root / RENDERING, "a synthetic render is under way or was interrupted\n")
    for name in (SUMMARY, RENDERING, "train_files.txt", "rois.csv", EIGEN_TEST_FILES, MONO_SPLIT):
        for tmp in atomic_temps(root / name):  # left by a render killed mid-write
            tmp.unlink()
    for sub in ("raw", "kitti2015"):
        if (root / sub).exists():
            shutil.rmtree(root / sub)
    (root / EIGEN_TEST_FILES).unlink(missing_ok=True)
    (root / MONO_SPLIT).unlink(missing_ok=True)


def _write_calibration(cfg: SyntheticConfig, root: Path, lidar: bool) -> None:
    """Each raw day folder's calibration files (the camera's, with ``lidar`` also the LiDAR's)."""
    dates = {train_drive(cfg, i)[0].split("/")[0] for i in range(cfg.train_pairs)}
    if lidar and cfg.eval_frames:
        dates.add(EVAL_DATE)
    for date in sorted(dates):
        write_text(root / "raw" / date / "calib_cam_to_cam.txt", calib_text(cfg.height, cfg.width, raw=True))
        if lidar:
            write_text(root / "raw" / date / "calib_velo_to_cam.txt", calib_velo_to_cam_text())


def _render(
    cfg: SyntheticConfig, root: Path, workers: int, progress: bool, lidar: bool
) -> tuple[list[tuple[str, str]], list]:
    """Render and write every frame: the training pairs' paths and each evaluation frame's result."""
    from tqdm import tqdm

    key = str(root)
    with tqdm(
        total=cfg.train_pairs + cfg.eval_frames, desc="synthetic", unit="frame", disable=not progress
    ) as bar:
        trains = _run(_write_train, [(cfg, key, i) for i in range(cfg.train_pairs)], workers, bar)
        evals = _run(_write_eval, [(cfg, key, i, lidar) for i in range(cfg.eval_frames)], workers, bar)
    if cfg.sequence_length:
        _write_sequences(cfg, root, [rotation for _, _, rotation in trains])
    return [(left, right) for left, right, _ in trains], evals


def _write_lists(
    cfg: SyntheticConfig, root: Path, pairs: list[tuple[str, str]], boxes: list[list], lidar: bool
) -> dict[str, Any]:
    """The split files and ``rois.csv`` (``boxes``: each evaluation frame's ROI rows); returns the
    summary without the LiDAR's statistics."""
    write_split(root / "train_files.txt", pairs)
    names = [f"{i:06d}_10" for i in range(cfg.eval_frames)]
    write_split(
        root / "kitti2015" / "test_files.txt",
        [(f"training/image_2/{n}.png", f"training/image_3/{n}.png") for n in names],
    )
    rois = pd.DataFrame(
        [row for rows in boxes for row in rows], columns=["image", "class", "x0", "y0", "x1", "y1"]
    )
    write_rois(root / "rois.csv", rois)
    if lidar and cfg.eval_frames:
        drive = eval_drive()
        write_split(
            root / EIGEN_TEST_FILES,
            [
                (f"{drive}/image_02/data/{i:010d}.png", f"{drive}/image_03/data/{i:010d}.png")
                for i in range(cfg.eval_frames)
            ],
        )
    return {
        "config": fingerprint_fields(cfg),  # sequence_length only when set: old summaries stay
        "focal_px": focal_for_width(cfg.width),
        "baseline_m": KITTI_BASELINE,
        "train_pairs": len(pairs),
        "eval_frames": len(names),
        "drives": len({train_drive(cfg, i)[0] for i in range(cfg.train_pairs)}),
        "rois": {c: int((rois["class"] == c).sum()) for c in ("car", "windshield", "glass", "sign")},
    }


def _write_sequences(cfg: SyntheticConfig, root: Path, rotations: list[np.ndarray]) -> None:
    """Each drive's camera 02 poses (:data:`POSES`: KITTI odometry's format, a 3x4 camera-to-world
    matrix per frame, row-major; each sequence in its own scene's world, ``rotations[i]`` the
    scene's of training pair ``i``) and :data:`MONO_SPLIT`: both sides of every frame with a
    neighbour on each side in its sequence."""
    frames = [train_drive(cfg, i) for i in range(cfg.train_pairs)]
    present = set(frames)
    poses: dict[str, list[str]] = {}
    lines = []
    for (drive, number), rotation in zip(frames, rotations, strict=True):
        position = number % cfg.sequence_length
        pose = sequence_pose(rotation, position * SEQUENCE_STEP)
        poses.setdefault(drive, []).append(" ".join(f"{v:.12e}" for v in pose[:3].ravel()) + "\n")
        if 0 < position < cfg.sequence_length - 1 and (drive, number + 1) in present:
            lines += [f"{drive} {number} l\n", f"{drive} {number} r\n"]
    for drive, rows in poses.items():
        write_text(root / "raw" / drive / POSES, "".join(rows))
    write_text(root / MONO_SPLIT, "".join(lines))
