"""``msdepth export-folder``: a stereo folder (:mod:`msdepth.data.folder`) from a KITTI-format tree.

For the walk-through in docs/user-guide.md: the synthetic set as "your own stereo camera", with PFM GT.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from msdepth.data import kitti
from msdepth.data.eval_index import build_eval_index
from msdepth.data.folder import Camera, write_camera
from msdepth.data.pairs import index_pairs
from msdepth.data.pfm import write_pfm
from msdepth.errors import DataError, OutputError
from msdepth.io import atomic_path, write_text
from msdepth.outputs import OutputPolicy


def export_folder(source_root: str | os.PathLike, out: str | os.PathLike) -> dict:
    """Write a stereo folder from a KITTI-format tree holding ``train_files.txt``, ``raw/`` and
    ``kitti2015/`` (the synthetic set: ``data.root`` after ``dvc repro prepare_data``).

    The training pairs become ``left/<drive>_<frame>.png`` and ``right/``; the KITTI 2015 frames
    ``left/eval_<frame>.png`` and ``right/`` too (the index leaves them out of training), their
    ``disp_noc_0`` GT ``gt/eval_<frame>.pfm`` (disparity in px, inf = none), listed in
    ``eval.txt``; the camera in ``camera.yaml``. ``out`` must not exist or be empty, nor lie inside
    ``source_root``; every file
    goes through the output policy (:class:`msdepth.outputs.OutputPolicy`) and is written atomically.
    """
    source_root, out = Path(source_root), Path(out)
    policy = OutputPolicy(out, "export-folder", input_dirs=(source_root,))
    if source_root.is_dir() and out.resolve().is_relative_to(source_root.resolve()):
        # data.root is a DVC output: a folder written into it would be lost or tracked by mistake
        raise OutputError(f"{out}: inside the tree it exports ({source_root}); choose a folder outside it")
    if out.is_dir() and any(out.iterdir()):
        raise OutputError(f"{out}: exists and is not an empty folder (not overwriting it)")
    pairs = index_pairs(source_root / "train_files.txt", source_root / "raw").pairs
    frames = build_eval_index(
        source_root / "kitti2015", source_root / "kitti2015" / "test_files.txt", "disp_noc_0"
    )
    cameras = {(float(r.focal), float(r.baseline)) for r in frames.itertuples()}
    if len(cameras) != 1:
        raise DataError(f"{source_root}: the evaluation frames have {len(cameras)} cameras; a folder has one")
    (focal, baseline), width = cameras.pop(), kitti.read_image(frames["left"].iloc[0]).shape[1]
    policy.prepare()
    for left, right in pairs:
        name = f"{left.parents[2].name}_{left.stem}{left.suffix}"
        _copy(policy, left, out / "left" / name)
        _copy(policy, right, out / "right" / name)
    lines = []
    for row in frames.itertuples():
        name = f"eval_{row.frame}"
        suffix = Path(row.left).suffix
        _copy(policy, Path(row.left), out / "left" / f"{name}{suffix}")
        _copy(policy, Path(row.right), out / "right" / f"{name}{suffix}")
        disp = kitti.read_disparity(row.gt)
        policy.claim([out / "gt" / f"{name}.pfm"], row.gt)
        write_pfm(out / "gt" / f"{name}.pfm", np.where(disp > 0, disp, np.inf))
        lines.append(f"left/{name}{suffix} right/{name}{suffix} gt/{name}.pfm\n")
    policy.claim([out / "eval.txt", out / "camera.yaml"], source_root)
    write_text(out / "eval.txt", "".join(lines))
    write_camera(out / "camera.yaml", Camera(focal, float(width), baseline))
    return {"train_pairs": len(pairs), "eval_frames": len(frames), "focal_px": focal, "width_px": width}


def _copy(policy: OutputPolicy, source: Path, target: Path) -> None:
    """Copy ``source`` to ``target`` atomically, once the output policy allows it (two sources
    named alike are refused, not one lost)."""
    policy.claim([target], source)
    with atomic_path(target) as tmp:
        shutil.copyfile(source, tmp)
