"""The index stage: the training pairs, the evaluation indexes and a report of any data source,
written to the index folder. KITTI and the synthetic set through :func:`build_indexes` (with the
extra sets of :mod:`msdepth.data.eval_sets`), a stereo folder through :mod:`msdepth.data.folder`;
both written by :func:`_write_indexes`. The evaluation index's format, and its reader for the later
stages, are :mod:`msdepth.data.eval_index`'s."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import pandas as pd

from msdepth.config.params import Params
from msdepth.data import kitti
from msdepth.data.eval_index import build_eval_index, set_index_path, write_eval_index
from msdepth.data.eval_sets import build_set_index, folder_eval_index
from msdepth.data.layout import folder_layout, layout
from msdepth.data.pairs import PairIndex, index_pairs
from msdepth.io import write_json
from msdepth.pipeline.paths import EVAL_FRAMES, INDEX_REPORT, SET_INDEXES, TRAIN_PAIRS

log = logging.getLogger("msdepth")


def build_indexes(
    params: Params, out_dir: str | os.PathLike, extra: dict[str, pd.DataFrame] | None = None
) -> dict:
    """Write ``train_pairs.txt``, ``eval_frames.csv`` (KITTI 2015), ``sets/<set>.csv`` (the extra
    sets' indexes ``extra``, :mod:`msdepth.data.eval_sets`) and ``report.json`` to ``out_dir``.
    A stereo folder's: :func:`_folder_indexes`, through :func:`_write_indexes`."""
    paths = layout(params)
    pairs = index_pairs(paths.train_split, paths.raw_root)
    frames = build_eval_index(paths.kitti2015_root, paths.eval_split, params.data.gt)
    return _write_indexes(params, out_dir, pairs, frames, extra, {"gt": params.data.gt})


def _write_indexes(
    params: Params,
    out_dir: str | os.PathLike,
    pairs: PairIndex,
    frames: pd.DataFrame,
    extra: dict[str, pd.DataFrame] | None = None,
    details: dict | None = None,
) -> dict:
    """Write the training pairs, the main evaluation index ``frames``, the extra sets' indexes and
    ``report.json`` (with ``details``) to ``out_dir``; returns the report. The files have the names
    of the pipeline's (:data:`msdepth.pipeline.paths.INDEX_DIR`), whatever ``out_dir``."""
    out = Path(out_dir)
    kitti.write_split(out / TRAIN_PAIRS.name, [(str(a), str(b)) for a, b in pairs.pairs])
    write_eval_index(out / EVAL_FRAMES.name, frames)
    extra = extra or {}
    (out / SET_INDEXES.name).mkdir(parents=True, exist_ok=True)
    for stale in (out / SET_INDEXES.name).glob("*.csv"):
        if stale.stem not in extra:
            stale.unlink()
    for name, table in extra.items():
        write_eval_index(set_index_path(out, name), table)
    report = {
        "source": params.data.source,
        "train_pairs_listed": len(pairs.pairs) + len(pairs.missing),
        "train_pairs_found": len(pairs.pairs),
        "train_pairs_missing": [f"{a} {b}" for a, b in pairs.missing],
        "eval_frames": len(frames),
        **(details or {}),
        "extra_sets": {name: len(table) for name, table in extra.items()},
    }
    write_json(out / INDEX_REPORT.name, report)
    return report


def _folder_indexes(params: Params, out_dir: str | os.PathLike) -> dict:
    """``data.source: folder``: the folder's training pairs (without the evaluation frames) and
    its evaluation list, which takes KITTI 2015's place as the main evaluation set."""
    from msdepth.data import folder

    pairs, excluded = folder.build_train_pairs(folder_layout(params))
    frames = folder_eval_index(params)
    details = {
        "gt": "data.folder.eval_list",
        "eval_frames_left_out_of_training": excluded,
        "eval_frames_without_gt": int((frames["gt_kind"] == "none").sum()),
    }
    return _write_indexes(params, out_dir, PairIndex(pairs, []), frames, {}, details)


def index_data(params: Params, out_dir: str | os.PathLike) -> dict:
    """Index the training pairs and evaluation frames of ``params``' data source found on disk into
    ``out_dir`` (a stereo folder has no extra sets: config.validate); logs and returns the report."""
    if params.data.source == "folder":
        report = _folder_indexes(params, out_dir)
    else:
        extra = {name: build_set_index(params, name) for name in params.eval.extra_sets}
        report = build_indexes(params, out_dir, extra)
    log.info(
        "index: %d/%d training pairs found, %d evaluation frames%s",
        report["train_pairs_found"],
        report["train_pairs_listed"],
        report["eval_frames"],
        "".join(f", {name}: {count}" for name, count in report["extra_sets"].items()),
    )
    return report
