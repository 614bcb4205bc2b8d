"""studies/real_pairs.py end to end on a tiny fake samples folder (the real-samples layout with
tiny synthetic frames, as tests/test_matcher.py's starts study test), on the shared real pairs
(``../shared/real-samples``; skipped where it is absent) for its verdict rows, and its reflective
units (frames) on a hand-made mask."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import save_tiny_model
from test_matcher import fake_samples

from msdepth.reporting.verdict import FULL_FRAME, MIN_UNITS, POOLABLE, Row, pooled_rows, read_external_rows

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT.parent / "shared" / "real-samples"


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
    assert (out / "verdict.json").is_file()  # claimed beside the report: the second run replaced it


def test_a_frame_is_the_unit_of_an_exact_class(monkeypatch):
    """Reflective units are frames, never tiles of one car: a frame with at least CLASS_PIXELS
    scored pixels of the class is one unit (its abs_rel over them), one with fewer is none."""
    monkeypatch.syspath_prepend(str(ROOT / "studies"))
    from real_pairs import CLASS_PIXELS, RealPair, class_values

    gt = np.full((40, 60), 20.0, np.float32)  # px of disparity everywhere
    mask = np.zeros(gt.shape, bool)
    mask[:10, : CLASS_PIXELS // 10] = True  # exactly CLASS_PIXELS px
    pair = RealPair("2012 x", "disp_occ+refl", gt, gt, gt, 700.0, 0.5, {"reflective": mask})
    (unit,) = class_values(pair, gt * 1.25, "reflective")  # disparity 25 % high: depth 20 % low
    assert unit["unit"] == "2012 x" and unit["abs_rel"] == pytest.approx(0.2, abs=1e-6)
    mask[0, 0] = False
    assert class_values(pair, gt, "reflective") == []


@pytest.mark.skipif(not SAMPLES.is_dir(), reason=f"{SAMPLES} absent (a clone without ../shared)")
def test_the_verdict_rows_of_the_shared_real_pairs(tmp_path, monkeypatch):
    """On the shared pairs at a tiny working size (the path, not the optimum): both outputs, and
    verdict.json as the compare stage reads it, with every class for each instrument (the optimum
    named as the pipeline names it, so that its rows pool), each over at least MIN_UNITS units."""
    monkeypatch.syspath_prepend(str(ROOT / "studies"))
    from real_pairs import main

    tiny = ["optimum.iterations=2", "optimum.levels=1", "optimum.start=constant"]
    args = ["--samples", str(SAMPLES), "--size", "48x160", "--weights", "10", "--out", str(tmp_path)]
    assert main([*args, *(x for s in tiny for x in ("--set", s))]) == 0
    assert "| 2012 000001_10 | disp_occ+refl | msssim k3 optimum w10 | reflective |" in (
        tmp_path / "real_pairs.md"
    ).read_text(encoding="utf-8")
    rows = read_external_rows(tmp_path / "verdict.json")
    classes = [FULL_FRAME, "car", "windshield", "glass", "sign", "reflective"]
    assert [(r.instrument, r.cls) for r in rows] == [
        (i, c) for i in ("cost start", "optimum w10") for c in classes
    ]
    assert all(r.n >= MIN_UNITS and r.has_interval for r in rows if r.cls != "reflective")
    assert {r.n for r in rows if r.cls == FULL_FRAME} == {5}  # the object pair, 2 KITTI 2015 and 2 KITTI 2012
    # Reflective: the two KITTI 2012 frames are its units, too few for an interval.
    reflective = next(r for r in rows if r.cls == "reflective")
    assert (
        reflective.n == 2
        and not reflective.has_interval
        and "no interval, 2 independent" in reflective.method
    )
    assert all(r.settings.startswith("msssim: kernel_size=3") for r in rows)
    assert POOLABLE.match("optimum w10") and not POOLABLE.match("cost start")
    same = rows[0].settings
    pipeline = Row(
        "optimum w10", "car", 0.0, -0.01, 0.01, 9, "paired bootstrap over ROIs", "optimum", settings=same
    )
    assert [(r.instrument, r.cls) for r in pooled_rows([*rows, pipeline])] == [("optimum w10, pooled", "car")]
    other = dataclasses.replace(pipeline, settings=same.replace("kernel_size=3", "kernel_size=7", 1))
    assert pooled_rows([*rows, other]) == []  # never pooled across settings


@pytest.mark.skipif(not SAMPLES.is_dir(), reason=f"{SAMPLES} absent (a clone without ../shared)")
def test_the_trained_networks_on_the_shared_real_pairs(tmp_path, monkeypatch):
    """``--models``: every network of a model tree (two variants, two seeds each, the CLI tests' tiny
    model) scored on every pair, each variant also over its seeds in the mean table, and the
    ``stereo networks`` rows (over units and seeds) in verdict.json as the compare stage reads it."""
    monkeypatch.syspath_prepend(str(ROOT / "studies"))
    from real_pairs import main

    for variant in ("ssim", "msssim"):
        for seed in (0, 1):
            (tmp_path / "models" / variant / f"seed{seed}").mkdir(parents=True)
            save_tiny_model(tmp_path / "models" / variant / f"seed{seed}" / "model.pt")
    tiny = ["optimum.iterations=2", "optimum.levels=1", "optimum.start=constant"]
    args = ["--samples", str(SAMPLES), "--size", "48x160", "--weights", "10", "--out", str(tmp_path / "out")]
    tiny.append("train.seeds=[0,1]")
    assert main([*args, "--models", str(tmp_path / "models"), *(x for s in tiny for x in ("--set", s))]) == 0
    text = (tmp_path / "out" / "real_pairs.md").read_text(encoding="utf-8")
    for method in ("network ssim seed0", "network ssim seed1", "network msssim seed1"):
        assert f"| 2015 000000_10 | disp_occ_0 | {method} | all |" in text
    assert "| 2012 000001_10 | disp_occ+refl | network msssim seed0 | reflective |" in text
    assert (
        "| all | network ssim (2 seeds) | 5 |" in text
        and "| reflective | network msssim (2 seeds) | 2 |" in text
    )
    rows = [
        r for r in read_external_rows(tmp_path / "out" / "verdict.json") if r.instrument == "stereo networks"
    ]
    assert [r.cls for r in rows] == [FULL_FRAME, "car", "windshield", "glass", "sign", "reflective"]
    paired = [r for r in rows if r.has_interval]
    assert len(paired) == 5 and all("paired by seed (2 pairs)" in r.method for r in paired)
    assert rows[0].label == "stereo networks, real pairs" and rows[0].n == 5
    assert all(r.diff == 0 for r in rows)  # the same tiny model for every variant and seed
