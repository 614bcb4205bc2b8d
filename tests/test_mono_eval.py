"""Evaluation of monocular runs: Monodepth2's depth, median scaling in every suite, scale ratios
and pose ATE in compare, pose ATE on the rendered sequences."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from msdepth import render
from msdepth.analysis.comparison import comparison_data
from msdepth.analysis.runs import monocular_data
from msdepth.config.params import EvalConfig, SyntheticConfig, params_from_dict
from msdepth.errors import DataError
from msdepth.evaluation.pose import _odometry_ates, sequence_ates
from msdepth.evaluation.results import median_scaling
from msdepth.evaluation.suites import Frame, depth_maps, evaluate_full, median_scaled_maps
from msdepth.io import write_png
from msdepth.reporting.comparison import build_comparison

CFG = EvalConfig(caps=(80.0,))


def _frames(n: int = 4) -> list[Frame]:
    rng = np.random.default_rng(0)
    return [Frame(f"f{i}", rng.uniform(2, 60, (6, 8)).astype(np.float32), 700.0, 0.54) for i in range(n)]


def test_monocular_depth_is_monodepth2s_of_the_sigmoid_disparity() -> None:
    frame = Frame("f", np.ones((4, 6), np.float32), 700.0, 0.54)
    disp = np.full((1, 2, 3), 0.15, np.float32)  # half the heads' maximum: sigmoid 0.5
    depth = depth_maps(disp, [frame], monocular=True)["f"]
    np.testing.assert_allclose(depth, 1 / (0.01 + (10 - 0.01) * 0.5), rtol=1e-6)
    metric = depth_maps(disp, [frame])["f"]  # stereo: focal * baseline / pixels
    np.testing.assert_allclose(metric, 700.0 * 0.54 / (0.15 * 6), rtol=1e-6)


def test_median_scaling_undoes_a_per_image_scale() -> None:
    frames = _frames()
    pred = {f.name: f.gt_depth * (i + 2) for i, f in enumerate(frames)}
    scaled, ratios = median_scaled_maps(pred, frames, CFG)
    assert ratios == pytest.approx({f.name: 1 / (i + 2) for i, f in enumerate(frames)})
    for f in frames:
        np.testing.assert_allclose(scaled[f.name], f.gt_depth, rtol=1e-6)


def test_full_suite_reports_ratios_and_judges_image_dependence_after_scaling() -> None:
    frames = _frames()
    pred = {f.name: f.gt_depth * (i + 2) for i, f in enumerate(frames)}
    summary, _ = evaluate_full(pred, frames, CFG, median_scaling=True)
    ratios = np.array([1 / (i + 2) for i in range(4)])
    assert summary["cap80"]["abs_rel"] == pytest.approx(0, abs=1e-6)
    assert summary["cap80"]["median_scaling"]["ratio_median"] == pytest.approx(np.median(ratios))
    assert summary["cap80"]["median_scaling"]["ratio_std_over_median"] == pytest.approx(
        ratios.std() / np.median(ratios)
    )
    # Scaled, the predictions are the GT: they vary from image to image exactly as it does.
    assert summary["image_dependence"]["variation_ratio"] == pytest.approx(1, rel=1e-5)


def test_monocular_modes_median_scale_the_extra_sets_too() -> None:
    assert not median_scaling(params_from_dict({}))
    assert median_scaling(params_from_dict({"eval": {"median_scaling": True}}))
    sequences = {"data": {"synthetic": {"sequence_length": 3}}}
    assert median_scaling(params_from_dict({**sequences, "train": {"mode": "mono"}}))


def _full(ratio: float | None) -> dict:
    cap = {"abs_rel": 0.1, "sq_rel": 0.1, "rmse": 1, "rmse_log": 0.1, "a1": 0.9, "a2": 0.95, "a3": 0.99}
    if ratio is not None:
        cap["median_scaling"] = {"ratio_median": ratio, "ratio_std_over_median": ratio / 10}
    return {"cap80": cap, "images": 2}


def test_compare_shows_scale_ratios_and_pose_ate_of_monocular_runs_only() -> None:
    full = {"ssim/seed0": _full(2.0), "ssim/seed1": _full(4.0), "prior": _full(None)}
    training = {
        r: {"pose": {"ate_mean": a, "ate_std": a / 2}} for r, a in (("ssim/seed0", 0.1), ("ssim/seed1", 0.3))
    }
    groups = {"ssim": ["ssim/seed0", "ssim/seed1"], "prior": ["prior"]}
    mono = monocular_data(full, training, groups, "cap80")
    assert mono == {
        "ssim": pytest.approx(
            {"runs": 2, "scale_ratio": 3.0, "scale_spread": 0.3, "pose_ate": 0.2, "pose_ate_std": 0.1}
        )
    }
    assert monocular_data({"prior": _full(None)}, {}, {"prior": ["prior"]}, "cap80") is None
    suites = {
        "full": {"ssim": _full(3.0), "prior": _full(None)},
        "roi": {"ssim": {"rois": 0, "no_rois": "x"}, "prior": {"rois": 0, "no_rois": "x"}},
    }
    _, md = build_comparison(comparison_data(suites, ["ssim"], ["prior"], monocular=mono))
    assert "## Monocular training: scale and pose" in md
    assert "| ssim | 3.0000 | 0.3000 | 0.2000 | 0.1000 |" in md
    stereo = build_comparison(comparison_data(suites, ["ssim"], ["prior"]))[1]
    assert "Monocular training" not in stereo


# Two drives of 4 frames: a sequence of 3 (scored) and one of 1 (too short for a pose) each.
SEQ = SyntheticConfig(seed=5, drives=2, train_pairs=8, eval_frames=1, height=48, width=160, sequence_length=3)


class _ConstantPose(nn.Module):
    """A pose network predicting the same translation (no rotation) for every pair of frames."""

    def __init__(self, translation: tuple[float, float, float]) -> None:
        super().__init__()
        self.translation = nn.Parameter(torch.tensor([translation]), requires_grad=False)

    def forward(self, first: torch.Tensor, second: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        n = first.shape[0]
        return torch.zeros(n, 3), self.translation.expand(n, 3)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("sequences")
    render.generate(SEQ, path, progress=False, workers=1, lidar=False)
    return path


def test_pose_ate_is_zero_for_the_true_motion_at_any_scale(rendered: Path) -> None:
    # The camera moves 0.8 m forward per frame: the pose to the next frame is -0.8 m in z; the
    # ATE aligns scale, so twice that is exact too.
    exact = sequence_ates(_ConstantPose((0.0, 0.0, -1.6)), rendered / "raw", 3, 32, 96)
    assert exact["snippets"] == 2 * 2  # per drive one 3-frame sequence: snippets from frames 0 and 1
    assert exact["ate_mean"] == pytest.approx(0, abs=1e-6)
    # Standing still: the aligned prediction stays at the origin; the error is the GT path's,
    # sqrt(0.8^2 + 1.6^2) / 3 for the 3-frame snippet and sqrt(0.8^2) / 2 for the 2-frame one.
    still = sequence_ates(_ConstantPose((0.0, 0.0, 0.0)), rendered / "raw", 3, 32, 96)
    assert still["ate_mean"] == pytest.approx((np.sqrt(0.8**2 + 1.6**2) / 3 + 0.8 / 2) / 2, rel=1e-6)


def test_pose_ate_without_sequences_is_one_error(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no rendered sequences"):
        sequence_ates(_ConstantPose((0.0, 0.0, 1.0)), tmp_path, 3, 32, 96)


class _BrightnessPose(nn.Module):
    """A pose network whose forward translation is the brightness change between its two frames."""

    def forward(self, first: torch.Tensor, second: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        step = (second - first).mean(dim=(1, 2, 3))
        return torch.zeros(first.shape[0], 3), torch.stack([0 * step, 0 * step, step], dim=1)


def _odometry(root: Path, sequence: str, frames: int, step: float = 0.8) -> None:
    """KITTI odometry's layout: ``frames`` images of sequence ``sequence`` (brightness rising frame
    by frame) and its poses, the camera moving ``step`` m forward per frame."""
    rng = np.random.default_rng(int(sequence))
    for n in range(frames):
        image = np.clip(rng.integers(0, 60, (24, 80, 3)) + 10 * n, 0, 255).astype(np.uint8)
        write_png(root / "sequences" / sequence / "image_2" / f"{n:06d}.png", image)
    poses = np.tile(np.eye(4)[:3].reshape(1, 12), (frames, 1))
    poses[:, 11] = step * np.arange(frames)
    (root / "poses").mkdir(parents=True, exist_ok=True)
    np.savetxt(root / "poses" / f"{sequence}.txt", poses, fmt="%.6e")


def test_pose_ate_on_kitti_odometry_per_sequence_and_pooled(tmp_path: Path) -> None:
    _odometry(tmp_path, "09", 7)
    assert _odometry_ates(_ConstantPose((0.0, 0.0, -1.6)), tmp_path, ["10"], 24, 80) == {}  # absent
    exact = _odometry_ates(_ConstantPose((0.0, 0.0, -1.6)), tmp_path, ["09", "10"], 24, 80)
    assert exact["snippets"] == 6 and exact["ate_mean"] == pytest.approx(0, abs=1e-6)
    assert list(exact["sequences"]) == ["09"]
    # Standing still: a snippet of F frames errs by sqrt(sum_k (0.8 k)^2) / F, k < F; snippets
    # start at frames 0..5 of 7, so they have 5, 5, 5, 4, 3 and 2 frames.
    still = _odometry_ates(_ConstantPose((0.0, 0.0, 0.0)), tmp_path, ["09"], 24, 80)
    per_length = {f: np.sqrt(sum((0.8 * k) ** 2 for k in range(f))) / f for f in (2, 3, 4, 5)}
    expected = [per_length[f] for f in (5, 5, 5, 4, 3, 2)]
    assert still["ate_mean"] == pytest.approx(np.mean(expected), rel=1e-6)
    assert still["sequences"]["09"] == {k: still[k] for k in ("ate_mean", "ate_std", "snippets")}


def test_pose_ate_on_odometry_pools_sequences_and_reads_in_chunks(tmp_path: Path) -> None:
    from msdepth.evaluation.pose import _trajectory_ates

    _odometry(tmp_path, "09", 7)
    _odometry(tmp_path, "10", 4, step=0.5)
    both = _odometry_ates(_BrightnessPose(), tmp_path, ["09", "10"], 24, 80)
    assert both["snippets"] == 6 + 3 and set(both["sequences"]) == {"09", "10"}
    paths = sorted((tmp_path / "sequences" / "09" / "image_2").glob("*.png"))
    truth = np.stack([np.eye(4)] * 7)
    truth[:, 2, 3] = 0.8 * np.arange(7)
    whole = _trajectory_ates(_BrightnessPose(), paths, truth, 24, 80, chunk=64)
    for chunk in (1, 2, 3):  # the pair that straddles two chunks is predicted once, as in one pass
        assert np.array_equal(_trajectory_ates(_BrightnessPose(), paths, truth, 24, 80, chunk=chunk), whole)
    assert both["sequences"]["09"]["ate_mean"] == pytest.approx(float(whole.mean()), rel=1e-12)


def test_odometry_with_a_frame_missing_is_one_error_naming_it(tmp_path: Path) -> None:
    _odometry(tmp_path, "09", 5)
    (tmp_path / "sequences" / "09" / "image_2" / "000003.png").unlink()
    with pytest.raises(DataError, match=r"09\.txt: 5 poses, but 1 of their frames .* \(first: 000003\.png\)"):
        _odometry_ates(_ConstantPose((0.0, 0.0, 1.0)), tmp_path, ["09"], 24, 80)


def test_only_a_monocular_run_is_median_scaled_not_the_baselines_or_the_optimum(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import json

    from msdepth.evaluation.results import run_suite

    monkeypatch.chdir(tmp_path)  # run_suite writes below metrics/
    params = params_from_dict({"data": {"synthetic": {"sequence_length": 3}}, "train": {"mode": "mono"}})
    frames = _frames()
    pred = {f.name: f.gt_depth * 1.25 for f in frames}  # GT < 60 m: below the cap
    run_suite(params, "full", "prior", pred, frames, None)  # as the baselines and optimum stages call it
    metric = json.loads((tmp_path / "metrics" / "full" / "prior.json").read_text())
    assert "median_scaling" not in metric["cap80"] and metric["cap80"]["abs_rel"] == pytest.approx(0.25)
    run_suite(params, "full", "ssim/seed0", pred, frames, None, scaled=True)  # as eval_full calls it
    scaled = json.loads((tmp_path / "metrics" / "full" / "ssim" / "seed0.json").read_text())
    assert scaled["cap80"]["median_scaling"]["ratio_median"] == pytest.approx(0.8)
    assert scaled["cap80"]["abs_rel"] == pytest.approx(0, abs=1e-6)
