"""Each loss at its own best smoothness weight (msdepth.optimum.selection), chosen on the other
fold of frames, and the verdict's "optimum own best" rows made from it (issue 66)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from msdepth.analysis.own_best import own_best_rows, own_best_tables
from msdepth.analysis.verdict import OWN_BEST, headline_columns
from msdepth.config.params import Params
from msdepth.optimum.selection import choose_weights, fold_of, select_rows

FRAMES = [f"{i:06d}_10" for i in range(12)]


def _full(errors: np.ndarray) -> pd.DataFrame:
    rows = [
        {"frame": f, "cap": cap, "abs_rel": e + (cap == 50) * 0.5}
        for f, e in zip(FRAMES, errors, strict=True)
        for cap in (80, 50)
    ]
    return pd.DataFrame(rows)


def _roi(errors: np.ndarray) -> pd.DataFrame:
    rows = [
        {"roi": 2 * i + k, "image": f, "class": "car", "cap": 80, "abs_rel": e + 0.01 * k}
        for i, (f, e) in enumerate(zip(FRAMES, errors, strict=True))
        for k in range(2)
    ]
    return pd.DataFrame(rows)


def _tables(errors: dict[tuple[str, str], np.ndarray]) -> tuple[dict, dict]:
    tables = {"full": {}, "roi": {}}
    by_weight: dict[str, dict[str, str]] = {}
    for (variant, w), e in errors.items():
        run = f"optimum/{variant}/{w}"
        tables["full"][run], tables["roi"][run] = _full(e), _roi(e)
        by_weight.setdefault(w, {})[variant] = run
    return tables, by_weight


def test_no_frame_is_scored_at_a_weight_it_chose() -> None:
    rng = np.random.default_rng(0)
    per_weight = {
        w: pd.DataFrame({"frame": FRAMES, "abs_rel": rng.uniform(0, 1, 12)}) for w in (3.0, 10.0, 30.0)
    }
    frames, chosen = choose_weights(per_weight)
    folds = fold_of(FRAMES)
    for fold, weight in chosen.items():
        other = [f for f in FRAMES if folds[f] != fold]
        means = {w: t.set_index("frame").loc[other, "abs_rel"].mean() for w, t in per_weight.items()}
        assert weight == min(means, key=means.get)
        assert all(frames[f] == weight for f in FRAMES if folds[f] == fold)


def test_weights_with_other_frames_are_refused() -> None:
    a = pd.DataFrame({"frame": FRAMES, "abs_rel": 0.1})
    with pytest.raises(ValueError, match="same"):
        choose_weights({3.0: a, 10.0: a.iloc[:4]})


def test_select_rows_keeps_each_frames_rows_from_its_weight() -> None:
    tables = {w: _roi(np.full(12, w)) for w in (3.0, 10.0)}
    picked = select_rows(tables, {f: (3.0 if i < 6 else 10.0) for i, f in enumerate(FRAMES)}, "image")
    assert picked["roi"].tolist() == list(range(24))
    assert picked["abs_rel"].round(2).tolist() == [3.0, 3.01] * 6 + [10.0, 10.01] * 6


def test_each_loss_gets_its_own_weight_and_the_verdict_a_row_naming_them() -> None:
    base = np.linspace(0.1, 0.2, 12)
    errors = {
        ("ssim", "w3"): base + 0.05, ("ssim", "w10"): base, ("ssim", "w30"): base + 0.02,
        ("msssim", "w3"): base - 0.03, ("msssim", "w10"): base + 0.01, ("msssim", "w30"): base + 0.04,
    }  # fmt: skip
    tables, by_weight = _tables(errors)
    runs, chosen = own_best_tables(tables, by_weight, 80)
    assert chosen == {"msssim": {0: 3.0, 1: 3.0}, "ssim": {0: 10.0, 1: 10.0}}
    assert np.allclose(tables["full"][runs["msssim"]].query("cap == 80")["abs_rel"], base - 0.03)
    rows = own_best_rows(*_tables(errors), Params(), "")
    assert {r.instrument for r in rows} == {f"optimum {OWN_BEST}"} and {r.cls for r in rows} == {
        "full frame",
        "car",
    }
    full = next(r for r in rows if r.cls == "full frame")
    assert full.diff == pytest.approx(-0.03) and full.high < 0
    assert "msssim: w3, w3" in full.method and "ssim: w10, w10" in full.method
    assert f"optimum {OWN_BEST}" in [c.instrument for c in headline_columns(10)]


def test_no_own_best_row_when_the_weights_saw_other_frames() -> None:
    tables, by_weight = _tables({("ssim", "w3"): np.ones(12), ("ssim", "w10"): np.ones(12)})
    tables["full"]["optimum/ssim/w3"] = tables["full"]["optimum/ssim/w3"].iloc[:8]
    assert own_best_tables(tables, by_weight, 80) == ({}, {})


def test_no_own_best_row_from_a_single_frame() -> None:
    """A one-frame set (real KITTI with one evaluation pair) has no other fold to choose on: the
    comparison goes on without the row instead of failing (CI, test_real_kitti_files_run_every_stage)."""
    tables, by_weight = _tables({(v, w): np.ones(12) for v in ("ssim", "msssim") for w in ("w3", "w10")})
    for suite in tables.values():
        for run in suite:
            key = "frame" if "frame" in suite[run] else "image"
            suite[run] = suite[run][suite[run][key] == FRAMES[0]]
    before = {s: dict(t) for s, t in tables.items()}
    assert own_best_tables(tables, by_weight, 80) == ({}, {})
    assert own_best_rows(tables, by_weight, Params(), "") == []
    assert {s: dict(t) for s, t in tables.items()} == before
