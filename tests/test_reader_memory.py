"""Each reader's peak memory stays a small multiple of what it may hold (issue 68, item 1): the
hostile files are small on disk, each reader runs in a child process and the child's peak resident
memory over its baseline (``ru_maxrss`` after the imports) is measured.

Before: a .npz of a few MB whose member declared 1.5 GiB peaked at 4.5 GiB, a 1.5 GiB sparse .npy
was read whole, a CSV of empty cells took 11x its size (7.7x in the probe's), 20 million ``{}``
records in ``msdepth experiments --json`` ran to 6.3 GB and a 3 MB label padded every row."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
MIB = 1 << 20

# The child: imports first (their memory is the baseline), then the reader; prints its peak over
# the baseline and the first line of the refusal, if any.
CHILD = """
import json, resource, sys
import numpy, pandas
from msdepth import readers
from msdepth.__main__ import main
from msdepth.errors import MsdepthError
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
error = ""
try:
    {call}
except MsdepthError as exc:
    error = str(exc)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({{"peak": (peak - base) * 1024, "error": error}}))
"""


def _peak(call: str) -> tuple[int, str]:
    env = {**os.environ, "PYTHONPATH": os.environ.get("MEMTEST_SRC", str(ROOT / "src"))}
    code = CHILD.format(call=call)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    return result["peak"], result["error"]


def _npy_header(nbytes: int) -> bytes:
    buffer = __import__("io").BytesIO()
    np.lib.format.write_array_header_1_0(
        buffer, {"descr": "<f4", "fortran_order": False, "shape": (nbytes // 4,)}
    )
    return buffer.getvalue()


def _declared_as(path: Path, size: int) -> None:
    """Patch the zip's one member to declare ``size`` bytes inflated (local and central headers)."""
    data = bytearray(path.read_bytes())
    local, central = data.find(b"PK\x03\x04"), data.find(b"PK\x01\x02")
    struct.pack_into("<I", data, local + 22, size)
    struct.pack_into("<I", data, central + 24, size)
    path.write_bytes(bytes(data))


def test_an_npz_member_declaring_1_5_gib_is_refused_before_inflating(tmp_path: Path) -> None:
    path = tmp_path / "depth.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("000001.npy", _npy_header(4 * MIB) + bytes(4 * MIB))
    _declared_as(path, 3 << 29)  # 1.5 GiB
    assert path.stat().st_size < MIB
    peak, error = _peak(f"readers.read_npz_file({str(path)!r}, 'depth maps')")
    assert error.startswith(f"{path}: its members declare 1,536 MiB inflated") and "\n" not in error, error
    assert peak < 32 * MIB, peak


def test_a_deflate_bomb_is_refused_before_inflating(tmp_path: Path) -> None:
    # Declared honestly: 128 MiB of zeros deflate to about 128 KB.
    path = tmp_path / "depth.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
        with archive.open("000001.npy", "w") as member:
            member.write(_npy_header(128 * MIB))
            for _ in range(8):
                member.write(bytes(16 * MIB))
    assert path.stat().st_size < 2 * MIB
    peak, error = _peak(f"readers.read_npz_file({str(path)!r}, 'depth maps')")
    assert error.startswith(f"{path}: its members declare 128 MiB inflated, over the ") and "64x" in error
    assert peak < 32 * MIB, peak


def test_an_npz_within_its_ratio_is_read_within_twice_its_arrays(tmp_path: Path) -> None:
    # The member is read into the array's own buffer: a read(n) of a zip member built n bytes, then
    # copied them (3x the array).
    path = tmp_path / "depth.npz"
    values = np.random.default_rng(0).random((64, 256, 512), dtype=np.float32)
    np.savez_compressed(path, a=values)
    peak, error = _peak(f"arrays = readers.read_npz_file({str(path)!r}, 'depth maps')")
    assert error == "" and peak < 1.5 * values.nbytes + 8 * MIB, peak


def test_a_sparse_npy_is_refused_without_allocating(tmp_path: Path) -> None:
    path = tmp_path / "disparities.npy"
    header = _npy_header(3 << 29)
    with open(path, "wb") as file:
        file.write(header)
        file.truncate(len(header) + (3 << 29))  # 1.5 GiB, nothing of it on disk
    if path.stat().st_blocks * 512 >= MIB:
        pytest.skip("this filesystem does not keep sparse files")
    peak, error = _peak(f"readers.read_npy_file({str(path)!r}, 'disparities')")
    assert error.startswith(f"{path}: a sparse disparities file (1,536 MiB,") and "\n" not in error, error
    assert peak < 32 * MIB, peak


def _csv(path: Path, line: str, header: str, nbytes: int) -> int:
    with open(path, "w") as file:
        file.write(header)
        written = len(header)
        while written < nbytes:
            file.write(line * 1000)
            written += 1000 * len(line)
    return path.stat().st_size


@pytest.mark.parametrize(
    ("line", "header"),
    [
        ("," * 99 + "\n", ",".join(f"c{i}" for i in range(100)) + "\n"),  # empty cells: a NaN of 8 bytes each
        (",".join("0" * 100) + "\n", ",".join(f"c{i}" for i in range(100)) + "\n"),  # 8-byte integers
    ],
    ids=["empty cells", "one-digit cells"],
)
def test_a_table_of_tiny_cells_is_refused_within_about_twice_its_size(
    tmp_path: Path, line: str, header: str
) -> None:
    path = tmp_path / "metrics.csv"
    size = _csv(path, line, header, 16 * MIB)
    peak, error = _peak(f"readers.read_table_file({str(path)!r}, 'per-unit metrics')")
    assert error.startswith(f"{path}: this per-unit metrics table takes over ") and "2x its file" in error
    assert peak < 3 * size, (peak, size)


def test_a_table_of_unique_short_strings_is_refused_within_a_small_multiple(tmp_path: Path) -> None:
    path = tmp_path / "metrics.csv"
    with open(path, "w") as file:
        file.write("a,b\n" + "".join(f"x{i:x},y{i:x}\n" for i in range(1_000_000)))
    size = path.stat().st_size
    peak, error = _peak(f"readers.read_table_file({str(path)!r}, 'per-unit metrics')")
    assert "2x its file" in error and peak < 5 * size, (peak, size)


def test_a_table_the_pipeline_writes_is_read_within_twice_its_size(tmp_path: Path) -> None:
    path = tmp_path / "metrics.csv"
    row = "2011_09_26_drive_0002_sync/0000000069," + ",".join(["0.1234567"] * 10) + "\n"
    size = _csv(path, row, "frame," + ",".join(f"m{i}" for i in range(10)) + "\n", 8 * MIB)
    peak, error = _peak(
        f"t = readers.read_table_file({str(path)!r}, 'per-unit metrics', dtype={{'frame': str}}); "
        "assert t.shape[1] == 11"
    )
    assert error == "" and peak < 2 * size, (peak, size)


def _experiments(path: Path) -> str:
    return f"main(['experiments', '--json', {str(path)!r}])"


def test_experiments_refuses_millions_of_records_before_parsing(tmp_path: Path) -> None:
    path = tmp_path / "show.json"
    path.write_text("[" + ",".join(["{}"] * 2_000_000) + "]")
    peak, _ = _peak(_experiments(path))
    assert peak < 2 * path.stat().st_size + 16 * MIB, peak


def test_experiments_refuses_millions_of_small_revisions_before_parsing(tmp_path: Path) -> None:
    # 5 million records of 11 bytes each pass the density check (5.7 bytes per value); parsed,
    # they took 1.1 GB before the cell limit refused them.
    path = tmp_path / "show.json"
    path.write_text("[" + ",".join(['{"rev":"a"}'] * 5_000_000) + "]")
    peak, error = _peak(f"__import__('msdepth.cli.experiments').cli.experiments.read_json({str(path)!r})")
    assert "5,000,000 JSON objects, over 500,000" in error and "nothing was parsed" in error, error
    assert peak < 2 * path.stat().st_size, (peak, path.stat().st_size)


def test_experiments_does_not_pad_every_row_to_a_long_label(tmp_path: Path) -> None:
    data = {"params": {"params.yaml": {"data": {"variants": ["ssim"], "ssim": {"kernel_size": 3}}}}}
    revs = [{"rev": f"{i:07x}", "name": f"e{i}", "data": data} for i in range(200)]
    record = {"rev": "workspace", "name": "x" * MIB, "data": data, "experiments": [{"revs": revs}]}
    path = tmp_path / "show.json"
    path.write_text(json.dumps([record]))
    peak, error = _peak(_experiments(path))
    assert error == "" and peak < 16 * MIB, peak


def test_a_json_file_of_millions_of_empty_objects_is_refused_before_parsing(tmp_path: Path) -> None:
    # 8 MB of "{}," parse to 2.7 million dicts: about 30x the file.
    path = tmp_path / "metrics.json"
    path.write_text("[" + ",".join(["{}"] * (8 * MIB // 3)) + "]")
    peak, error = _peak(f"readers.read_json_file({str(path)!r}, 'metrics')")
    assert error.startswith(f"{path}: up to ") and "over one per 4 bytes" in error, error
    assert peak < path.stat().st_size + 8 * MIB, peak
