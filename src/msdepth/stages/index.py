"""Stage ``index``: index the training pairs and evaluation frames found on disk."""

from __future__ import annotations

import logging

from ..config import Params
from ..data.index import build_indexes
from .common import INDEX_DIR

log = logging.getLogger("msdepth")


def index(params: Params) -> None:
    """Index the training pairs and evaluation frames found on disk."""
    report = build_indexes(params, INDEX_DIR)
    log.info(
        "index: %d/%d training pairs found, %d evaluation frames",
        report["train_pairs_found"],
        report["train_pairs_listed"],
        report["eval_frames"],
    )
