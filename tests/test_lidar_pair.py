"""studies/lidar_pair.py: every method on a tiny synthetic pair with a sparse, scan-like GT (known
answers: SGBM and the cost start find the plane), a missing file of the pair as one line naming it,
and the shared KITTI object pair against its Velodyne scan (skipped where ``../shared`` is absent)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import run_script, save_tiny_model
from test_matcher import scene

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT.parent / "shared" / "real-samples"
TINY = ["optimum.iterations=2", "optimum.levels=1", "optimum.start=constant", "optimum.refine_iterations=2"]


def _sets(*overrides: str) -> list[str]:
    return [x for s in (*TINY, *overrides) for x in ("--set", s)]


def test_every_method_on_a_plane_with_a_scan_like_gt(tmp_path, monkeypatch, capsys):
    """A plane at 5 px, GT on every 4th pixel of every 3rd row (a scan's sparsity): each method a
    row (SGBM, per variant its cost start and optimum at the weights asked for), SGBM and the cost
    starts on the plane (abs_rel < 0.05) on exactly the GT points; the networks of --models, each
    seed a row and each variant's mean over its seeds."""
    monkeypatch.syspath_prepend(str(ROOT / "studies"))
    import lidar_pair

    left, right, truth = scene(5, 5)
    gt = np.zeros_like(truth, dtype=np.float32)
    gt[::3, ::4] = truth[::3, ::4]
    images = [(np.clip(i, 0, 1) * 255).round().astype(np.uint8) for i in (left, right)]
    pair = lidar_pair.LidarPair(images[0], images[1], gt, 700.0, 0.5)  # 5 px: 70 m, inside the cap
    monkeypatch.setattr(lidar_pair, "object_pair", lambda base: pair)
    for variant in ("ssim", "msssim"):
        for seed in (0, 1):
            (tmp_path / "models" / variant / f"seed{seed}").mkdir(parents=True)
            save_tiny_model(tmp_path / "models" / variant / f"seed{seed}" / "model.pt")
    args = ["--samples", str(tmp_path), "--size", "full", "--weights", "3,10", "--out", str(tmp_path / "out")]
    assert lidar_pair.main([*args, "--models", str(tmp_path / "models"), *_sets()]) == 0
    text = (tmp_path / "out" / "lidar_pair.md").read_text(encoding="utf-8")
    rows = {
        line.split(" | ")[0][2:]: line.split(" | ")[1:] for line in text.splitlines() if line.startswith("| ")
    }
    methods = ["SGBM"] + [f"{v} {m}" for v in ("ssim", "msssim k3", "msssim k7")
                          for m in ("cost start", "optimum w3", "optimum w10")]  # fmt: skip
    networks = [f"network {v} seed{s}" for v in ("ssim", "msssim") for s in (0, 1)]
    means = [f"network {v} (mean of 2 seeds)" for v in ("ssim", "msssim")]
    assert list(rows)[1:] == [*methods, *networks, *means]  # after the header
    points = str(int((gt > 0).sum()))
    assert all(rows[m][0] == points for m in [*methods, *networks, *means])
    for method in ("SGBM", "ssim cost start", "msssim k3 cost start"):
        assert float(rows[method][1]) < 0.05, (method, rows[method])


def test_a_missing_file_of_the_pair_is_one_line_naming_it(tmp_path):
    (tmp_path / "kitti-object-pair").mkdir()
    proc = run_script("studies/lidar_pair.py", "--samples", str(tmp_path), "--out", str(tmp_path / "out"),
                      cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 1
    assert (
        proc.stderr.strip()
        == f"error: {tmp_path / 'kitti-object-pair' / 'left.png'}: missing (the KITTI object pair's folder)"
    )
    assert not (tmp_path / "out" / "lidar_pair.md").exists()


@pytest.mark.skipif(not SAMPLES.is_dir(), reason=f"{SAMPLES} absent (a clone without ../shared)")
def test_the_shared_object_pair_against_its_scan(tmp_path, monkeypatch):
    """The real pair at a tiny working size (the path, not the optimum): 17,815 scan points in
    (1e-3, 80) m at full size, SGBM near its committed 0.244 abs_rel (studies/results/real)."""
    monkeypatch.syspath_prepend(str(ROOT / "studies"))
    import lidar_pair

    args = ["--samples", str(SAMPLES), "--size", "48x160", "--weights", "10", "--out", str(tmp_path)]
    assert lidar_pair.main([*args, *_sets()]) == 0
    text = (tmp_path / "lidar_pair.md").read_text(encoding="utf-8")
    sgbm = next(line for line in text.splitlines() if line.startswith("| SGBM |")).split(" | ")
    assert sgbm[1] == "17815" and float(sgbm[2]) == pytest.approx(0.244, abs=0.005)
