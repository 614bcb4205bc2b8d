"""LiDAR ground truth: Velodyne scans, raw calibration, and the projection the field evaluates with.

:func:`kitti.lidar_depth_map` is checked against a straightforward per-point transcription of
Monodepth2's ``generate_depth_map(..., vel_depth=True)`` written here, on random clouds that hit
every rule (behind, outside, on the camera plane, several points per pixel) and on the real scan.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from msdepth.data import kitti
from msdepth.errors import DataError
from msdepth.geometry.warp import warp

SHARED = Path(__file__).resolve().parents[2] / "shared"
REAL = SHARED / "real-samples" / "kitti-object-pair"

# KITTI's 2011_09_26 calibration (published numbers): camera-2 projection, rectifying rotation,
# LiDAR -> camera-0 transform.
P2 = np.array(
    [
        [7.215377e02, 0.0, 6.095593e02, 4.485728e01],
        [0.0, 7.215377e02, 1.728540e02, 2.163791e-01],
        [0.0, 0.0, 1.0, 2.745884e-03],
    ]
)
R0 = np.array(
    [
        [9.999239e-01, 9.837760e-03, -7.445048e-03],
        [-9.869795e-03, 9.999421e-01, -4.278459e-03],
        [7.402527e-03, 4.351614e-03, 9.999631e-01],
    ]
)
VELO_TO_CAM = np.array(
    [
        [7.533745e-03, -9.999714e-01, -6.166020e-04, -4.069766e-03],
        [1.480249e-02, 7.280733e-04, -9.998902e-01, -7.631618e-02],
        [9.998621e-01, 7.523790e-03, 1.480755e-02, -2.717806e-01],
    ]
)


def _row(key: str, values) -> str:
    return f"{key}: " + " ".join(f"{v:.6e}" for v in np.ravel(values)) + "\n"


def _write_raw_calib(day: Path, cam_extra: str = "", velo_extra: str = "") -> None:
    day.mkdir(parents=True, exist_ok=True)
    (day / "calib_cam_to_cam.txt").write_text(
        "calib_time: 09-Jan-2012 13:57:47\ncorner_dist: 9.950000e-02\n"
        + _row("R_rect_00", R0)
        + _row("S_rect_02", (1242, 375))
        + _row("R_rect_02", np.eye(3))
        + _row("P_rect_02", P2)
        + cam_extra
    )
    (day / "calib_velo_to_cam.txt").write_text(
        "calib_time: 15-Mar-2012 11:37:16\n"
        + _row("R", VELO_TO_CAM[:, :3])
        + _row("T", VELO_TO_CAM[:, 3])
        + "delta_f: 0.000000e+00 0.000000e+00\n"
        + velo_extra
    )


def reference_depth_map(points, velo_to_cam, rect, proj, shape) -> np.ndarray:
    """Point by point, as the field's code reads: drop x < 0, project with P · R_rect · [R|T],
    pixel = round(u) - 1, round(v) - 1, keep in-image points, nearest x per pixel."""
    velo = np.eye(4)
    velo[: velo_to_cam.shape[0], :] = velo_to_cam
    rect4 = np.eye(4)
    rect4[: rect.shape[0], : rect.shape[1]] = rect
    h, w = shape
    nearest: dict[tuple[int, int], float] = {}
    for x, y, z in np.asarray(points, dtype=np.float64)[:, :3]:
        if not x >= 0:
            continue
        u, v, s = proj @ (rect4 @ (velo @ np.array([x, y, z, 1.0])))
        if s == 0 or not (math.isfinite(u / s) and math.isfinite(v / s)):
            continue
        col, row = round(u / s) - 1, round(v / s) - 1  # Python's round is numpy's: half to even
        if 0 <= col < w and 0 <= row < h:
            nearest[row, col] = min(nearest.get((row, col), math.inf), x)
    out = np.zeros(shape, dtype=np.float32)
    for (row, col), x in nearest.items():
        out[row, col] = x
    return out


def _random_cloud(seed: int, n: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    front = np.c_[rng.uniform(0, 60, n), rng.uniform(-20, 20, n), rng.uniform(-3, 2, n), rng.random(n)]
    behind = np.c_[rng.uniform(-40, 0, n // 4), rng.uniform(-5, 5, n // 4), rng.uniform(-2, 2, n // 4)]
    # x = 0 is kept (only x < 0 is dropped): behind camera 2, such points land mirrored in the
    # image with depth 0 and, being "nearest", blank the pixel, as in Monodepth2.
    plane = np.c_[np.zeros(n // 20), rng.uniform(-0.3, 0.3, n // 20), rng.uniform(-0.3, 0.3, n // 20)]
    special = np.array(
        [
            [0.2718, 0.0, 0.0],  # next to camera 2: a division by almost 0
            [-10.0, 0.0, 0.0],  # behind the LiDAR, would project mirrored into the image
            [np.nan, 1.0, 1.0],
            [20.0, np.nan, 0.0],
            [1e6, 0.0, 0.0],
        ]
    )
    extra = np.r_[behind, plane, special]
    extra = np.c_[extra, np.zeros(len(extra))]
    return np.r_[front, extra].astype(np.float32)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_depth_map_equals_the_reference_on_random_clouds(seed: int) -> None:
    points = _random_cloud(seed, 20_000)
    # A small image: thousands of points compete for each pixel, so "nearest wins" is exercised.
    proj = P2 * np.array([[0.1], [0.1], [1.0]])
    shape = (36, 124)
    got = kitti.lidar_depth_map(points, VELO_TO_CAM, R0, proj, shape)
    assert got.dtype == np.float32 and got.shape == shape
    np.testing.assert_array_equal(got, reference_depth_map(points, VELO_TO_CAM, R0, proj, shape))
    assert (got > 0).mean() > 0.5  # the test would be empty otherwise


def test_depth_value_is_the_lidar_forward_coordinate_and_the_nearest_point_wins() -> None:
    """Two points on one camera ray (same pixel): the nearer one's LiDAR x, not the camera z."""
    cam_to_velo = np.linalg.inv(np.r_[VELO_TO_CAM, [[0, 0, 0, 1]]])
    rect4 = np.eye(4)
    rect4[:3, :3] = R0
    k, t = P2[:, :3], P2[:, 3]
    rays = []
    for depth in (30.0, 12.0, 50.0):
        rectified = np.linalg.solve(k, depth * np.array([101.0, 51.0, 1.0]) - t)  # pixel (50, 100)
        camera = np.linalg.solve(rect4, np.r_[rectified, 1.0])
        rays.append((cam_to_velo @ camera)[:3])
    got = kitti.lidar_depth_map(np.array(rays), VELO_TO_CAM, R0, P2, (375, 1242))
    assert np.count_nonzero(got) == 1
    assert got[50, 100] == pytest.approx(rays[1][0], abs=1e-5)
    assert abs(rays[1][0] - 12.0) > 0.2  # LiDAR x differs from the camera depth by ~0.27 m


def test_transforms_may_be_given_as_3x4_3x3_or_4x4() -> None:
    points = _random_cloud(3, 5_000)
    velo4, rect4 = np.eye(4), np.eye(4)
    velo4[:3] = VELO_TO_CAM
    rect4[:3, :3] = R0
    a = kitti.lidar_depth_map(points, VELO_TO_CAM, R0, P2, (375, 1242))
    b = kitti.lidar_depth_map(points, velo4, rect4, P2, (375, 1242))
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="rect must be 3x3, 3x4 or 4x4"):
        kitti.lidar_depth_map(points, VELO_TO_CAM, R0[:2], P2, (375, 1242))
    with pytest.raises(ValueError, match="proj must be 3x4"):
        kitti.lidar_depth_map(points, VELO_TO_CAM, R0, P2[:, :3], (375, 1242))


def test_no_point_in_view_gives_an_empty_map() -> None:
    behind = np.array([[-5.0, 0.0, 0.0, 0.0]], dtype=np.float32)
    assert not kitti.lidar_depth_map(behind, VELO_TO_CAM, R0, P2, (10, 20)).any()
    assert not kitti.lidar_depth_map(np.zeros((0, 4)), VELO_TO_CAM, R0, P2, (10, 20)).any()


# ------------------------------------------------------------------------------- readers


def test_velodyne_round_trip_and_bad_sizes(tmp_path: Path) -> None:
    points = _random_cloud(4, 100)
    points.tofile(tmp_path / "0000000000.bin")
    np.testing.assert_array_equal(kitti.read_velodyne(tmp_path / "0000000000.bin"), points)
    (tmp_path / "cut.bin").write_bytes(points.tobytes()[:-3])
    with pytest.raises(DataError, match=r"cut\.bin: Velodyne scan is \d+ bytes, not a multiple of 16"):
        kitti.read_velodyne(tmp_path / "cut.bin")
    with pytest.raises(DataError, match=r"missing\.bin: no such Velodyne scan file"):
        kitti.read_velodyne(tmp_path / "missing.bin")
    (tmp_path / "empty.bin").write_bytes(b"")
    assert kitti.read_velodyne(tmp_path / "empty.bin").shape == (0, 4)


def test_velodyne_writer_writes_kittis_bytes(tmp_path: Path) -> None:
    points = _random_cloud(5, 50)
    kitti.write_velodyne(tmp_path / "a" / "0000000000.bin", points.astype(np.float64))  # cast to <f4
    assert (tmp_path / "a" / "0000000000.bin").read_bytes() == points.astype("<f4").tobytes()
    assert [p.name for p in (tmp_path / "a").iterdir()] == ["0000000000.bin"]  # no temp file left
    with pytest.raises(DataError, match=r"b\.bin: a Velodyne scan must be \(N, 4\)"):
        kitti.write_velodyne(tmp_path / "b.bin", points[:, :3])
    assert not (tmp_path / "b.bin").exists()


def test_raw_calibration(tmp_path: Path) -> None:
    _write_raw_calib(tmp_path / "2011_09_26")
    calib = kitti.read_raw_calib(tmp_path / "2011_09_26")
    assert calib.shape == (375, 1242)
    np.testing.assert_allclose(calib.proj, P2)
    np.testing.assert_allclose(calib.rect, R0)
    np.testing.assert_allclose(calib.velo_to_cam[:3], VELO_TO_CAM)
    np.testing.assert_array_equal(calib.velo_to_cam[3], [0, 0, 0, 1])
    scan = tmp_path / "scan.bin"
    points = _random_cloud(5, 3_000)
    points.tofile(scan)
    np.testing.assert_array_equal(
        kitti.velodyne_depth(scan, calib), reference_depth_map(points, VELO_TO_CAM, R0, P2, (375, 1242))
    )


@pytest.mark.parametrize(
    ("file", "drop", "message"),
    [
        ("calib_cam_to_cam.txt", "P_rect_02", "calib_cam_to_cam.txt: no P_rect_02 entry"),
        ("calib_cam_to_cam.txt", "R_rect_00", "calib_cam_to_cam.txt: no R_rect_00 entry"),
        ("calib_cam_to_cam.txt", "S_rect_02", "calib_cam_to_cam.txt: no S_rect_02 entry"),
        ("calib_velo_to_cam.txt", "T", "calib_velo_to_cam.txt: no T entry"),
        ("calib_velo_to_cam.txt", None, r"calib_velo_to_cam.txt: no such calibration file"),
    ],
)
def test_raw_calibration_errors_name_the_file_and_key(tmp_path: Path, file: str, drop, message: str) -> None:
    _write_raw_calib(tmp_path)
    path = tmp_path / file
    if drop is None:
        path.unlink()
    else:
        path.write_text(
            "".join(ln for ln in path.read_text().splitlines(True) if not ln.startswith(drop + ":"))
        )
    with pytest.raises(DataError, match=message):
        kitti.read_raw_calib(tmp_path)


def test_raw_calibration_with_a_wrong_size_is_a_data_error(tmp_path: Path) -> None:
    _write_raw_calib(tmp_path, velo_extra="")
    text = (tmp_path / "calib_velo_to_cam.txt").read_text().replace("T: ", "T: 1.0 ")
    (tmp_path / "calib_velo_to_cam.txt").write_text(text)
    with pytest.raises(DataError, match=r"calib_velo_to_cam.txt: T must be 3 finite numbers, got 4"):
        kitti.read_raw_calib(tmp_path)


# ---------------------------------------------------------------------------- the real scan


def _real() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    if not REAL.is_dir():
        pytest.skip("../shared/real-samples is not available")
    return kitti.read_velodyne(REAL / "lidar.bin"), kitti.read_calib(REAL / "calib.txt")


def test_real_scan_equals_the_reference() -> None:
    points, calib = _real()
    assert points.shape == (103_344, 4)
    args = (calib["Tr_velo_to_cam"].reshape(3, 4), calib["R0_rect"].reshape(3, 3), calib["P2"].reshape(3, 4))
    got = kitti.lidar_depth_map(points, *args, (375, 1242))
    np.testing.assert_array_equal(got, reference_depth_map(points, *args, (375, 1242)))
    assert 17_500 < np.count_nonzero(got) < 18_100  # ~17.8k points with depth
    assert 0 < got[got > 0].min() and got.max() < 80.5


def test_real_lidar_disparity_reconstructs_the_left_image() -> None:
    """GT disparity f·B/depth from the scan, used to sample the right image, must reproduce the left
    image at those pixels far better than the unwarped right image does: the projection, the
    pixel convention and the depth <-> disparity conversion together."""
    points, calib = _real()
    left = kitti.read_image(REAL / "left.png").astype(np.float32) / 255
    right = kitti.read_image(REAL / "right.png").astype(np.float32) / 255
    h, w = left.shape[:2]
    depth = kitti.lidar_depth_map(
        points,
        calib["Tr_velo_to_cam"].reshape(3, 4),
        calib["R0_rect"].reshape(3, 3),
        calib["P2"].reshape(3, 4),
        (h, w),
    )
    focal, baseline = kitti.stereo_from_calib(calib)
    valid = depth > 0
    disparity = np.zeros_like(depth)
    disparity[valid] = focal * baseline / depth[valid]

    def tensor(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(a).permute(2, 0, 1)[None]

    estimate = warp(tensor(right), -torch.from_numpy(disparity / w)[None, None])[0].permute(1, 2, 0).numpy()
    warped = np.abs(estimate - left)[valid].mean()
    unwarped = np.abs(right - left)[valid].mean()
    assert warped < 0.08 and unwarped > 0.15  # README: ~0.067 vs 0.166
