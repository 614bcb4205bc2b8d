"""End to end: `dvc exp run -S train.mode=mono -S data.synthetic.sequence_length=3` of the real
dvc.yaml in a tiny copy of the project: sequences rendered, every variant trained monocularly,
evaluated median-scaled, its pose ATE written."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
from conftest import dvc, project, require_dvc

# The tests here run DVC on copied projects: the second tier (`-m slow`).
pytestmark = pytest.mark.slow

# The pose network's ResNet needs sides of 64 px or more; the rest as small as the stages allow.
TINY = {
    "data": {
        "height": 64,
        "width": 192,
        "synthetic": {"drives": 2, "train_pairs": 12, "eval_frames": 3, "height": 64, "width": 192},
    },
    "model": {"width_multiplier": 0.0625, "pose_width_multiplier": 0.0625},
    "train": {"epochs": 1, "batch_size": 4, "seeds": [0]},
    "msssim": {"levels": 3},
}
MONO = ["-S", "train.mode=mono", "-S", "data.synthetic.sequence_length=3"]
# The stages of a monocular run, up to its suites (compare also waits for the optimum stages, which
# do not depend on the mode; its monocular table is tested in test_mono_eval.py).
TARGETS = ["eval_full", "eval_roi"]


@pytest.fixture(scope="module")
def repo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    require_dvc()
    return project(tmp_path_factory.mktemp("mono"), tiny=TINY)


def test_mono_without_sequences_stops_at_validation_in_one_line(repo: Path) -> None:
    proc = dvc(["exp", "run", "--quiet", "-S", "train.mode=mono"], repo, ok=False)
    errors = [
        line for line in (proc.stdout + proc.stderr).splitlines() if line.startswith("error: params.yaml")
    ]
    assert proc.returncode != 0 and len(errors) == 1, proc.stderr[-2000:]
    assert (
        "train.mode: 'mono' trains on frame sequences: KITTI's raw drives (data.source kitti) or "
        "rendered ones (data.source synthetic with data.synthetic.sequence_length >= 3" in errors[0]
    )
    assert not (repo / "data" / "synthetic").exists()  # nothing after validate_params ran
    subprocess.run(["git", "checkout", "params.yaml"], cwd=repo, check=True)


def test_exp_run_trains_and_evaluates_every_variant_monocularly(repo: Path) -> None:
    dvc(["exp", "run", "--quiet", "-n", "mono", *MONO, *TARGETS], repo)
    raw = repo / "data" / "synthetic"
    assert (raw / "train_mono_files.txt").stat().st_size > 0 and list(raw.glob("raw/*/*/poses.txt"))
    for variant in ("ssim", "msssim"):
        full = json.loads((repo / "metrics" / "full" / variant / "seed0.json").read_text())
        scaling = full["cap80"]["median_scaling"]
        assert scaling["ratio_median"] > 0 and scaling["ratio_std_over_median"] >= 0
        assert 0 < full["cap80"]["abs_rel"] < 10
        roi = json.loads((repo / "metrics" / "roi" / variant / "seed0.json").read_text())
        assert 0 < roi["cap80"]["overall"]["abs_rel"] < 10
        pose = json.loads((repo / "metrics" / "train" / variant / "seed0.json").read_text())["pose"]
        # 2 drives x 6 frames: two 3-frame sequences each, 2 snippets per sequence.
        assert pose["snippets"] == 8 and pose["ate_mean"] >= 0
        headline = json.loads((repo / "metrics" / "headline" / "full" / variant / "seed0.json").read_text())
        assert headline["scale_ratio"] == pytest.approx(scaling["ratio_median"])
    assert "mono" in dvc(["exp", "show", "--md"], repo).stdout
