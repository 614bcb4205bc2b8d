"""Training pairs: the index of rectified stereo pairs and the augmenting torch Dataset.

The synthetic set and real KITTI differ only in where the files are (the index); how a
sample is read, resized and augmented is the same code for both.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset

from msdepth.data import kitti
from msdepth.errors import DataError
from msdepth.io import atomic_path
from msdepth.readers import MAX_ARRAY_BYTES, open_regular, read_npy_header


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
    # np.array copies: the image may be a read-only memory-mapped cache slice.
    return torch.from_numpy(np.array(image)).permute(2, 0, 1).float().div_(255.0)


def augment(
    left: torch.Tensor, right: torch.Tensor, gen: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
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
        left, right = colour_jitter([left, right], gen)
    return left, right


def colour_jitter(images: list[torch.Tensor], gen: torch.Generator) -> list[torch.Tensor]:
    """Monodepth's colour change, the same for every image: gamma U(0.8, 1.2), brightness x
    U(0.5, 2.0), per-channel colour x U(0.8, 1.2), then clipped to [0, 1]."""
    gamma = 0.8 + 0.4 * torch.rand(1, generator=gen)
    brightness = 0.5 + 1.5 * torch.rand(1, generator=gen)
    colour = (0.8 + 0.4 * torch.rand(3, 1, 1, generator=gen)) * brightness
    return [(image**gamma * colour).clamp_(0, 1) for image in images]


def check_same_size(
    path: Path, shape: tuple[int, ...], other: Path, other_shape: tuple[int, ...], what: str
) -> None:
    """A right view or GT map of another size than its left image would silently misplace every
    pixel: a DataError naming both files."""
    if tuple(shape[:2]) != tuple(other_shape[:2]):
        raise DataError(f"{path} is {tuple(shape[:2])} but its {what} {other} is {tuple(other_shape[:2])}")


def _read_resized_pair(left: Path, right: Path, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Decode a stereo pair and resize both views to the network input (uint8 RGB)."""
    left_img, right_img = kitti.read_image(left), kitti.read_image(right)
    check_same_size(left, left_img.shape, right, right_img.shape, "right image")
    return resize(left_img, height, width), resize(right_img, height, width)


@dataclass(frozen=True)
class CacheReport:
    """What :func:`build_pair_cache` stored, in cache order, and the pairs it left out."""

    pairs: list[tuple[Path, Path]]
    unreadable: list[tuple[Path, Path, str]]  # (left, right, the reader's error)


def build_pair_cache(
    pairs: list[tuple[Path, Path]], height: int, width: int, path: str | os.PathLike, progress: bool = True
) -> CacheReport:
    """Decode and resize every pair once into a uint8 ``.npy`` array (N, 2, H, W, 3), atomically.

    Training then memory-maps it: no PNG/JPEG decoding or resizing per step, so the loader
    cannot starve the model (the resized images are exactly what :class:`StereoPairs` would
    compute, so results do not change). 29,000 KITTI pairs at 256 x 512 take 22.8 GB.

    A pair with an unreadable image (zero bytes, truncated, not an image) is left out and
    reported, so one bad file among thousands never stops or corrupts training; views of
    different sizes are an error naming both files; no readable pair at all is an error.
    """
    from tqdm import tqdm

    if not pairs:
        raise DataError(f"{path}: no pairs to cache")
    kept: list[tuple[Path, Path]] = []
    unreadable: list[tuple[Path, Path, str]] = []
    with atomic_path(path, suffix=".npy") as tmp:
        cache = np.lib.format.open_memmap(
            tmp, mode="w+", dtype=np.uint8, shape=(len(pairs), 2, height, width, 3)
        )
        for left, right in tqdm(pairs, desc="cache", unit="pair", disable=not progress):
            try:
                left_img, right_img = kitti.read_image(left), kitti.read_image(right)
            except DataError as exc:
                unreadable.append((left, right, str(exc)))
                continue
            check_same_size(left, left_img.shape, right, right_img.shape, "right image")
            cache[len(kept), 0] = resize(left_img, height, width)
            cache[len(kept), 1] = resize(right_img, height, width)
            kept.append((left, right))
        if not kept:
            raise DataError(
                f"{path}: none of the {len(pairs)} pairs is readable; first error: {unreadable[0][2]}"
            )
        cache.flush()
        if len(kept) < len(pairs):  # rewrite with only the rows filled (the .npy header holds the shape)
            with atomic_path(tmp, suffix=".npy") as compact_tmp:
                compact = np.lib.format.open_memmap(
                    compact_tmp, mode="w+", dtype=np.uint8, shape=(len(kept), *cache.shape[1:])
                )
                compact[:] = cache[: len(kept)]
                compact.flush()
                del compact
        del cache
    return CacheReport(kept, unreadable)


def load_pair_cache(path: str | os.PathLike, num_pairs: int, height: int, width: int) -> np.ndarray:
    """Memory-map a cache written by :func:`build_pair_cache`, checking it fits the index and size.

    One open (:func:`msdepth.readers.open_regular`: a FIFO or a folder is one line, never a hang); the
    header is checked against the file's size before the map is made."""
    expected = (num_pairs, 2, height, width, 3)
    with open_regular(path, "pair cache", MAX_ARRAY_BYTES) as file:
        try:
            shape, fortran, dtype = read_npy_header(file, os.fstat(file.fileno()).st_size, str(path))
        except DataError as exc:
            raise DataError(f"{exc}; re-run the cache stage") from None
        if shape != expected or dtype != np.uint8 or fortran:
            raise DataError(
                f"{path}: pair cache is {dtype} {shape}, expected uint8 {expected} for this "
                "index and data.height/width; re-run the cache stage"
            )
        return np.memmap(file, dtype=np.uint8, mode="r", shape=expected, offset=file.tell())


def training_data_sha256(cache: np.ndarray | None, files: Iterable[Path]) -> str:
    """sha256 (hex, 16 digits) of the data a training run learns from: the pair cache's pixels
    where there is one (88 MB at the default size: well under a second), else each file's path,
    size and modification time (reading every image of a real split at each start would cost
    minutes; a file rewritten with the same bytes then only trains anew, never resumes wrongly).

    Part of the checkpoint fingerprint: re-rendered or re-downloaded training images of the same
    count and size must not resume a checkpoint that learned from the old ones.

    Example:
        >>> a = np.zeros((2, 2, 4, 6, 3), np.uint8)
        >>> b = a.copy(); b[1, 0, 3, 5, 2] = 1
        >>> training_data_sha256(a, []) == training_data_sha256(b, [])
        False
    """
    digest = hashlib.sha256()
    if cache is not None:
        digest.update(f"cache {cache.dtype} {tuple(cache.shape)}\0".encode())
        for start in range(0, len(cache), 256):  # a memory map: a slice at a time, never all of it
            digest.update(np.ascontiguousarray(cache[start : start + 256]).tobytes())
        return digest.hexdigest()[:16]
    for path in files:
        try:
            info = os.stat(path)
            digest.update(f"{path}\0{info.st_size}\0{info.st_mtime_ns}\0".encode())
        except OSError:  # the loader names a missing file when it reaches it
            digest.update(f"{path}\0missing\0".encode())
    return digest.hexdigest()[:16]


class StereoPairs(Dataset):
    """Rectified stereo pairs resized to the network input, optionally cropped and augmented.

    Images come from ``cache`` (see :func:`build_pair_cache`) when given, else are decoded
    and resized per sample. Augmentation draws from a generator seeded by (seed, epoch,
    index), so a sample is the same whatever the number of loader workers, and a resumed run
    sees the same data. With ``crop_scale`` s > 1 the pairs are resized (and cached) at s times
    ``height`` x ``width`` and a sample is a random ``height`` x ``width`` window of it, the same
    in both views (a horizontal shift within a rectified pair stays one), drawn from a generator
    of its own so that the augmentation's draws stay those of the uncropped sample.
    """

    def __init__(
        self,
        pairs: list[tuple[Path, Path]],
        height: int,
        width: int,
        augment: bool = False,
        seed: int = 0,
        cache: np.ndarray | None = None,
        crop_scale: int = 1,
    ) -> None:
        if not pairs:
            raise DataError("StereoPairs: the pair list is empty")
        if crop_scale < 1:
            raise DataError(f"StereoPairs: crop_scale must be >= 1, got {crop_scale}")
        self.source = (height * crop_scale, width * crop_scale)
        if cache is not None and cache.shape != (len(pairs), 2, *self.source, 3):
            raise DataError(
                f"StereoPairs: cache shape {cache.shape} does not match {len(pairs)} pairs "
                f"at {self.source[0]}x{self.source[1]}"
            )
        self.pairs, self.height, self.width, self.cache = pairs, height, width, cache
        self.augment, self.seed, self.epoch = augment, seed, 0

    def set_epoch(self, epoch: int) -> None:
        """Change the augmentation draws for a new epoch."""
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.pairs)

    def name(self, i: int) -> str:
        """The file that names sample ``i`` in error messages: its left image."""
        return str(self.pairs[i][0])

    def __getitem__(self, i: int) -> dict:
        if self.cache is not None:
            left_img, right_img = self.cache[i, 0], self.cache[i, 1]
        else:
            left_img, right_img = _read_resized_pair(*self.pairs[i], *self.source)
        if self.source != (self.height, self.width):
            top, left_x = crop_origin(self.source, (self.height, self.width), self.seed, self.epoch, i)
            window = np.s_[top : top + self.height, left_x : left_x + self.width]
            left_img, right_img = left_img[window], right_img[window]
        left, right = to_tensor(left_img), to_tensor(right_img)
        if self.augment:
            left, right = augment(left, right, sample_generator(self.seed, self.epoch, i))
        return {"left": left, "right": right, "index": i}


def crop_origin(
    source: tuple[int, int], crop: tuple[int, int], seed: int, epoch: int, index: int
) -> tuple[int, int]:
    """The (top, left) corner of sample ``index``'s crop in ``epoch``: uniform over every ``crop``
    window of a ``source``-sized image, from a generator of its own (seeded by seed, epoch, index).

    Example:
        >>> crop_origin((128, 384), (64, 192), 0, 0, 0) == crop_origin((128, 384), (64, 192), 0, 0, 0)
        True
    """
    gen = torch.Generator().manual_seed(
        int(np.random.SeedSequence([seed, epoch, index, 1]).generate_state(1)[0])
    )
    top = int(torch.randint(source[0] - crop[0] + 1, (1,), generator=gen))
    left = int(torch.randint(source[1] - crop[1] + 1, (1,), generator=gen))
    return top, left


def sample_generator(seed: int, epoch: int, index: int) -> torch.Generator:
    """The augmentation generator of sample ``index`` in ``epoch``: the same whatever the number of
    loader workers, and in a resumed run."""
    return torch.Generator().manual_seed(
        int(np.random.SeedSequence([seed, epoch, index]).generate_state(1)[0])
    )
