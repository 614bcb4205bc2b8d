"""Stage ``cache``: decode and resize the training pairs once into data/cache/train_pairs.npy."""

from __future__ import annotations

import logging
import sys

from msdepth.config.params import Params
from msdepth.data import kitti
from msdepth.data.pairs import build_pair_cache, load_pair_list
from msdepth.io import write_json
from msdepth.pipeline.paths import CACHE_REPORT, CACHED_PAIRS, PAIR_CACHE, TRAIN_PAIRS, run_stage

log = logging.getLogger("msdepth")


def cache(params: Params) -> None:
    """Decode and resize the training pairs once; pairs with unreadable images are left out and reported."""
    pairs = load_pair_list(TRAIN_PAIRS)
    report = build_pair_cache(pairs, params.data.height, params.data.width, PAIR_CACHE)
    kitti.write_split(CACHED_PAIRS, [(str(a), str(b)) for a, b in report.pairs])
    write_json(
        CACHE_REPORT,
        {
            "pairs_indexed": len(pairs),
            "pairs_cached": len(report.pairs),
            "pairs_unreadable": len(report.unreadable),
            "unreadable": [{"left": str(a), "right": str(b), "error": e} for a, b, e in report.unreadable],
        },
    )
    for left, right, error in report.unreadable[:20]:
        log.warning("cache: left out %s %s: %s", left, right, error)
    log.info(
        "cache: %d of %d pairs at %dx%d in %s (%d unreadable, listed in %s)",
        len(report.pairs),
        len(pairs),
        params.data.height,
        params.data.width,
        PAIR_CACHE,
        len(report.unreadable),
        CACHE_REPORT,
    )


if __name__ == "__main__":
    sys.exit(run_stage(cache, *sys.argv[1:]))
