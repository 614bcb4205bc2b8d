"""The PFM header is read by tokens within its first bytes (issue 27, item 7): a regex over the
whole file took quadratic time, 18.6 s for a 32 KB header of digits."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from msdepth.data.pfm import HEADER_LIMIT, read_pfm, write_pfm
from msdepth.errors import DataError


def test_a_long_header_of_digits_is_refused_at_the_limit(tmp_path: Path) -> None:
    (tmp_path / "slow.pfm").write_bytes(b"Pf 1 1 " + b"1" * 32_768 + b"x")
    with pytest.raises(DataError, match=rf"slow.pfm: not a PFM file .*within its first {HEADER_LIMIT} bytes"):
        read_pfm(tmp_path / "slow.pfm")


@pytest.mark.parametrize(
    "header",
    [b"Pf\n3 2\n-1.0\n", b"Pf 3 2 -1 ", b"Pf\t3\r\n2\n-.5e0\n", b"Pf\n3 2\n" + b" " * 200 + b"-1.0\n"],
    ids=["standard", "spaces", "mixed-whitespace", "padded"],
)
def test_headers_with_any_whitespace_are_read(tmp_path: Path, header: bytes) -> None:
    samples = np.arange(6, dtype="<f4").reshape(2, 3)
    (tmp_path / "a.pfm").write_bytes(header + samples[::-1].tobytes())
    np.testing.assert_array_equal(read_pfm(tmp_path / "a.pfm"), samples)


@pytest.mark.parametrize(
    "header",
    [b"Pf3 2 -1\n", b"Pf\n3x 2\n-1\n", b"Pf\n3 2\n-1", b"PF\n3 2\nabc\n", b"Pf\n1234567890 2\n-1\n"],
    ids=["no-space-after-magic", "bad-width", "no-end", "bad-scale", "ten-digit-width"],
)
def test_malformed_headers_are_one_data_error(tmp_path: Path, header: bytes) -> None:
    (tmp_path / "a.pfm").write_bytes(header)
    with pytest.raises(DataError, match="a.pfm: not a PFM file"):
        read_pfm(tmp_path / "a.pfm")


def test_round_trip_still_holds(tmp_path: Path) -> None:
    image = np.random.default_rng(0).random((5, 7, 3)).astype(np.float32)
    write_pfm(tmp_path / "c.pfm", image, little_endian=False)
    np.testing.assert_array_equal(read_pfm(tmp_path / "c.pfm"), image)
