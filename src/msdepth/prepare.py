"""The KITTI-format data tree that the prepare_data stage makes under ``data.root``: the synthetic
set rendered (:mod:`msdepth.render`), KITTI fetched (:mod:`msdepth.download`: only the
drives the splits need), or a stereo folder checked (:mod:`msdepth.data.folder`)."""

from __future__ import annotations

import logging
from pathlib import Path

from msdepth.config.params import Params
from msdepth.data.layout import folder_layout
from msdepth.data.owners import check_synthetic_root

log = logging.getLogger("msdepth")


def prepare_data(params: Params, dry_run: bool = False) -> None:
    """Create the KITTI-format tree under data.root: render the synthetic set, fetch KITTI (what is
    complete is skipped) or check a stereo folder's layout (nothing written). ``dry_run``: write
    nothing, say what would be done (for KITTI: each missing archive's size, HEAD requests only)."""
    if params.data.source == "folder":
        _check_stereo_folder(params, dry_run)
    elif params.data.source == "synthetic":
        _render_synthetic(params, dry_run)
    else:
        from msdepth.download.kitti import fetch_kitti

        fetch_kitti(params, dry_run)


def _check_stereo_folder(params: Params, dry_run: bool) -> None:
    """data.source folder: check the stereo folder's layout; nothing is written."""
    from msdepth.data.folder import check_folder

    report = check_folder(folder_layout(params))
    if dry_run:
        print(f"dry run: the stereo folder {params.data.root} is complete: {report}; nothing written")
        return
    log.info("stereo folder %s: %s", params.data.root, report)


def _render_synthetic(params: Params, dry_run: bool) -> None:
    """data.source synthetic: render the set under data.root."""
    s, root = params.data.synthetic, Path(params.data.root)
    check_synthetic_root(root)  # also in a dry run: it says at once that the render would refuse
    if dry_run:
        print(
            f"dry run: would render the synthetic set under {root}: {s.drives} drive(s), "
            f"{s.train_pairs} training pairs, {s.eval_frames} evaluation frames at {s.height}x{s.width}; "
            "nothing written"
        )
        return
    from msdepth import render

    log.info("synthetic set: %s", render.generate(s, root))
