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


def test_crlf_line_ends_are_read_unshifted(tmp_path: Path) -> None:
    # Issue 42 case 10: "\r\n" after the scale shifted the samples by one byte (values of -6e37..2e38,
    # 66 % counted as valid GT).
    samples = np.arange(6, dtype="<f4").reshape(2, 3) + 0.5
    for header in (b"Pf\r\n3 2\r\n-1.0\r\n", b"Pf\n3 2\n-1.0\n", b"Pf\r3 2\r-1.0\r"):
        (tmp_path / "a.pfm").write_bytes(header + samples[::-1].tobytes())
        np.testing.assert_array_equal(read_pfm(tmp_path / "a.pfm"), samples)


def test_a_lone_cr_before_a_newline_byte_is_refused_not_misread(tmp_path: Path) -> None:
    # The bottom row's first sample starts with byte 0x0a: after a lone "\r" that reads as "\r\n".
    samples = np.frombuffer(b"\n\0\0\0" + np.arange(1, 6, dtype="<f4").tobytes(), "<f4").reshape(2, 3)
    (tmp_path / "a.pfm").write_bytes(b"Pf\r3 2\r-1.0\r" + samples.tobytes())
    with pytest.raises(DataError, match="truncated PFM"):
        read_pfm(tmp_path / "a.pfm")


@pytest.mark.parametrize(
    ("extra", "expected"),
    [
        (-1, "truncated PFM"),
        (1, "PFM with trailing bytes"),
        (4, "PFM with trailing bytes"),
        (-4, "truncated PFM"),
    ],
)
def test_a_body_not_exactly_w_h_c_floats_is_refused(tmp_path: Path, extra: int, expected: str) -> None:
    body = np.arange(6, dtype="<f4").tobytes()
    body = body[:extra] if extra < 0 else body + b"\0" * extra
    for header in (b"Pf\n3 2\n-1.0\n", b"Pf\r\n3 2\r\n-1.0\r\n"):
        (tmp_path / "a.pfm").write_bytes(header + body)
        with pytest.raises(DataError, match=rf"a\.pfm: {expected}: 3x2x1 float32 need exactly 24 bytes"):
            read_pfm(tmp_path / "a.pfm")
