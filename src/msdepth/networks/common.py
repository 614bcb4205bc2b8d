"""What msdepth's networks share: the width multiplier's channel rounding and the disparity range.

Kept apart from the networks themselves so that :mod:`msdepth.networks.model_file` can build either depth
network (:mod:`msdepth.networks.vgg`'s or :mod:`msdepth.networks.resnet_depth`'s) without an import cycle.
"""

from __future__ import annotations

MAX_DISPARITY = 0.3  # depth networks output 0.3 * sigmoid, a fraction of the width (Monodepth's)


def scaled_channels(channels: int, multiplier: float) -> int:
    """A layer's channel count at a width multiplier: rounded, at least 1."""
    return max(1, int(round(channels * multiplier)))
