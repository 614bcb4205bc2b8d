"""Stage ``cache``: decode and resize the training pairs once into data/cache/train_pairs.npy."""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.data.cache import cache_pairs
from msdepth.pipeline.paths import CACHE_REPORT, CACHED_PAIRS, PAIR_CACHE, TRAIN_PAIRS, run_stage


def cache(params: Params) -> None:
    """Decode and resize the training pairs once; pairs with unreadable images are left out and reported."""
    cache_pairs(TRAIN_PAIRS, *params.image_size, PAIR_CACHE, CACHED_PAIRS, CACHE_REPORT)


if __name__ == "__main__":
    sys.exit(run_stage(cache, *sys.argv[1:]))
