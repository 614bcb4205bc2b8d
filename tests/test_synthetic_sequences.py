"""Synthetic training sequences (data.synthetic.sequence_length): exact poses and depth agree."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from msdepth import render
from msdepth.config.params import CameraConfig, ConfigError, SyntheticConfig
from msdepth.data import kitti, sequences
from msdepth.data.layout import MONO_SPLIT
from msdepth.data.pairs import sample_generator
from msdepth.geometry import camera as geometry
from msdepth.render.kitti_tree import POSES

# Two drives of 4 frames: one sequence of 3 and one of 1 frame each; frame 1 of each has both neighbours.
# The ideal views (the camera off): the reprojection test compares intensities across frames, which
# the camera's per-frame exposure and noise would break (tests/test_camera.py tests the camera).
CFG = SyntheticConfig(
    seed=5, drives=2, train_pairs=8, eval_frames=1, height=64, width=192, sequence_length=3,
    camera=CameraConfig(enabled=False),
)  # fmt: skip


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("sequences")
    render.generate(CFG, path, progress=False, workers=1, lidar=False)
    return path


def _poses(root: Path, drive: str) -> np.ndarray:
    rows = np.loadtxt(root / "raw" / drive / POSES).reshape(-1, 3, 4)
    return np.concatenate([rows, np.tile([[[0, 0, 0, 1.0]]], (len(rows), 1, 1))], axis=1)


def _frame(root: Path, drive: str, number: int) -> tuple[np.ndarray, np.ndarray]:
    """Left image (float, [0, 1]) and its exact depth (inf = sky) of one frame."""
    name = f"{number:010d}.png"
    image = kitti.read_image(root / "raw" / drive / "image_02" / "data" / name).astype(np.float32) / 255
    disp = kitti.read_disparity(root / "raw" / drive / "disp_02" / "data" / name)
    with np.errstate(divide="ignore"):
        depth = np.where(disp > 0, render.focal_for_width(CFG.width) * kitti.KITTI_BASELINE / disp, np.inf)
    return image, depth


def test_split_lists_frames_with_both_neighbours(root: Path) -> None:
    entries = sequences._read_mono_split(root / MONO_SPLIT)
    drives = [render.train_drive(CFG, i)[0] for i in (0, 4)]
    assert [(e.drive, e.frame, e.side) for e in entries] == [
        (d, 1, side) for d in drives for side in ("l", "r")
    ]
    index = sequences._index_sequences(root / "raw", entries, stereo=True)
    assert len(index.samples) == 4 and index.missing_frame == index.missing_neighbour == 0


def test_camera_moves_forward_by_the_step(root: Path) -> None:
    poses = _poses(root, render.train_drive(CFG, 0)[0])
    assert poses.shape == (4, 4, 4)
    step = np.linalg.inv(poses[0]) @ poses[1]  # frame 1's camera in frame 0's
    np.testing.assert_allclose(step, [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.8], [0, 0, 0, 1]], atol=1e-9)
    np.testing.assert_allclose(poses[3][:3, 3], 0, atol=1e-12)  # a new sequence starts at its origin


def test_exact_depth_and_pose_reproject_onto_the_next_frame(root: Path) -> None:
    """A pixel of frame 1 moved by the exact pose lands where frame 0 sees the same point at the
    depth the pose predicts, and frame 0 warped so matches frame 1's image."""
    drive = render.train_drive(CFG, 0)[0]
    poses = _poses(root, drive)
    (target, depth), (source, source_depth) = _frame(root, drive, 1), _frame(root, drive, 0)
    h, w = CFG.height, CFG.width
    calib = (root / "raw" / drive).parent / "calib_cam_to_cam.txt"
    k = torch.from_numpy(sequences._raw_intrinsics(calib, h, w))[None]  # what training reads, float64
    pose = torch.from_numpy(np.linalg.inv(poses[0]) @ poses[1])[None]  # target camera -> source
    finite = np.isfinite(depth) & (depth < 60)
    z = torch.from_numpy(np.where(finite, depth, 1.0).astype(np.float64))[None, None]
    points = pose @ geometry._backproject(z, torch.linalg.inv(k))
    grid = geometry.project(geometry._backproject(z, torch.linalg.inv(k)), k, pose, h, w)[0].numpy()
    u, v = np.rint((grid[..., 0] + 1) / 2 * (w - 1)), np.rint((grid[..., 1] + 1) / 2 * (h - 1))
    inside = finite & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    seen = source_depth[v[inside].astype(int), u[inside].astype(int)]
    predicted = points[0, 2].view(h, w).numpy()[inside]
    assert inside.mean() > 0.5
    assert np.median(np.abs(seen - predicted) / predicted) < 0.01  # one-pixel rounding at most
    image = lambda a: torch.from_numpy(a).permute(2, 0, 1)[None].double()  # noqa: E731
    warped = geometry.reproject(image(source), z, k, torch.linalg.inv(k), pose)[0].permute(1, 2, 0).numpy()
    error = np.abs(warped - target).mean(2)[finite]
    unwarped = np.abs(source - target).mean(2)[finite]
    # Sensor noise (~0.01 per frame) and view-dependent glass remain; the motion is explained.
    assert error.mean() < 0.03 and error.mean() < 0.7 * unwarped.mean()
    assert np.percentile(error, 90) < 0.5 * np.percentile(unwarped, 90)


@pytest.mark.parametrize("length", [1, 2, -1])
def test_sequence_length_needs_neighbours(length: int) -> None:
    from msdepth.config.params import Params

    with pytest.raises(ConfigError, match="sequence_length"):
        SyntheticConfig(sequence_length=length).validate("data.synthetic", Params())


def test_default_renders_no_sequences(tmp_path: Path) -> None:
    cfg = SyntheticConfig(seed=5, drives=1, train_pairs=1, eval_frames=1, height=32, width=64)
    summary = render.generate(cfg, tmp_path, progress=False, workers=1, lidar=False)
    assert "sequence_length" not in summary["config"]
    assert not (tmp_path / MONO_SPLIT).exists() and not list(tmp_path.rglob(POSES))


def test_intrinsics_from_the_raw_calibration(root: Path) -> None:
    """The rendered calib (MATLAB principal point) gives the renderer's camera, scaled with the
    pixel centres when the frames are resized."""
    calib = root / "raw" / render.DATES[0] / "calib_cam_to_cam.txt"
    f, h, w = render.focal_for_width(CFG.width), CFG.height, CFG.width
    np.testing.assert_allclose(
        sequences._raw_intrinsics(calib, h, w)[:3, :3], [[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]]
    )
    half = sequences._raw_intrinsics(calib, h // 2, w // 2)
    np.testing.assert_allclose(
        half[[0, 1, 0, 1], [0, 1, 2, 2]], [f / 2, f / 2, (w / 2 - 1) / 2, (h / 2 - 1) / 2]
    )


def test_a_mirrored_sample_swaps_the_partner_side(root: Path) -> None:
    """Augmentation that mirrors the frames mirrors the principal point and puts the stereo
    partner on the other side; without augmentation a left target's partner is on the right."""
    samples = sequences._index_sequences(
        root / "raw", sequences._read_mono_split(root / MONO_SPLIT), stereo=True
    )
    plain = sequences.SequenceFrames(samples.samples, (-1, 1), 32, 96, stereo=True)
    augmented = sequences.SequenceFrames(samples.samples, (-1, 1), 32, 96, stereo=True, augment=True, seed=1)
    draws = [torch.rand(2, generator=sample_generator(1, 0, i)) for i in range(len(samples.samples))]
    i = next(i for i, u in enumerate(draws) if u[0] < 0.5 and u[1] >= 0.5)  # mirrored, colours kept
    a, b = plain[i], augmented[i]
    assert b["right"] == 1 - a["right"]
    assert b["k"][0, 2] == pytest.approx(95 - a["k"][0, 2].item())
    for key in ("target", "sources", "partner"):
        assert torch.equal(b[key], torch.flip(a[key], dims=[-1]))
    assert a["sources"].shape == (2, 3, 32, 96) and plain[0]["right"] == 0  # split: l before r
