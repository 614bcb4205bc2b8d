"""studies/real_pairs.py end to end on a tiny fake samples folder (the real-samples layout with
tiny synthetic frames, as tests/test_matcher.py's starts study test)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from test_matcher import fake_samples

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_real_pairs_study_on_a_tiny_fake_samples_folder(tmp_path):
    """Every method on every pair at hand, the reflective class on KITTI 2012's, the absent object
    pair named, the report written through the output policy (a second run may replace it)."""
    samples = tmp_path / "samples"
    fake_samples(samples)
    calib = samples / "kitti2012-training" / "calib"  # the fake frames' width is no KITTI width
    calib.mkdir()
    for n in ("000000", "000001"):
        (calib / f"{n}.txt").write_text(
            "P2: 700 0 64 0 0 700 20 0 0 0 1 0\nP3: 700 0 64 -378 0 700 20 0 0 0 1 0\n"
        )
    params = yaml.safe_load((ROOT / "params.yaml").read_text(encoding="utf-8"))
    params["optimum"].update(levels=1, iterations=2)  # the path, not the optimum
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(params), encoding="utf-8")
    out = tmp_path / "out"
    command = [sys.executable, str(ROOT / "studies" / "real_pairs.py"), "--samples", str(samples)]
    command += ["--params", str(tmp_path / "p.yaml"), "--size", "full", "--out", str(out)]
    for _ in range(2):
        proc = subprocess.run(command, capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-3000:]
    text = (out / "real_pairs.md").read_text(encoding="utf-8")
    assert "absent: kitti-object-pair" in text
    methods = 1 + 3 * (1 + len(params["optimum"]["smoothness_sweep"]))  # SGBM; per variant: start, weights
    assert text.count("| 2015 000000_10 | disp_occ_0 |") == methods
    assert text.count("| 2012 000001_10 | disp_occ+refl |") == 2 * methods  # all and reflective
    assert "| 2012 000000_10 | disp_occ+refl | msssim k7 optimum w30 | reflective |" in text
    assert "| 2015 000000_10 | disp_occ_0 | SGBM | all | 5120 | 0.0" in text  # the plane at 5 px, matched
    assert "[4/4] 2012 000001_10 msssim k7 optimum w30" in proc.stdout
