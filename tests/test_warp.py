"""Tests of the horizontal bilinear warp: exact shifts, interpolation, borders, gradients, real data."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from msdepth.geometry.warp import warp

SHARED = Path(__file__).resolve().parents[2] / "shared"
KITTI_PAIR = SHARED / "real-samples" / "kitti-object-pair"


def _constant_disp(image: torch.Tensor, pixels: float) -> torch.Tensor:
    """A constant disparity of ``pixels`` px, expressed as a fraction of the width."""
    b, _, h, w = image.shape
    return torch.full((b, 1, h, w), pixels / w, dtype=image.dtype)


@pytest.fixture
def image() -> torch.Tensor:
    return torch.rand(2, 3, 7, 20, generator=torch.Generator().manual_seed(0), dtype=torch.float64)


def test_zero_disparity_is_identity(image: torch.Tensor) -> None:
    for mode in ("border", "zeros"):
        assert torch.allclose(warp(image, _constant_disp(image, 0.0), mode), image, atol=1e-12)


@pytest.mark.parametrize("shift", [1, 2, 5, -1, -3])
def test_integer_shift_is_exact_away_from_borders(image: torch.Tensor, shift: int) -> None:
    out = warp(image, _constant_disp(image, shift))
    # out(x) = image(x + shift) = roll(image, -shift)(x) wherever x + shift is inside the image.
    expected = torch.roll(image, -shift, dims=-1)
    inside = slice(0, image.shape[-1] - shift) if shift > 0 else slice(-shift, None)
    assert torch.allclose(out[..., inside], expected[..., inside], atol=1e-10)


def test_subpixel_shift_is_linear_interpolation(image: torch.Tensor) -> None:
    frac = 0.3
    out = warp(image, _constant_disp(image, 2 + frac))
    expected = (1 - frac) * image[..., 2:-1] + frac * image[..., 3:]
    assert torch.allclose(out[..., :-3], expected, atol=1e-10)


def test_per_pixel_disparity_samples_each_pixel_independently() -> None:
    row = torch.arange(10, dtype=torch.float64).view(1, 1, 1, 10)
    pixels = torch.tensor([0.0, 1.0, 2.5, -1.0, 0.25, 3.0, -2.0, 0.0, 1.0, -0.5], dtype=torch.float64)
    out = warp(row, (pixels / 10).view(1, 1, 1, 10))
    # The image is its own coordinate: sampling at x + d returns x + d (inside the image).
    assert torch.allclose(out.flatten(), torch.arange(10.0, dtype=torch.float64) + pixels, atol=1e-10)


def test_border_modes(image: torch.Tensor) -> None:
    w = image.shape[-1]
    far_right = _constant_disp(image, w + 5.0)
    far_left = _constant_disp(image, -(w + 5.0))
    # Border replication (Monodepth2) repeats the edge columns; zeros (Monodepth) reads 0.
    assert torch.allclose(warp(image, far_right, "border"), image[..., -1:].expand_as(image), atol=1e-10)
    assert torch.allclose(warp(image, far_left, "border"), image[..., :1].expand_as(image), atol=1e-10)
    assert torch.count_nonzero(warp(image, far_right, "zeros")) == 0
    # Half a pixel past the last column: zeros mode fades to half the edge value.
    half = warp(image, _constant_disp(image, 0.5), "zeros")
    assert torch.allclose(half[..., -1], 0.5 * image[..., -1], atol=1e-10)


def test_rejects_bad_shapes_and_modes(image: torch.Tensor) -> None:
    with pytest.raises(ValueError, match="disparity"):
        warp(image, torch.zeros(2, 2, 7, 20, dtype=image.dtype))
    with pytest.raises(ValueError, match="padding_mode"):
        warp(image, _constant_disp(image, 0.0), "reflection")  # type: ignore[arg-type]


@pytest.mark.parametrize("mode", ["border", "zeros"])
def test_gradients_flow_to_both_inputs(image: torch.Tensor, mode: str) -> None:
    image = image.clone().requires_grad_(True)
    disp = (0.05 * torch.rand(2, 1, 7, 20, dtype=image.dtype)).requires_grad_(True)
    warp(image, disp, mode).square().sum().backward()
    assert image.grad is not None and torch.isfinite(image.grad).all() and image.grad.abs().sum() > 0
    assert disp.grad is not None and torch.isfinite(disp.grad).all() and disp.grad.abs().sum() > 0


def test_gradcheck_disparity() -> None:
    image = torch.rand(1, 2, 3, 9, dtype=torch.float64)
    # Keep sample points off integer pixels, where bilinear interpolation has a kink.
    disp = ((torch.rand(1, 1, 3, 9, dtype=torch.float64) * 0.6 + 0.2 + 1.0) / 9).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda d: warp(image, d), (disp,))


@pytest.mark.parametrize("mode", ["border", "zeros"])
@pytest.mark.parametrize("width", [2, 3, 20])
def test_same_as_grid_sample_far_outside_the_image(mode: str, width: int) -> None:
    """Shifts of up to 3 widths: the same values and gradients as grid_sample on the plain grid
    (the non-finite guard leaves finite coordinates alone)."""
    image = torch.rand(1, 2, 3, width, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    disp = ((torch.rand(1, 1, 3, width, dtype=torch.float64) - 0.5) * 6).requires_grad_(True)
    ours = warp(image, disp, mode)
    (grad,) = torch.autograd.grad(ours.sum(), disp)
    d = disp.detach().requires_grad_(True)
    xs = torch.linspace(-1.0, 1.0, width, dtype=torch.float64)
    grid_x = xs.view(1, 1, width) + 2.0 * width / (width - 1) * d[:, 0]
    grid = torch.stack(
        (grid_x, torch.linspace(-1.0, 1.0, 3, dtype=torch.float64).view(1, 3, 1).expand(1, 3, width)), -1
    )
    ref = torch.nn.functional.grid_sample(image, grid, mode="bilinear", padding_mode=mode, align_corners=True)
    (ref_grad,) = torch.autograd.grad(ref.sum(), d)
    torch.testing.assert_close(ours, ref, rtol=0, atol=1e-12)
    torch.testing.assert_close(grad, ref_grad, rtol=0, atol=1e-12)


def test_non_finite_disparity_neither_crashes_nor_spreads() -> None:
    """NaN, ±inf and 1e30 disparities (a diverged network): finite samples and gradients. In a
    subprocess, because grid_sample's CPU backward segfaults on such coordinates unguarded."""
    script = """
import torch
from msdepth.geometry.warp import warp
image = torch.rand(2, 3, 8, 16, requires_grad=True)
disp = torch.full((2, 1, 8, 16), float("nan"))
disp[0, 0, :3], disp[0, 0, 3:6], disp[1, 0, :3], disp[1, 0, 3:6] = float("inf"), -float("inf"), 1e30, 0.05
disp.requires_grad_(True)
for mode in ("border", "zeros"):
    out = warp(image, disp, mode)
    out.sum().backward()
    assert out.isfinite().all() and image.grad.isfinite().all() and disp.grad.isfinite().all(), mode
    assert disp.grad[1, 0, 3:6].abs().sum() > 0  # the finite disparities still learn
    image.grad = disp.grad = None
print("ok")
"""
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", (proc.returncode, proc.stderr[-2000:])


# ----------------------------------------------------------------------------- real data


def _read_rgb(path: Path) -> np.ndarray:
    import cv2

    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert bgr is not None, f"could not read {path}"
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0


def _read_calib(path: Path) -> dict[str, np.ndarray]:
    calib = {}
    for line in path.read_text().splitlines():
        if ":" in line:
            key, values = line.split(":", 1)
            calib[key.strip()] = np.array(values.split(), dtype=np.float64)
    return calib


@pytest.mark.skipif(not KITTI_PAIR.is_dir(), reason="shared real samples not available")
def test_lidar_disparity_warps_right_image_onto_left() -> None:
    left, right = _read_rgb(KITTI_PAIR / "left.png"), _read_rgb(KITTI_PAIR / "right.png")
    h, w = left.shape[:2]
    calib = _read_calib(KITTI_PAIR / "calib.txt")
    p2, p3 = calib["P2"].reshape(3, 4), calib["P3"].reshape(3, 4)
    r0 = np.eye(4)
    r0[:3, :3] = calib["R0_rect"].reshape(3, 3)
    velo_to_cam = np.eye(4)
    velo_to_cam[:3, :] = calib["Tr_velo_to_cam"].reshape(3, 4)
    focal = p2[0, 0]
    baseline = (p2[0, 3] - p3[0, 3]) / focal
    assert baseline == pytest.approx(0.5327, abs=1e-3)

    scan = np.fromfile(KITTI_PAIR / "lidar.bin", dtype=np.float32).reshape(-1, 4)
    homogeneous = np.c_[scan[:, :3], np.ones(len(scan))]
    projected = (p2 @ r0 @ velo_to_cam @ homogeneous.T).T
    depth = projected[:, 2]
    front = depth > 0
    u = np.round(projected[front, 0] / depth[front]).astype(int)
    v = np.round(projected[front, 1] / depth[front]).astype(int)
    depth = depth[front]
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    u, v, depth = u[inside], v[inside], depth[inside]
    # Far points first, so the nearest point wins where several land on one pixel.
    order = np.argsort(-depth)
    disparity = np.zeros((h, w), dtype=np.float32)
    disparity[v[order], u[order]] = focal * baseline / depth[order]
    valid = disparity > 0
    assert valid.sum() > 15_000

    to_tensor = lambda a: torch.from_numpy(a).permute(2, 0, 1)[None]  # noqa: E731
    left_estimate = warp(to_tensor(right), -torch.from_numpy(disparity / w)[None, None])
    estimate = left_estimate[0].permute(1, 2, 0).numpy()
    warped_l1 = np.abs(estimate - left)[valid].mean()
    unwarped_l1 = np.abs(right - left)[valid].mean()
    assert warped_l1 < 0.09
    assert unwarped_l1 > 0.14
    assert warped_l1 < 0.5 * unwarped_l1
