"""Fuzz the KITTI readers: whatever bytes or shapes they are given, they either return a result
that keeps their documented invariants or raise one DataError naming the file, nothing else. And
params files: random trees (keys that are not strings, aliases) load or give one ConfigError line.

Three kinds of input per reader: random bytes (some dressed up with a PNG/JPEG signature),
well-formed files of random shapes, dtypes and values, and well-formed files that were then
truncated, had bytes flipped or inserted, or got junk appended. Hypothesis runs derandomized, so
CI sees the same examples; the ``@example`` cases are inputs that once broke a reader.
"""

from __future__ import annotations

import contextlib
import csv
import io
import sys
import tempfile
import zlib
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Any, Callable, Iterator

import cv2
import numpy as np
import pandas as pd
import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from msdepth.config.params import Params, load_params, params_from_dict
from msdepth.data import kitti
from msdepth.errors import ConfigError, DataError, MsdepthError

FUZZ = settings(
    max_examples=60,
    deadline=None,
    derandomize=True,
    database=None,  # nothing written into the repository
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
PNG_END = b"IEND\xaeB`\x82"


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    # Hypothesis reruns the test body many times per call, so function-scoped tmp_path would be
    # shared between examples; each example gets its own folder below this one instead.
    return tmp_path_factory.mktemp("fuzz")


@contextlib.contextmanager
def _file(base: Path, name: str, data: bytes) -> Iterator[Path]:
    with tempfile.TemporaryDirectory(dir=base) as folder:
        path = Path(folder) / name
        path.write_bytes(data)
        yield path


def _read(reader: Callable[[Path], Any], path: Path) -> Any:
    """``reader(path)``, or None when it raised DataError naming ``path``; any other exception
    propagates and fails the test."""
    try:
        return reader(path)
    except DataError as exc:
        assert isinstance(exc, MsdepthError)
        assert str(path) in str(exc), f"the message does not name the file: {exc}"
        return None


# ------------------------------------------------------------------------------------ images


def _check_image(img: np.ndarray | None) -> None:
    if img is not None:
        assert isinstance(img, np.ndarray) and img.dtype == np.uint8
        assert img.ndim == 3 and img.shape[2] == 3 and min(img.shape[:2]) >= 1


def _check_disparity(disp: np.ndarray | None) -> None:
    if disp is not None:
        assert isinstance(disp, np.ndarray) and disp.dtype == np.float32 and disp.ndim == 2
        assert np.isfinite(disp).all() and (disp >= 0).all()
        code = disp.astype(np.float64) * 256.0
        assert (code == np.round(code)).all() and code.max() <= 65535  # exactly uint16 / 256


def _check_obj_map(ids: np.ndarray | None) -> None:
    if ids is not None:
        assert isinstance(ids, np.ndarray) and ids.dtype == np.uint8 and ids.ndim == 2


def _peak_rss_mb() -> float:
    """This process's peak resident memory so far (MiB); 0 where the platform cannot tell."""
    try:
        import resource
    except ImportError:  # Windows
        return 0.0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 2**10  # bytes on macOS, KiB on Linux


def _read_all_images(path: Path) -> tuple[Any, Any, Any]:
    """All three image readers on one file, each result checked against its invariants."""
    before = _peak_rss_mb()
    img = _read(kitti.read_image, path)
    disp = _read(kitti.read_disparity, path)
    ids = _read(kitti.read_obj_map, path)
    classes = _read(kitti.read_class_map, path)
    if classes is not None:  # exactly the object maps whose values are class bits
        assert ids is not None and not (classes & ~np.uint8(sum(kitti.CLASS_BITS.values()))).any()
    # A file of a few KiB must not cost gigabytes (OpenCV trusts a PNG chunk's declared length).
    grown = _peak_rss_mb() - before
    assert grown < 512, f"reading {path.stat().st_size} bytes raised peak memory by {grown:.0f} MiB"
    _check_image(img)
    _check_disparity(disp)
    _check_obj_map(ids)
    return img, disp, ids


_image_bytes = st.one_of(
    st.binary(max_size=512),
    st.binary(max_size=256).map(lambda b: PNG_MAGIC + b),
    st.binary(max_size=256).map(lambda b: PNG_MAGIC + b + PNG_END),
    st.binary(max_size=256).map(lambda b: b"\xff\xd8" + b + b"\xff\xd9"),
    st.binary(max_size=64).map(lambda b: b"BM" + b),  # other formats OpenCV sniffs
    st.binary(max_size=64).map(lambda b: b"P5\n2 2\n255\n" + b),
    st.binary(max_size=64).map(lambda b: b"II*\x00" + b),
)


@settings(FUZZ, max_examples=200)
@given(data=_image_bytes, suffix=st.sampled_from([".png", ".jpg"]))
@example(data=PNG_MAGIC + b"\xb8\xcf\xa0\x8e" + PNG_END, suffix=".png")  # a chunk "of 3 GB": 3 GB RSS, 5 s
def test_image_readers_on_random_bytes(base: Path, data: bytes, suffix: str) -> None:
    with _file(base, "frame" + suffix, data) as path:
        _read_all_images(path)


@st.composite
def _arrays(draw: st.DrawFn) -> np.ndarray:
    """Random image arrays: uint8/uint16, 1/3/4 channels, 1x1 up to 40x40, varied contents."""
    dtype = draw(st.sampled_from([np.uint8, np.uint16]))
    channels = draw(st.sampled_from([1, 3, 4]))
    h, w = draw(st.integers(1, 40)), draw(st.integers(1, 40))
    shape = (h, w) if channels == 1 else (h, w, channels)
    top = int(np.iinfo(dtype).max)
    fill = draw(st.sampled_from(["random", "zeros", "max", "sparse", "low"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    if fill == "zeros":
        return np.zeros(shape, dtype)
    if fill == "max":
        return np.full(shape, top, dtype)
    arr = rng.integers(0, top, shape, dtype=dtype, endpoint=True)
    if fill == "sparse":  # mostly invalid (0) disparities, like KITTI's LiDAR GT
        arr[rng.random(shape) < 0.9] = 0
    if fill == "low" and dtype == np.uint16:  # 16-bit data that would fit into 8 bits
        arr %= np.uint16(256)
    return arr


def _encode(arr: np.ndarray, suffix: str) -> bytes | None:
    """The array as a file of that format, or None where OpenCV cannot store it (16-bit JPEG)."""
    if suffix == ".jpg" and (arr.dtype != np.uint8 or arr.ndim == 3 and arr.shape[2] == 4):
        return None
    ok, buf = cv2.imencode(suffix, arr)
    assert ok
    return buf.tobytes()


@settings(FUZZ, max_examples=150)
@given(arr=_arrays(), suffix=st.sampled_from([".png", ".png", ".jpg"]))
def test_image_readers_on_valid_files_of_random_shape(base: Path, arr: np.ndarray, suffix: str) -> None:
    data = _encode(arr, suffix)
    if data is None:
        suffix, data = ".png", _encode(arr, ".png")
    channels = 1 if arr.ndim == 2 else arr.shape[2]
    with _file(base, "frame" + suffix, data) as path:
        img, disp, ids = _read_all_images(path)
    gray8 = arr.dtype == np.uint8 and channels == 1
    gray16 = arr.dtype == np.uint16 and channels == 1 and suffix == ".png"
    # Each reader accepts exactly its own format: nothing lost, nothing wrong let through.
    # read_image converts grey, 16-bit and alpha to 8-bit RGB; the GT readers take their own format only.
    assert img is not None, f"read_image on {arr.dtype} x{channels} {suffix}"
    assert (disp is not None) == gray16, f"read_disparity on {arr.dtype} x{channels} {suffix}"
    # an id map must be lossless: a JPEG one is refused (its ids would be blurred into others)
    assert (ids is not None) == (gray8 and suffix == ".png"), (
        f"read_obj_map on {arr.dtype} x{channels} {suffix}"
    )
    assert img.shape == (*arr.shape[:2], 3)
    if suffix == ".png" and arr.dtype == np.uint8 and channels == 3:  # lossless: RGB from OpenCV's BGR
        np.testing.assert_array_equal(img, arr[..., ::-1])
    if disp is not None:
        np.testing.assert_array_equal(disp, arr.astype(np.float32) / 256.0)
    if ids is not None:
        assert ids.shape == arr.shape
        if suffix == ".png":
            np.testing.assert_array_equal(ids, arr)


@st.composite
def _mutated(draw: st.DrawFn) -> tuple[bytes, str, str]:
    """A valid image file, then truncated, bytes flipped, bytes inserted or junk appended."""
    arr = draw(_arrays())
    suffix = draw(st.sampled_from([".png", ".jpg"]))
    data = _encode(arr, suffix)
    if data is None:
        suffix, data = ".png", _encode(arr, ".png")
    how = draw(st.sampled_from(["truncate", "flip", "insert", "append"]))
    if how == "truncate":
        data = data[: draw(st.integers(1, len(data) - 1))]
    elif how == "flip":
        buf = bytearray(data)
        for _ in range(draw(st.integers(1, 8))):
            i = draw(st.integers(0, len(buf) - 1))
            buf[i] ^= draw(st.integers(1, 255))
        data = bytes(buf)
    elif how == "insert":
        i = draw(st.integers(0, len(data)))
        data = data[:i] + draw(st.binary(min_size=1, max_size=16)) + data[i:]
    else:
        data = data + draw(st.binary(min_size=1, max_size=16))
    return data, suffix, how


@settings(FUZZ, max_examples=150)
@given(case=_mutated())
def test_image_readers_on_mutated_files(base: Path, case: tuple[bytes, str, str]) -> None:
    data, suffix, how = case
    with _file(base, "frame" + suffix, data) as path:
        results = _read_all_images(path)
    if how == "truncate":  # OpenCV fills a cut-off image with grey rows; that must not pass
        assert results == (None, None, None), f"truncated {suffix} ({len(data)} bytes) was read"


# ---------------------------------------------------------------------------------- ROI CSVs


def _check_rois(df: pd.DataFrame | None) -> None:
    if df is not None:
        assert isinstance(df, pd.DataFrame) and list(df.columns) == list(kitti.ROI_COLUMNS)
        for c in ("x0", "y0", "x1", "y1"):
            assert df[c].dtype == np.int64
        assert (df["x0"] >= 0).all() and (df["y0"] >= 0).all()
        assert (df["x0"] < df["x1"]).all() and (df["y0"] < df["y1"]).all()
        assert df["class"].isin(kitti.ROI_CLASSES).all()
        assert all(isinstance(name, str) and name for name in df["image"])


@FUZZ
@given(
    data=st.one_of(
        st.binary(max_size=512),
        st.text(max_size=200).map(lambda t: t.encode("utf-8")),
        st.binary(max_size=200).map(lambda b: b"image,class,x0,y0,x1,y1\n" + b),
    )
)
def test_read_rois_on_random_bytes(base: Path, data: bytes) -> None:
    with _file(base, "rois.csv", data) as path:
        _check_rois(_read(kitti.read_rois, path))


_ODD_CELLS = [
    "",
    " ",
    "1.0",
    "1.5",
    "1e3",
    " 7 ",
    "+3",
    "-0",
    "-1",
    "true",
    "True",
    "NaN",
    "nan",
    "inf",
    "-inf",
    "1_000",
    "0x10",
    "NULL",
    "None",
    "N/A",
    "1e400",
    "1e30",
    "2147483648",
    "9007199254740993",  # 2**53 + 1: not a float64
    "9223372036854775807",
    "9223372036854775808",
    "18446744073709551616",  # int64 / uint64 limits
]
_odd_coord = st.one_of(
    st.sampled_from(_ODD_CELLS),
    st.integers(-(2**80), 2**80).map(str),  # negative and far beyond int64
    st.floats().map(repr),  # '1.5', 'nan', 'inf', '1e+300', '-0.0'
    st.text(max_size=5),
)
_coord = st.one_of(st.integers(0, 60).map(str), _odd_coord)
_valid_row = st.builds(
    lambda image, cls, x0, y0, w, h: {
        "image": image,
        "class": cls,
        "x0": str(x0),
        "y0": str(y0),
        "x1": str(x0 + w),
        "y1": str(y0 + h),
    },
    st.from_regex(r"\A[0-9]{6}_1[01]\Z"),
    st.sampled_from(kitti.ROI_CLASSES),
    st.integers(0, 2000),
    st.integers(0, 2000),
    st.integers(1, 500),
    st.integers(1, 500),
)
_random_row = st.fixed_dictionaries(
    {
        "image": st.one_of(st.from_regex(r"\A[0-9]{6}_10\Z"), st.text(max_size=8)),
        "class": st.one_of(st.sampled_from(kitti.ROI_CLASSES), st.text(max_size=8)),
        "x0": _coord,
        "y0": _coord,
        "x1": _coord,
        "y1": _coord,
    }
)


@st.composite
def _roi_tables(draw: st.DrawFn) -> tuple[str, list[str] | None, list[dict[str, str]]]:
    """CSV text, its header (None: no header line) and the rows as written."""
    rows = draw(st.lists(st.one_of(_valid_row, _random_row), max_size=5))
    mode = draw(st.sampled_from(["exact", "exact", "shuffled", "missing", "none"]))
    header: list[str] | None = list(kitti.ROI_COLUMNS)
    if mode == "shuffled":  # any column order, plus unrelated columns
        extra = draw(st.lists(st.sampled_from(["score", "note", ""]), max_size=2, unique=True))
        header = draw(st.permutations(header + extra))
    elif mode == "missing":
        header.remove(draw(st.sampled_from(kitti.ROI_COLUMNS)))
    elif mode == "none":
        header = None
    columns = header or list(kitti.ROI_COLUMNS)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    if header is not None:
        writer.writerow(header)
    for row in rows:
        writer.writerow([row.get(c, "x") for c in columns])
    return out.getvalue(), header, rows


def _as_int(cell: str) -> int:
    """The integer a coordinate cell spells, or raise (a cell the reader must not accept)."""
    number = Decimal(cell.strip())
    if not number.is_finite() or number != number.to_integral_value():
        raise InvalidOperation(cell)
    return int(number)


def _check_accepted_table(
    df: pd.DataFrame | None, header: list[str] | None, rows: list[dict[str, str]]
) -> None:
    """Invariants, and if the table was accepted: every row there with exactly the values written
    (no overflow, no rounding, no 'true' read as 1)."""
    _check_rois(df)
    if df is None:
        return
    assert header is not None and set(kitti.ROI_COLUMNS) <= set(header)
    assert len(df) == len(rows)
    for got, row in zip(df.to_dict("records"), rows, strict=True):
        assert (got["image"], got["class"]) == (row["image"], row["class"])
        for c in ("x0", "y0", "x1", "y1"):
            try:
                want = _as_int(row[c])
            except (InvalidOperation, ValueError):
                raise AssertionError(f"read_rois accepted {c}={row[c]!r} as {got[c]}") from None
            assert got[c] == want, f"read_rois read {c}={row[c]!r} as {got[c]}"


@settings(FUZZ, max_examples=100)
@given(table=_roi_tables())
def test_read_rois_on_tables_of_random_values(base: Path, table: tuple[str, list[str] | None, list]) -> None:
    text, header, rows = table
    with _file(base, "rois.csv", text.encode("utf-8")) as path:
        _check_accepted_table(_read(kitti.read_rois, path), header, rows)


_ONE_BOX = {"image": "000000_10", "class": "car", "x0": "0", "y0": "0", "x1": "1", "y1": "1"}


@settings(FUZZ, max_examples=150)
@given(
    rows=st.lists(_valid_row, min_size=1, max_size=3),
    where=st.integers(0, 2),
    column=st.sampled_from(kitti.ROI_COLUMNS),
    cell=st.one_of(
        _odd_coord, st.sampled_from(["", " car", "Car", "bus", "000000_10 ", "a,b", '"']), st.text(max_size=3)
    ),
)
@example(rows=[_ONE_BOX], where=0, column="x1", cell="true")  # was read as 1
@example(rows=[_ONE_BOX], where=0, column="x1", cell="1e30")  # was read as -2**63
@example(rows=[_ONE_BOX], where=0, column="y1", cell="9007199254740993")  # was read as 2**53
def test_read_rois_with_one_odd_cell(
    base: Path, rows: list[dict[str, str]], where: int, column: str, cell: str
) -> None:
    # A valid table but for one cell, so that cell alone decides whether the table is accepted.
    rows = [dict(row) for row in rows]
    rows[where % len(rows)][column] = cell
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(kitti.ROI_COLUMNS)
    writer.writerows([row[c] for c in kitti.ROI_COLUMNS] for row in rows)
    with _file(base, "rois.csv", out.getvalue().encode("utf-8")) as path:
        _check_accepted_table(_read(kitti.read_rois, path), list(kitti.ROI_COLUMNS), rows)


@FUZZ
@given(
    table=_roi_tables(),
    cut=st.floats(0.0, 1.0),
    flips=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(1, 255)), max_size=4),
)
def test_read_rois_on_mutated_files(
    base: Path, table: tuple, cut: float, flips: list[tuple[float, int]]
) -> None:
    buf = bytearray(table[0].encode("utf-8"))
    for where, mask in flips:
        if buf:
            buf[int(where * (len(buf) - 1))] ^= mask
    with _file(base, "rois.csv", bytes(buf[: int(cut * len(buf))])) as path:
        _check_rois(_read(kitti.read_rois, path))


# ------------------------------------------------------------------------- splits and calib


def _check_split(pairs: list | None) -> None:
    if pairs is not None:
        assert pairs and all(isinstance(p, tuple) and len(p) == 2 for p in pairs)
        assert all(s and not any(c.isspace() for c in s) for p in pairs for s in p)


_text_bytes = st.one_of(
    st.binary(max_size=300),
    st.text(max_size=200).map(lambda t: t.encode("utf-8")),
    st.lists(st.lists(st.text("abc/._0 \t\x00é", max_size=10), max_size=4).map(" ".join), max_size=6).map(
        lambda lines: "\n".join(lines).encode("utf-8")
    ),
)


@settings(FUZZ, max_examples=150)
@given(data=_text_bytes)
@example(data=b"\x80")  # not UTF-8: was a UnicodeDecodeError
def test_read_split_on_random_bytes(base: Path, data: bytes) -> None:
    with _file(base, "files.txt", data) as path:
        _check_split(_read(kitti.read_split, path))


_calib_number = st.one_of(
    st.floats(-2000, 2000).map(repr),
    st.floats().map(repr),  # nan, inf, huge, tiny
    st.sampled_from(["0", "-0", "nan", "inf", "-inf", "1e400", "abc", "1_0", ""]),
)
_calib_line = st.builds(
    lambda key, values: f"{key}: {' '.join(values)}",
    st.sampled_from(["P2", "P3", "P_rect_02", "P_rect_03", "S_rect_02", "calib_time", "x", ""]),
    st.lists(_calib_number, max_size=13),
)


@st.composite
def _calib_files(draw: st.DrawFn) -> bytes:
    kind = draw(st.sampled_from(["random", "lines", "stereo"]))
    if kind == "random":
        return draw(_text_bytes)
    lines = draw(st.lists(_calib_line, max_size=6))
    if kind == "stereo":  # a full P2/P3 pair whose numbers may be anything
        left, right = draw(st.sampled_from([("P2", "P3"), ("P_rect_02", "P_rect_03")]))
        for key in (left, right):
            values = draw(st.lists(_calib_number, min_size=12, max_size=12))
            lines.append(f"{key}: {' '.join(values)}")
    return "\n".join(draw(st.permutations(lines))).encode("utf-8")


@settings(FUZZ, max_examples=150)
@given(data=_calib_files())
@example(data=b"P2: 1.0 0 0 0 0 0 0 0 0 0 0 0\nP3: 0 0 0 0 0 0 0 0 0 0 0 0")  # zero baseline
@example(data=b"P2: nan 0 0 0 0 0 0 0 0 0 0 0\nP3: 0 0 0 0 0 0 0 0 0 0 0 0")  # NaN focal
def test_calibration_readers_on_random_files(base: Path, data: bytes) -> None:
    with _file(base, "calib.txt", data) as path:
        calib = _read(kitti.read_calib, path)
        stereo = _read(lambda p: kitti.focal_and_baseline(414, p), path)  # not a KITTI width: reads p
    if calib is not None:
        assert calib and all(
            isinstance(v, np.ndarray) and v.dtype == np.float64 and v.size for v in calib.values()
        )
    if stereo is not None:
        focal, baseline = stereo
        # A depth of focal * baseline / disparity must be a positive, finite number of metres.
        assert np.isfinite(focal) and focal > 0, f"focal {focal}"
        assert np.isfinite(baseline) and baseline > 0, f"baseline {baseline}"


# ------------------------------------------------------------------------------------ params

_PARAM_NAMES = ["data", "train", "eval", "model", "loss", "compare", "msssim", "variants", "synthetic"]
_PARAM_NAMES += ["kitti", "height", "width", "seed", "seeds", "epochs", "caps", "alpha", "levels", "source"]
_param_keys = st.one_of(
    st.sampled_from(_PARAM_NAMES), st.text(max_size=6), st.integers(), st.booleans(), st.none(), st.floats()
)
_param_leaves = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.floats(),  # nan, inf, huge, tiny
    st.text(max_size=8),
    st.sampled_from([0, 1, 8, 64, 192, 0.5, "ssim", "msssim", "synthetic", "eigen", [], {}]),
)
_param_trees = st.recursive(
    _param_leaves,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(_param_keys, inner, max_size=4),
    max_leaves=12,
)
_YAMLISH = st.text(":-[]{}&*!|>'\"#?,~. \n\t0aby1", max_size=60)


@st.composite
def _params_files(draw: st.DrawFn) -> tuple[dict | None, bytes]:
    """(tree, its YAML) for a random params tree placed at a real section, some of its keys not
    strings and one of its values under two keys (safe_dump writes an anchor and an alias); or
    (None, YAML-like text)."""
    if draw(st.booleans()):
        return None, draw(_YAMLISH).encode("utf-8")
    tree = draw(st.dictionaries(_param_keys, _param_trees, max_size=4))
    shared = draw(st.one_of(st.lists(_param_leaves, min_size=1, max_size=3), _param_trees))
    for name in draw(st.lists(st.sampled_from(_PARAM_NAMES), max_size=2)):
        tree[name] = shared
    for section in reversed(
        draw(st.sampled_from([[], ["train"], ["data"], ["data", "synthetic"], ["msssim"]]))
    ):
        tree = {section: tree}
    return tree, yaml.safe_dump(tree, sort_keys=False, allow_unicode=True).encode("utf-8")


def _check_params_refusal(build: Callable[[], Any], prefix: str) -> None:
    """``build()`` returns Params or raises one short ConfigError line starting with ``prefix``."""
    try:
        assert isinstance(build(), Params)
    except ConfigError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 400, str(exc)[:1000]
        assert str(exc).startswith(prefix), str(exc)


@settings(FUZZ, max_examples=200)
@given(case=_params_files())
@example(case=(None, b"1: x\n~: y\ntrue: z\n"))  # keys that are not strings: was a TypeError
@example(
    case=(None, b'a: &a ["lol", "lol"]\nb: &b [*a, *a]\ntrain: {learning_rate: *b}\n')
)  # echoed expanded
@example(case=(None, b"train: {epochs: " + b"9" * 5001 + b"}\n"))  # int too long to convert: was a ValueError
@example(case=(None, b"train: {epochs: 3}\n\xff\n"))  # not UTF-8: was a UnicodeDecodeError
def test_params_on_random_trees_keys_and_aliases(base: Path, case: tuple[dict | None, bytes]) -> None:
    tree, data = case
    with _file(base, "params.yaml", data) as path:
        _check_params_refusal(lambda: load_params(path), f"{path}: ")
    if tree is not None:
        _check_params_refusal(lambda: params_from_dict(tree), "")


# ------------------------------------------------------------------- header-declared image sizes


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")


@st.composite
def _declared_size_files(draw: st.DrawFn) -> tuple[bytes, int, int]:
    """A valid small PNG or JPEG whose header is rewritten to declare another size, up to 2**31 - 1
    (PNG) or 65535 (JPEG) a side: the decoder would allocate what the header says."""
    width = draw(st.one_of(st.integers(1, 64), st.integers(1, 65535), st.integers(1, 2**31 - 1)))
    height = draw(st.one_of(st.integers(1, 64), st.integers(1, 65535), st.integers(1, 2**31 - 1)))
    image = np.full((8, 8, 3), draw(st.integers(0, 255)), np.uint8)
    if draw(st.booleans()):
        data = _encode(image, ".png")
        ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + data[24:29]
        return data[:8] + _png_chunk(b"IHDR", ihdr) + data[33:], width, height
    width, height = min(width, 65535), min(height, 65535)
    data = bytearray(_encode(image, ".jpg"))
    sof = data.index(b"\xff\xc0")
    data[sof + 5 : sof + 9] = height.to_bytes(2, "big") + width.to_bytes(2, "big")
    return bytes(data), width, height


@settings(FUZZ, max_examples=80)
@given(case=_declared_size_files())
@example(case=(b"", 50_000, 50_000))  # replaced below by a PNG declaring it: was an uncaught cv2.error
def test_image_readers_on_header_declared_sizes(base: Path, case: tuple[bytes, int, int]) -> None:
    from msdepth.data.imagefile import MAX_IMAGE_PIXELS

    data, width, height = case
    if not data:
        ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 2, 0, 0, 0])
        idat = _png_chunk(b"IDAT", zlib.compress(b"\0" * 99))
        data = PNG_MAGIC + _png_chunk(b"IHDR", ihdr) + idat + _png_chunk(b"IEND", b"")
    with _file(base, "frame.png", data) as path:
        img, _, _ = _read_all_images(path)  # memory checked there: < 512 MiB growth
        if width * height > MAX_IMAGE_PIXELS:
            with pytest.raises(DataError, match=f"declares {width} x {height} px"):
                kitti.read_image(path)
    if img is not None:  # a decoder may read a different size only if it fits the data it has
        assert img.shape[0] * img.shape[1] <= MAX_IMAGE_PIXELS


# ------------------------------------------------------------------------------ model metadata

_ANY_VALUE = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
    st.lists(st.integers(0, 9), max_size=3),
    st.sampled_from([0.0625, 0.125, 3.0, 32, 96, 20000, "group", "residual", "none", "independent"]),
)


@pytest.fixture(scope="module")
def tiny_weights() -> dict:
    import torch

    from msdepth.networks.vgg import MonodepthVGG

    torch.manual_seed(0)
    return MonodepthVGG(0.0625).state_dict()


@settings(FUZZ, max_examples=60)
@given(
    changes=st.dictionaries(
        st.sampled_from(["width_multiplier", "height", "width", "norm", "heads", "variant", "seed", "extra"]),
        _ANY_VALUE,
        max_size=4,
    ),
    drop=st.sets(st.sampled_from(["width_multiplier", "height", "width", "model"]), max_size=1),
)
@example(changes={"width_multiplier": -32}, drop=set())  # were tracebacks
@example(changes={"width_multiplier": "abc"}, drop=set())
@example(changes={"width_multiplier": 3.0, "height": 20000, "width": 20000}, drop=set())  # 4.8 GB
def test_load_model_on_random_metadata(base: Path, tiny_weights: dict, changes: dict, drop: set) -> None:
    """Whatever the metadata, load_model returns a model that fits it, or one MsdepthError naming
    the file; never another exception, and never a network other than the weights describe."""
    import torch

    from msdepth.networks.model_file import load_model

    state = {"model": tiny_weights, "criterion": {}, "width_multiplier": 0.0625, "height": 32, "width": 96}
    state = {k: v for k, v in {**state, **changes}.items() if k not in drop}
    with tempfile.TemporaryDirectory(dir=base) as folder:
        path = Path(folder) / "model.pt"
        torch.save(state, path)
        before = _peak_rss_mb()
        try:
            model, meta = load_model(path)
        except MsdepthError as exc:
            message = str(exc)
            assert message.startswith(str(path)) and "\n" not in message, message
            return
        assert _peak_rss_mb() - before < 256
    assert meta["width_multiplier"] == 0.0625 and 32 <= meta["height"] <= 4096 and meta["height"] % 8 == 0
    assert sum(p.numel() for p in model.parameters()) == sum(v.numel() for v in tiny_weights.values())
