"""Stage ``prepare_data``: the KITTI-format data tree (the synthetic set, or the downloaded KITTI)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated, Any

from ..config import Params
from ..data.layout import folder_layout, layout

log = logging.getLogger("msdepth")


def prepare_data(
    params: Params,
    *,
    dry_run: Annotated[
        bool,
        "write nothing: for KITTI, ask each missing archive's size (HEAD requests only) and print "
        "per archive and in total what would be fetched and what is already complete",
    ] = False,
) -> None:
    """Create the KITTI-format tree under data.root: render the synthetic set, or fetch KITTI.

    KITTI (data.source: kitti) is downloaded, verified and extracted resumably: what is complete
    is skipped. Without any network, one line says so at once. A stereo folder (data.source:
    folder) is only checked: one error listing what the layout misses; nothing is written.
    """
    if params.data.source == "folder":
        from ..data.folder import check_folder

        report = check_folder(folder_layout(params))
        if dry_run:
            print(f"dry run: the stereo folder {params.data.root} is complete: {report}; nothing written")
            return
        log.info("stereo folder %s: %s", params.data.root, report)
        return
    if params.data.source == "synthetic":
        s, root = params.data.synthetic, Path(params.data.root)
        if dry_run:
            print(
                f"dry run: would render the synthetic set under {root}: {s.drives} drive(s), "
                f"{s.train_pairs} training pairs, {s.eval_frames} evaluation frames at {s.height}x{s.width}; "
                "nothing written"
            )
            return
        from ..data import synthetic

        log.info("synthetic set: %s", synthetic.generate(s, root))
        return
    from ..data import download

    k, paths = params.data.kitti, layout(params)
    names = download.parse_archive_list(k.archive_list)
    subset = list(k.drives) if k.drives is not None else (k.drive_count or None)
    options: dict[str, Any] = dict(jobs=k.jobs, dry_run=dry_run, jpeg=k.jpeg, allow_http=k.allow_http)
    raw = download.fetch_all(
        k.base_url,
        download.select_archives(names, subset),
        k.download_dir,
        paths.raw_root,
        label="KITTI raw",
        **options,
    )
    scene = download.fetch_all(
        k.base_url,
        [k.scene_flow_archive],
        k.download_dir,
        paths.kitti2015_root,
        label="KITTI 2015",
        **options,
    )
    if dry_run:
        print(download.dry_run_total([raw, scene]))
        return
    log.info("kitti: raw archives %s; KITTI 2015 %s", _summary(raw), _summary(scene))


def _summary(report: dict) -> str:
    return ", ".join(f"{k} {len(v) if isinstance(v, (list, dict)) else v}" for k, v in report.items())
