"""Every entry point reads params, YAML and images through the one reader of each (issue 42, build
items 2 and 3), and stages, studies and benchmarks write through msdepth.io's atomic writers: a
source scan, so a new stage, study or command cannot read or write around them, and the files that
used to (a folder source's camera file, the KITTI JPEG conversion) refuse hostile input in one line."""

from __future__ import annotations

import re
import struct
import zlib
from pathlib import Path

import pytest

from msdepth.data import folder
from msdepth.download import extraction
from msdepth.errors import DataError

ROOT = Path(__file__).resolve().parents[1]
SOURCES = [p for d in ("src", "stages", "studies", "benchmarks") for p in sorted((ROOT / d).rglob("*.py"))]
# The readers themselves, and dvc.yaml's own reader (the pipeline file, not params).
YAML_READERS = {"src/msdepth/config/params_yaml.py", "src/msdepth/pipeline/dvcyaml.py"}
IMAGE_READERS = {"src/msdepth/data/imagefile.py"}


def _offenders(pattern: str, allowed: set[str]) -> list[str]:
    found = []
    for path in SOURCES:
        name = path.relative_to(ROOT).as_posix()
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if re.search(pattern, line) and name not in allowed:
                found.append(f"{name}:{number}: {line.strip()}")
    return found


def test_no_entry_point_parses_yaml_around_the_params_reader() -> None:
    # studies/glass_check.py, studies/monocular.py, reporting/revisions.py and data/folder.py's camera
    # file used yaml.safe_load: duplicate keys, aliases and unbounded sizes went through.
    assert _offenders(r"\byaml\.(safe_|full_|unsafe_)?load(_all)?\(", YAML_READERS) == []


def test_no_entry_point_decodes_an_image_around_the_image_reader() -> None:
    # the download's JPEG conversion (now download/extraction.py) used cv2.imread: no bound before decoding.
    pattern = r"\bcv2\.(imread|imreadmulti|imdecode)\(|\bImage\.open\(|\bimageio\."
    assert _offenders(pattern, IMAGE_READERS) == []


def test_no_entry_point_writes_a_file_around_the_atomic_writers() -> None:
    # Eight studies wrote their --out with Path.write_text or savefig: a user's file at that name was
    # replaced, and a killed run left half a file. Stages, studies and benchmarks write through
    # msdepth.io (write_text, write_json, write_png, ...) and figures through
    # msdepth.reporting.figures.write_figure, after the output policy's claim.
    # src/ is left out: it holds the writers themselves (a write inside their atomic_path block).
    library = {p.relative_to(ROOT).as_posix() for p in SOURCES if p.is_relative_to(ROOT / "src")}
    assert _offenders(r"\.write_text\(|\.write_bytes\(|\bsavefig\(", library) == []


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (b"focal_px: 700\nfocal_px: 800\nwidth_px: 1400\nbaseline_m: 0.1\n", "duplicate key"),
        (b"focal_px: &f 700\nwidth_px: *f\nbaseline_m: 0.1\n", "alias"),
        (b"focal_px: 7\xe90\nwidth_px: 1400\nbaseline_m: 0.1\n", "not a readable YAML camera file"),
        (b"# " + b"x" * 70_000 + b"\nfocal_px: 1\n", "over the limit of 65,536 bytes for camera files"),
        (b"focal_px: " + b"9" * 5000 + b"\nwidth_px: 1400\nbaseline_m: 0.1\n", "out of range"),
    ],
)
def test_a_hostile_camera_file_is_one_line_naming_it(tmp_path: Path, content: bytes, expected: str) -> None:
    (tmp_path / "camera.yaml").write_bytes(content)
    with pytest.raises(DataError) as err:
        folder._read_camera(tmp_path / "camera.yaml")
    message = str(err.value)
    assert message.startswith(f"{tmp_path / 'camera.yaml'}: ") and "\n" not in message, message
    assert expected in message and len(message) < 400, message


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def test_the_kitti_jpeg_conversion_bounds_an_image_before_decoding_it(tmp_path: Path) -> None:
    # A 70-byte PNG declaring 50,000 x 50,000 px in a downloaded archive: OpenCV allocated first.
    ihdr = struct.pack(">IIBBBBB", 50_000, 50_000, 8, 2, 0, 0, 0)
    bomb = b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IEND", b"")
    (tmp_path / "image_02").mkdir()
    (tmp_path / "image_02" / "0000000000.png").write_bytes(bomb)
    with pytest.raises(DataError, match=r"0000000000\.png: the header declares 50000 x 50000 px"):
        extraction._to_jpeg(tmp_path, 90)
    assert (tmp_path / "image_02" / "0000000000.png").read_bytes() == bomb
    assert not list(tmp_path.rglob("*.jpg"))


# Reads of files the pipeline wrote itself, allowed outside msdepth.io's readers, with why.
PIPELINE_READ_ALLOWED = {
    # the package's own source, hashed and parsed (no user file)
    ("src/msdepth/pipeline/paths.py", "path.read_bytes()"),
    # a PNG this command wrote a moment ago in its own temporary folder
    ("src/msdepth/cli/example.py", "png_size(written.read_bytes())"),
    # the pair cache is memory-mapped after open_regular has checked it
    ("src/msdepth/data/pairs.py", 'cache = np.load(path, mmap_mode="r")'),
    # git's output and bytes already read through read_bounded, not a file
    ("src/msdepth/data/kitti.py", "pd.read_csv(io.BytesIO(data)"),
}


def test_src_reads_its_own_outputs_through_the_bounded_readers() -> None:
    """Metrics JSON and CSV, disparities and depth maps, records and pages the pipeline wrote are
    read back through msdepth.readers (a FIFO or a huge file at an output's path: one line)."""
    pattern = r"\.read_text\(|\.read_bytes\(|\bnp\.load\(|\bpd\.read_csv\(|\bjson\.load\("
    found = []
    for path in SOURCES:
        name = path.relative_to(ROOT).as_posix()
        if not name.startswith("src/") or name == "src/msdepth/readers.py":
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if re.search(pattern, line) and not any(
                name == f and part in line for f, part in PIPELINE_READ_ALLOWED
            ):
                found.append(f"{name}:{number}: {line.strip()}")
    assert found == []


def _npz_bomb(path: Path) -> None:
    """An .npz whose one member declares 1 GiB of zeros (it compresses to about 1 MB)."""
    import zipfile

    header = b"\x93NUMPY\x01\x00" + b"v\x00{'descr': '<f4', 'fortran_order': False, 'shape': (268435456,), }"
    header = header[:8] + struct.pack("<H", 118) + header[10:].ljust(118 - 1) + b"\n"
    with (
        zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive,
        archive.open("x.npy", "w", force_zip64=True) as m,
    ):
        m.write(header)
        for _ in range(1024):
            m.write(bytes(1 << 20))


def _hostile(tmp_path: Path, case: str) -> Path:
    import os

    import numpy as np

    path = tmp_path / f"{case}.bin"
    if case == "fifo":
        os.mkfifo(path)
    elif case == "folder":
        path.mkdir()
    elif case == "huge":
        path.write_bytes(b"0" * 5000)
    elif case == "truncated_npy":
        np.save(tmp_path / "t.npy", np.zeros((4, 5), np.float32))
        path.write_bytes((tmp_path / "t.npy").read_bytes()[:-3])
    elif case == "object_npy":
        np.save(tmp_path / "o.npy", np.array([{}], dtype=object), allow_pickle=True)
        path.write_bytes((tmp_path / "o.npy").read_bytes())
    elif case == "deep_json":
        path.write_text("[" * 200_000)
    elif case == "not_utf8":
        path.write_bytes(b'{"a": "\xe9"}')
    elif case == "npz_bomb":
        _npz_bomb(path)
    return path


@pytest.mark.parametrize(
    ("reader", "cases"),
    [
        ("read_json_file", ["fifo", "folder", "missing", "huge", "deep_json", "not_utf8"]),
        ("read_text_file", ["fifo", "folder", "missing", "huge", "not_utf8"]),
        ("read_table_file", ["fifo", "folder", "missing", "huge"]),
        ("read_npy_file", ["fifo", "folder", "missing", "huge", "truncated_npy", "object_npy"]),
        ("read_npz_file", ["fifo", "folder", "missing", "huge", "truncated_npy", "npz_bomb"]),
    ],
)
def test_each_reader_of_pipeline_outputs_refuses_the_hostile_set_in_one_line(
    tmp_path: Path, reader: str, cases: list[str]
) -> None:
    from msdepth import readers

    read = getattr(readers, reader)
    for case in cases:
        path = _hostile(tmp_path, case)
        limit = 1000 if case == "huge" else 64 << 20
        with pytest.raises(DataError) as err:
            read(path, "metrics", limit)
        message = str(err.value)
        assert message.startswith(str(path)) and "\n" not in message and len(message) < 400, (case, message)


def test_one_opening_for_reading_in_src() -> None:
    """open_regular is the one place src opens a file by descriptor for reading (the output
    manifest included, through follow_symlinks=False); the other os.open is the manifest's append."""
    found = [
        f"{path.relative_to(ROOT).as_posix()}:{n}"
        for path in SOURCES
        if path.is_relative_to(ROOT / "src")
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if re.search(r"\bos\.open\(", line)
    ]
    assert len(found) == 2, found
    assert found[0].startswith("src/msdepth/outputs.py:") and found[1].startswith(
        "src/msdepth/readers.py:"
    ), found
