"""Stage ``index``: index the training pairs and evaluation frames found on disk."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.data.indexing import index_data
from msdepth.pipeline.paths import INDEX_DIR, run_stage


def index(params: Params) -> None:
    """Index the training pairs and evaluation frames found on disk."""
    index_data(params, INDEX_DIR)


if __name__ == "__main__":
    sys.exit(run_stage(index, *sys.argv[1:]))
