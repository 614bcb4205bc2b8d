"""Atomic writers: a failure mid-write leaves the previous file (or none), never a partial one."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from msdepth import io
from msdepth.errors import DataError


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
            Path, "write_bytes", lambda self, data: (open(self, "wb").write(b"\x89PNG"), _fail_midway())
        )
    else:
        monkeypatch.setattr(
            np, "savez_compressed", lambda f, **a: (Path(f).write_bytes(b"PK"), _fail_midway())
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


# ----------------------------------------------------------------------------- PNG encoder


def _png_rows(data: bytes) -> tuple[dict, np.ndarray]:
    """A minimal PNG reader for the encoder's own output: header fields and filtered rows."""
    import struct
    import zlib

    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, chunks = 8, []
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos : pos + 4])
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + n]
        (crc,) = struct.unpack(">I", data[pos + 8 + n : pos + 12 + n])
        assert crc == zlib.crc32(kind + body), kind
        chunks.append((kind, body))
        pos += 12 + n
    assert [k for k, _ in chunks] == [b"IHDR", b"IDAT", b"IEND"]
    w, h, depth, color, *_ = struct.unpack(">IIBBBBB", chunks[0][1])
    raw = np.frombuffer(zlib.decompress(chunks[1][1]), np.uint8).reshape(h, -1)
    return {"w": w, "h": h, "depth": depth, "color": color}, raw


@pytest.mark.parametrize(
    "image",
    [
        np.arange(5 * 7 * 3, dtype=np.uint8).reshape(5, 7, 3) * 37,
        (np.arange(6 * 4, dtype=np.uint8).reshape(6, 4) * 91),
        (np.arange(3 * 9, dtype=np.uint16).reshape(3, 9) * 2411),  # spans both bytes, > 255
        (np.arange(4 * 5 * 3, dtype=np.uint16).reshape(4, 5, 3) * 1013),  # KITTI flow maps
    ],
    ids=["rgb", "gray8", "gray16", "rgb16"],
)
def test_png_round_trips_through_opencv_in_rgb_order(tmp_path: Path, image: np.ndarray) -> None:
    import cv2

    path = tmp_path / "x.png"
    io.write_png(path, image)
    back = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image.ndim == 3:
        back = back[..., ::-1]  # OpenCV reads BGR
    assert back.dtype == image.dtype and np.array_equal(back, image)


def test_png_rows_are_up_filtered_and_big_endian() -> None:
    """Hand-checked layout: filter byte 2 ("Up") per row, row 0 raw, then differences mod 256."""
    image = np.array([[1, 300], [258, 44]], np.uint16)
    header, raw = _png_rows(io._encode_png(image))
    assert header == {"w": 2, "h": 2, "depth": 16, "color": 0}
    assert raw.tolist() == [
        [2, 0, 1, 1, 44],  # 1 = 0x0001, 300 = 0x012C
        [2, 1, 1, 255, 0],  # 258 = 0x0102 minus 0x0001 -> (1, 1); 44 = 0x002C minus 0x012C -> (255, 0)
    ]


def test_png_bytes_depend_only_on_the_pixels() -> None:
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (16, 24, 3), dtype=np.uint8)
    assert io._encode_png(image) == io._encode_png(image.copy(order="F"))
    assert io._encode_png(image) != io._encode_png(image[::-1].copy())


@pytest.mark.parametrize(
    "image",
    [np.zeros((4, 4), np.float32), np.zeros((4, 4, 4), np.uint8), np.zeros((0, 4), np.uint8)],
    ids=["float", "rgba", "empty"],
)
def test_png_refuses_what_it_cannot_write_naming_the_file(tmp_path: Path, image: np.ndarray) -> None:
    path = tmp_path / "bad.png"
    with pytest.raises(DataError, match="bad.png"):
        io.write_png(path, image)
    assert not path.exists() and not list(tmp_path.iterdir())


def test_atomic_temps_finds_only_what_a_killed_writer_left(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    killed = io.atomic_path(path)  # entered and never left: a writer killed before its rename
    tmp = killed.__enter__()
    lookalikes = [
        ".m.json.notes",
        ".m.json.ABCDEFGH.json",  # mkstemp draws lower case
        ".m.json.abcd1234.json.bak",
        "m.json.abcd1234.json",
        ".other.json.abcd1234.json",
        ".m.json.abcd123.json",
        ".m.json.abcd1234.json",  # the form before the msdepth-tmp mark: a user's name could have it
        ".m.json.msdepth-tmp-abcd1234.json.bak",
    ]
    for name in lookalikes:
        (tmp_path / name).write_text("a user's file")
    assert tmp.name.startswith(".m.json.msdepth-tmp-") and tmp.suffix == ".json"
    assert io.atomic_temps(path) == [tmp]
    assert io.atomic_temps(tmp_path / "absent" / "m.json") == []
    tmp.unlink()


@pytest.mark.parametrize(
    ("name", "suffix"),
    [
        ("m.json", None),
        ("noext", None),
        ("a.b-c", None),
        ("x.tar.gz", None),
        ("w name.png", None),
        ("d.bin", ".npy"),
    ],
)
def test_both_finders_know_every_temp_atomic_path_makes(
    tmp_path: Path, name: str, suffix: str | None
) -> None:
    # atomic_temps (one output's) and remove_stale_temps (a folder's) read the same name form.
    killed = io.atomic_path(tmp_path / name, suffix=suffix)  # entered and never left
    tmp = killed.__enter__()
    (tmp_path / ".other.json.msdepth-tmp-abcd1234.json").write_text("another output's temp")
    assert io.atomic_temps(tmp_path / name, suffix=suffix) == [tmp]
    assert tmp in io.remove_stale_temps(tmp_path) and not tmp.exists()


# A writer killed with SIGKILL inside atomic_path, after writing half its data.
KILLED_WRITER = """
import os, signal, sys
from msdepth import io
with io.atomic_path(sys.argv[1]) as tmp:
    tmp.write_bytes(b"half a point cloud")
    os.kill(os.getpid(), signal.SIGKILL)
"""

# Names like a temp's that the project never writes: each must survive the clean-up.
LOOKALIKES = [
    ".0016.ply.aizb060n.ply",  # the form before the msdepth-tmp mark (issue #27, item 12)
    ".0016.ply.msdepth-tmp-aizb060n.ply.bak",
    ".0016.ply.msdepth-tmp-AIZB060N.ply",
    ".0016.ply.msdepth-tmp-aizb06.ply",
    "0016.ply.msdepth-tmp-aizb060n.ply",
    ".msdepth-tmp-aizb060n.ply",
]


def test_the_temp_of_a_writer_killed_mid_write_is_removed_and_nothing_else(tmp_path: Path) -> None:
    # Item 12: `kill -9` left .0016.ply.aizb060n.ply behind for good.
    out = tmp_path / "out" / "sub"
    out.mkdir(parents=True)
    proc = subprocess.run([sys.executable, "-c", KILLED_WRITER, str(out / "0016.ply")], check=False)
    assert proc.returncode == -9
    (temp,) = out.iterdir()
    assert temp.name.startswith(".0016.ply.msdepth-tmp-") and temp.read_bytes() == b"half a point cloud"
    for name in LOOKALIKES:
        (out / name).write_text("a user's file")
    (out / ".link.ply.msdepth-tmp-aizb060n.ply").symlink_to(out / LOOKALIKES[0])
    assert io.remove_stale_temps(tmp_path / "out") == [temp]
    assert sorted(p.name for p in out.iterdir()) == sorted(
        LOOKALIKES + [".link.ply.msdepth-tmp-aizb060n.ply"]
    )
    assert io.remove_stale_temps(tmp_path / "absent") == []


def test_only_the_temps_of_the_callers_outputs_are_removed(tmp_path: Path) -> None:
    killed = [io.atomic_path(tmp_path / name) for name in ("a.npy", "b.npy")]
    for writer in killed:
        writer.__enter__()  # entered and never left (kept referenced: collected, it would clean up)
    (a_temp,), (b_temp,) = tmp_path.glob(".a.npy.*"), tmp_path.glob(".b.npy.*")
    assert io.remove_stale_temps(tmp_path, lambda final: final == tmp_path / "a.npy") == [a_temp]
    assert list(tmp_path.iterdir()) == [b_temp]
