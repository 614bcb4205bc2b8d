"""Which data source owns the tree under a data root (the marks each leaves), so that no source
deletes or writes into another's.

Each source has a tree of its own (``data.root``: ``data/synthetic`` for the synthetic set,
``data/kitti`` for real KITTI). A tree says who made it:

- the synthetic set: ``synthetic.json`` (its summary, written last) or, while a render is under
  way or was interrupted, :data:`RENDERING`;
- KITTI: the download's completion markers ``.<archive>.complete``
  (:mod:`msdepth.download.extraction`) in the folders archives are extracted into (``raw/``,
  ``kitti2015/``, the annotated depth's).

The renderer replaces only a tree it marked as its own (or an empty one), and the download
writes into no tree the renderer marked nor a stereo folder (:data:`FOLDER_MARKS`); either
refuses with one line naming the root.
"""

from __future__ import annotations

from pathlib import Path

from msdepth.errors import DataError

SUMMARY = "synthetic.json"
# Written first by the renderer and removed after SUMMARY: a tree whose render was interrupted is
# still known as the renderer's own.
RENDERING = ".synthetic-rendering"
# A stereo folder's camera file and evaluation list (data.folder.camera and eval_list's defaults),
# and export-folder's manifest: what data.source folder's tree holds at its top.
FOLDER_MARKS = ("camera.yaml", "eval.txt", ".msdepth-export-folder")
_KITTI_MARKERS = ".*.complete"  # download.py's completion markers, one folder below the root


def _synthetic_mark(root: Path) -> Path | None:
    """The file that marks ``root`` as the synthetic set's tree, or None."""
    for name in (SUMMARY, RENDERING):
        if (root / name).is_file():
            return root / name
    return None


def _kitti_mark(root: Path) -> Path | None:
    """A completion marker of KITTI's download under ``root`` (one folder down), or None."""
    if not root.is_dir():
        return None
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        markers = sorted(folder.glob(_KITTI_MARKERS))
        if markers:
            return markers[0]
    return None


def check_synthetic_root(root: Path) -> None:
    """Refuse (DataError, one line naming ``root``) unless the renderer may replace what is under
    ``root``: nothing there yet, or a tree it marked as its own that holds no KITTI download."""
    root = Path(root)
    advice = "the synthetic set needs a data.root of its own (default data/synthetic); nothing was deleted"
    kitti = _kitti_mark(root)
    if kitti is not None:
        raise DataError(f"{root}: holds KITTI's download ({kitti.relative_to(root)}): {advice}")
    if root.exists() and not root.is_dir():
        raise DataError(f"{root}: is a file, not a folder: {advice}")
    if not root.is_dir() or _synthetic_mark(root) is not None:
        return
    entries = sorted(p.name for p in root.iterdir())
    if entries:
        found = f"no {SUMMARY}; e.g. {entries[0]}"
        raise DataError(f"{root}: holds files the synthetic renderer did not write ({found}): {advice}")


def _folder_mark(root: Path) -> Path | None:
    """The file that marks ``root`` as a stereo folder (data.source: folder), or None."""
    for name in FOLDER_MARKS:
        if (root / name).is_file():
            return root / name
    return None


def check_kitti_root(root: Path) -> None:
    """Refuse (DataError, one line naming ``root``) to put KITTI into the synthetic set's tree or a
    stereo folder's (data.source: folder): a member of the same name would replace its file."""
    root = Path(root)
    mark = _synthetic_mark(root)
    what = "the synthetic set"
    if mark is None:
        mark, what = _folder_mark(root), "a stereo folder (data.source: folder)"
    if mark is not None:
        raise DataError(
            f"{root}: holds {what} ({mark.name}): KITTI needs a data.root of its own "
            "(e.g. data/kitti); nothing was written"
        )
