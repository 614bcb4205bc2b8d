"""studies/kernels.py: each kernel against SSIM and k=3, paired by seed, on a hand-made run folder."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(folder: Path, spec: str, seed: int, shift: float) -> None:
    row = {
        "abs_rel": 0.2 + shift + 0.01 * seed,
        "roi_abs_rel": 0.5 + shift,
        "roi_by_class": {"car": 0.4 + shift + 0.02 * seed},
    }
    (folder / f"{spec}_seed{seed}.json").write_text(json.dumps(row))


@pytest.fixture
def kernels(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "studies"))
    import kernels

    yield kernels
    del sys.modules["kernels"]


def test_the_kernel_table_pairs_seeds_and_quotes_the_dissertation(tmp_path: Path, kernels, capsys) -> None:
    for seed in range(3):
        _run(tmp_path, "ssim", seed, 0.0)
        _run(tmp_path, "msssim_k3", seed, -0.01 * (1 + seed % 2))  # differences -0.01, -0.02, -0.01
        _run(tmp_path, "msssim_k7", seed, 0.0)
    assert kernels.main(["--runs", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    row = next(line for line in lines if line.startswith("| car | k=3 |"))
    # Mean -0.0133; t(2) 4.303 x sd 0.00577 / sqrt 3 = 0.0143: [-0.028, +0.001], lower in 3 of 3.
    assert "| \u22120.013 [\u22120.028, +0.001] (3/3) |" in row
    full = next(line for line in lines if line.startswith("| full frame | k=7 |"))
    assert full.endswith(
        "| +0.000 [+0.000, +0.000] (0/3) | +0.013 [\u22120.001, +0.028] (0/3) | \u22120.042 | +0.002 |"
    )


def test_a_folder_without_ssim_is_one_line(tmp_path: Path, kernels, capsys) -> None:
    _run(tmp_path, "msssim_k3", 0, 0.0)
    assert kernels.main(["--runs", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "needs SSIM's and at least one MS-SSIM kernel's runs" in err
