"""Monodepth2's ATE over 5-frame snippets: known answers and the rendered sequences' poses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from msdepth.errors import DataError
from msdepth.evaluation.pose import _compute_ate, _dump_xyz, _local_poses, _read_poses, _snippet_ates
from msdepth.geometry.camera import transformation_from_parameters


def _trajectory(n: int = 8) -> np.ndarray:
    """Camera-to-world poses of a camera driving forward 1 m per frame while turning slowly."""
    poses = []
    for i in range(n):
        axis = torch.tensor([[0.0, 0.05 * i, 0.0]], dtype=torch.float64)
        pose = transformation_from_parameters(
            axis, torch.tensor([[0.1 * i, 0.0, float(i)]], dtype=torch.float64)
        )
        poses.append(pose[0].numpy())
    return np.stack(poses)


def test_compute_ate_known_answers() -> None:
    gt = np.array([[0.0, 0, 0], [1, 0, 0]])
    assert _compute_ate(gt, np.array([[0.0, 0, 0], [0, 1, 0]])) == pytest.approx(0.5)  # scale 0: |gt| / 2
    assert _compute_ate(gt, gt * 0.3 + 5) == pytest.approx(0.0, abs=1e-12)  # offset and scale removed
    pred = np.array([[0.0, 0, 0], [1, 1, 0]])  # scale 1/2: error (-0.5, 0.5) -> sqrt(0.5) / 2
    assert _compute_ate(gt, pred) == pytest.approx(np.sqrt(0.5) / 2)


def test_dump_xyz_chains_relative_poses() -> None:
    step = np.eye(4)
    step[2, 3] = -1.0  # a camera moving 1 m forward sees the world move 1 m back
    np.testing.assert_allclose(_dump_xyz([step, step]), [[0, 0, 0], [0, 0, -1], [0, 0, -2]])


def test_exact_poses_give_zero_and_scaled_poses_too() -> None:
    gt = _trajectory()
    exact = _local_poses(gt)
    ates = _snippet_ates(exact, gt)
    assert ates.shape == (7,) and np.abs(ates).max() < 1e-12
    scaled = exact.copy()
    scaled[:, :3, 3] *= 0.1  # a monocular network's unknown scale
    assert np.abs(_snippet_ates(scaled, gt)).max() < 1e-12
    wrong = np.repeat(np.eye(4)[None], 7, axis=0)  # standing still: nothing to scale
    assert _snippet_ates(wrong, gt)[0] == pytest.approx(np.sqrt((_dump_xyz(exact[:4]) ** 2).sum()) / 5)


def test_read_poses_of_a_rendered_sequence(tmp_path: Path) -> None:
    path = tmp_path / "poses.txt"
    rows = _trajectory(3)[:, :3].reshape(3, 12)
    np.savetxt(path, rows)
    np.testing.assert_allclose(_read_poses(path), _trajectory(3))
    path.write_text("1 2 3\n")
    with pytest.raises(DataError, match=r"poses.txt: expected 12 finite numbers per line"):
        _read_poses(path)


_POSE = "1 0 0 0 0 1 0 0 0 0 1 0\n"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (_POSE + "1 0 0 0 0 1 0 0 0 0 1\n", "line 2: expected 12 numbers (a 3x4 pose), got 11 field(s)"),
        (_POSE + "# a comment\n1 0 0 0 0 1 0 0 0 0 1 x\n", "line 3: 'x' is not a number"),
        (_POSE + _POSE.replace("1 0\n", "1 nan\n"), "pose 2 of 2 holds a NaN or an infinite number"),
        (
            _POSE + "1 0 0 0 0 1 0 0 0 0 1 \xe9\n",
            "not a KITTI poses file (a byte that is not ASCII text at byte 46)",
        ),
        ("# no pose\n", "expected 12 finite numbers per line (a 3x4 pose), got shape (0, 1)"),
    ],
)
def test_a_malformed_poses_file_is_one_line_naming_it(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "poses.txt"
    path.write_bytes(text.encode("utf-8"))
    with pytest.raises(DataError) as err:
        _read_poses(path)
    assert str(err.value) == f"{path}: {message}"
