"""The cache stage's files: the training pairs decoded and resized once
(:func:`msdepth.data.pairs.build_pair_cache`), the list of those cached, and a report of the pairs
left out as unreadable."""

from __future__ import annotations

import logging
from pathlib import Path

from msdepth.data import kitti
from msdepth.data.pairs import CacheReport, build_pair_cache, load_pair_list
from msdepth.io import write_json

log = logging.getLogger("msdepth")


def cache_pairs(
    pair_list: Path, height: int, width: int, cache: Path, cached_list: Path, report_path: Path
) -> CacheReport:
    """Decode and resize the pairs of ``pair_list`` into ``cache``; write the pairs it holds, in its
    order, to ``cached_list`` and the counts and unreadable pairs to ``report_path`` (the first 20
    of them also logged)."""
    pairs = load_pair_list(pair_list)
    report = build_pair_cache(pairs, height, width, cache)
    kitti.write_split(cached_list, [(str(a), str(b)) for a, b in report.pairs])
    write_json(
        report_path,
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
        height,
        width,
        cache,
        len(report.unreadable),
        report_path,
    )
    return report
