"""Tests of Monodepth2's monocular loss: minimum reprojection, auto-masking, a Lambertian scene."""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn

from msdepth.config.params import params_from_dict
from msdepth.geometry.camera import _translation_matrix, stereo_pose
from msdepth.losses.appearance import build_appearance, terms
from msdepth.losses.monocular import (
    IDENTITY_TIE_BREAK,
    MonocularLoss,
    _minimum_reprojection,
    _partner_pose,
    _reprojection_error,
    monocular_losses,
)
from msdepth.networks.pose import PoseNet
from msdepth.networks.resnet import ResNetEncoder
from msdepth.networks.resnet_depth import DepthDecoder

H, W = 32, 48


def _random(*shape: int, seed: int) -> torch.Tensor:
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def _term(name: str):
    # mix has no per-pixel cost, so the optimum's default cost start is refused: sgbm.
    return build_appearance(
        params_from_dict({"variants": [name], "compare": {"reference": name}, "optimum": {"start": "sgbm"}}),
        name,
    ).double()


def _k(batch: int = 1, h: int = H, w: int = W) -> torch.Tensor:
    k = torch.eye(4, dtype=torch.float64)  # homogeneous (4, 4), Monodepth2's convention
    k[0, 0], k[1, 1], k[0, 2], k[1, 2] = 0.58 * w, 1.92 * h, 0.5 * w, 0.5 * h
    return k.expand(batch, 4, 4).clone()


def _sigmoid_for_depth(depth: float, like: torch.Tensor) -> torch.Tensor:
    """The network output that :func:`msdepth.geometry.camera.disp_to_depth` turns into ``depth``."""
    return torch.full_like(like, (1 / depth - 0.01) / (10 - 0.01))


# ----------------------------------------------------------------------------- hand-built cases


def test_reprojection_error_is_zero_for_equal_images_and_l1_on_flat_ones() -> None:
    x = _random(1, 3, 8, 8, seed=0)
    assert _reprojection_error(x, x).abs().max() < 1e-12
    # Flat images: SSIM's structure terms vanish, luminance of 0.2 vs 0.6 is what SSIM sees.
    a, b = (
        torch.full((1, 3, 5, 5), 0.2, dtype=torch.float64),
        torch.full((1, 3, 5, 5), 0.6, dtype=torch.float64),
    )
    lum = (2 * 0.2 * 0.6 + 0.01**2) / (0.2**2 + 0.6**2 + 0.01**2)
    assert torch.allclose(
        _reprojection_error(a, b),
        torch.full((1, 1, 5, 5), 0.85 * (1 - lum) / 2 + 0.15 * 0.4, dtype=torch.float64),
    )


def test_minimum_reprojection_picks_the_better_source_per_pixel() -> None:
    target = _random(1, 3, 12, 16, seed=1)
    noise = _random(1, 3, 12, 16, seed=2)
    good_left = torch.where(torch.arange(16) < 8, target, noise)  # exact in the left half
    good_right = torch.where(torch.arange(16) >= 8, target, noise)  # exact in the right half
    composite, masked = _minimum_reprojection(target, [good_left, good_right])
    # Away from the seam (the 3x3 SSIM window reaches one column across it), the exact one wins.
    assert torch.equal(composite[..., :7], target[..., :7]) and torch.equal(
        composite[..., 9:], target[..., 9:]
    )
    assert not masked.any()


def test_automask_masks_a_static_pixel() -> None:
    # A static scene (source == target) under a predicted motion: every textured pixel's identity
    # error (0) beats the reprojection, so it is masked; its composite pixel is the unwarped source.
    target = _random(1, 3, 12, 16, seed=3)
    moved = torch.roll(target, 1, dims=-1)
    composite, masked = _minimum_reprojection(target, [moved], identities=[target])
    assert masked.all() and torch.equal(composite, target)
    # A tie goes to the reprojection (deterministic tie-break instead of Monodepth2's noise).
    composite, masked = _minimum_reprojection(target, [target.clone()], identities=[target])
    assert not masked.any() and IDENTITY_TIE_BREAK > 0


def test_gradient_flows_only_through_the_chosen_reconstruction() -> None:
    target = _random(1, 3, 6, 6, seed=4)
    good = target.clone().requires_grad_()
    bad = (1 - target).requires_grad_()
    composite, _ = _minimum_reprojection(target, [bad, good])
    composite.sum().backward()
    assert good.grad.abs().sum() > 0 and bad.grad.abs().sum() == 0


# ----------------------------------------------------------------------------- a Lambertian scene


def _render_plane(depth: float, camera_z: float, h: int = H, w: int = W) -> torch.Tensor:
    """A fronto-parallel plane at world ``depth`` with a smooth Lambertian texture, seen by a camera
    at ``(0, 0, camera_z)`` with :func:`_k`'s intrinsics: each pixel's world point, analytically."""
    k = _k(1, h, w)[0]
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij"
    )
    z = depth - camera_z
    wx, wy = (xs - cx) * z / fx, (ys - cy) * z / fy
    channels = [
        0.5 + 0.4 * torch.sin(a * wx + b * wy + c)
        for a, b, c in ((0.5, 0.3, 0), (0.2, -0.6, 1), (0.7, 0.1, 2))
    ]
    return torch.stack(channels)[None]


@pytest.mark.parametrize("variant", sorted(terms()))
def test_lambertian_scene_with_exact_pose_and_depth_gives_near_zero_loss(variant: str) -> None:
    depth = 10.0
    target = _render_plane(depth, camera_z=0.0)
    before, after = _render_plane(depth, camera_z=-1.0), _render_plane(depth, camera_z=-2.0)
    # Target camera points -> source camera: the sources stand 1 m and 2 m behind (they see more).
    poses = [_translation_matrix(torch.tensor([[0.0, 0.0, dz]], dtype=torch.float64)) for dz in (1.0, 2.0)]
    k = _k()
    loss = MonocularLoss(_term(variant), automask=False)
    shapes = [(1, 1, H >> s, W >> s) for s in range(4)]

    def appearance(d: float) -> float:
        disps = [_sigmoid_for_depth(d, torch.zeros(s, dtype=torch.float64)) for s in shapes]
        return loss(disps, target, [before, after], poses, k, torch.linalg.inv(k))["appearance"].item()

    exact, wrong = appearance(depth), appearance(depth * 2)
    assert exact < 0.01 and exact < wrong / 10, (exact, wrong)


def test_loss_terms_smoothness_and_automask_share() -> None:
    target = _random(2, 3, H, W, seed=5)
    sources = [_random(2, 3, H, W, seed=6), target.clone()]  # the second: static, so masked
    k = _k(2)
    poses = [_translation_matrix(torch.tensor([[0.3, 0.0, 0.0]] * 2, dtype=torch.float64))] * 2
    # Constant disparity: no smoothness; with a disparity ramp, smoothness is the same at any
    # overall level (mean normalisation).
    flat = [torch.full((2, 1, H >> s, W >> s), 0.4, dtype=torch.float64) for s in range(4)]
    out = MonocularLoss(_term("ssim"))(flat, target, sources, poses, k, torch.linalg.inv(k))
    assert out["smoothness"] == 0 and out["automask"] > 0.9
    assert math.isclose(out["total"].item(), out["appearance"].item())
    ramp = [
        torch.linspace(0.1, 0.2, W >> s, dtype=torch.float64).expand(2, 1, H >> s, W >> s) for s in range(4)
    ]
    criterion = MonocularLoss(_term("ssim"))
    first = criterion(ramp, target, sources, poses, k, torch.linalg.inv(k))["smoothness"]
    second = criterion([3 * d for d in ramp], target, sources, poses, k, torch.linalg.inv(k))["smoothness"]
    assert first > 0 and torch.allclose(first, second)


def test_every_variant_trains_through_the_loss() -> None:
    target, source = _random(1, 3, H, W, seed=7), _random(1, 3, H, W, seed=8)
    k = _k()
    pose = _translation_matrix(torch.tensor([[0.1, 0.0, 0.0]], dtype=torch.float64))
    for name in terms():
        disps = [
            torch.full((1, 1, H >> s, W >> s), 0.3, dtype=torch.float64, requires_grad=True) for s in range(4)
        ]
        out = MonocularLoss(_term(name))(disps, target, [source], [pose], k, torch.linalg.inv(k))
        out["total"].backward()
        assert torch.isfinite(out["total"]) and all(torch.isfinite(d.grad).all() for d in disps), name
        assert disps[0].grad.abs().sum() > 0, name


def test_bad_inputs_are_refused() -> None:
    criterion = MonocularLoss(_term("ssim"))
    target, k = _random(1, 3, H, W, seed=9), _k()
    with pytest.raises(ValueError, match="one pose per source"):
        criterion([torch.zeros(1, 1, H, W)], target, [target], [], k, k)
    with pytest.raises(ValueError, match="scale 0 disparity"):
        criterion([torch.zeros(1, 2, H, W)], target, [target], [torch.eye(4)[None]], k, k)
    with pytest.raises(TypeError, match="AppearanceTerm"):
        MonocularLoss(torch.nn.Identity())  # type: ignore[arg-type]


@pytest.mark.parametrize("stereo", [False, True])
def test_a_few_steps_of_m_and_ms_training_lower_the_loss(stereo: bool) -> None:
    """ResNet depth and pose networks on the rendered plane: frames 1 m apart, and in MS a stereo
    partner 0.1 to the right; 4 Adam steps lower the total, and the same seed repeats the bits."""
    totals = []
    for _ in range(2):
        torch.manual_seed(0)
        # Monodepth2's depth network: one sigmoid disparity per scale.
        depth_net, pose_net = nn.Sequential(ResNetEncoder(), DepthDecoder()), PoseNet()
        criterion = MonocularLoss(_term("ssim").float())

        # Two planes (10 m and 20 m) at 64 x 64 (the ResNet's smallest input).
        def frames(z: float) -> torch.Tensor:
            return torch.cat([_render_plane(d, z, 64, 64) for d in (10.0, 20.0)]).float()

        target, neighbours = frames(0.0), {-1: frames(-1.0), 1: frames(1.0)}
        partner = torch.roll(target, -1, dims=-1) if stereo else None
        k = _k(2, 64, 64).float()
        optimiser = torch.optim.Adam([*depth_net.parameters(), *pose_net.parameters()], lr=1e-4)
        run = []
        for _ in range(4):
            out = monocular_losses(depth_net, pose_net, criterion, target, neighbours, k, partner)
            optimiser.zero_grad()
            out["total"].backward()
            optimiser.step()
            run.append(out["total"].item())
        totals.append(run)
    assert totals[0] == totals[1]
    assert totals[0][-1] < totals[0][0], totals[0]


def test_partner_pose_per_target_side() -> None:
    """A batch of left and right targets: each partner's pose is stereo_pose of its own side."""
    target = torch.zeros(3, 3, 8, 8)
    poses = _partner_pose(torch.tensor([0, 1, 0]), target)
    assert poses[:, 0, 3].tolist() == pytest.approx([-0.1, 0.1, -0.1])
    assert torch.equal(poses[1], stereo_pose("r", 1)[0]) and torch.equal(poses[0], stereo_pose("l", 1)[0])
    assert torch.equal(_partner_pose("r", target), stereo_pose("r", 3))
