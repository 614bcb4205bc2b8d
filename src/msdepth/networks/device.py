"""The torch device of a device name (``train.device``, ``msdepth predict --device``)."""

from __future__ import annotations

import torch

from msdepth.errors import MsdepthError


def resolve_device(name: str) -> torch.device:
    """``auto`` picks CUDA when present; asking for CUDA without one is an error."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise MsdepthError("device cuda requested but torch sees no CUDA device (use cpu or auto)")
    return torch.device(name)


def one_pixel_wide_strided_convs(model: torch.nn.Module, height: int, width: int) -> list[str]:
    """The strided convolutions of ``model`` whose input is one pixel wide for an ``height`` x
    ``width`` image (found by one no-grad forward in eval mode, so no running statistic moves).

    Why: PyTorch 2.13's CPU kernel for the bf16 weight gradient of a 3x3 stride-2 convolution on
    a one-pixel-wide input returns NaN at random (uninitialised memory: 10-81 % of calls, by shape,
    measured on an AVX-512-BF16 EPYC; never in fp32, never at widths of 2 or more), so a bf16 CPU run at
    such a size ends in NaN weights.
    """
    found: list[str] = []
    hooks = [
        module.register_forward_pre_hook(
            lambda _m, args, name=name: found.append(name) if args[0].shape[-1] == 1 else None
        )
        for name, module in model.named_modules()
        if isinstance(module, torch.nn.Conv2d) and max(module.stride) > 1
    ]
    was_training = model.training
    device = next(model.parameters()).device
    try:
        model.eval()
        with torch.no_grad():
            model(torch.zeros(1, 3, height, width, device=device))
    finally:
        model.train(was_training)
        for hook in hooks:
            hook.remove()
    return found
