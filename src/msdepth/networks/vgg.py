"""Monodepth's VGG encoder-decoder (Godard et al. 2017; dissertation Figure 2.2).

From the left image it predicts left and right disparities, as a fraction of the image
width, at 4 scales (1/1, 1/2, 1/4, 1/8). ``width_multiplier`` scales every channel count,
so 1.0 is the paper's model (~31 M parameters) and 0.25 runs on a laptop CPU.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from msdepth.config.network_sizes import TRAINING_SIDES, sides_problem
from msdepth.errors import MsdepthError
from msdepth.networks.common import MAX_DISPARITY, scaled_channels
from msdepth.networks.resnet_depth import ResNetMonodepth
from msdepth.networks.serialization import load_weights_file, save_weights_file

if TYPE_CHECKING:
    from msdepth.config.params import Params

# (kernel, channels) of the encoder blocks conv1..conv7; each block is a stride-2 conv
# followed by a stride-1 conv ("convNb"), as in the dissertation's table.
ENCODER = ((7, 32), (5, 64), (3, 128), (3, 256), (3, 512), (3, 512), (3, 512))
# Output channels of upconv7..upconv1 (the iconv after each has the same width).
DECODER = (512, 512, 256, 128, 64, 32, 16)

Norm = Literal["none", "group"]
NORMS = ("none", "group")
Heads = Literal["independent", "residual"]
HEADS = ("independent", "residual")


def group_count(channels: int) -> int:
    """GroupNorm groups for a layer: about 4 channels per group, at most 32 (Wu & He 2018's
    default), and a divisor of ``channels``."""
    return math.gcd(channels, min(32, max(1, channels // 4)))


def _conv(in_ch: int, out_ch: int, kernel: int, stride: int = 1, norm: Norm = "none") -> nn.Sequential:
    # Zero padding of (k-1)//2 then a conv, ELU, as in Monodepth's `conv`; with norm="group" a
    # GroupNorm between them (per image, so batch size and data parallelism do not change it).
    pad = (kernel - 1) // 2
    if norm == "none":
        return nn.Sequential(nn.Conv2d(in_ch, out_ch, kernel, stride, pad), nn.ELU(inplace=True))
    return nn.Sequential(
        nn.Conv2d(in_ch, out_ch, kernel, stride, pad, bias=False),
        nn.GroupNorm(group_count(out_ch), out_ch),
        nn.ELU(inplace=True),
    )


class MonodepthVGG(nn.Module):
    """The VGG depth network; ``forward`` returns 4 disparity maps, finest first.

    Each map has 2 channels (0 = left disparity, 1 = right disparity) in fractions of the
    width at that scale. Any input size works (upsampling follows the skip's size); sizes
    divisible by 8 make the 4 outputs exact halvings.

    ``norm="none"`` and ``heads="independent"`` are the dissertation's network. ``norm="group"``
    puts a GroupNorm after every convolution but the disparity heads. ``heads="residual"`` makes
    each finer head predict a correction to the coarser scale's disparity (added in logit space
    to its bilinear upsampling), coarse to fine: the finest map starts from what the coarse
    scales learned instead of from its own initial value.
    """

    def __init__(
        self,
        width_multiplier: float = 1.0,
        init_disparity: float | None = None,
        norm: Norm = "none",
        heads: Heads = "independent",
    ) -> None:
        super().__init__()
        if norm not in NORMS:
            raise ValueError(f"MonodepthVGG: norm must be one of {NORMS}, got {norm!r}")
        if heads not in HEADS:
            raise ValueError(f"MonodepthVGG: heads must be one of {HEADS}, got {heads!r}")
        self.norm, self.residual = norm, heads == "residual"
        enc = [(k, scaled_channels(c, width_multiplier)) for k, c in ENCODER]
        dec = [scaled_channels(c, width_multiplier) for c in DECODER]
        self.encoder = nn.ModuleList()
        in_ch = 3
        for kernel, ch in enc:
            self.encoder.append(
                nn.Sequential(_conv(in_ch, ch, kernel, 2, norm), _conv(ch, ch, kernel, 1, norm))
            )
            in_ch = ch
        skips = [ch for _, ch in enc[:-1]][::-1]  # conv6b .. conv1b
        self.upconvs = nn.ModuleList()
        self.iconvs = nn.ModuleList()
        self.heads = nn.ModuleList()
        for i, ch in enumerate(dec):
            self.upconvs.append(_conv(in_ch, ch, 3, 1, norm))
            skip = skips[i] if i < len(skips) else 0
            # The three finest iconvs also take the upsampled coarser disparity ("+disp*").
            extra = 2 if i >= 4 else 0
            self.iconvs.append(_conv(ch + skip + extra, ch, 3, 1, norm))
            if i >= 3:  # iconv4 .. iconv1 feed disp4 .. disp1
                self.heads.append(nn.Conv2d(ch, 2, 3, 1, 1))
            in_ch = ch
        if init_disparity is not None:
            self.init_heads(init_disparity)

    def init_heads(self, disparity: float) -> None:
        """Start every head near ``disparity`` (fraction of width) with small weights.

        A network that starts at 0.15 (sigmoid(0)) of the width predicts ~30 px at 192 px
        and can stall in the smoothness minimum; starting near typical disparities lets
        small, short runs learn (see docs/design.md).
        """
        bias = math.log(disparity / (MAX_DISPARITY - disparity))  # logit(disparity / 0.3)
        for i, head in enumerate(self.heads):
            nn.init.normal_(head.weight, std=1e-3)
            # Residual heads: only the coarsest (the first) sets the level, the others add to it.
            nn.init.constant_(head.bias, 0.0 if self.residual and i > 0 else bias)

    def forward(self, image: Tensor) -> list[Tensor]:
        feats = []
        x = image
        for block in self.encoder:
            x = block(x)
            feats.append(x)
        skips = feats[:-1][::-1]  # conv6b .. conv1b
        disps: list[Tensor] = []
        logits: Tensor | None = None
        for i, (up, iconv) in enumerate(zip(self.upconvs, self.iconvs, strict=True)):
            size = skips[i].shape[-2:] if i < len(skips) else image.shape[-2:]
            x = up(F.interpolate(x, size=size, mode="nearest"))
            parts = [x]
            if i < len(skips):
                parts.append(skips[i])
            if i >= 4:
                parts.append(F.interpolate(disps[-1], size=size, mode="nearest"))
            x = iconv(torch.cat(parts, dim=1))
            if i >= 3:
                head = self.heads[i - 3](x)
                if self.residual and logits is not None:
                    head = head + F.interpolate(logits, size=size, mode="bilinear", align_corners=False)
                logits = head
                disps.append(MAX_DISPARITY * torch.sigmoid(head))
        return disps[::-1]


ARCHITECTURES = ("vgg", "resnet18")
DepthNetwork = MonodepthVGG | ResNetMonodepth  # both: image -> 4 maps (B, 2, h, w), finest first


def depth_network(
    architecture: str,
    width_multiplier: float,
    norm: Norm = "none",
    heads: Heads = "independent",
    init_disparity: float | None = None,
) -> DepthNetwork:
    """The depth network of ``model.architecture``: vgg (``norm``, ``heads`` and ``init_disparity``
    are its options) or resnet18 (Monodepth2's, with its own initialisation)."""
    if architecture == "resnet18":
        return ResNetMonodepth(width_multiplier)
    return MonodepthVGG(width_multiplier, init_disparity=init_disparity, norm=norm, heads=heads)


# ----------------------------------------------------------------------------- files


def save_model(
    path: str | os.PathLike,
    model: DepthNetwork,
    criterion: nn.Module,
    params: Params,
    variant: str,
    seed: int,
) -> None:
    """Final weights (the network's and the loss's, e.g. learned level weights) plus what is needed
    to rebuild and run the network, written atomically and reproducibly."""
    state = {
        "model": model.state_dict(),
        "criterion": criterion.state_dict(),
        "width_multiplier": params.model.width_multiplier,
        "norm": params.model.norm,
        "heads": params.model.heads,
        "height": params.data.height,
        "width": params.data.width,
        "variant": variant,
        "seed": seed,
    }
    if params.model.architecture != "vgg":  # a VGG model's file keeps the bytes it had before
        state["architecture"] = params.model.architecture
    save_weights_file(path, state)


# What save_model writes: a file with any other top-level key was not written by msdepth.
MODEL_KEYS = (
    *("model", "criterion", "width_multiplier", "norm", "heads", "height", "width", "variant", "seed"),
    "architecture",
)
MAX_INPUT_SIDE = 4096  # px; a model file's height and width (20000 x 20000 took 4.8 GB to run)
MAX_WIDTH_MULTIPLIER = 16.0


def _metadata_problem(state: dict) -> str | None:
    """Why a model file's top-level entries are not what :func:`save_model` writes; None if they are."""
    unknown = sorted(str(k) for k in state if k not in MODEL_KEYS)
    missing = [k for k in ("model", "width_multiplier", "height", "width") if k not in state]
    if unknown or missing:
        return f"{'unknown entry' if unknown else 'no'} {', '.join((unknown or missing)[:5])}"
    multiplier, norm, heads = (
        state["width_multiplier"],
        state.get("norm", "none"),
        state.get("heads", "independent"),
    )
    if not (
        isinstance(multiplier, (int, float))
        and not isinstance(multiplier, bool)
        and 0 < multiplier <= MAX_WIDTH_MULTIPLIER
    ):
        return f"width_multiplier must be a number in (0, {MAX_WIDTH_MULTIPLIER:g}], got {multiplier!r}"
    rule = TRAINING_SIDES  # a model file's size is its training size
    for key in ("height", "width"):
        value = state[key]
        if not (
            isinstance(value, int)
            and not isinstance(value, bool)
            and rule.fits(value)
            and value <= MAX_INPUT_SIDE
        ):
            return (
                f"{key} must be a multiple of {rule.multiple} from {rule.minimum} to {MAX_INPUT_SIDE} px, "
                f"got {value!r}"
            )
    if norm not in NORMS or heads not in HEADS:
        return f"norm must be one of {NORMS} and heads one of {HEADS}, got {norm!r} and {heads!r}"
    architecture = state.get("architecture", "vgg")
    if architecture not in ARCHITECTURES:
        return f"architecture must be one of {ARCHITECTURES}, got {architecture!r}"
    sides = (state["height"], state["width"])
    rule = sides_problem(architecture, sides)
    if rule is not None:
        return f"a {architecture} network needs sides that are {rule}, got {sides}"
    weights = state["model"]
    if not isinstance(weights, dict) or not all(isinstance(v, Tensor) for v in weights.values()):
        return "its 'model' entry is not a state dict of tensors"
    return None


def _state_dict_problem(model: nn.Module, weights: dict) -> str | None:
    """Which keys or shapes of ``weights`` differ from ``model``'s (e.g. a meta-device model)."""
    expected = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    found = {str(k): tuple(v.shape) for k, v in weights.items()}
    missing = [k for k in expected if k not in found]
    extra = [k for k in found if k not in expected]
    shapes = [
        f"{k} {found[k]} (expected {expected[k]})" for k in expected if k in found and found[k] != expected[k]
    ]
    parts = [
        f"{label} {', '.join(items[:3])}{f' and {len(items) - 3} more' if len(items) > 3 else ''}"
        for label, items in (("missing", missing), ("unexpected", extra), ("shape of", shapes))
        if items
    ]
    return "; ".join(parts) or None


def load_model(path: str | os.PathLike, device: str | torch.device = "cpu") -> tuple[DepthNetwork, dict]:
    """Rebuild the network saved by :func:`save_model`; returns (model in eval mode, metadata).

    The file is read weights-only (:func:`msdepth.networks.serialization.load_weights_file`): one that
    needs code to load is refused, so a shared model cannot run anything. Its metadata must be
    what save_model writes (types, ranges, no other key) and its weights must have the shapes of
    the network the metadata describes, checked on the meta device before anything is allocated;
    otherwise MsdepthError names the file and what differs."""
    path = Path(path)
    if not path.exists():
        raise MsdepthError(f"{path}: no trained model (run the train stage first)")
    state = load_weights_file(path, device, what="model")
    problem = _metadata_problem(state)
    if problem:
        raise MsdepthError(f"{path}: not a model file written by msdepth ({problem})")
    # Files written before the norm, heads and architecture options hold the dissertation's network.
    options = {
        "architecture": state.get("architecture", "vgg"),
        "width_multiplier": state["width_multiplier"],
        "norm": state.get("norm", "none"),
        "heads": state.get("heads", "independent"),
    }
    with torch.device("meta"):
        problem = _state_dict_problem(depth_network(**options), state["model"])
    if problem:
        raise MsdepthError(
            f"{path}: its weights do not fit a {options['architecture']} network of width_multiplier="
            f"{state['width_multiplier']}: {problem}"
        )
    model = depth_network(**options)
    model.load_state_dict(state["model"])
    meta = {k: v for k, v in state.items() if k not in ("model", "criterion")}
    return model.to(device).eval(), meta
