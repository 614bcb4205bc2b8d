"""Monodepth2's separate pose network: a ResNet-18 encoder of two stacked frames and its pose decoder.

The decoder outputs axis-angle and translation, scaled by 0.01 (Monodepth2's ``PoseDecoder``,
which keeps the initial poses near the identity). :func:`relative_pose` applies Monodepth2's
frame-order convention: the network always sees the earlier frame first, and the pose
predicted for a frame before the target is inverted, so the result maps target camera points
to the source camera (what :func:`msdepth.geometry.camera.reproject` takes).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from msdepth.geometry.camera import transformation_from_parameters
from msdepth.networks.common import scaled_channels
from msdepth.networks.resnet import CHANNELS, ResNetEncoder

POSE_SCALE = 0.01
DECODER_HIDDEN = 256  # Monodepth2's PoseDecoder channels


class PoseDecoder(nn.Module):
    """Last encoder feature -> per frame ``(axis_angle, translation)``, each (B, frames, 3)."""

    def __init__(
        self, in_channels: int = CHANNELS[-1], frames: int = 2, hidden: int = DECODER_HIDDEN
    ) -> None:
        super().__init__()
        self.frames = frames
        self.squeeze = nn.Conv2d(in_channels, hidden, 1)
        self.pose0 = nn.Conv2d(hidden, hidden, 3, 1, 1)
        self.pose1 = nn.Conv2d(hidden, hidden, 3, 1, 1)
        self.pose2 = nn.Conv2d(hidden, 6 * frames, 1)
        self.relu = nn.ReLU()

    def forward(self, feature: Tensor) -> tuple[Tensor, Tensor]:
        """(B, C, h, w) -> axis-angle and translation, (B, frames, 3) each, ×0.01."""
        x = self.relu(self.squeeze(feature))
        x = self.relu(self.pose1(self.relu(self.pose0(x))))
        out = POSE_SCALE * self.pose2(x).mean((2, 3)).view(-1, self.frames, 6)
        return out[..., :3], out[..., 3:]


class PoseNet(nn.Module):
    """Monodepth2's ``separate_resnet`` pose network: two frames stacked -> their relative pose.

    ``width_multiplier`` scales every channel count of the encoder and of the decoder's hidden
    layers (``model.pose_width_multiplier``); 1.0 is Monodepth2's network.
    """

    def __init__(self, width_multiplier: float = 1.0) -> None:
        super().__init__()
        self.encoder = ResNetEncoder(input_images=2, width_multiplier=width_multiplier)
        hidden = scaled_channels(DECODER_HIDDEN, width_multiplier)
        self.decoder = PoseDecoder(self.encoder.channels[-1], frames=2, hidden=hidden)

    def forward(self, first: Tensor, second: Tensor) -> tuple[Tensor, Tensor]:
        """(B, 3, H, W) frames in temporal order -> the first predicted frame's ``(axis_angle,
        translation)``, (B, 3) each (Monodepth2 predicts two and uses the first)."""
        axis_angle, translation = self.decoder(self.encoder(_stack(first, second))[-1])
        return axis_angle[:, 0], translation[:, 0]


def _stack(first: Tensor, second: Tensor) -> Tensor:
    """The two frames stacked on the channel axis, after a shape check."""
    if first.dim() != 4 or first.shape[1] != 3 or first.shape != second.shape:
        raise ValueError(
            f"PoseNet: expected two (B, 3, H, W) frames, got {tuple(first.shape)} and {tuple(second.shape)}"
        )
    return torch.cat((first, second), 1)


def relative_pose(net: PoseNet, target: Tensor, source: Tensor, offset: int) -> Tensor:
    """(B, 4, 4) pose from the target camera to the source frame at ``offset`` (-1, +1, ...) from it.

    As Monodepth2's ``predict_poses``: frames go in temporal order, and for ``offset < 0`` the
    predicted transformation is inverted.
    """
    if offset == 0:
        raise ValueError("relative_pose: offset 0 is the target frame itself")
    pair = (source, target) if offset < 0 else (target, source)
    axis_angle, translation = net(*pair)
    return transformation_from_parameters(axis_angle, translation, invert=offset < 0)
