"""Monodepth2's ResNet-18 encoder (its ``ResnetEncoder``), for the pose network and the depth network.

The layers carry torchvision's ``resnet18`` names (``conv1``, ``bn1``, ``layer1.0.conv1``, ...),
so a torchvision state dict that a user downloaded loads with :func:`load_pretrained`; nothing
is ever downloaded here. ``input_images`` frames stacked on the channel axis feed one network
(Monodepth2's ``ResNetMultiImageInput``: the pose encoder sees 2 frames).
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
from torch import Tensor, nn

from msdepth.errors import MsdepthError
from msdepth.networks.common import scaled_channels
from msdepth.networks.serialization import load_weights_file

CHANNELS = (64, 64, 128, 256, 512)  # the five feature maps, at 1/2, 1/4, 1/8, 1/16, 1/32
MEAN, STD = 0.45, 0.225  # Monodepth2 normalises [0, 1] images with these before the encoder


class BasicBlock(nn.Module):
    """ResNet's two-convolution residual block, with a 1x1 projection when the shape changes."""

    def __init__(self, in_ch: int, out_ch: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(in_ch, out_ch, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(out_ch)
        self.conv2 = nn.Conv2d(out_ch, out_ch, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(out_ch)
        self.relu = nn.ReLU(inplace=True)
        self.downsample: nn.Module | None = None
        if stride != 1 or in_ch != out_ch:
            self.downsample = nn.Sequential(
                nn.Conv2d(in_ch, out_ch, 1, stride, bias=False), nn.BatchNorm2d(out_ch)
            )

    def forward(self, x: Tensor) -> Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        return self.relu(self.bn2(self.conv2(out)) + identity)


class ResNetEncoder(nn.Module):
    """ResNet-18 without its classifier; ``forward`` returns the five feature maps of :data:`CHANNELS`
    (``width_multiplier`` scales every channel count, as ``model.width_multiplier`` the VGG
    network's; 1.0 = ResNet-18, the only width a torchvision state dict fits)."""

    def __init__(self, input_images: int = 1, width_multiplier: float = 1.0) -> None:
        super().__init__()
        if input_images < 1:
            raise ValueError(f"ResNetEncoder: input_images must be >= 1, got {input_images}")
        self.input_images = input_images
        self.channels = tuple(scaled_channels(c, width_multiplier) for c in CHANNELS)
        stem = self.channels[0]
        self.conv1 = nn.Conv2d(3 * input_images, stem, 7, 2, 3, bias=False)
        self.bn1 = nn.BatchNorm2d(stem)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        widths = self.channels[1:]
        for i, (in_ch, out_ch) in enumerate(zip((stem, *widths[:-1]), widths, strict=True)):
            stride = 1 if i == 0 else 2
            self.add_module(
                f"layer{i + 1}", nn.Sequential(BasicBlock(in_ch, out_ch, stride), BasicBlock(out_ch, out_ch))
            )
        for m in self.modules():  # torchvision's (and Monodepth2's) initialisation
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)

    def forward(self, images: Tensor) -> list[Tensor]:
        """(B, 3·input_images, H, W) in [0, 1] -> features at 1/2 .. 1/32 resolution."""
        x = self.relu(self.bn1(self.conv1((images - MEAN) / STD)))
        features = [x]
        x = self.maxpool(x)
        for i in range(1, 5):
            x = getattr(self, f"layer{i}")(x)
            features.append(x)
        return features


def load_pretrained(encoder: ResNetEncoder, path: str | os.PathLike) -> None:
    """Load a torchvision ``resnet18`` state dict from ``path`` into ``encoder`` (its ``fc`` is dropped).

    For several input images, ``conv1``'s weights are repeated per image and divided by their
    count, as Monodepth2 does, so stacked identical frames give the single-image features.
    Raises MsdepthError naming the file when it is not such a state dict.
    """
    path = Path(path)
    remedy = 'give model.pretrained a torchvision resnet18 state dict (or "" to train from scratch)'
    state = load_weights_file(path, "cpu", what="ResNet-18 state dict", remedy=remedy)
    names = [k for k in state if not isinstance(k, str)]
    if names:  # sorting the missing and unexpected names below would raise a TypeError
        raise MsdepthError(
            f"{path}: not a torchvision resnet18 state dict (a key that is not a parameter name: "
            f"{repr(names[0])[:40]}); {remedy}"
        )
    state = {k: v for k, v in state.items() if not k.startswith("fc.")}
    if isinstance(state.get("conv1.weight"), Tensor) and encoder.input_images > 1:
        n = encoder.input_images
        state["conv1.weight"] = torch.cat([state["conv1.weight"]] * n, dim=1) / n
    expected = encoder.state_dict()
    missing = sorted(set(expected) - set(state))
    extra = sorted(set(state) - set(expected))
    shapes = [
        k
        for k in expected
        if k in state and (not isinstance(state[k], Tensor) or state[k].shape != expected[k].shape)
    ]
    if missing or extra or shapes:
        problem = "; ".join(
            f"{label} {', '.join(keys[:3])}{' ...' if len(keys) > 3 else ''}"
            for label, keys in (("missing", missing), ("unexpected", extra), ("shape of", shapes))
            if keys
        )
        raise MsdepthError(f"{path}: not a torchvision resnet18 state dict ({problem}); {remedy}")
    encoder.load_state_dict(state)
