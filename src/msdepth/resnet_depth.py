"""Monodepth2's depth network: the ResNet-18 encoder (:mod:`msdepth.resnet`) and its depth decoder.

The decoder upsamples the 1/32 features five times by nearest neighbour, each time a 3x3
convolution (reflection padding, ELU) before and after concatenating the encoder's skip, and
outputs a sigmoid disparity at 1/1, 1/2, 1/4 and 1/8 of the input (Monodepth2's
``DepthDecoder``); :func:`msdepth.geometry.disp_to_depth` turns one into depth. Trained from
scratch by default; :func:`msdepth.resnet.load_pretrained` loads a user's torchvision weights.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .resnet import CHANNELS, ResNetEncoder

DECODER_CHANNELS = (16, 32, 64, 128, 256)  # Monodepth2's num_ch_dec, finest first
SCALES = 4


def conv_block(in_ch: int, out_ch: int, activation: bool = True) -> nn.Sequential:
    """Reflection padding, 3x3 convolution and (Monodepth2's ``ConvBlock``) ELU."""
    layers: list[nn.Module] = [nn.ReflectionPad2d(1), nn.Conv2d(in_ch, out_ch, 3)]
    if activation:
        layers.append(nn.ELU(inplace=True))
    return nn.Sequential(*layers)


class DepthDecoder(nn.Module):
    """Encoder features (:data:`msdepth.resnet.CHANNELS`) -> sigmoid disparities, finest first."""

    def __init__(self, encoder_channels: tuple[int, ...] = CHANNELS) -> None:
        super().__init__()
        dec = DECODER_CHANNELS
        self.upconvs0 = nn.ModuleList()
        self.upconvs1 = nn.ModuleList()
        for i in range(5):  # index i = the decoder level of dec[i]; run coarse (4) to fine (0)
            self.upconvs0.append(conv_block(encoder_channels[-1] if i == 4 else dec[i + 1], dec[i]))
            skip = encoder_channels[i - 1] if i > 0 else 0
            self.upconvs1.append(conv_block(dec[i] + skip, dec[i]))
        self.dispconvs = nn.ModuleList(conv_block(dec[s], 1, activation=False) for s in range(SCALES))

    def forward(self, features: list[Tensor]) -> list[Tensor]:
        """The five encoder feature maps -> (B, 1, H/2**s, W/2**s) disparities in (0, 1), s = 0..3."""
        x = features[-1]
        disps: list[Tensor] = []
        for i in range(4, -1, -1):
            x = F.interpolate(self.upconvs0[i](x), scale_factor=2, mode="nearest")
            if i > 0:
                x = torch.cat((x, features[i - 1]), 1)
            x = self.upconvs1[i](x)
            if i < SCALES:
                disps.append(torch.sigmoid(self.dispconvs[i](x)))
        return disps[::-1]


class ResNetDepth(nn.Module):
    """Monodepth2's depth network: one image -> 4 sigmoid disparity maps, finest first. The input
    sides must be multiples of 32 (the encoder's five halvings are undone exactly) and at least 64
    (the reflection padding of the 1/32 features needs 2 px)."""

    def __init__(self) -> None:
        super().__init__()
        self.encoder = ResNetEncoder()
        self.decoder = DepthDecoder()

    def forward(self, image: Tensor) -> list[Tensor]:
        """(B, 3, H, W) in [0, 1] -> disparities at 1/1 .. 1/8."""
        if image.dim() != 4 or any(side % 32 or side < 64 for side in image.shape[-2:]):
            raise ValueError(
                "ResNetDepth: input must be (B, 3, H, W), H and W multiples of 32 and >= 64, "
                f"got {tuple(image.shape)}"
            )
        return self.decoder(self.encoder(image))
