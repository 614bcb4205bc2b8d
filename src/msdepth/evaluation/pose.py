"""Monodepth2's pose evaluation: absolute trajectory error (ATE) over 5-frame snippets.

As Monodepth2's ``evaluate_pose.py``: the relative poses of consecutive frames (each mapping a
frame's camera points to the next frame's camera, :func:`msdepth.networks.pose.relative_pose` with offset
+1) are chained over a snippet of ``track_length`` frames into camera positions, the first
frame at the origin; the predicted positions are shifted so the first ones coincide, scaled by
the least-squares factor onto the ground truth (monocular poses have no scale), and the error
is ``sqrt(sum |scale·pred - gt|²) / frames``. Ground truth comes as KITTI odometry poses: a 3x4
camera-to-world matrix per frame, row-major, one line each (the synthetic sequences' ``poses.txt``).
"""

from __future__ import annotations

import io
import logging
import os
import re
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from msdepth.errors import DataError
from msdepth.readers import read_bounded, read_json_file

if TYPE_CHECKING:
    from msdepth.config.params import Params
    from msdepth.networks.pose import PoseNet

log = logging.getLogger("msdepth")

TRACK_LENGTH = 5  # Monodepth2's snippet length
# The most a poses file may hold: a million poses (data.synthetic's most frames, in one drive) of 12
# numbers as the renderer writes them (%.12e: 19 bytes and a space each), 229 MiB; KITTI odometry's
# longest sequence (00, 4,541 poses) is under 1 MiB.
MAX_POSES_BYTES = 256 << 20


def _read_poses(path: str | os.PathLike) -> np.ndarray:
    """(N, 4, 4) camera-to-world poses of a KITTI odometry poses file; a DataError names a bad file.

    Only a regular, non-empty file of at most :data:`MAX_POSES_BYTES` is read
    (:func:`msdepth.readers.read_bounded`), and only ASCII text (numbers, ``#`` comments) is parsed.
    """
    data = read_bounded(path, "poses", MAX_POSES_BYTES)
    if not data.isascii():  # a pose file is numbers: anything else is another file (or garbage)
        at = re.search(rb"[\x80-\xff]", data).start()  # type: ignore[union-attr]
        raise DataError(f"{path}: not a KITTI poses file (a byte that is not ASCII text at byte {at})")
    try:
        with warnings.catch_warnings():  # "input contained no data": refused below, by the shape
            warnings.simplefilter("ignore", UserWarning)
            rows = np.loadtxt(io.BytesIO(data), ndmin=2, encoding="ascii")
    except ValueError as exc:
        raise DataError(f"{path}: {_pose_problem(data, exc)}") from None
    if rows.shape[1] != 12 or not len(rows):
        raise DataError(f"{path}: expected 12 finite numbers per line (a 3x4 pose), got shape {rows.shape}")
    infinite = np.flatnonzero(~np.isfinite(rows).all(axis=1))
    if infinite.size:  # "nan", "inf", or a number beyond float64 ("9" * 400)
        raise DataError(f"{path}: pose {infinite[0] + 1} of {len(rows)} holds a NaN or an infinite number")
    bottom = np.tile([[[0.0, 0.0, 0.0, 1.0]]], (len(rows), 1, 1))
    return np.concatenate((rows.reshape(-1, 3, 4), bottom), axis=1)


def _pose_problem(data: bytes, exc: ValueError) -> str:
    """The first line of ``data`` (ASCII text that np.loadtxt refused with ``exc``) that is not 12
    numbers, said with its line number: numpy's own message counts rows from 0 in one case and
    from 1 in another, and suggests its ``usecols``."""
    for number, line in enumerate(io.BytesIO(data), 1):  # lazily: no copy of a large file
        fields = line.partition(b"#")[0].split()
        if fields and len(fields) != 12:
            return f"line {number}: expected 12 numbers (a 3x4 pose), got {len(fields)} field(s)"
        for field in fields:
            try:
                float(field)
            except ValueError:
                return f"line {number}: {field[:40].decode()!r} is not a number"
    return f"not a KITTI poses file ({str(exc).split(';')[0][:200]})"


def _local_poses(global_poses: np.ndarray) -> np.ndarray:
    """(N - 1, 4, 4) poses from each frame's camera to the next one's, of (N, 4, 4) camera-to-world
    poses (Monodepth2's ``gt_local_poses``: ``inv(inv(G[i-1]) · G[i])``)."""
    return np.stack(
        [
            np.linalg.inv(np.linalg.inv(a) @ b)
            for a, b in zip(global_poses[:-1], global_poses[1:], strict=True)
        ]
    )


def _dump_xyz(transformations: Sequence[np.ndarray]) -> np.ndarray:
    """(len + 1, 3) camera positions of a chain of relative poses, the first at the origin
    (Monodepth2's ``_dump_xyz``)."""
    cam_to_world = np.eye(4)
    xyzs = [cam_to_world[:3, 3]]
    for transformation in transformations:
        cam_to_world = cam_to_world @ transformation
        xyzs.append(cam_to_world[:3, 3])
    return np.array(xyzs)


def _compute_ate(gt_xyz: np.ndarray, pred_xyz: np.ndarray) -> float:
    """Monodepth2's ``_compute_ate``: RMSE-like error of ``pred_xyz`` (F, 3) against ``gt_xyz`` after
    moving its first position onto the ground truth's and the least-squares scale. A prediction
    that stays at one point gets scale 0 (Monodepth2's division gives NaN there)."""
    aligned = pred_xyz + (gt_xyz[0] - pred_xyz[0])[None, :]
    norm = np.sum(aligned**2)
    scale = np.sum(gt_xyz * aligned) / norm if norm > 0 else 0.0
    return float(np.sqrt(np.sum((aligned * scale - gt_xyz) ** 2)) / gt_xyz.shape[0])


def _snippet_ates(
    predicted: np.ndarray, ground_truth: np.ndarray, track_length: int = TRACK_LENGTH
) -> np.ndarray:
    """The ATE of every snippet of ``track_length`` frames: ``predicted`` (N - 1, 4, 4) relative
    poses of consecutive frames, ``ground_truth`` (N, 4, 4) camera-to-world poses of the same N
    frames. As Monodepth2, snippets start at every frame; those near the end are shorter."""
    if len(predicted) != len(ground_truth) - 1 or len(ground_truth) < 2:
        raise ValueError(
            f"snippet_ates: need N >= 2 ground-truth poses and N - 1 predicted, got "
            f"{len(ground_truth)} and {len(predicted)}"
        )
    gt_local = _local_poses(ground_truth)
    ates = []
    for i in range(len(ground_truth) - 1):
        snippet = slice(i, i + track_length - 1)
        ates.append(_compute_ate(_dump_xyz(gt_local[snippet]), _dump_xyz(predicted[snippet])))
    return np.array(ates)


def _trajectory_ates(
    net: PoseNet,
    paths: Sequence[Path],
    truth: np.ndarray,
    height: int,
    width: int,
    track_length: int = TRACK_LENGTH,
    chunk: int = 64,
) -> np.ndarray:
    """:func:`_snippet_ates` of ``net``'s relative poses between consecutive frames of ``paths``
    (resized to ``height`` x ``width`` as training sees them) against the camera-to-world poses
    ``truth`` of the same frames; ``chunk`` frames are decoded at a time."""
    import torch

    from msdepth.data.kitti import read_image
    from msdepth.data.pairs import resize, to_tensor
    from msdepth.networks.pose import relative_pose

    weight = next(net.parameters(), None)
    device = weight.device if weight is not None else torch.device("cpu")
    net.eval()
    predicted = []
    for start in range(0, len(paths) - 1, chunk):
        span = paths[start : start + chunk + 1]  # one frame of overlap: the next chunk's first pair
        frames = torch.stack([to_tensor(resize(read_image(p), height, width)) for p in span]).to(device)
        with torch.no_grad():
            predicted.append(relative_pose(net, frames[:-1], frames[1:], 1).cpu().double().numpy())
    return _snippet_ates(np.concatenate(predicted), truth, track_length)


def summary(ates: np.ndarray) -> dict:
    """The snippets' mean and std ATE and their count."""
    return {"ate_mean": float(ates.mean()), "ate_std": float(ates.std()), "snippets": int(ates.size)}


def sequence_ates(
    net: PoseNet,
    raw_root: str | os.PathLike,
    sequence_length: int,
    height: int,
    width: int,
    track_length: int = TRACK_LENGTH,
) -> dict:
    """Monodepth2's pose evaluation of ``net`` on the rendered sequences below ``raw_root``.

    Every drive with a ``poses.txt`` (the synthetic set's, ``data.synthetic.sequence_length``
    frames per sequence, the last one maybe shorter) is cut into its sequences; each sequence's
    camera-02 frames give the relative poses of consecutive frames, scored against the exact poses
    (:func:`_trajectory_ates`). Returns the snippets' :func:`summary`.
    """
    from msdepth.data.sequences import frame_path

    raw_root = Path(raw_root)
    files = sorted(raw_root.glob("*/*/poses.txt"))
    if not files or sequence_length < 2:
        raise DataError(f"{raw_root}: no rendered sequences (poses.txt) to evaluate poses on")
    ates = []
    for file in files:
        drive, truth = file.parent.relative_to(raw_root).as_posix(), _read_poses(file)
        for start in range(0, len(truth) - 1, sequence_length):
            span = range(start, min(start + sequence_length, len(truth)))
            if len(span) < 2:
                continue
            paths = [frame_path(raw_root, drive, n, "l") for n in span]
            if any(p is None for p in paths):
                raise DataError(f"{file}: a frame of its sequence at {start} is missing")
            truth_span = truth[span.start : span.stop]
            ates.append(_trajectory_ates(net, paths, truth_span, height, width, track_length))  # type: ignore[arg-type]
    return summary(np.concatenate(ates))


def _odometry_ates(
    net: PoseNet,
    root: str | os.PathLike,
    sequences: Sequence[str],
    height: int,
    width: int,
    track_length: int = TRACK_LENGTH,
) -> dict:
    """Monodepth2's pose evaluation on KITTI odometry: for each of ``sequences`` present below
    ``root`` (``poses/<NN>.txt`` and ``sequences/<NN>/image_2/<frame:06d>.png``, or ``.jpg``), the
    ATE of every 5-frame snippet over all its frames. Returns the :func:`summary` of every
    snippet of the sequences present, with each one's under ``sequences`` (``{}`` when none is);
    a sequence whose poses and images disagree is a DataError."""
    from msdepth.data.kitti import resolve_image

    root, found = Path(root), {}
    ates = []
    for seq in sequences:
        poses = root / "poses" / f"{seq}.txt"
        if not poses.is_file():
            continue
        truth = _read_poses(poses)
        paths = [resolve_image(root, f"sequences/{seq}/image_2/{n:06d}.png") for n in range(len(truth))]
        missing = [n for n, p in enumerate(paths) if p is None]
        if missing:
            raise DataError(
                f"{poses}: {len(truth)} poses, but {len(missing)} of their frames are not in "
                f"{root / 'sequences' / seq / 'image_2'} (first: {missing[0]:06d}.png)"
            )
        ates.append(_trajectory_ates(net, paths, truth, height, width, track_length))  # type: ignore[arg-type]
        found[seq] = summary(ates[-1])
    return {**summary(np.concatenate(ates)), "sequences": found} if found else {}


def add_pose_metrics(params: Params, net: PoseNet, run: str, summary_path: Path) -> None:
    """Monocular run ``run``'s pose ATE by its pose network ``net``, added to its training summary
    ``summary_path`` as ``pose``: on the rendered sequences (:func:`sequence_ates`), or on the KITTI
    odometry sequences that are on disk (:func:`_odometry_ates`, each one's also under
    ``pose.sequences``; none is fetched, so with none there the summary has no ``pose``)."""
    from msdepth.data.layout import layout
    from msdepth.io import write_json

    paths, h, w = layout(params), params.data.height, params.data.width
    if params.data.source == "kitti":
        assert paths.odometry is not None  # the KITTI layout always names it
        pose = _odometry_ates(net, paths.odometry, params.data.kitti.odometry_sequences, h, w)
        if not pose:
            log.info("train %s: no KITTI odometry poses below %s: pose not evaluated", run, paths.odometry)
            return
    else:
        pose = sequence_ates(net, paths.raw_root, params.data.synthetic.sequence_length, h, w)
    write_json(summary_path, {**read_json_file(summary_path, "training summary"), "pose": pose})
    for name, values in {"": pose, **pose.get("sequences", {})}.items():
        log.info(
            "train %s: pose ATE%s %.4f ± %.4f over %d snippets",
            run,
            f" of sequence {name}" if name else "",
            values["ate_mean"],
            values["ate_std"],
            values["snippets"],
        )
