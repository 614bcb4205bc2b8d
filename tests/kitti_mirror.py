"""KITTI-shaped trees for the tests: exactly the folders and files KITTI's archives hold.

A raw drive archive holds ``image_00``-``image_03`` (``data/*.png`` and ``timestamps.txt``),
``velodyne_points`` (``data/*.bin``, ``timestamps*.txt``) and ``oxts`` (``data/*.txt``,
``dataformat.txt``, ``timestamps.txt``); a day's calibration archive holds
``calib_cam_to_cam.txt``, ``calib_velo_to_cam.txt`` and ``calib_imu_to_velo.txt``;
``data_scene_flow.zip`` holds ``training/`` (``image_2``, ``image_3`` with ``_10`` and ``_11``
frames, ``disp_occ_0/1``, ``disp_noc_0/1``, ``flow_occ``, ``flow_noc``, ``obj_map``,
``viz_flow_occ``, ``viz_flow_occ_dilate_1``) and ``testing/`` (``image_2``, ``image_3``).
Nothing of the synthetic set's own (``disp_02``, ``class_map``, ``rois.csv``, split lists)
is in them.

:func:`mirror_from_synthetic` builds such trees from the renderer's output, synthesising what it
lacks: Velodyne scans (a sparse subset of each training frame's rendered depth, back-projected
into LiDAR coordinates through KITTI's real ``calib_velo_to_cam``, so that
:func:`msdepth.data.kitti.lidar_depth_map` finds those depths again), grey images, oxts and
timestamps. :func:`mirror_from_real` builds them from the real sample in ``../shared``.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from msdepth.data import kitti
from msdepth.io import write_png
from msdepth.render import focal_for_width

# KITTI's 2011_09_26 calibration: LiDAR -> camera 0 ([R|T]) and the rectifying rotation.
VELO_TO_CAM = np.array(
    [
        [7.533745e-03, -9.999714e-01, -6.166020e-04, -4.069766e-03],
        [1.480249e-02, 7.280733e-04, -9.998902e-01, -7.631618e-02],
        [9.998621e-01, 7.523790e-03, 1.480755e-02, -2.717806e-01],
    ]
)
R_RECT_00 = np.array(
    [
        [9.999239e-01, 9.837760e-03, -7.445048e-03],
        [-9.869795e-03, 9.999421e-01, -4.278459e-03],
        [7.402527e-03, 4.351614e-03, 9.999631e-01],
    ]
)
IMU_TO_VELO = np.array(
    [
        [9.999976e-01, 7.553071e-04, -2.035826e-03, -8.086759e-01],
        [-7.854027e-04, 9.998898e-01, -1.482298e-02, 3.195559e-01],
        [2.024406e-03, 1.482454e-02, 9.998881e-01, -7.997231e-01],
    ]
)
LIDAR_RANGE = 80.0  # metres: the synthetic GT beyond is no LiDAR return
OXTS_FIELDS = (
    "lat lon alt roll pitch yaw vn ve vf vl vu ax ay az af al au wx wy wz wf wl wu "
    "pos_accuracy vel_accuracy navstat numsats posmode velmode orimode"
).split()


def _row(key: str, values) -> str:
    return f"{key}: " + " ".join(f"{v:.6e}" for v in np.ravel(values)) + "\n"


def cam_to_cam_text(proj: dict[str, np.ndarray], rect: np.ndarray, width: int, height: int) -> str:
    """A raw ``calib_cam_to_cam.txt`` (all four cameras) with the rectified projections ``proj``
    (``{"00": P, ..., "03": P}``, 3x4) and ``R_rect_00`` = ``rect``; the rest is plausible filler."""
    text = "calib_time: 09-Jan-2012 13:57:47\ncorner_dist: 9.950000e-02\n"
    for cam, p in proj.items():
        k = p[:, :3]
        text += _row(f"S_{cam}", (1392, 512))
        text += _row(f"K_{cam}", k)
        text += _row(f"D_{cam}", (-0.37, 0.20, 0.0, 0.0, -0.07))
        text += _row(f"R_{cam}", np.eye(3))
        text += _row(f"T_{cam}", (p[0, 3] / p[0, 0], 0.0, 0.0))
        text += _row(f"S_rect_{cam}", (width, height))
        text += _row(f"R_rect_{cam}", rect if cam == "00" else np.eye(3))
        text += _row(f"P_rect_{cam}", p)
    return text


def _rt_text(matrix: np.ndarray, calib_time: str) -> str:
    return (
        f"calib_time: {calib_time}\n"
        + _row("R", matrix[:, :3])
        + _row("T", matrix[:, 3])
        + "delta_f: 0.000000e+00 0.000000e+00\ndelta_c: 0.000000e+00 0.000000e+00\n"
    )


def write_day_calib(day: Path, cam_to_cam: str, velo_to_cam: np.ndarray = VELO_TO_CAM) -> None:
    """The three files of a day's calibration archive."""
    day.mkdir(parents=True, exist_ok=True)
    (day / "calib_cam_to_cam.txt").write_text(cam_to_cam)
    (day / "calib_velo_to_cam.txt").write_text(_rt_text(velo_to_cam, "15-Mar-2012 11:37:16"))
    (day / "calib_imu_to_velo.txt").write_text(_rt_text(IMU_TO_VELO, "25-May-2012 16:47:16"))


def scan_from_depth(
    depth: np.ndarray, proj: np.ndarray, rect: np.ndarray, rng: np.random.Generator, density: float = 0.05
) -> tuple[np.ndarray, np.ndarray]:
    """A Velodyne scan (float32 (N, 4)) whose projection is a ``density`` subset of ``depth``.

    Pixel (row, col) holds the point at projective depth ``depth[row, col]`` on the ray of
    ``u, v = col + 1, row + 1`` (the inverse of ``round(u) - 1``), moved into LiDAR coordinates
    through ``rect`` and :data:`VELO_TO_CAM`. Points behind the LiDAR and beside the camera's view
    are added, as a real scan has them. Returns the scan and the depth map it should give (the
    points' LiDAR x at their pixels, 0 elsewhere).
    """
    rows, cols = np.nonzero((depth > 0) & (depth <= LIDAR_RANGE))
    keep = rng.random(len(rows)) < density
    rows, cols, z = rows[keep], cols[keep], depth[rows[keep], cols[keep]].astype(np.float64)
    image = np.stack([(cols + 1) * z, (rows + 1) * z, z])  # P · X_rect = z · (u, v, 1)
    rectified = np.linalg.solve(proj[:, :3], image - proj[:, 3:])
    velo4 = np.r_[VELO_TO_CAM, [[0, 0, 0, 1]]]
    camera = np.linalg.solve(rect, rectified)
    velo = np.linalg.solve(velo4, np.r_[camera, np.ones((1, camera.shape[1]))])[:3].T
    n = max(1, len(velo) // 10)
    behind = np.c_[rng.uniform(-40, -1, n), rng.uniform(-20, 20, n), rng.uniform(-2, 1, n)]
    beside = np.c_[
        rng.uniform(1, 20, n), rng.choice([-1, 1], n) * rng.uniform(30, 60, n), rng.uniform(-2, 1, n)
    ]
    points = np.r_[velo, behind, beside]
    scan = np.c_[points, rng.uniform(0, 1, len(points))].astype(np.float32)
    expected = np.zeros(depth.shape, dtype=np.float32)
    expected[rows, cols] = scan[: len(rows), 0]
    return scan, expected


def _timestamps(n: int) -> str:
    return "".join(
        f"2011-09-26 13:02:{25 + i // 10:02d}.{(i % 10) * 103_000_000 + 964389:09d}\n" for i in range(n)
    )


def _grey(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)


def write_drive(drive: Path, frames: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> None:
    """A raw ``<drive>_sync`` folder as its archive holds it: per frame (left RGB, right RGB, scan)."""
    for i, (left, right, scan) in enumerate(frames):
        name = f"{i:010d}"
        for cam, image in (("00", _grey(left)), ("01", _grey(right)), ("02", left), ("03", right)):
            write_png(drive / f"image_{cam}" / "data" / f"{name}.png", image)
        (drive / "velodyne_points" / "data").mkdir(parents=True, exist_ok=True)
        scan.astype(np.float32).tofile(drive / "velodyne_points" / "data" / f"{name}.bin")
        (drive / "oxts" / "data").mkdir(parents=True, exist_ok=True)
        values = [49.011 + 1e-5 * i, 8.4169, 112.8, 0.02, 0.01, -1.3] + [0.1] * 19 + [4, 10, 4, 4, 4]
        (drive / "oxts" / "data" / f"{name}.txt").write_text(" ".join(f"{v:g}" for v in values) + "\n")
    stamps = _timestamps(len(frames))
    for folder in ("image_00", "image_01", "image_02", "image_03", "oxts"):
        (drive / folder / "timestamps.txt").write_text(stamps)
    for suffix in ("", "_start", "_end"):
        (drive / "velodyne_points" / f"timestamps{suffix}.txt").write_text(stamps)
    (drive / "oxts" / "dataformat.txt").write_text("".join(f"{f}: value\n" for f in OXTS_FIELDS))


def write_scene_flow(
    root: Path,
    frames: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
    calib: list[str] | None = None,
) -> None:
    """``training/`` and ``testing/`` of data_scene_flow.zip: per frame (left, right, occ GT
    disparity px, noc GT disparity px, obj_map). ``calib`` texts go to ``training/calib_cam_to_cam``,
    which KITTI ships separately (data_scene_flow_calib.zip): only for widths Monodepth's focal
    table does not know."""
    training, testing = root / "training", root / "testing"
    for i, (left, right, occ, noc, obj) in enumerate(frames):
        h, w = occ.shape
        for suffix in ("10", "11"):  # the frame and the next one (optical flow); only _10 is evaluated
            name = f"{i:06d}_{suffix}.png"
            for split in (training, testing):
                write_png(split / "image_2" / name, left)
                write_png(split / "image_3" / name, right)
        name = f"{i:06d}_10.png"
        for t in ("0", "1"):
            kitti.write_disparity(training / f"disp_occ_{t}" / name, occ)
            kitti.write_disparity(training / f"disp_noc_{t}" / name, noc)
        for folder in ("flow_occ", "flow_noc"):
            write_png(training / folder / name, np.zeros((h, w, 3), dtype=np.uint16))
        for folder in ("viz_flow_occ", "viz_flow_occ_dilate_1"):
            write_png(training / folder / name, np.zeros((h, w, 3), dtype=np.uint8))
        write_png(training / "obj_map" / name, obj)
        if calib is not None:
            (training / "calib_cam_to_cam").mkdir(parents=True, exist_ok=True)
            (training / "calib_cam_to_cam" / f"{i:06d}.txt").write_text(calib[i])


def synthetic_projections(width: int, height: int) -> dict[str, np.ndarray]:
    """The synthetic rig's rectified projections: cameras 00/02 at the origin, 01/03 0.54 m right."""
    f = focal_for_width(width)
    k = np.array([[f, 0, (width - 1) / 2.0], [0, f, (height - 1) / 2.0], [0, 0, 1]])
    left, right = np.c_[k, np.zeros(3)], np.c_[k, [-f * kitti.KITTI_BASELINE, 0, 0]]
    return {"00": left, "01": right, "02": left, "03": right}


def mirror_from_synthetic(tree: Path, out: Path, seed: int = 0) -> dict[str, np.ndarray]:
    """KITTI-shaped ``out/raw`` and ``out/kitti2015`` from the renderer's ``tree``.

    Returns, per training left image (path relative to ``raw/``), the depth map its scan gives.
    The renderer's raw evaluation drive (Eigen layout, no ``disp_02``) is left out.
    """
    rng = np.random.default_rng(seed)
    expected: dict[str, np.ndarray] = {}
    for day in sorted(p for p in (tree / "raw").iterdir() if p.is_dir()):
        # Training drives only: the renderer's raw evaluation drive has its own scans, made for
        # its own calibration, not the KITTI one written here.
        drives = sorted(d for d in day.glob("*_sync") if (d / "disp_02").is_dir())
        if not drives:
            continue
        left0 = kitti.read_image(next((drives[0] / "image_02" / "data").glob("*.png")))
        h, w = left0.shape[:2]
        proj = synthetic_projections(w, h)
        write_day_calib(out / "raw" / day.name, cam_to_cam_text(proj, R_RECT_00, w, h))
        focal = focal_for_width(w)
        for drive in drives:
            frames = []
            for left_path in sorted((drive / "image_02" / "data").glob("*.png")):
                disp = kitti.read_disparity(drive / "disp_02" / "data" / left_path.name)
                depth = np.where(disp > 0, focal * kitti.KITTI_BASELINE / np.maximum(disp, 1e-6), 0)
                scan, depth_map = scan_from_depth(depth, proj["02"], R_RECT_00, rng)
                right = kitti.read_image(drive / "image_03" / "data" / left_path.name)
                frames.append((kitti.read_image(left_path), right, scan))
                expected[f"{day.name}/{drive.name}/image_02/data/{left_path.name}"] = depth_map
            write_drive(out / "raw" / day.name / drive.name, frames)
    training = tree / "kitti2015" / "training"
    eval_frames, calib = [], []
    for left_path in sorted((training / "image_2").glob("*_10.png")):
        name = left_path.name
        eval_frames.append(
            (
                kitti.read_image(left_path),
                kitti.read_image(training / "image_3" / name),
                kitti.read_disparity(training / "disp_occ_0" / name),
                kitti.read_disparity(training / "disp_noc_0" / name),
                kitti.read_obj_map(training / "obj_map" / name),
            )
        )
        h, w = eval_frames[-1][2].shape
        calib.append(cam_to_cam_text(synthetic_projections(w, h), R_RECT_00, w, h))
    write_scene_flow(out / "kitti2015", eval_frames, calib)
    return expected


# ------------------------------------------------------------------------------ real sample


def raw_calib_from_object(calib: dict[str, np.ndarray], width: int, height: int) -> tuple[str, np.ndarray]:
    """The object benchmark's ``calib.txt`` (P0-P3, R0_rect, Tr_velo_to_cam) in raw format:
    the ``calib_cam_to_cam.txt`` text and the velo -> cam [R|T] (3x4)."""
    proj = {f"0{i}": calib[f"P{i}"].reshape(3, 4) for i in range(4)}
    text = cam_to_cam_text(proj, calib["R0_rect"].reshape(3, 3), width, height)
    return text, calib["Tr_velo_to_cam"].reshape(3, 4)


# Hand-drawn boxes of the parked cars in the real sample's left image (x0, y0, x1, y1), as
# KITTI 2015's obj_map would mark them (instance ids 1..4).
REAL_CARS = ((470, 180, 542, 234), (685, 180, 772, 254), (735, 185, 905, 308), (826, 195, 1242, 375))


def mirror_from_real(real: Path, out: Path, train_frames: int = 8) -> np.ndarray:
    """One raw drive of ``train_frames`` copies of the real pair and its scan, and a
    data_scene_flow tree whose one training frame is the pair with GT disparity from the scan
    (f · 0.54 / depth, the inverse of the evaluation's conversion; sparse, as KITTI 2015's GT).
    No KITTI 2015 calibration: 1242 is in Monodepth's focal table. Returns the GT disparity."""
    left, right = kitti.read_image(real / "left.png"), kitti.read_image(real / "right.png")
    h, w = left.shape[:2]
    calib = kitti.read_calib(real / "calib.txt")
    cam_to_cam, velo_to_cam = raw_calib_from_object(calib, w, h)
    day = out / "raw" / "2011_09_26"
    write_day_calib(day, cam_to_cam, velo_to_cam)
    scan = kitti.read_velodyne(real / "lidar.bin")
    write_drive(day / "2011_09_26_drive_0001_sync", [(left, right, scan)] * train_frames)
    raw = kitti.read_raw_calib(day)
    depth = kitti.velodyne_depth(day / "2011_09_26_drive_0001_sync/velodyne_points/data/0000000000.bin", raw)
    focal, baseline = kitti.focal_and_baseline(w)
    disp = np.where(depth > 0, focal * baseline / np.maximum(depth, 1e-6), 0).astype(np.float32)
    obj = np.zeros((h, w), dtype=np.uint8)
    for i, (x0, y0, x1, y1) in enumerate(REAL_CARS, start=1):
        obj[y0:y1, x0:x1] = i  # later (nearer) cars cover earlier ones, as occlusion does
    write_scene_flow(out / "kitti2015", [(left, right, disp, disp, obj)])
    return disp
