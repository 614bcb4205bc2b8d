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
from msdepth.download import archives
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
    # the download's JPEG conversion (now download/archives.py) used cv2.imread: no bound before decoding.
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
        archives._to_jpeg(tmp_path, 90)
    assert (tmp_path / "image_02" / "0000000000.png").read_bytes() == bomb
    assert not list(tmp_path.rglob("*.jpg"))
