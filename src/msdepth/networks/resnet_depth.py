"""Monodepth2's depth network: the ResNet-18 encoder (:mod:`msdepth.networks.resnet`) and its depth decoder.

The decoder upsamples the 1/32 features five times by nearest neighbour, each time a 3x3
convolution (reflection padding, ELU) before and after concatenating the encoder's skip, and
outputs a sigmoid disparity at 1/1, 1/2, 1/4 and 1/8 of the input (Monodepth2's
``DepthDecoder``); :func:`msdepth.geometry.camera.disp_to_depth` turns one into depth. Trained from
scratch by default; :func:`msdepth.networks.resnet.load_pretrained` loads a user's torchvision weights.

:class:`ResNetMonodepth` is the same network behind the VGG network's interface
(``model.architecture: resnet18``): two output channels (left and right disparity) of
0.3 · sigmoid, so that the stereo loss, the monocular loss, inference and the model files take
either network unchanged.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from msdepth.config.network_sizes import NETWORK_SIDES, sides_problem
from msdepth.networks.common import MAX_DISPARITY, scaled_channels
from msdepth.networks.resnet import CHANNELS, ResNetEncoder

DECODER_CHANNELS = (16, 32, 64, 128, 256)  # Monodepth2's num_ch_dec, finest first
SCALES = 4


def _conv_block(in_ch: int, out_ch: int, activation: bool = True) -> nn.Sequential:
    """Reflection padding, 3x3 convolution and (Monodepth2's ``ConvBlock``) ELU."""
    layers: list[nn.Module] = [nn.ReflectionPad2d(1), nn.Conv2d(in_ch, out_ch, 3)]
    if activation:
        layers.append(nn.ELU(inplace=True))
    return nn.Sequential(*layers)


class DepthDecoder(nn.Module):
    """Encoder features (:data:`msdepth.networks.resnet.CHANNELS`) -> sigmoid disparities, finest first.

    ``width_multiplier`` scales the decoder's channels as the encoder's; ``output_channels`` is
    Monodepth2's ``num_output_channels`` (1; 2 for a left and a right disparity)."""

    def __init__(
        self,
        encoder_channels: tuple[int, ...] = CHANNELS,
        width_multiplier: float = 1.0,
        output_channels: int = 1,
    ) -> None:
        super().__init__()
        dec = tuple(scaled_channels(c, width_multiplier) for c in DECODER_CHANNELS)
        self.upconvs0 = nn.ModuleList()
        self.upconvs1 = nn.ModuleList()
        for i in range(5):  # index i = the decoder level of dec[i]; run coarse (4) to fine (0)
            self.upconvs0.append(_conv_block(encoder_channels[-1] if i == 4 else dec[i + 1], dec[i]))
            skip = encoder_channels[i - 1] if i > 0 else 0
            self.upconvs1.append(_conv_block(dec[i] + skip, dec[i]))
        self.dispconvs = nn.ModuleList(
            _conv_block(dec[s], output_channels, activation=False) for s in range(SCALES)
        )

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


def _check_input(image: Tensor, name: str) -> None:
    """A ValueError unless ``image`` is (B, 3, H, W) with sides the resnet18 network runs at
    (:data:`msdepth.config.network_sizes.NETWORK_SIDES`: multiples of 32, at least 64)."""
    rule = NETWORK_SIDES["resnet18"]
    if image.dim() != 4 or sides_problem("resnet18", image.shape[-2:]) is not None:
        raise ValueError(
            f"{name}: input must be (B, 3, H, W), H and W multiples of {rule.multiple} and "
            f">= {rule.minimum}, got {tuple(image.shape)}"
        )


class ResNetMonodepth(nn.Module):
    """Monodepth2's ResNet-18 depth network with the VGG network's outputs: 4 maps, finest first
    (1/1 .. 1/8), each (B, 2, h, w) = left and right disparity as 0.3 · sigmoid, a fraction of
    the width (:class:`msdepth.networks.vgg.MonodepthVGG`'s convention; the monocular loss reads the
    left one / 0.3 as Monodepth2's sigmoid disparity). ``width_multiplier`` scales encoder and
    decoder (1.0 = Monodepth2's, the only width a torchvision state dict fits). The input sides
    must be multiples of 32 and at least 64.

    ``init_disparity`` (``model.init_disparity``, a fraction of the width) starts every output there,
    as the VGG network's heads: Monodepth2's own start, sigmoid(0), is 0.15 of the width (about
    60 px on a KITTI-sized image), from which a stereo run from scratch collapsed to one constant
    map (issue 52's screen); None keeps Monodepth2's."""

    def __init__(self, width_multiplier: float = 1.0, init_disparity: float | None = None) -> None:
        super().__init__()
        self.encoder = ResNetEncoder(width_multiplier=width_multiplier)
        self.decoder = DepthDecoder(self.encoder.channels, width_multiplier, output_channels=2)
        if init_disparity is not None:
            self.init_outputs(init_disparity)

    def init_outputs(self, disparity: float) -> None:
        """Start every scale's output near ``disparity`` (fraction of width) with small weights."""
        bias = math.log(disparity / (MAX_DISPARITY - disparity))  # logit(disparity / 0.3)
        for block in self.decoder.dispconvs:
            conv = block[1]  # after the reflection padding
            nn.init.normal_(conv.weight, std=1e-3)
            nn.init.constant_(conv.bias, bias)

    def forward(self, image: Tensor) -> list[Tensor]:
        """(B, 3, H, W) in [0, 1] -> 4 disparity maps, finest first."""
        _check_input(image, type(self).__name__)
        return [MAX_DISPARITY * d for d in self.decoder(self.encoder(image))]
