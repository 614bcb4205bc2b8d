"""Training pairs: the index of rectified stereo pairs and the augmenting torch Dataset.

The synthetic set and real KITTI differ only in where the files are (the index); how a
sample is read, resized and augmented is the same code for both.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset

from ..errors import DataError
from . import kitti


@dataclass(frozen=True)
class PairIndex:
    """Pairs found on disk (absolute paths) and the listed pairs that were not."""

    pairs: list[tuple[Path, Path]]
    missing: list[tuple[str, str]]


def index_pairs(split_file: str | os.PathLike, image_root: str | os.PathLike) -> PairIndex:
    """Resolve every "left right" line of ``split_file`` under ``image_root``.

    The lists say ``.jpg`` while a KITTI download holds ``.png``: whichever exists is taken.
    Missing pairs are reported, not fatal; an index with no usable pair is a DataError.
    """
    root = Path(image_root)
    found, missing = [], []
    for left, right in kitti.read_split(split_file):
        lp, rp = kitti.resolve_image(root, left), kitti.resolve_image(root, right)
        if lp is None or rp is None:
            missing.append((left, right))
        else:
            found.append((lp, rp))
    if not found:
        raise DataError(f"{split_file}: none of its {len(missing)} pairs exist under {root}")
    return PairIndex(found, missing)


def load_pair_list(path: str | os.PathLike) -> list[tuple[Path, Path]]:
    """Read an index written by the index stage (absolute or repo-relative paths)."""
    return [(Path(a), Path(b)) for a, b in kitti.read_split(path)]


def resize(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """Area resize (the right filter for downscaling), RGB uint8 in and out."""
    if image.shape[:2] == (height, width):
        return image
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


def to_tensor(image: np.ndarray) -> torch.Tensor:
    """HxWx3 uint8 -> 3xHxW float32 in [0, 1]."""
    return torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1).float().div_(255.0)


def augment(left: torch.Tensor, right: torch.Tensor, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Monodepth's augmentation (dissertation 3.4).

    With p = 0.5 the pair is mirrored: the new left view is the flipped right image (so the
    geometry stays a valid left/right pair). With p = 0.5 the same colour change is applied to
    both views: gamma U(0.8, 1.2), brightness x U(0.5, 2.0), per-channel colour x U(0.8, 1.2),
    then clipped to [0, 1].
    """
    u = torch.rand(2, generator=gen)
    if u[0] < 0.5:
        left, right = torch.flip(right, dims=[-1]), torch.flip(left, dims=[-1])
    if u[1] < 0.5:
        gamma = 0.8 + 0.4 * torch.rand(1, generator=gen)
        brightness = 0.5 + 1.5 * torch.rand(1, generator=gen)
        colour = (0.8 + 0.4 * torch.rand(3, 1, 1, generator=gen)) * brightness
        left = (left**gamma * colour).clamp_(0, 1)
        right = (right**gamma * colour).clamp_(0, 1)
    return left, right


class StereoPairs(Dataset):
    """Rectified stereo pairs resized to the network input, optionally augmented.

    Augmentation draws from a generator seeded by (seed, epoch, index), so a sample is the
    same whatever the number of loader workers, and a resumed run sees the same data.
    """

    def __init__(
        self, pairs: list[tuple[Path, Path]], height: int, width: int, augment: bool = False, seed: int = 0
    ) -> None:
        if not pairs:
            raise DataError("StereoPairs: the pair list is empty")
        self.pairs, self.height, self.width = pairs, height, width
        self.augment, self.seed, self.epoch = augment, seed, 0

    def set_epoch(self, epoch: int) -> None:
        """Change the augmentation draws for a new epoch."""
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, i: int) -> dict:
        lp, rp = self.pairs[i]
        left_img, right_img = kitti.read_image(lp), kitti.read_image(rp)
        if left_img.shape != right_img.shape:
            raise DataError(f"{lp} is {left_img.shape[:2]} but its right image {rp} is {right_img.shape[:2]}")
        left = to_tensor(resize(left_img, self.height, self.width))
        right = to_tensor(resize(right_img, self.height, self.width))
        if self.augment:
            seed = int(np.random.SeedSequence([self.seed, self.epoch, i]).generate_state(1)[0])
            gen = torch.Generator().manual_seed(seed)
            left, right = augment(left, right, gen)
        return {"left": left, "right": right, "index": i}
