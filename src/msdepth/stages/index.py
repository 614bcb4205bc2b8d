"""Stage ``index``: index the training pairs and evaluation frames found on disk."""

from __future__ import annotations

import logging

from ..config import Params
from ..data.eval_sets import build_set_index
from ..data.index import build_indexes
from .common import INDEX_DIR

log = logging.getLogger("msdepth")


def index(params: Params) -> None:
    """Index the training pairs and evaluation frames found on disk."""
    extra = {name: build_set_index(params, name) for name in params.eval.extra_sets}
    report = build_indexes(params, INDEX_DIR, extra)
    log.info(
        "index: %d/%d training pairs found, %d evaluation frames%s",
        report["train_pairs_found"],
        report["train_pairs_listed"],
        report["eval_frames"],
        "".join(f", {name}: {count}" for name, count in report["extra_sets"].items()),
    )
