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
