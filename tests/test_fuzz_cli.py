"""Fuzz every entry point (issue 42, build item 7): each ``msdepth`` subcommand and the params
reader get hostile file names (newlines, non-UTF-8 bytes, U+2028), sizes and params. Whatever they
get, they exit 0 or 1 (2 for a usage error), print every error as one line with no traceback, and
write nothing outside their output. Few examples each (hypothesis, derandomized), so the fast tier
stays fast; ``test_every_subcommand_is_fuzzed`` fails until a new subcommand is added here.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import tempfile
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
import pytest
from conftest import save_tiny_model
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from msdepth.__main__ import _build_parser, main
from msdepth.config.params import apply_overrides, params_from_dict
from msdepth.errors import ConfigError

FEW = settings(
    max_examples=12,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
FUZZED = ("predict", "optimum", "export-onnx", "export-folder", "experiments", "photometry")
MAX_LINE = 1000  # an error line echoing a 100 KB value is a defect too (case 12)

# A file name component: any character but "/" and NUL, or any bytes (not UTF-8 too) but those.
_names = st.one_of(
    st.text(
        st.characters(blacklist_characters="/\x00", blacklist_categories=("Cs",)), min_size=1, max_size=12
    ),
    st.binary(min_size=1, max_size=12).map(
        lambda b: os.fsdecode(b.replace(b"/", b"_").replace(b"\x00", b"_"))
    ),
    st.sampled_from(["evil\nscene", "caf\udce9", "a\u2028b", "a\rb", "-x", " ", "x" * 250]),
).filter(lambda n: n not in (".", ".."))
_sides = st.sampled_from([None, -8, 0, 1, 7, 32, 4097, 10**6, 2**40])
_ints = st.sampled_from([-1, 0, 1, 3, 10**9, 2**63])


@pytest.fixture(scope="module")
def model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return save_tiny_model(tmp_path_factory.mktemp("model") / "model.pt")


@contextlib.contextmanager
def _folder() -> Iterator[Path]:
    with tempfile.TemporaryDirectory() as folder:
        yield Path(folder)


def _image(path: Path, seed: int = 0, kind: str = "png") -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if kind == "junk":
        path.write_bytes(np.random.default_rng(seed).bytes(64))
        return
    image = np.random.default_rng(seed).integers(0, 256, (24, 40, 3), np.uint8)
    path.write_bytes(cv2.imencode(".png", image)[1].tobytes())


def _snapshot(root: Path, skip: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in root.rglob("*") if p.is_file() and not p.is_relative_to(skip)}


def _run(argv: list[str]) -> tuple[int, str]:
    """``main(argv)``: its exit code and stderr, checked: 0, 1 or 2, no traceback, every error one
    line of bounded length."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse's usage error
            code = exc.code
    text = err.getvalue()
    assert code in (0, 1, 2), (code, text)
    assert "Traceback" not in text, text
    errors = [line for line in text.splitlines() if line.startswith("error:")]
    assert code == 0 or errors or "usage:" in text, text
    assert all(len(line) < MAX_LINE for line in errors), errors
    return code, text


def test_every_subcommand_is_fuzzed() -> None:
    sub = next(a for a in _build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert set(sub.choices) == set(FUZZED)


def _opt(flag: str, value: object) -> list[str]:
    return [] if value is None else [flag, str(value)]


@settings(FEW, max_examples=8)
@given(
    name=_names,
    kind=st.sampled_from(["png", "junk"]),
    suffix=st.sampled_from([".png", ".jpg", ".avi", ".txt", ""]),
    height=_sides,
    width=_sides,
    megapixels=st.sampled_from([None, "nan", "inf", "-1", "0", "1e-9", "0.0005", "1e300"]),
    batch=_ints,
)
def test_predict_on_hostile_names_sizes_and_options(
    model: Path, name: str, kind: str, suffix: str, height: int | None, width: int | None, megapixels, batch
) -> None:
    with _folder() as tmp:
        try:
            _image(tmp / "in" / (name + suffix), 1, kind)
        except OSError:  # a name the file system refuses (too long in bytes): nothing to test
            return
        _image(tmp / "in" / "ok.png", 2)
        before = _snapshot(tmp, tmp / "out")
        argv = ["predict", str(tmp / "in"), "--model", str(model), "--out", str(tmp / "out"), "--quiet"]
        argv += _opt("--height", height) + _opt("--width", width)
        argv += _opt("--max-megapixels", megapixels) + _opt("--batch-size", batch)
        _run(argv)
        assert _snapshot(tmp, tmp / "out") == before  # the inputs and the model untouched


_OPTIMUM_KEYS = st.sampled_from(
    [
        "optimum.height",
        "optimum.width",
        "optimum.batch_size",
        "optimum.start",
        "msssim.kernel_size",
        "optimum",
        "no.such",
    ]
)
_VALUES = st.one_of(
    st.sampled_from(["-1", "0", "1e400", "nan", "[1, 2]", "{a: 1}", "&a x", "9" * 5000, "sgbm", "", "~"]),
    st.text(max_size=8),
)


@FEW
@given(
    left=_names,
    variant=st.sampled_from(["ssim", "msssim", "", "../x", "a\nb"]),
    sets=st.lists(st.tuples(_OPTIMUM_KEYS, _VALUES).map("=".join), max_size=2),
    height=st.sampled_from([None, -1, 0, 23, 10**9]),
)
def test_optimum_on_hostile_names_and_params(
    left: str, variant: str, sets: list[str], height: int | None
) -> None:
    with _folder() as tmp:
        try:
            _image(tmp / "L" / f"{left}.png", 1)
            _image(tmp / "R" / f"{left}.png", 2)
        except OSError:
            return
        before = _snapshot(tmp, tmp / "out")
        argv = ["optimum", str(tmp / "L"), str(tmp / "R"), "--out", str(tmp / "out"), "--variant", variant]
        for item in [*sets, "optimum.iterations=2", "optimum.levels=1"]:
            argv += ["--set", item]
        argv += _opt("--height", height) + _opt("--width", height) + ["--quiet"]
        _run(argv)
        assert _snapshot(tmp, tmp / "out") == before


@settings(FEW, max_examples=6)
@given(
    out=_names,
    height=st.sampled_from([None, -8, 0, 10**6, 2**40]),
    opset=st.sampled_from([None, -1, 10, 21, 2**63]),
)
def test_export_onnx_on_hostile_names_and_sizes(model: Path, out: str, height: int | None, opset) -> None:
    with _folder() as tmp:
        argv = ["export-onnx", "--model", str(model), "--out", str(tmp / "o" / out)]
        argv += _opt("--height", height) + _opt("--width", height) + _opt("--opset", opset)
        if height is None and opset is None:
            argv += ["--opset", "9"]  # a refusal: a whole export per example is too slow for this tier
        _run(argv)
        assert model.is_file()


@FEW
@given(to=_names, source=st.sampled_from(["missing", "file", "empty", "junk tree"]))
def test_export_folder_on_hostile_names_and_trees(to: str, source: str) -> None:
    with _folder() as tmp:
        src = tmp / "src"
        if source == "file":
            src.write_bytes(b"\x89PNG not a tree")
        elif source == "empty":
            src.mkdir()
        elif source == "junk tree":
            _image(src / "raw" / "2011_09_26" / "calib_cam_to_cam.txt", 1, "junk")
            _image(src / "kitti2015" / "training" / "image_2" / "000000_10.png", 2, "junk")
        code, _ = _run(["export-folder", "--from", str(src), "--to", str(tmp / to)])
        assert code != 0


@FEW
@given(
    out=_names,
    tree=st.sampled_from(["missing", "file", "empty", "junk images", "gt of another size"]),
    width=st.sampled_from([None, -1, 0, 15, 16, 4097, 10**9]),
)
def test_photometry_on_hostile_names_trees_and_widths(out: str, tree: str, width: int | None) -> None:
    with _folder() as tmp:
        training = tmp / "k15" / "training"
        if tree == "file":
            (tmp / "k15").write_bytes(b"not a folder")
        elif tree == "empty":
            training.mkdir(parents=True)
        elif tree != "missing":
            for sub, seed in (("image_2", 1), ("image_3", 2), ("disp_occ_0", 3)):
                _image(training / sub / "000000_10.png", seed, "junk" if tree == "junk images" else "png")
            if tree == "gt of another size":
                gt = np.ones((10, 10), np.uint16) * 256
                (training / "disp_occ_0" / "000000_10.png").write_bytes(cv2.imencode(".png", gt)[1].tobytes())
        before = _snapshot(tmp, tmp / "nothing")
        try:
            code, _ = _run(["photometry", str(tmp / "k15"), "--out", str(tmp / out), *_opt("--width", width)])
        except OSError:  # a name the file system refuses (too long in bytes): nothing to test
            return
        assert code != 0
        assert {p: b for p, b in _snapshot(tmp, tmp / "nothing").items() if p in before} == before


@settings(FEW, max_examples=40)
@given(
    sets=st.lists(
        st.tuples(st.text(max_size=12), st.sampled_from(["=", ""]), _VALUES).map("".join), max_size=3
    )
)
def test_the_params_reader_on_hostile_assignments(sets: list[str]) -> None:
    try:
        params_from_dict(apply_overrides({}, sets))
    except ConfigError as exc:
        message = str(exc)
        assert "\n" not in message and len(message) < MAX_LINE, message


@FEW
@given(
    content=st.one_of(
        st.binary(max_size=200),
        st.recursive(
            st.none() | st.booleans() | st.floats(allow_nan=False) | st.text(max_size=8),
            lambda inner: (
                st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner, max_size=3)
            ),
            max_leaves=12,
        ).map(lambda v: json.dumps(v).encode()),
    ),
    md=st.booleans(),
)
def test_experiments_reads_any_file_in_one_line(content: bytes, md: bool) -> None:
    # A saved `dvc exp show --json` output of any bytes or any JSON shape: a table or one error line.
    with _folder() as folder:
        path = folder / "show.json"
        path.write_bytes(content)
        _run(["experiments", "--json", str(path), *(["--md"] if md else [])])
