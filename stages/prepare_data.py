"""Stage ``prepare_data``: the KITTI-format data tree (the synthetic set, or the downloaded KITTI)."""

from __future__ import annotations

import sys
from typing import Annotated

from msdepth import prepare
from msdepth.config.params import Params
from msdepth.pipeline.paths import run_stage


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
    is skipped. Only what the chosen splits need is fetched: the raw drives that the training
    split and each extra evaluation set's list name (data.kitti.drives / drive_count restrict
    further) with their days' calibration, KITTI 2015, and KITTI's annotated depth for
    eigen_benchmark. Without any network, one line says so at once. A stereo folder
    (data.source: folder) is only checked: one error listing what the layout misses; nothing is
    written.
    """
    prepare.prepare_data(params, dry_run)


if __name__ == "__main__":
    sys.exit(run_stage(prepare_data, *sys.argv[1:]))
