"""Atomic writers: a failure mid-write leaves the previous file (or none), never a partial one."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from msdepth import io


def _fail_midway(*args, **kwargs):
    raise OSError(28, "No space left on device")


@pytest.mark.parametrize("writer", ["json", "text", "png", "npz"])
def test_failed_write_keeps_the_previous_file_and_leaves_no_temp(
    tmp_path: Path, monkeypatch, writer: str
) -> None:
    path = tmp_path / {"json": "m.json", "text": "t.md", "png": "d.png", "npz": "d.npz"}[writer]
    write = {
        "json": lambda: io.write_json(path, {"abs_rel": 0.1}),
        "text": lambda: io.write_text(path, "| table |"),
        "png": lambda: io.write_png(path, np.zeros((4, 5, 3), np.uint8)),
        "npz": lambda: io.save_npz(path, depth=np.ones((2, 3))),
    }[writer]
    write()
    before = path.read_bytes()
    # Break the layer below the writer after it has started a temp file.
    if writer in ("json", "text"):
        monkeypatch.setattr(
            Path, "write_text", lambda self, data: (self.write_bytes(b'{"abs'), _fail_midway())
        )
    elif writer == "png":
        monkeypatch.setattr(
            io.cv2, "imwrite", lambda name, img: (Path(name).write_bytes(b"\x89PNG"), _fail_midway())
        )
    else:
        monkeypatch.setattr(
            io.np, "savez_compressed", lambda f, **a: (Path(f).write_bytes(b"PK"), _fail_midway())
        )
    with pytest.raises(OSError, match="No space left"):
        write()
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


def test_write_json_round_trip(tmp_path: Path) -> None:
    io.write_json(tmp_path / "a" / "b.json", {"x": [1, 2.5]})
    assert json.loads((tmp_path / "a" / "b.json").read_text()) == {"x": [1, 2.5]}


def test_outputs_get_ordinary_file_permissions(tmp_path: Path) -> None:
    """Not mkstemp's 0600: other users and tools (a web server, a shared cache) can read results."""
    import os
    import stat

    umask = os.umask(0o022)
    try:
        io.write_json(tmp_path / "m.json", {})
    finally:
        os.umask(umask)
    assert stat.S_IMODE((tmp_path / "m.json").stat().st_mode) == 0o644
