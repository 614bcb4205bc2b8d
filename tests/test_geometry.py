"""Tests of the camera geometry against transcriptions of Monodepth2's ``layers.py`` and known answers."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from msdepth.geometry.camera import (
    _backproject,
    _rotation_from_axis_angle,
    _translation_matrix,
    disp_to_depth,
    project,
    reproject,
    stereo_pose,
    transformation_from_parameters,
)
from msdepth.geometry.warp import warp

# ----------------------------------------------------------------------------- Monodepth2, transcribed
# Written out from nianticlabs/monodepth2 layers.py (element by element, as there), the reference
# the vectorised functions are checked against.


def md2_disp_to_depth(disp, min_depth, max_depth):
    min_disp = 1 / max_depth
    max_disp = 1 / min_depth
    scaled_disp = min_disp + (max_disp - min_disp) * disp
    return scaled_disp, 1 / scaled_disp


def md2_rot_from_axisangle(vec):  # vec: (B, 1, 3)
    angle = torch.norm(vec, 2, 2, True)
    axis = vec / (angle + 1e-7)
    ca, sa = torch.cos(angle), torch.sin(angle)
    C = 1 - ca
    x, y, z = axis[..., 0].unsqueeze(1), axis[..., 1].unsqueeze(1), axis[..., 2].unsqueeze(1)
    xs, ys, zs = x * sa, y * sa, z * sa
    xC, yC, zC = x * C, y * C, z * C
    xyC, yzC, zxC = x * yC, y * zC, z * xC
    rot = torch.zeros((vec.shape[0], 4, 4), dtype=vec.dtype)
    rot[:, 0, 0] = torch.squeeze(x * xC + ca)
    rot[:, 0, 1] = torch.squeeze(xyC - zs)
    rot[:, 0, 2] = torch.squeeze(zxC + ys)
    rot[:, 1, 0] = torch.squeeze(xyC + zs)
    rot[:, 1, 1] = torch.squeeze(y * yC + ca)
    rot[:, 1, 2] = torch.squeeze(yzC - xs)
    rot[:, 2, 0] = torch.squeeze(zxC - ys)
    rot[:, 2, 1] = torch.squeeze(yzC + xs)
    rot[:, 2, 2] = torch.squeeze(z * zC + ca)
    rot[:, 3, 3] = 1
    return rot


def md2_get_translation_matrix(translation_vector):
    T = torch.zeros(translation_vector.shape[0], 4, 4, dtype=translation_vector.dtype)
    t = translation_vector.contiguous().view(-1, 3, 1)
    T[:, 0, 0] = T[:, 1, 1] = T[:, 2, 2] = T[:, 3, 3] = 1
    T[:, :3, 3, None] = t
    return T


def md2_transformation_from_parameters(axisangle, translation, invert=False):
    R = md2_rot_from_axisangle(axisangle)
    t = translation.clone()
    if invert:
        R = R.transpose(1, 2)
        t *= -1
    T = md2_get_translation_matrix(t)
    return torch.matmul(R, T) if invert else torch.matmul(T, R)


def md2_backproject_depth(depth, inv_K, batch_size, height, width):
    meshgrid = np.meshgrid(range(width), range(height), indexing="xy")
    id_coords = torch.from_numpy(np.stack(meshgrid, axis=0).astype(np.float64))
    ones = torch.ones(batch_size, 1, height * width, dtype=torch.float64)
    pix_coords = torch.unsqueeze(torch.stack([id_coords[0].view(-1), id_coords[1].view(-1)], 0), 0)
    pix_coords = torch.cat([pix_coords.repeat(batch_size, 1, 1), ones], 1)
    cam_points = torch.matmul(inv_K[:, :3, :3], pix_coords)
    cam_points = depth.view(batch_size, 1, -1) * cam_points
    return torch.cat([cam_points, ones], 1)


def md2_project_3d(points, K, T, batch_size, height, width, eps=1e-7):
    P = torch.matmul(K, T)[:, :3, :]
    cam_points = torch.matmul(P, points)
    pix_coords = cam_points[:, :2, :] / (cam_points[:, 2, :].unsqueeze(1) + eps)
    pix_coords = pix_coords.view(batch_size, 2, height, width).permute(0, 2, 3, 1).clone()
    pix_coords[..., 0] /= width - 1
    pix_coords[..., 1] /= height - 1
    return (pix_coords - 0.5) * 2


# ----------------------------------------------------------------------------- fixtures


def _random(*shape: int, seed: int = 0) -> torch.Tensor:
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def _k(batch: int, h: int, w: int) -> torch.Tensor:
    # KITTI-like intrinsics at this size (Monodepth2's normalised K: fx = 0.58 W, fy = 1.92 H).
    k = torch.eye(4, dtype=torch.float64)  # homogeneous (4, 4), Monodepth2's convention
    k[0, 0], k[1, 1], k[0, 2], k[1, 2] = 0.58 * w, 1.92 * h, 0.5 * w, 0.5 * h
    return k.expand(batch, 4, 4).clone()


# ----------------------------------------------------------------------------- against the transcription


def test_disp_to_depth_matches_monodepth2_and_its_range() -> None:
    disp = _random(2, 1, 5, 7)
    scaled, depth = disp_to_depth(disp)
    ref_scaled, ref_depth = md2_disp_to_depth(disp, 0.1, 100.0)
    assert torch.equal(scaled, ref_scaled) and torch.equal(depth, ref_depth)
    _, ends = disp_to_depth(torch.tensor([0.0, 1.0], dtype=torch.float64))
    assert torch.allclose(ends, torch.tensor([100.0, 0.1], dtype=torch.float64))
    with pytest.raises(ValueError, match="min_depth < max_depth"):
        disp_to_depth(disp, 1.0, 0.5)


@pytest.mark.parametrize("scale", [0.0, 1e-9, 0.01, 1.0, 3.0])
def test_rotation_matches_monodepth2(scale: float) -> None:
    vec = (_random(4, 3, seed=1) - 0.5) * scale
    ours = _rotation_from_axis_angle(vec)
    assert torch.allclose(ours, md2_rot_from_axisangle(vec[:, None]), atol=1e-12)
    # A rotation up to the 1e-7 added to the angle (the axis is 1e-7/angle short of unit length).
    r = ours[:, :3, :3]
    eye = torch.eye(3, dtype=torch.float64).expand(4, 3, 3)
    assert torch.allclose(r @ r.transpose(1, 2), eye, atol=1e-5)
    assert torch.allclose(torch.linalg.det(r), torch.ones(4, dtype=torch.float64), atol=1e-5)


def test_rotation_known_answer_quarter_turn_about_y() -> None:
    r = _rotation_from_axis_angle(torch.tensor([[0.0, torch.pi / 2, 0.0]], dtype=torch.float64))[0, :3, :3]
    # Right-handed: +z goes to +x, +x to -z.
    assert torch.allclose(
        r @ torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), torch.tensor([1.0, 0, 0], dtype=torch.float64)
    )
    assert torch.allclose(
        r @ torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64),
        torch.tensor([0, 0, -1.0], dtype=torch.float64),
    )


def test_zero_rotation_has_finite_gradient() -> None:
    vec = torch.zeros(1, 3, dtype=torch.float64, requires_grad=True)
    _rotation_from_axis_angle(vec).sum().backward()
    assert torch.isfinite(vec.grad).all()


@pytest.mark.parametrize("invert", [False, True])
def test_transformation_matches_monodepth2(invert: bool) -> None:
    axis_angle, translation = _random(3, 3, seed=2) - 0.5, _random(3, 3, seed=3) - 0.5
    ours = transformation_from_parameters(axis_angle, translation, invert)
    ref = md2_transformation_from_parameters(axis_angle[:, None], translation[:, None], invert)
    assert torch.allclose(ours, ref, atol=1e-12)
    assert torch.allclose(_translation_matrix(translation), md2_get_translation_matrix(translation))


def test_inverted_transformation_is_the_inverse() -> None:
    axis_angle, translation = _random(3, 3, seed=4) - 0.5, _random(3, 3, seed=5) - 0.5
    product = transformation_from_parameters(axis_angle, translation) @ transformation_from_parameters(
        axis_angle, translation, invert=True
    )
    assert torch.allclose(product, torch.eye(4, dtype=torch.float64).expand(3, 4, 4), atol=1e-5)


@pytest.mark.parametrize("size", [(6, 9), (8, 24), (1, 5)])
def test_backproject_and_project_match_monodepth2(size: tuple[int, int]) -> None:
    h, w = size
    depth = 1 + 10 * _random(2, 1, h, w, seed=6)
    k = _k(2, h, w)
    inv_k = torch.linalg.inv(k)
    points = _backproject(depth, inv_k)
    assert torch.allclose(points, md2_backproject_depth(depth, inv_k, 2, h, w), atol=1e-12)
    pose = transformation_from_parameters(0.05 * (_random(2, 3, seed=7) - 0.5), _random(2, 3, seed=8) - 0.5)
    if h > 1:  # Monodepth2 divides by H - 1 = 0 for one row; ours keeps the row at -1
        assert torch.allclose(
            project(points, k, pose, h, w), md2_project_3d(points, k, pose, 2, h, w), atol=1e-10
        )


# ----------------------------------------------------------------------------- known answers


def test_identity_pose_reprojects_to_itself() -> None:
    h, w = 7, 20
    image, depth, k = _random(2, 3, h, w, seed=9), 1 + 30 * _random(2, 1, h, w, seed=10), _k(2, h, w)
    identity = torch.eye(4, dtype=torch.float64).expand(2, 4, 4)
    out = reproject(image, depth, k, torch.linalg.inv(k), identity)
    # Monodepth2 adds 1e-7 to Z before dividing: up to x·1e-7/Z ≈ 1.5e-6 px here, ~1e-6 in value.
    assert torch.allclose(out, image, rtol=0, atol=1e-5)


@pytest.mark.parametrize("baseline", [0.54, -0.3])
def test_x_translation_is_the_stereo_shift(baseline: float) -> None:
    # A point at depth Z seen from a camera moved by b along x lands f·b/Z px further along x:
    # exactly the stereo warp by a disparity of f·b/Z px (as a fraction of the width).
    h, w = 9, 30
    image, depth, k = _random(2, 3, h, w, seed=11), 2 + 20 * _random(2, 1, h, w, seed=12), _k(2, h, w)
    pose = _translation_matrix(torch.tensor([[baseline, 0.0, 0.0]] * 2, dtype=torch.float64))
    for mode in ("border", "zeros"):
        out = reproject(image, depth, k, torch.linalg.inv(k), pose, mode)
        shift = k[:, 0, 0].view(2, 1, 1, 1) * baseline / depth / w
        assert torch.allclose(out, warp(image, shift, mode), rtol=0, atol=1e-5)


def test_reproject_gradient_flows_to_depth_and_pose() -> None:
    h, w = 6, 10
    depth = (1 + 5 * _random(1, 1, h, w, seed=13)).requires_grad_()
    params = torch.tensor([[0.01, -0.02, 0.0]], dtype=torch.float64, requires_grad=True)
    k = _k(1, h, w)
    pose = transformation_from_parameters(params, torch.tensor([[0.1, 0.0, 0.2]], dtype=torch.float64))
    reproject(_random(1, 3, h, w, seed=14), depth, k, torch.linalg.inv(k), pose).sum().backward()
    assert torch.isfinite(depth.grad).all() and depth.grad.abs().sum() > 0
    assert torch.isfinite(params.grad).all() and params.grad.abs().sum() > 0


def test_non_finite_depth_samples_outside_not_crash() -> None:
    h, w = 4, 6
    depth = torch.full((1, 1, h, w), float("nan"), dtype=torch.float64, requires_grad=True)
    k = _k(1, h, w)
    pose = _translation_matrix(torch.tensor([[0.5, 0.0, 0.0]], dtype=torch.float64))
    out = reproject(_random(1, 3, h, w), depth, k, torch.linalg.inv(k), pose)
    out.sum().backward()  # no crash
    assert out.shape == (1, 3, h, w)


def test_bad_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match="rotation_from_axis_angle"):
        _rotation_from_axis_angle(torch.zeros(2, 1, 3))
    with pytest.raises(ValueError, match="backproject"):
        _backproject(torch.zeros(1, 2, 3, 3), torch.eye(4)[None])
    with pytest.raises(ValueError, match="reproject"):
        reproject(
            torch.zeros(1, 3, 4, 4),
            torch.ones(1, 1, 3, 3),
            torch.eye(4)[None],
            torch.eye(4)[None],
            torch.eye(4)[None],
        )


@pytest.mark.parametrize("side", ["l", "r"])
def test_stereo_pose_reprojects_as_monodepths_stereo_warp(side: str) -> None:
    # Monodepth reconstructs the left view with warp(right, -d_left), the right with warp(left, +d_right).
    h, w = 8, 24
    partner, depth, k = _random(1, 3, h, w, seed=15), 2 + 20 * _random(1, 1, h, w, seed=16), _k(1, h, w)
    out = reproject(partner, depth, k, torch.linalg.inv(k), stereo_pose(side, 1, 0.54, torch.float64))
    disp = k[0, 0, 0] * 0.54 / depth / w
    assert torch.allclose(out, warp(partner, -disp if side == "l" else disp), rtol=0, atol=1e-5)
    with pytest.raises(ValueError, match="side"):
        stereo_pose("s", 1)
