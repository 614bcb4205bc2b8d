"""Fixtures shared by several test modules."""

from __future__ import annotations

import functools
import runpy
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from msdepth.io import write_png

ROOT = Path(__file__).resolve().parents[1]

# Size of the tiny training pairs: 32 x 64 keeps 3 MS-SSIM levels at the coarsest training scale.
PAIR_H, PAIR_W = 32, 64


@pytest.fixture(scope="session")
def pairs(tmp_path_factory) -> list[tuple[Path, Path]]:
    """Eight stereo pairs of PAIR_H x PAIR_W: a random texture and the same texture shifted by 2 px."""
    root = tmp_path_factory.mktemp("pairs")
    rng = np.random.default_rng(0)
    out = []
    for i in range(8):
        scene = rng.integers(0, 256, (PAIR_H, PAIR_W + 2, 3), dtype=np.uint8)
        left, right = root / f"l{i}.png", root / f"r{i}.png"
        write_png(left, scene[:, 2:])
        write_png(right, scene[:, :-2])
        out.append((left, right))
    return out


@functools.cache
def stage(name: str) -> SimpleNamespace:
    """The stage script ``stages/<name>.py`` loaded as a namespace (its ``__main__`` block not run):
    the scripts are not a package, and nothing in ``msdepth`` imports them."""
    return SimpleNamespace(**runpy.run_path(str(ROOT / "stages" / f"{name}.py")))
