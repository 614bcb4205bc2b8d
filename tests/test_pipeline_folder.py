"""End to end with data.source folder: the synthetic set exported as a stereo folder
(`msdepth export-folder`, PFM GT, no ROIs), then `dvc repro` of the real dvc.yaml on it."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import yaml
from conftest import UP_TO_DATE, dvc_status, project, require_dvc, run_checked

from msdepth.reporting.figures import ROI_FIGURES, STAGE_FIGURES

# The tests here run DVC on copied projects: the second tier (`-m slow`).
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def folder_repo(tmp_path_factory) -> Path:
    require_dvc()
    work = project(tmp_path_factory.mktemp("folder"), {"eval": {"extra_sets": []}})
    dvc = [sys.executable, "-m", "dvc"]
    run_checked([*dvc, "repro", "--quiet", "prepare_data"], work)  # the synthetic set in data/synthetic
    run_checked(
        [sys.executable, "-m", "msdepth", "export-folder", "--from", "data/synthetic", "--to", "my_stereo"],
        work,
    )
    params = yaml.safe_load((work / "params.yaml").read_text())
    params["data"].update(source="folder", root="my_stereo")
    (work / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    # compare depends on metrics/sets, which with eval.extra_sets: [] no stage writes (a clone has
    # the committed one; this fresh project has none).
    (work / "metrics" / "sets").mkdir(parents=True)
    run_checked([*dvc, "repro", "--quiet"], work)
    return work


def test_repro_on_an_exported_folder(folder_repo: Path):
    repo = folder_repo
    eval_list = (repo / "my_stereo" / "eval.txt").read_text().splitlines()
    assert len(eval_list) == 3 and all(line.endswith(".pfm") for line in eval_list)
    index = (repo / "data" / "index" / "eval_frames.csv").read_text()
    assert index.count(",pfm,") == 3
    report = json.loads((repo / "data" / "index" / "report.json").read_text())
    assert report["source"] == "folder" and report["train_pairs_found"] == 16
    assert report["eval_frames_left_out_of_training"] == 3
    assert "eval_" not in (repo / "data" / "index" / "train_pairs.txt").read_text()  # never trained on
    for run in ("ssim/seed0", "msssim/seed0"):
        full = json.loads((repo / "metrics" / "full" / f"{run}.json").read_text())
        assert full["images"] == 3 and 0 < full["cap80"]["abs_rel"] < 10
        roi = json.loads((repo / "metrics" / "roi" / f"{run}.json").read_text())
        assert roi["rois"] == 0 and "no_rois" in roi
        assert json.loads((repo / "metrics" / "headline" / "roi" / f"{run}.json").read_text()) == {"rois": 0}
        assert (repo / "metrics" / "gradients" / f"{run}.csv").read_text().count("\n") == 1
    for baseline in ("constant", "prior"):
        assert "skipped" in json.loads((repo / "metrics" / "full" / f"{baseline}.json").read_text())
    md = (repo / "metrics" / "compare.md").read_text()
    assert "no ROIs: ROI suites skipped" in md and "## ROI" not in md and "| ssim" in md
    assert "data.source folder" in md  # the baselines' reason
    means = repo / "metrics" / "headline" / "mean"
    assert sorted(p.name for p in means.iterdir()) == ["msssim.json", "ssim.json"]
    assert set(json.loads((means / "ssim.json").read_text())) == {"abs_rel", "a1"}  # no ROIs
    figures = sorted(p.name for p in (repo / "plots" / "figures").iterdir())
    assert figures == sorted(set(STAGE_FIGURES) - set(ROI_FIGURES))  # no ROIs, no ROI figures
    shown = json.loads(run_checked([sys.executable, "-m", "dvc", "metrics", "show", "--json"], repo))
    assert not any("error" in rev for rev in shown.values()), shown
    assert dvc_status(repo) == UP_TO_DATE
