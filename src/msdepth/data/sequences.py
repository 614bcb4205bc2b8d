"""Monodepth2's split files of KITTI raw frames (``drive frame side`` per line) and their sequences.

A line such as ``2011_09_26/2011_09_26_drive_0022_sync 473 r`` names the frame
``<raw root>/2011_09_26/2011_09_26_drive_0022_sync/image_03/data/0000000473.png`` (``l`` = camera
2, ``r`` = camera 3; ``.jpg`` is accepted as well, see :func:`msdepth.data.kitti.resolve_image`).
Its source frames are the frames at the given offsets in the same drive and camera, and its stereo
partner the same frame of the other camera. Frames whose file or a neighbour's is missing are
skipped and counted, as Monodepth2's lists leave out a drive's first and last frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from torch.utils.data import Dataset

from msdepth.data.kitti import list_lines, read_calib, read_image, resolve_image
from msdepth.data.pairs import check_same_size, colour_jitter, resize, sample_generator, to_tensor
from msdepth.errors import DataError

CAMERAS = {"l": "image_02", "r": "image_03"}
OTHER_SIDE = {"l": "r", "r": "l"}


@dataclass(frozen=True)
class SplitEntry:
    """One line of a Monodepth2 split: drive folder (relative to the raw root), frame index, side."""

    drive: str
    frame: int
    side: str


@dataclass(frozen=True)
class SequenceSample:
    """A target frame, its source frames by offset, and its stereo partner (None if absent)."""

    target: Path
    sources: dict[int, Path]
    stereo: Path | None


@dataclass
class SequenceIndex:
    """The usable samples of a split, and how many of its lines were skipped and why."""

    samples: list[SequenceSample] = field(default_factory=list)
    missing_frame: int = 0  # the target frame's file is not on disk
    missing_neighbour: int = 0  # a source frame (or, when required, the stereo partner) is not


def _read_mono_split(path: str | Path) -> list[SplitEntry]:
    """The entries of a Monodepth2 split file; a DataError names the file and line of a bad one."""
    entries = []
    for number, line, fields in list_lines(path, "no such split file"):
        if len(fields) != 3 or fields[2] not in CAMERAS or not fields[1].isdigit():
            raise DataError(
                f"{path}:{number}: expected 'drive frame side' (side l or r, frame a non-negative "
                f"integer), got {line.strip()!r}"
            )
        drive = fields[0].rstrip("/")
        if not drive or ".." in Path(drive).parts or Path(drive).is_absolute():
            raise DataError(f"{path}:{number}: drive {fields[0]!r} must be a folder below the raw root")
        entries.append(SplitEntry(drive, int(fields[1]), fields[2]))
    if not entries:
        raise DataError(f"{path}: split file lists no frames")
    return entries


def frame_path(raw_root: Path, drive: str, frame: int, side: str) -> Path | None:
    """The file of one KITTI raw frame (``.png`` or ``.jpg``), or None if it is not on disk."""
    if frame < 0:
        return None
    return resolve_image(Path(raw_root), f"{drive}/{CAMERAS[side]}/data/{frame:010d}.png")


def _index_sequences(
    raw_root: str | Path,
    entries: Sequence[SplitEntry],
    offsets: Sequence[int] = (-1, 1),
    stereo: bool = False,
) -> SequenceIndex:
    """The samples of ``entries`` whose target and source frames (and, with ``stereo``, the stereo
    partner) are on disk below ``raw_root``; the others are counted in the result."""
    if 0 in offsets or not offsets:
        raise ValueError(f"index_sequences: offsets must be non-zero, got {list(offsets)}")
    index = SequenceIndex()
    for entry in entries:
        target = frame_path(Path(raw_root), entry.drive, entry.frame, entry.side)
        if target is None:
            index.missing_frame += 1
            continue
        sources = {o: frame_path(Path(raw_root), entry.drive, entry.frame + o, entry.side) for o in offsets}
        partner = frame_path(Path(raw_root), entry.drive, entry.frame, OTHER_SIDE[entry.side])
        if any(p is None for p in sources.values()) or (stereo and partner is None):
            index.missing_neighbour += 1
            continue
        index.samples.append(SequenceSample(target, sources, partner))  # type: ignore[arg-type]
    return index


def training_sequences(
    split: Path, raw_root: Path, offsets: Sequence[int], stereo: bool
) -> list[SequenceSample]:
    """The usable samples of the split file ``split`` below ``raw_root`` (:func:`_index_sequences`);
    a DataError names the split when none is usable."""
    index = _index_sequences(raw_root, _read_mono_split(split), offsets, stereo)
    if not index.samples:
        raise DataError(
            f"{split}: no usable frame below {raw_root} ({index.missing_frame} missing, "
            f"{index.missing_neighbour} without a neighbour{' or stereo partner' if stereo else ''})"
        )
    return index.samples


def _sample_side(sample: SequenceSample) -> str:
    """``l`` or ``r``: the camera of the sample's target frame (``.../image_02/data/N.png`` is ``l``)."""
    return "l" if sample.target.parent.parent.name == CAMERAS["l"] else "r"


def _raw_intrinsics(calib_path: Path, height: int, width: int) -> np.ndarray:
    """The (4, 4) intrinsics of camera 02 from a raw day's ``calib_cam_to_cam.txt``, scaled to
    images resized to ``height`` x ``width`` (pixel centres: ``x' = (x + 0.5)·W'/W - 0.5``).

    ``P_rect_02``'s principal point is in KITTI's MATLAB convention (1-based pixels), as
    :func:`msdepth.render.calib_text` writes it; one is taken off."""
    calib = read_calib(calib_path)
    proj, size = calib.get("P_rect_02"), calib.get("S_rect_02")
    if proj is None or size is None or proj.size != 12 or size.size != 2 or not np.isfinite(proj).all():
        raise DataError(f"{calib_path}: needs P_rect_02 (12 numbers) and S_rect_02 (width, height)")
    if not (size > 0).all():
        raise DataError(f"{calib_path}: S_rect_02 must be a positive width and height, got {size}")
    sx, sy = width / size[0], height / size[1]
    proj = proj.reshape(3, 4)
    k = np.eye(4)
    k[0, 0], k[1, 1] = proj[0, 0] * sx, proj[1, 1] * sy
    k[0, 2], k[1, 2] = (proj[0, 2] - 1 + 0.5) * sx - 0.5, (proj[1, 2] - 1 + 0.5) * sy - 0.5
    return k


class SequenceFrames(Dataset):
    """Monodepth2's training samples: a target frame, its source frames (in ``offsets`` order) and,
    with ``stereo``, its stereo partner, resized to ``height`` x ``width``, with the intrinsics of
    the target's raw day (:func:`_raw_intrinsics`).

    Augmentation (Monodepth2's, with Monodepth's colour change of :func:`colour_jitter`): with
    p = 0.5 every frame is mirrored, which puts the partner on the other side (``side`` flips and
    the principal point is mirrored); with p = 0.5 the same colour change is applied to every frame.
    The generator is :func:`~msdepth.data.pairs.sample_generator`'s, as for stereo pairs.
    """

    def __init__(
        self,
        samples: Sequence[SequenceSample],
        offsets: Sequence[int],
        height: int,
        width: int,
        stereo: bool = False,
        augment: bool = False,
        seed: int = 0,
    ) -> None:
        if not samples:
            raise DataError("SequenceFrames: no usable sample (every target misses a frame or a neighbour)")
        if stereo and any(s.stereo is None for s in samples):
            raise DataError(f"SequenceFrames: {samples[0].target}: a sample has no stereo partner")
        self.samples, self.offsets, self.height, self.width = list(samples), tuple(offsets), height, width
        self.stereo, self.augment, self.seed, self.epoch = stereo, augment, seed, 0
        self._intrinsics: dict[Path, np.ndarray] = {}

    def set_epoch(self, epoch: int) -> None:
        """Change the augmentation draws for a new epoch."""
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.samples)

    def name(self, i: int) -> str:
        """The file that names sample ``i`` in error messages: its target frame."""
        return str(self.samples[i].target)

    def intrinsics(self, sample: SequenceSample) -> np.ndarray:
        """The (4, 4) intrinsics of ``sample``'s raw day at the training size (read once per day)."""
        calib = sample.target.parents[3] / "calib_cam_to_cam.txt"
        if calib not in self._intrinsics:
            self._intrinsics[calib] = _raw_intrinsics(calib, self.height, self.width)
        return self._intrinsics[calib]

    def __getitem__(self, i: int) -> dict:
        sample = self.samples[i]
        paths = [sample.target, *(sample.sources[o] for o in self.offsets)]
        paths += [sample.stereo] if self.stereo else []
        decoded = [read_image(path) for path in paths]
        for path, image in zip(paths[1:], decoded[1:], strict=True):  # a neighbour of another size
            check_same_size(path, image.shape, sample.target, decoded[0].shape, "target frame")
        images = [to_tensor(resize(image, self.height, self.width)) for image in decoded]
        k, side = self.intrinsics(sample).copy(), _sample_side(sample)
        if self.augment:
            gen = sample_generator(self.seed, self.epoch, i)
            u = torch.rand(2, generator=gen)
            if u[0] < 0.5:
                images = [torch.flip(image, dims=[-1]) for image in images]
                k[0, 2], side = self.width - 1 - k[0, 2], OTHER_SIDE[side]
            if u[1] < 0.5:
                images = colour_jitter(images, gen)
        batch = {"target": images[0], "sources": torch.stack(images[1 : 1 + len(self.offsets)]), "index": i}
        batch |= {"k": torch.from_numpy(k).float(), "right": int(side == "r")}
        if self.stereo:
            batch["partner"] = images[-1]
        return batch
