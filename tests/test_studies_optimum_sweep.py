"""studies/optimum_sweep.py end to end on the smallest inputs it accepts (issue 54): the sweep on two
rendered frames at 48 x 160 and a few Adam steps. It writes no file: it prints a markdown table, and a
bad argument is one ``error:`` line.
"""

from __future__ import annotations

import json
import math
import runpy
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import run_script

from msdepth.errors import run_main
from msdepth.evaluation.rendered import rendered_eval_set

ROOT = Path(__file__).resolve().parents[1]

# The sweep at its smallest: a 48 x 160 render, one level, three Adam steps after the matched start.
SWEEP_TINY = [
    "--set=data.synthetic.height=48",
    "--set=data.synthetic.width=160",
    "--set=optimum.iterations=3",
    "--set=optimum.levels=1",
    "--set=optimum.refine_iterations=3",
    "--set=optimum.refine_levels=1",
]


def _study(name: str) -> SimpleNamespace:
    """studies/<name>.py as a namespace, its ``__main__`` block not run."""
    return SimpleNamespace(**runpy.run_path(str(ROOT / "studies" / f"{name}.py")))


def _table(stdout: str) -> list[dict[str, str]]:
    """The rows of the one markdown table in ``stdout``, each a dict by column header."""
    lines = [line for line in stdout.splitlines() if line.startswith("|")]
    cells = [[c.strip() for c in line.strip().strip("|").split("|")] for line in lines]
    assert cells and set(lines[1]) <= set("|-: "), stdout  # header, then the separator
    return [dict(zip(cells[0], row, strict=True)) for row in cells[2:]]


def _one_error_line(code: int | None, captured, expected: str) -> None:
    """The run exited 1 with nothing on stdout and one ``error:`` line holding ``expected``, an input
    fault in the script's own words (not an unexpected exception's line, nor a traceback)."""
    lines = captured.err.splitlines()
    assert code == 1 and captured.out == "", (code, captured)
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    assert expected in lines[0] and "unexpected" not in lines[0], lines[0]


# ------------------------------------------------------------------------------ optimum_sweep.py


def test_the_sweep_reports_one_row_per_variant_and_weight_asked_for(tmp_path: Path) -> None:
    """Two variants at two weights on two frames: the oracle constant's row, then one row per
    (variant, weight) in the order asked, each echoed as JSON on stderr; the weight reaches the
    solver (its two rows differ), the optimum beats the oracle constant, and no file is written."""
    args = ["--frames", "2", "--variants", "ssim", "msssim:3", "--weights", "1", "3", *SWEEP_TINY]
    proc = run_script("studies/optimum_sweep.py", *args, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = _table(proc.stdout)
    asked = [("ssim", "1.000"), ("ssim", "3.000"), ("msssim:3", "1.000"), ("msssim:3", "3.000")]
    assert [(r["run"], r["weight"]) for r in rows] == [("oracle constant", ""), *asked]
    assert {"abs_rel", "a1", "D1 %", "EPE px", "s/pair", "box car", "mask car"} <= set(rows[0])
    echoed = [json.loads(line) for line in proc.stderr.splitlines() if line.startswith("{")]
    assert [(e["run"], f"{e['weight']:.3f}") for e in echoed] == asked
    assert [f"{e['abs_rel']:.3f}" for e in echoed] == [r["abs_rel"] for r in rows[1:]]
    oracle = float(rows[0]["abs_rel"])
    for row in rows[1:]:
        assert 0 < float(row["abs_rel"]) < oracle and 0 < float(row["a1"]) <= 1, row
    for low, high in (echoed[0:2], echoed[2:4]):
        assert low["abs_rel"] != high["abs_rel"], (low, high)
    assert list(tmp_path.iterdir()) == []


def test_the_sweep_defaults_to_the_params_sweep_and_adds_matchers_and_the_trace(tmp_path: Path) -> None:
    """Without --weights the rows are optimum.smoothness_sweep's weights; --matchers adds SGM on the
    variant's cost volume and SGBM (no weight) before them; --trace prints the mean loss of each
    level at step 25, one line per level."""
    sweep = [
        "--set=optimum.smoothness_sweep=[1.0, 10.0]",
        "--set=optimum.iterations=25",
        "--set=optimum.levels=2",
    ]
    args = ["--frames", "1", "--variants", "ssim", "--matchers", "--trace", *SWEEP_TINY, *sweep]
    proc = run_script("studies/optimum_sweep.py", *args, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = _table(proc.stdout)
    runs = [("oracle constant", ""), ("SGM ssim", ""), ("SGBM", ""), ("ssim", "1.000"), ("ssim", "10.000")]
    assert [(r["run"], r["weight"]) for r in rows] == runs
    trace = [line for line in proc.stdout.splitlines() if line.startswith("ssim level ")]
    assert [line.split(":")[0] for line in trace] == ["ssim level 0", "ssim level 1"]
    for line in trace:
        step, loss = line.split(": ", 1)[1].split(": ")
        assert step == "25" and 0 < float(loss) < math.inf, line


def test_the_trace_of_levels_shorter_than_25_steps_gives_their_last_step(tmp_path: Path) -> None:
    """--trace with optimum.iterations 3: each level's line holds its loss at step 3 (it printed an
    empty line when no mark of 25, 50, ... was reached)."""
    args = ["--frames", "1", "--variants", "ssim", "--weights", "10", "--trace", *SWEEP_TINY]
    proc = run_script("studies/optimum_sweep.py", *args, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    trace = [line for line in proc.stdout.splitlines() if line.startswith("ssim level ")]
    assert len(trace) == 1, proc.stdout
    step, loss = trace[0].split(": ", 1)[1].split(": ")
    assert step == "3" and 0 < float(loss) < math.inf, trace


def test_the_sweeps_scores_of_the_gt_itself_are_exact() -> None:
    """The sweep's scoring (the rendered frames, ``scores``): a disparity equal to the GT scores
    abs_rel, D1 and EPE 0 and a1 1 over the frame and in every box and mask class; twice the GT's
    disparity (half its depth) scores abs_rel 0.5 and a1 0 everywhere."""
    from msdepth.config.params import apply_overrides, params_from_dict, read_params_file

    sweep = _study("optimum_sweep")
    tiny = ["data.synthetic.height=48", "data.synthetic.width=160"]
    params = params_from_dict(apply_overrides(read_params_file(ROOT / "params.yaml"), tiny))
    rendered = rendered_eval_set(params.data.synthetic, 2, params.data.synthetic.camera)
    frames, rois = rendered.frames, rendered.rois
    exact = [
        np.where(f.valid, f.focal * f.baseline / np.where(f.valid, f.gt_depth, 1.0), 1.0) / f.shape[1]
        for f in frames
    ]
    got = sweep.scores(exact, frames, rois, params)
    classes = [k for k in got if k.startswith(("box ", "mask "))]
    assert {"box car", "mask car"} <= set(classes), got
    assert got["a1"] == 1.0 and got["D1 %"] == 0.0 and got["EPE px"] == pytest.approx(0, abs=1e-3)
    for key in ["abs_rel", *classes]:
        assert got[key] == pytest.approx(0, abs=1e-5), key
    half = sweep.scores([2 * d for d in exact], frames, rois, params)
    assert half["a1"] == 0.0
    for key in ["abs_rel", *classes]:
        assert half[key] == pytest.approx(0.5, abs=1e-5), key


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--frames", "0"], "--frames: must be at least 1, got 0"),
        (["--weights", "1", "-1"], "--weights: each must be in [0, 10000], got [1.0, -1.0]"),
        (["--weights", "nan"], "--weights: each must be in [0, 10000], got [nan]"),
        (["--variants", "bogus"], "unknown variant 'bogus'"),
        (["--set=optimum.nonsense=1"], "unknown parameter(s) ['optimum.nonsense']"),
    ],
)
def test_the_sweep_refuses_a_bad_argument_in_one_line(argv: list[str], expected: str, capsys) -> None:
    """A frame count below 1, a weight that is negative or not a number (once run as a meaningless
    row), an unknown variant or parameter: one ``error:`` line, exit 1, no table."""
    sweep = _study("optimum_sweep")
    code = run_main("studies/optimum_sweep.py", lambda: sweep.main(["--frames", "1", *SWEEP_TINY, *argv]))
    _one_error_line(code, capsys.readouterr(), expected)
