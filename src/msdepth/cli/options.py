"""argparse options that several ``msdepth`` subcommands share (kept free of torch, so that
``--help`` stays fast)."""

from __future__ import annotations

import argparse


def camera_options(p: argparse.ArgumentParser, principal_point: bool = True) -> None:
    """The stereo camera: focal length and baseline, and (for point clouds) the principal point.

    Options left at None take the defaults of the code that uses them (KITTI's camera).
    """
    p.add_argument(
        "--focal",
        type=float,
        help="focal length in px at the input image's resolution (default: KITTI's for that width: "
        "721.5377 px at 1242, scaled with the width)",
    )
    p.add_argument("--baseline", type=float, help="stereo baseline in m (default: 0.54, KITTI's)")
    if principal_point:
        p.add_argument(
            "--cx", type=float, help="principal point x in px for the point cloud (default: image centre)"
        )
        p.add_argument(
            "--cy", type=float, help="principal point y in px for the point cloud (default: image centre)"
        )
