"""Byte counts shared by the download's steps: the read size, a file's size on disk, and a size for people."""

from __future__ import annotations

from pathlib import Path

CHUNK_SIZE = 1 << 20  # 1 MiB reads: few syscalls, and a progress bar that still moves


def file_size(path: Path) -> int:
    """The size of ``path`` in bytes; 0 if it does not exist (a download not yet started)."""
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return 0


def human_size(nbytes: int) -> str:
    """``nbytes`` for people: ``512 B``, ``1.5 MiB``, ``3.2 GiB`` (GiB at most)."""
    size = float(nbytes)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if size < 1024 or unit == "GiB":
            return f"{size:.1f} {unit}" if unit != "B" else f"{nbytes} B"
        size /= 1024
    raise AssertionError("unreachable")
