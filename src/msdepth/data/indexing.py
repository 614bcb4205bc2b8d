"""The index stage's indexes of any data source: KITTI and the synthetic set through
:func:`msdepth.data.index.build_indexes` (with the extra sets of :mod:`msdepth.data.eval_sets`), a
stereo folder through :mod:`msdepth.data.folder`; both written by
:func:`msdepth.data.index.write_indexes`."""

from __future__ import annotations

import logging
import os

import pandas as pd

from msdepth.config.params import Params
from msdepth.data.eval_sets import build_set_index
from msdepth.data.index import EVAL_COLUMNS, build_indexes, write_indexes
from msdepth.data.layout import folder_layout
from msdepth.data.pairs import PairIndex

log = logging.getLogger("msdepth")


def folder_eval_index(params: Params) -> pd.DataFrame:
    """A stereo folder's evaluation index (:func:`msdepth.data.folder.eval_rows`)."""
    from msdepth.data import folder

    rows = folder.eval_rows(folder_layout(params), npy_is_disparity=params.data.folder.npy_is_disparity)
    return pd.DataFrame(rows, columns=list(EVAL_COLUMNS))


def folder_indexes(params: Params, out_dir: str | os.PathLike) -> dict:
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
    return write_indexes(params, out_dir, PairIndex(pairs, []), frames, {}, details)


def index_data(params: Params, out_dir: str | os.PathLike) -> dict:
    """Index the training pairs and evaluation frames of ``params``' data source found on disk into
    ``out_dir`` (a stereo folder has no extra sets: config.validate); logs and returns the report."""
    if params.data.source == "folder":
        report = folder_indexes(params, out_dir)
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
