"""studies/camera_screen.py (issue 66, item 4) end to end at its smallest: two conditions, two frames at
48 x 160, two weights and a few Adam steps; its outputs' structure, its resume, and its one-line refusals.
"""

from __future__ import annotations

import runpy
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest
from conftest import run_script

from msdepth.config.params import CameraConfig, params_from_dict, read_params_file
from msdepth.errors import run_main
from msdepth.evaluation.rendered import rendered_eval_set

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = "studies/camera_screen.py"
TINY = [
    "--set=data.synthetic.height=48",
    "--set=data.synthetic.width=160",
    "--set=optimum.iterations=3",
    "--set=optimum.levels=1",
    "--set=optimum.refine_iterations=3",
    "--set=optimum.refine_levels=1",
]
ARGS = ["--frames", "2", "--conditions", "ideal", "all", "--weights", "3", "10", "--threads", "1", *TINY]


def _study() -> SimpleNamespace:
    """studies/camera_screen.py as a namespace, its ``__main__`` block not run."""
    return SimpleNamespace(**runpy.run_path(str(ROOT / SCRIPT)))


@pytest.fixture(scope="module")
def screened(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    """The tiny screen, run once: its output folder and the finished process."""
    out = tmp_path_factory.mktemp("screen")
    proc = run_script(SCRIPT, *ARGS, "--out", str(out), cwd=out, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out, proc


@pytest.mark.slow
def test_the_screen_writes_a_table_per_condition_a_summary_and_the_per_frame_scores(screened) -> None:
    """screen.md holds the two summary tables (own best, w10; a row per condition) and a section per
    condition naming its chosen weights; every scores file holds each variant at each weight on each
    frame, with the ROI boxes; summary.csv has a row per condition, class and weight choice."""
    out, proc = screened
    text = (out / "screen.md").read_text()
    assert text.count("| condition | full frame |") == 2 and "### ideal" in text and "### all" in text
    assert "Own best weights, per fold of frames (0, 1): SSIM w" in text
    for name in ("ideal", "all"):
        scores = pd.read_csv(out / f"scores_{name}.csv")
        full = scores[scores["suite"] == "full"]
        assert sorted(set(zip(full["variant"], full["weight"], full["image"], strict=True))) == [
            (v, w, f) for v in ("msssim", "ssim") for w in (3.0, 10.0) for f in ("000000_10", "000001_10")
        ]
        assert (scores["suite"] == "roi").any() and (scores["cap"] == 80).all()
        assert f"{name}: ssim w3" in proc.stderr and f"{name}: done in" in proc.stderr
    summary = pd.read_csv(out / "summary.csv")
    assert set(summary["condition"]) == {"ideal", "all"} and set(summary["weights"]) == {"own best", "w10"}
    assert "full frame" in set(summary["class"]) and summary["diff"].notna().all()


@pytest.mark.slow
def test_the_camera_changes_the_scores_and_a_rerun_resumes(screened) -> None:
    """``ideal`` and ``all`` differ in their scores; a rerun finds both conditions complete, runs no
    optimum and writes the same tables; a rerun of other settings into the folder is refused."""
    out, _ = screened
    a, b = (pd.read_csv(out / f"scores_{n}.csv")["abs_rel"] for n in ("ideal", "all"))
    assert len(a) == len(b) and not a.equals(b)
    before = (out / "screen.md").read_text()
    proc = run_script(SCRIPT, *ARGS, "--out", str(out), cwd=out, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "ideal: complete in" in proc.stderr and "s/pair" not in proc.stderr
    assert (out / "screen.md").read_text() == before
    other = run_script(SCRIPT, *ARGS, "--frames", "3", "--out", str(out), cwd=out, timeout=120)
    assert other.returncode == 1 and other.stderr.startswith("error: --out:"), other.stderr
    assert "holds a screen of other settings" in other.stderr and len(other.stderr.splitlines()) == 1


def test_ideal_and_all_render_different_bytes_and_each_effect_alone() -> None:
    """The ``ideal`` condition renders the views without a camera, ``all`` with the calibrated one:
    their bytes differ, the GT does not; each single effect keeps only its own params on."""
    study = _study()
    raw = read_params_file(ROOT / "params.yaml")
    raw["data"]["synthetic"] |= {"height": 48, "width": 160}
    params = params_from_dict(raw)
    default = params.data.synthetic.camera
    ideal, full = (
        rendered_eval_set(params.data.synthetic, 1, study.camera(n, default)) for n in ("ideal", "all")
    )
    for a, b in zip(ideal.pairs[0], full.pairs[0], strict=True):
        assert a.shape == b.shape and a.tobytes() != b.tobytes()
    assert (ideal.frames[0].gt_depth == full.frames[0].gt_depth).all() and ideal.rois.equals(full.rois)
    assert study.camera("all", default) == CameraConfig(**{**vars(default), "enabled": True})
    noise = study.camera("noise", default)
    assert (noise.read_noise, noise.shot_noise) == (default.read_noise, default.shot_noise)
    assert (noise.blur, noise.vignetting, noise.gain_mismatch) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--frames", "0"], "--frames: must be at least 2 (two folds of frames), got 0"),
        (["--conditions", "ideal", "bogus"], "--conditions: unknown ['bogus']"),
        (["--weights", "-1"], "--weights: each must be in [0, 10000], got [-1.0]"),
        (["--threads", "0"], "--threads: must be in 1.."),
    ],
)
def test_a_bad_argument_is_one_line_naming_the_option(
    argv: list[str], expected: str, tmp_path: Path, capsys
) -> None:
    """A frame count below two folds, an unknown condition, a negative weight, no threads: one
    ``error:`` line naming the option, exit 1, nothing written."""
    study = _study()
    code = run_main(SCRIPT, lambda: study.main(["--out", str(tmp_path / "out"), *argv]))
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert code == 1 and captured.out == "", (code, captured)
    assert len(lines) == 1 and lines[0].startswith("error: ") and expected in lines[0], lines
    assert not (tmp_path / "out").exists()
