"""KITTI for the params: the archives the splits and evaluation sets need, fetched into the
KITTI-format tree under ``data.root`` (:func:`fetch_kitti`, the prepare_data stage's
``data.source: kitti``) through :mod:`msdepth.download.fetching`."""

from __future__ import annotations

import logging
from pathlib import Path

from msdepth.config.params import Params
from msdepth.data.layout import layout
from msdepth.data.owners import check_kitti_root
from msdepth.download.fetching import dry_run_total, fetch_all
from msdepth.download.lists import parse_archive_list, select_needed
from msdepth.download.transfer import FetchOptions

log = logging.getLogger("msdepth")


def fetch_kitti(params: Params, dry_run: bool) -> None:
    """data.source kitti: fetch what the splits need (resumable); ``dry_run``: sizes only. Never
    into the synthetic set's tree (DataError)."""
    check_kitti_root(Path(params.data.root))
    k, paths = params.data.kitti, layout(params)
    names = parse_archive_list(k.archive_list)
    subset = list(k.drives) if k.drives is not None else (k.drive_count or None)
    selection = select_needed(names, _needed_splits(params), subset, archive_list=k.archive_list)
    options = FetchOptions(jobs=k.jobs, dry_run=dry_run, jpeg=k.jpeg, allow_http=k.allow_http)
    reports = {
        "raw archives": fetch_all(
            k.base_url,
            selection.archives,
            k.download_dir,
            paths.raw_root,
            options,
            label="KITTI raw",
            header=selection.describe(),
        ),
    }
    for label, archive, dest in _single_archives(params):
        reports[label] = fetch_all(k.base_url, [archive], k.download_dir, dest, options, label=label)
    if dry_run:
        print(dry_run_total(list(reports.values())))
        return
    log.info(
        "kitti: %s; %s",
        selection.describe(),
        "; ".join(f"{what} {_summary(r)}" for what, r in reports.items()),
    )


def _single_archives(params: Params) -> list[tuple[str, str, Path]]:
    """``(label, archive, folder it is extracted into)`` of each one-archive KITTI download the
    params need: KITTI 2015 always; the annotated depth for eval.extra_sets' eigen_benchmark
    (``train/``, ``val/``); KITTI 2012's stereo/flow archive for its kitti2012 (``training/``,
    ``testing/``, :mod:`msdepth.data.kitti2012`)."""
    from msdepth.data import kitti2012

    k, paths = params.data.kitti, layout(params)
    out = [("KITTI 2015", k.scene_flow_archive, paths.kitti2015_root)]
    if "eigen_benchmark" in params.eval.extra_sets:
        out.append(("KITTI annotated depth", k.depth_annotated_archive, paths.depth_annotated))
    if "kitti2012" in params.eval.extra_sets:
        out.append(("KITTI 2012", kitti2012.ARCHIVE, paths.kitti2012_root.parent))
    return out


# The list file of each extra evaluation set (eval.extra_sets), as msdepth.data.eval_sets reads it.
SET_SPLITS = {"eigen": "eigen_split", "eigen_benchmark": "eigen_benchmark_split"}


def _needed_splits(params: Params) -> dict[str, Path]:
    """The split lists whose drives KITTI's download must fetch: the training split, the list of
    each set of eval.extra_sets (KITTI 2015, always evaluated, is an archive of its own) and, for
    train.mode mono | mono_stereo, the monocular split (data.kitti.mono_split)."""
    paths = layout(params)
    splits = {"the train split": paths.train_split}
    for name in params.eval.extra_sets:
        if name in SET_SPLITS:  # kitti2012 lists no raw drive: its archive holds its frames
            splits[name] = getattr(paths, SET_SPLITS[name])
    if params.train.monocular and paths.mono_split is not None:
        splits["the monocular split"] = paths.mono_split
    return splits


def _summary(report: dict) -> str:
    return ", ".join(f"{k} {len(v) if isinstance(v, (list, dict)) else v}" for k, v in report.items())
