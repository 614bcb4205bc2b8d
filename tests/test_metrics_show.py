"""`dvc metrics show` and `dvc metrics diff` read as the comparison (issue 43): each variant's mean
over its seeds is a flat DVC metric (``metrics/headline/mean/<variant>.json``, written by the
compare stage from compare.json's numbers), listed before each run's rows, in a table whose width
is held. These run DVC on the repository's committed metrics (no pipeline run: seconds)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import python_env, require_dvc

from msdepth.analysis.comparison import mean_rows
from msdepth.pipeline.paths import COMPARE_JSON, MEANS, mean_path

ROOT = Path(__file__).resolve().parents[1]

# The widest line `dvc metrics show` may print (issue 43): a terminal's 132. The path column is 52
# (the extra set's and optimum's rows), abs_rel, a1, roi, masks and the four ROI classes take the
# rest (127 with the committed values). A new column or a longer path fails here: decide it on purpose.
WIDEST = 132


def _dvc_metrics_show() -> list[str]:
    proc = subprocess.run(
        [sys.executable, "-m", "dvc", "metrics", "show"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=python_env(),
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout.splitlines()


# Runs DVC (seconds, on the committed metrics): the second tier, like every DVC test.
@pytest.mark.slow
def test_dvc_metrics_show_lists_the_means_first_then_each_run_in_seed_order():
    require_dvc()
    lines = _dvc_metrics_show()
    widest = max(lines, key=len)
    assert len(widest) <= WIDEST, f"`dvc metrics show` prints {len(widest)} characters:\n{widest}"
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    paths = [line.split()[0] for line in lines[1:]]
    means = sorted(mean_path(v).as_posix() for v in params["variants"])
    assert paths[: len(means)] == means, paths
    assert not any(p.startswith(f"{MEANS.as_posix()}/") for p in paths[len(means) :]), paths
    seeds: dict[str, list[int]] = {}  # per folder (suite and variant), its runs' seeds as listed
    for path in paths:
        if m := re.fullmatch(r"(.+)/seed(\d+)\.json", path):
            seeds.setdefault(m[1], []).append(int(m[2]))
    assert seeds and all(listed == params["train"]["seeds"] for listed in seeds.values()), seeds


def test_committed_means_are_compare_json_numbers():
    """Each committed mean file holds compare.json's numbers for its variant: no second formula."""
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    result = json.loads((ROOT / COMPARE_JSON).read_text())
    cap = f"cap{params['eval']['caps'][0]:g}"
    rows = mean_rows(result, params["variants"], cap)
    for variant in params["variants"]:
        committed = json.loads((ROOT / mean_path(variant)).read_text())
        assert committed == rows[variant], variant
        assert committed["abs_rel"] == result["full"][cap][variant]["abs_rel"]
        assert committed["windshield"] == result["roi"][cap][variant]["by_class"]["windshield"]["abs_rel"]
    assert sorted(p.name for p in (ROOT / MEANS).iterdir()) == sorted(f"{v}.json" for v in params["variants"])


def _comparison(roi: dict) -> dict:
    full = {"abs_rel": 0.2, "a1": 0.7, "rmse": 5.0}
    return {"full": {"cap80": {"a": full}}, "roi": roi, "roi_masks": {}}


def test_mean_rows_are_flat_with_a_column_per_class():
    """Without ROIs: tests/test_folder.py."""
    overall = {"abs_rel": 0.4, "a1": 0.5}
    by_class = {"windshield": {"abs_rel": 0.6, "a1": 0.3}, "car": {"abs_rel": 0.35, "a1": 0.6}}
    result = _comparison({"cap80": {"a": {"overall": overall, "by_class": by_class}}})
    result["roi_masks"] = {"cap80": {"a": {"overall": {"abs_rel": 0.45}}}}
    row = {"abs_rel": 0.2, "a1": 0.7, "roi": 0.4, "masks": 0.45}
    assert mean_rows(result, ["a"], "cap80") == {"a": {**row, "windshield": 0.6, "car": 0.35}}
