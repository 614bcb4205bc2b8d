"""KITTI 2012 as an extra evaluation set (msdepth.data.kitti2012, eval_sets' kitti2012): its layout,
its GT with the reflective surfaces, its camera, and the suites on the shared two-frame sample
(``../shared/real-samples/kitti2012-training``; those tests skip where it is absent)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from msdepth.config.params import Params
from msdepth.data import kitti, kitti2012
from msdepth.data.eval_sets import _build_kitti2012_index
from msdepth.errors import DataError
from msdepth.evaluation.results import score_set
from msdepth.evaluation.suites import load_frames
from msdepth.io import write_png

SAMPLE = Path(__file__).resolve().parents[1].parent / "shared" / "real-samples" / "kitti2012-training"
needs_sample = pytest.mark.skipif(not SAMPLE.is_dir(), reason=f"{SAMPLE} absent (a clone without ../shared)")


def tiny_set(root: Path, width: int = 1226, frames: tuple[str, ...] = ("000000_10",)) -> None:
    """A KITTI 2012 training layout of flat frames: GT 20 px, the reflective GT 10 px in the lower half."""
    for frame in frames:
        for folder in (kitti2012.LEFT, kitti2012.RIGHT):
            (root / folder).mkdir(parents=True, exist_ok=True)
            write_png(root / folder / f"{frame}.png", np.full((8, width, 3), 100, np.uint8))
        refl = np.zeros((8, width), np.float32)
        refl[4:] = 10.0
        for folder, disp in (
            (kitti2012.GT, np.full((8, width), 20.0, np.float32)),
            (kitti2012.REFLECTIVE_GT, refl),
        ):
            (root / folder).mkdir(parents=True, exist_ok=True)
            kitti.write_disparity(root / folder / f"{frame}.png", disp)


def test_the_reflective_gt_takes_the_place_of_disp_occ_and_is_the_class(tmp_path):
    tiny_set(tmp_path)
    gt, reflective = kitti2012.read_gt_disparity(tmp_path / kitti2012.GT / "000000_10.png")
    assert (gt[:4] == 20).all() and (gt[4:] == 10).all()
    assert reflective.sum() == 4 * 1226
    class_map = kitti2012.reflective_class_map(tmp_path / kitti2012.REFLECTIVE_GT / "000000_10.png")
    assert set(np.unique(class_map)) == {0, kitti.CLASS_BITS["reflective"]}


def test_camera_from_calib_overrides_the_default_by_width(tmp_path):
    assert kitti2012.camera(tmp_path, "000003_10", 1226) == (707.0912, 0.54)
    (tmp_path / "calib").mkdir()
    p2 = "P2: 700 0 600 46 0 700 180 0 0 0 1 0"
    p3 = "P3: 700 0 600 -329 0 700 180 0 0 0 1 0"
    (tmp_path / "calib" / "000003.txt").write_text(f"{p2}\n{p3}\n")
    focal, baseline = kitti2012.camera(tmp_path, "000003_10", 1226)
    assert focal == 700 and baseline == pytest.approx(375 / 700)


def test_an_unknown_width_without_calib_and_a_missing_image_are_one_line_errors(tmp_path):
    with pytest.raises(DataError, match="1000 px wide, not a KITTI 2012 width"):
        kitti2012.camera(tmp_path, "000000_10", 1000)
    tiny_set(tmp_path)
    (tmp_path / kitti2012.RIGHT / "000000_10.png").unlink()
    with pytest.raises(DataError, match=r"colored_1/000000_10\.png: missing"):
        _build_kitti2012_index(tmp_path)


def scored(tmp_path: Path, monkeypatch, root: Path, depth: float) -> dict:
    """The kitti2012 set of ``root`` scored with a constant ``depth``: its full-image summary."""
    frames = load_frames(_build_kitti2012_index(root))
    monkeypatch.chdir(tmp_path)  # score_set writes below metrics/ of the working folder
    pred = {f.name: np.full(f.shape, depth, np.float32) for f in frames}
    score_set(Params(), "kitti2012", "constant", pred, frames, scaled=False)
    summary = json.loads(
        next((tmp_path / "metrics" / "sets" / "kitti2012").rglob("constant.json")).read_text()
    )
    assert summary["images"] == len(frames)
    return summary


def test_the_set_scores_the_reflective_class_on_its_exact_pixels(tmp_path, monkeypatch):
    """Depth at the GT of the non-reflective half: abs_rel 0 there, the reflective half's error alone
    in the class (GT 10 px, predicted 20 px: depth half the GT's, abs_rel 0.5, D1 100 %, EPE 10 px)."""
    tiny_set(tmp_path / "set")
    summary = scored(tmp_path, monkeypatch, tmp_path / "set", 707.0912 * 0.54 / 20)
    reflective = summary["masks"]["cap80"]["by_class"]["reflective"]
    assert reflective["abs_rel"] == pytest.approx(0.5, abs=1e-3)
    assert summary["masks"]["stereo"]["reflective"]["d1"] == pytest.approx(100.0)
    assert summary["masks"]["stereo"]["reflective"]["epe"] == pytest.approx(10.0, abs=0.05)
    assert summary["cap80"]["abs_rel"] == pytest.approx(0.25, abs=1e-3)  # the whole frame: half of it
    headline = json.loads(next((tmp_path / "metrics" / "headline").rglob("constant.json")).read_text())
    assert headline["reflective_abs_rel"] == pytest.approx(0.5, abs=1e-3)
    assert headline["reflective_d1"] == pytest.approx(100.0)


@needs_sample
def test_disp_refl_occ_holds_the_reflective_surfaces_only_on_the_shared_frames():
    """What the module docstring states: disp_refl_occ is no superset of disp_occ (KITTI 2012's
    reflective GT, checked on the real frames)."""
    counts = {}
    for frame in kitti2012.frames(SAMPLE):
        occ = kitti.read_disparity(SAMPLE / kitti2012.GT / f"{frame}.png") > 0
        refl = kitti.read_disparity(SAMPLE / kitti2012.REFLECTIVE_GT / f"{frame}.png") > 0
        counts[frame] = (int(occ.sum()), int(refl.sum()), int((refl & ~occ).sum()))
    assert counts == {"000000_10": (162583, 58, 33), "000001_10": (109555, 28568, 25013)}


@needs_sample
def test_the_suites_run_on_the_shared_kitti2012_frames(tmp_path, monkeypatch):
    index = _build_kitti2012_index(SAMPLE)
    assert list(index["frame"]) == ["000000_10", "000001_10"]
    assert list(index["focal"]) == [707.0912, 707.0912]  # 1226 px wide, no calib/: the default
    summary = scored(tmp_path, monkeypatch, SAMPLE, 20.0)
    masks = summary["masks"]
    assert masks["rois"] == 2 and masks["cap80"]["by_class"]["reflective"]["count"] == 2
    assert 0 < masks["cap80"]["by_class"]["reflective"]["abs_rel"] < 10
    assert 0 <= masks["stereo"]["reflective"]["d1"] <= 100 and masks["stereo"]["reflective"]["frames"] == 2
    assert np.isfinite(summary["cap80"]["abs_rel"])


def test_kitti2012_is_an_extra_set_the_params_accept():
    params = Params()
    params = dataclasses.replace(params, eval=dataclasses.replace(params.eval, extra_sets=("kitti2012",)))
    params.eval.validate("eval", params)


def set_summaries(root: Path) -> dict[str, dict]:
    """The kitti2012 set's full summaries below ``root``/metrics, by run file stem."""
    return {
        p.stem: json.loads(p.read_text()) for p in (root / "metrics" / "sets" / "kitti2012").rglob("*.json")
    }


@needs_sample
def test_a_network_and_the_baselines_are_scored_on_the_shared_frames_with_their_reflective_class(
    tmp_path, monkeypatch
):
    """The eval_set and baselines_set stages' functions on the shared frames: an untrained network
    (the path, not its numbers) and both baselines of a stand-in training GT, each with the
    reflective class's exact-mask scores and D1."""
    import torch

    from msdepth.data.eval_index import write_eval_index
    from msdepth.evaluation import baselines
    from msdepth.evaluation.extra_sets import evaluate_on_set
    from msdepth.training.train import build_model

    params = Params()
    params = dataclasses.replace(params, eval=dataclasses.replace(params.eval, extra_sets=("kitti2012",)))
    index_path = tmp_path / "kitti2012.csv"
    write_eval_index(index_path, _build_kitti2012_index(SAMPLE))
    monkeypatch.chdir(tmp_path)
    torch.manual_seed(0)
    model = build_model(params).eval()
    evaluate_on_set(params, "kitti2012", "ssim/seed0", model, {"height": 64, "width": 192}, index_path)
    gt = np.full((4, 37, 122), 0.02, np.float32)  # fraction of width: ~25 px at 1226
    monkeypatch.setattr(baselines, "_indexed_training_gt", lambda _: baselines.TrainingGT(gt, available=4))
    baselines.score_set_baselines(params, "kitti2012", tmp_path / "unused.txt", index_path)
    summaries = set_summaries(tmp_path)
    assert set(summaries) >= {"seed0", "constant", "prior"}
    for run in ("seed0", "constant", "prior"):
        masks = summaries[run]["masks"]
        assert masks["cap80"]["by_class"]["reflective"]["count"] == 2
        assert 0 <= masks["stereo"]["reflective"]["d1"] <= 100


def test_compare_md_has_the_reflective_class_of_the_set(tmp_path, monkeypatch):
    """compare.md's kitti2012 section: the whole frame's pixels said, and a table of the exact class
    per run (a run off by 10 % everywhere has abs_rel 0.1 there)."""
    from msdepth.reporting.pipeline_compare import _compare_set

    tiny_set(tmp_path / "set", frames=("000000_10", "000001_10"))
    frames = load_frames(_build_kitti2012_index(tmp_path / "set"))
    monkeypatch.chdir(tmp_path)
    params = Params()
    params = dataclasses.replace(params, train=dataclasses.replace(params.train, seeds=(0,)))
    for run, scale in (("ssim/seed0", 1.1), ("msssim/seed0", 1.0), ("constant", 2.0), ("prior", 3.0)):
        score_set(
            params, "kitti2012", run, {f.name: f.gt_depth * scale for f in frames}, frames, scaled=False
        )
    result, md = _compare_set(params, "kitti2012")
    assert "every GT pixel of the whole frame" in md and "Garg" not in md
    assert "## kitti2012: exact class pixels, cap 80 m" in md
    row = next(line for line in md.splitlines() if line.startswith("| reflective | ssim"))
    assert row.split("|")[3].strip() == "0.1000"
    assert result["masks"]["msssim"]["cap80"]["by_class"]["reflective"]["abs_rel"] == pytest.approx(0.0)
