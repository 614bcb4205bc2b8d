"""The network-free instruments on an extra evaluation set (``eval.extra_sets``), frame by frame:
the stages ``match_set@<set>-<variant>``, ``sgbm_set@<set>`` and ``optimum_set@<set>-<variant>``
(stages/match_set.py, stages/optimum_set.py) call these.

- The cost start (SGM on the variant's own cost volume) and OpenCV's SGBM, unrefined, exactly as
  the optimum starts from them (:func:`msdepth.optimum.starts.start_disparity`: matched at the
  frame's own size capped by ``optimum.max_width``, its left view resampled to the frame's size).
  On the default frames, narrower than the cap, that is the ``match`` stages' disparity.
- The optimum at each weight of ``optimum.set_weights`` (:func:`msdepth.optimum.solver.optimum_disparities`):
  ``optimum.smoothness_weight`` alone by default; ``smoothness_sweep``'s weights there on request.

Each is scored with the set's full-image suite (:func:`msdepth.evaluation.results.score_set`: the
exact classes where the set has them, D1 and EPE) and its ROI suite on the set's boxes
(``data/index/set_rois/<set>.csv``), as the run the default frames name it
(:func:`~msdepth.pipeline.paths.match_run`, :func:`~msdepth.pipeline.paths.optimum_run`).

One frame in memory at a time while matching or optimising: each frame's disparity goes to a
scratch folder the stage owns (:func:`_scratch_dir`, below ``checkpoints/``, not a DVC output),
written atomically, so a killed run redoes only the frames it had not finished. The folder holds a
key (:func:`_scratch_key`: the instrument, the params it reads, the set index's hash, every image's
size and modification time, the code's fingerprint) and is emptied when the key differs; it is
removed once the metrics are written. With ``optimum.jobs`` > 1 the frames run in worker processes
that end with the stage, even when it is killed (:func:`msdepth.optimum.workers.worker_pool`).
Scoring then reads the set's GT and depth maps, as the networks' ``eval_set`` stage does.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import shutil
import time
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from msdepth.config.checks import has_per_pixel_cost
from msdepth.config.params import Params
from msdepth.errors import ConfigError, DataError, MsdepthError
from msdepth.optimum.frames import checked_matcher
from msdepth.pipeline.paths import (
    CHECKPOINTS,
    SGBM,
    match_run,
    optimum_run,
    source_digest,
)
from msdepth.readers import read_json_file, read_npy_file

log = logging.getLogger("msdepth")

SCRATCH = CHECKPOINTS / "sets"  # <set>/<run>/: a set stage's per-frame disparities until it is scored
KEY = "key.json"  # what a scratch folder's frames were computed with (_scratch_key)
# A frame's disparity (fraction of the width, at the working size) in its scratch folder: row i of the index.
FRAME_FILE = "frame{:06d}.npy"

# The modules (every .py file of a package) whose code shapes a scratch frame: their bytes are part of
# the scratch key, so frames written by older code are redone. Each is a dep of the set stages in
# dvc.yaml (a test keeps them so).
OPTIMUM_MODULES = (
    "optimum",
    "losses/appearance",
    "losses/monodepth.py",
    "losses/objective.py",
    "losses/ssim.py",
    "losses/ssim_kernels.py",
    "config/variants",
    "geometry",
    "data/kitti.py",
    "data/imagefile.py",
    "data/pairs.py",
)

Disparity = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (left, right) uint8 RGB -> (h, w) fraction


def _scratch_dir(name: str, run: str, root: Path = SCRATCH) -> Path:
    """The scratch folder of run ``run`` on extra set ``name``: ``checkpoints/sets/<set>/<run>``."""
    return Path(root) / name / run


def _scratch_key(params: Params, instrument: str, variant: str | None, set_index: Path) -> dict:
    """What a scratch folder's frames depend on: the instrument, the ``optimum`` and ``loss`` sections,
    the variant's own section (for SGM and the optimum), the sha256 of the set's index, every image's
    path, size and modification time (:func:`msdepth.data.pairs.training_data_sha256`: images
    replaced under the same names are new inputs) and the code's fingerprint (:data:`OPTIMUM_MODULES`,
    :func:`msdepth.pipeline.paths.source_digest`), as JSON reads it back (a resumed run compares it
    with the folder's :data:`KEY`)."""
    from msdepth.data.eval_index import read_eval_index
    from msdepth.data.pairs import training_data_sha256
    from msdepth.readers import file_sha256

    index = read_eval_index(set_index)
    images = [Path(p) for row in index.itertuples() for p in (row.left, row.right)]
    key = {
        "instrument": instrument,
        "set_index_sha256": file_sha256(set_index, "index"),
        "images": training_data_sha256(None, images),
        "code": source_digest(Path(__file__).resolve().parents[1], OPTIMUM_MODULES),
        # jobs: how many frames run at once, not what a frame's result is
        "optimum": {k: v for k, v in dataclasses.asdict(params.optimum).items() if k != "jobs"},
        "loss": dataclasses.asdict(params.loss),
    }
    if variant is not None:
        key[variant] = dataclasses.asdict(params.appearance[variant])
    return json.loads(json.dumps(key, default=str))


def _open_scratch(folder: Path, key: dict) -> int:
    """Make ``folder`` hold the frames of ``key`` only: kept when its :data:`KEY` equals ``key``,
    else removed and started anew with that key. Returns the number of frames kept."""
    from msdepth.io import write_json

    path = folder / KEY
    try:
        same = read_json_file(path, "scratch key") == key
    except DataError:
        same = False
    if not same:
        shutil.rmtree(folder, ignore_errors=True)
        write_json(path, key)
    return len(list(folder.glob(FRAME_FILE.replace("{:06d}", "*"))))


def _remove_scratch(folder: Path, root: Path = SCRATCH) -> None:
    """Remove a finished run's scratch ``folder`` and its parents up to ``root`` left empty."""
    shutil.rmtree(folder, ignore_errors=True)
    for parent in folder.parents:
        if not parent.is_relative_to(root):
            break
        try:
            parent.rmdir()
        except OSError:  # not empty: another run's scratch
            break


@dataclasses.dataclass(frozen=True)
class SetInstrument:
    """A network-free instrument as a picklable callable ``(left, right) -> (h, w)`` disparity
    (fraction of the width), so that worker processes (``optimum.jobs``) can run it.

    ``start``: ``cost`` (SGM on ``matcher``'s cost volume) or ``sgbm`` (``matcher`` ``sgbm``), as
    :func:`msdepth.optimum.starts.start_disparity` matches them; ``optimum``: ``matcher``'s optimum at
    smoothness weight ``weight`` (:func:`msdepth.optimum.solver.optimum_disparities`).
    """

    params: Params
    start: str
    matcher: str
    weight: float | None = None

    def __call__(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """The left view's disparity of one uint8 RGB pair."""
        if self.start == "optimum":
            from msdepth.optimum.solver import optimum_disparities

            pair = [(left, right)]
            return optimum_disparities(pair, self.params, self.matcher, self.weight, progress=False)[0]
        from msdepth.optimum.starts import start_disparity

        return start_disparity(left, right, self.params, self.matcher, self.start)[0]


def _frame(disparity: Disparity, left: str, right: str, path: Path) -> float:
    """Read one pair, save its ``disparity`` atomically at ``path``; the seconds it took."""
    from msdepth.data.kitti import read_image
    from msdepth.io import save_npy

    started = time.perf_counter()
    save_npy(path, np.asarray(disparity(read_image(left), read_image(right)), dtype=np.float32))
    return time.perf_counter() - started


def frame_disparities(
    index: pd.DataFrame, folder: Path, disparity: Disparity, label: str, jobs: int = 1, threads: int = 1
) -> None:
    """``disparity`` of every row ``(left, right)`` of ``index`` not yet in ``folder``, each saved
    atomically as :data:`FRAME_FILE`; progress (frame, seconds) logged per frame.

    One frame at a time, or with ``jobs`` > 1 that many frames at once in worker processes
    (:func:`msdepth.optimum.workers.worker_pool`: spawned, ending with this process even when it is
    killed, each with ``threads`` torch threads and one frame in memory; ``disparity`` must pickle, as a
    :class:`SetInstrument` does). The first failure stops the run: frames not yet started are
    cancelled, the finished ones kept for the next run.
    """
    total = len(index)
    rows = enumerate(index.itertuples())
    todo = [(i, row) for i, row in rows if not (folder / FRAME_FILE.format(i)).is_file()]
    if len(todo) < total:
        log.info("%s: resuming, %d of %d frames done", label, total - len(todo), total)
    if jobs == 1 or len(todo) < 2:
        for i, row in todo:
            seconds = _frame(disparity, row.left, row.right, folder / FRAME_FILE.format(i))
            log.info("%s: frame %d/%d (%s) in %.1f s", label, i + 1, total, row.frame, seconds)
        return
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    from msdepth.optimum.workers import worker_pool

    pool = worker_pool(min(jobs, len(todo)), threads)  # spawned; they end with this process
    try:
        running = {
            pool.submit(_frame, disparity, row.left, row.right, folder / FRAME_FILE.format(i)): (i, row)
            for i, row in todo
        }
        for future in as_completed(running):
            i, row = running[future]
            log.info("%s: frame %d/%d (%s) in %.1f s", label, i + 1, total, row.frame, future.result())
    except BrokenProcessPool:
        raise MsdepthError(
            f"{label}: a worker process died (killed, or out of memory: lower optimum.jobs); "
            "the frames it finished are kept"
        ) from None
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _score_scratch(
    params: Params, name: str, run: str, index: pd.DataFrame, folder: Path, rois: Path | None
) -> None:
    """The frames' disparities in ``folder`` as depth at each frame's GT size
    (:func:`msdepth.evaluation.suites.depth_maps`, one frame at a time), scored on set ``name`` (and
    its boxes ``rois``) as run ``run`` (:func:`msdepth.evaluation.results.score_set`)."""
    from msdepth.evaluation.results import score_set
    from msdepth.evaluation.suites import depth_maps, load_frames

    frames = load_frames(index)
    pred: dict[str, np.ndarray] = {}
    for i, frame in enumerate(frames):
        pred.update(depth_maps([read_npy_file(folder / FRAME_FILE.format(i), "disparity")], [frame]))
    score_set(params, name, run, pred, frames, rois=rois)


def _score_set_instrument(
    params: Params,
    name: str,
    run: str,
    set_index: Path,
    rois: Path | None,
    key: dict,
    disparity: Disparity,
) -> None:
    """Run ``disparity`` on every frame of extra set ``name`` (its index ``set_index``) with
    ``optimum.threads`` torch threads (in ``optimum.jobs`` processes), resuming from its scratch
    folder (``key``: :func:`_scratch_key`), score it as run ``run`` (on the boxes ``rois`` too) and
    remove the scratch folder."""
    import torch

    from msdepth.data.eval_index import read_eval_index

    cfg = params.optimum
    torch.set_num_threads(cfg.threads)
    index = read_eval_index(set_index)
    folder = _scratch_dir(name, run)
    _open_scratch(folder, key)
    frame_disparities(index, folder, disparity, f"{run} on {name}", cfg.jobs, cfg.threads)
    _score_scratch(params, name, run, index, folder, rois)
    _remove_scratch(folder)


def score_set_match(
    params: Params, name: str, matcher: str, set_index: Path, rois: Path | None = None
) -> None:
    """A matcher on extra set ``name``: SGM on variant ``matcher``'s own cost volume (the optimum's
    ``cost`` start) or OpenCV's SGBM (``matcher`` ``sgbm``), unrefined, as run
    :func:`~msdepth.pipeline.paths.match_run`. A variant without a per-pixel cost (``mix``) writes
    skipped metrics, as on the default frames. With ``rois`` (the set's ROI file), the ROI suite too."""
    from msdepth.evaluation.baselines import write_set_skipped

    run = match_run(checked_matcher(params, matcher))
    if matcher != SGBM and not has_per_pixel_cost(params.appearance[matcher]):
        reason = f"variant {matcher} has no per-pixel cost: no cost volume to match on"
        write_set_skipped(name, run, reason, rois is not None)
        return
    start = SGBM if matcher == SGBM else "cost"
    variant = None if matcher == SGBM else matcher
    key = _scratch_key(params, start, variant, set_index)
    _score_set_instrument(params, name, run, set_index, rois, key, SetInstrument(params, start, matcher))


def _checked_set_weight(params: Params, weight: str) -> float:
    """``weight`` as a float, a ConfigError unless it is one of ``optimum.set_weights`` (the weights
    an extra set runs the optimum at)."""
    try:
        value = float(weight)
    except ValueError:
        raise ConfigError(f"smoothness weight {weight!r} is not a number") from None
    if value not in params.optimum.set_weights:
        raise ConfigError(
            f"smoothness weight {weight} is not in optimum.set_weights "
            f"({[float(w) for w in params.optimum.set_weights]}), the weights an extra set runs"
        )
    return value


def score_set_optimum(
    params: Params, name: str, variant: str, weight: str, set_index: Path, rois: Path | None = None
) -> None:
    """``variant``'s optimum at ``weight`` (one of ``optimum.set_weights``, as dvc.yaml spells it) on
    every frame of extra set ``name``, one pair at a time, as run
    :func:`~msdepth.pipeline.paths.optimum_run`; with ``rois`` (the set's ROI file), the ROI suite too."""
    value = _checked_set_weight(params, weight)
    run = optimum_run(params.variant(variant), weight)
    key = _scratch_key(params, "optimum", variant, set_index)
    instrument = SetInstrument(params, "optimum", variant, value)
    _score_set_instrument(params, name, run, set_index, rois, key, instrument)
