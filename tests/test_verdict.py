"""The verdict's rows (per class, every instrument), its intervals over seeds, the external rows'
reader, the pooling rule and the sentences, on hand-made numbers with known answers."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from msdepth.config.params import CompareConfig
from msdepth.errors import DataError
from msdepth.evaluation.metrics import METRICS
from msdepth.reporting.power import t_quantile
from msdepth.reporting.verdict import (
    FULL_FRAME,
    MIN_UNITS,
    Row,
    RowScope,
    _class_sentence,
    _parse_monocular_table,
    _units_text,
    display_names,
    headline_instruments,
    interval_cell,
    network_rows,
    optimum_rows,
    pooled_rows,
    read_external_rows,
    read_monocular,
    seed_rows,
    summary_lines,
    verdict_data,
    verdict_lines,
    welch_interval,
)

ROOT = Path(__file__).resolve().parents[1]
CFG = CompareConfig(reference="ssim", bootstrap_samples=300, confidence=0.95, seed=0)
# Per class: ROIs, and MS-SSIM's abs_rel minus SSIM's on every one of them (and every seed).
SHIFTS = {"windshield": (8, -0.1), "car": (6, 0.0), "sign": (MIN_UNITS - 1, -0.2)}


def roi_table(shift: bool) -> pd.DataFrame:
    """A per-ROI table: SSIM's abs_rel varies by ROI (each seed's the same, so that the seed draws
    add nothing); MS-SSIM's is SHIFTS' offset from it."""
    rows, roi = [], 0
    for cls, (count, delta) in SHIFTS.items():
        for i in range(count):
            base = 0.3 + 0.05 * i
            rows.append(
                {"roi": roi, "image": f"{i:06d}_10", "class": cls, "cap": 80, "value": base + shift * delta}
            )
            roi += 1
    t = pd.DataFrame(rows)
    for m in METRICS:
        t[m] = t["value"]
    return t.drop(columns="value")


def full_table(shift: bool) -> pd.DataFrame:
    """A per-image table: MS-SSIM 0.05 above SSIM on every image (each seed the same)."""
    t = pd.DataFrame({"frame": [f"{i:06d}_10" for i in range(10)], "cap": 80})
    for m in METRICS:
        t[m] = 0.2 + 0.01 * np.arange(10) + shift * 0.05
    return t


def test_network_rows_give_the_known_per_class_difference() -> None:
    groups = {v: [f"{v}/seed{s}" for s in (0, 1)] for v in ("ssim", "msssim")}
    tables = {
        "full": {r: full_table(v == "msssim") for v in groups for r in groups[v]},
        "roi": {r: roi_table(v == "msssim") for v in groups for r in groups[v]},
    }
    rows = {r.cls: r for r in network_rows(tables, groups, CFG, 80.0)}
    assert list(rows) == [FULL_FRAME, "car", "windshield"]  # sign: fewer than MIN_UNITS ROIs, left out
    w = rows["windshield"]
    assert (w.diff, w.low, w.high) == pytest.approx((-0.1, -0.1, -0.1)) and w.excludes_zero and w.n == 8
    assert (rows["car"].diff, rows["car"].low, rows["car"].high) == pytest.approx((0, 0, 0))
    assert not rows["car"].excludes_zero
    assert rows[FULL_FRAME].diff == pytest.approx(0.05) and rows[FULL_FRAME].low == pytest.approx(0.05)
    assert {r.kind for r in rows.values()} == {"network"} and w.instrument == "stereo networks"


def test_optimum_rows_pair_each_weight_alone() -> None:
    tables = {"roi": {"o/ssim/w3": roi_table(False), "o/msssim/w3": roi_table(True)}}
    runs = {"w3": {"ssim": "o/ssim/w3", "msssim": "o/msssim/w3"}}
    rows = {r.cls: r for r in optimum_rows(tables, runs, CFG, 80.0)}
    assert set(rows) == {"car", "windshield"}
    assert rows["windshield"].instrument == "optimum w3" and rows["windshield"].kind == "optimum"
    assert (rows["windshield"].low, rows["windshield"].high) == pytest.approx((-0.1, -0.1))


def class_column_table(shift: bool, frames: int) -> pd.DataFrame:
    """A set's per-image table with a whole-frame class column: MS-SSIM 0.05 above SSIM on the
    frame, 0.1 below it on the frames' cars; the first frame has no car (NaN)."""
    t = full_table(shift).head(frames).copy()
    car = 0.4 + 0.01 * np.arange(frames) - shift * 0.1
    car[0] = np.nan
    return t.assign(car_abs_rel=car)


@pytest.mark.parametrize("frames", [8, 3])
def test_an_extra_sets_class_columns_are_paired_frame_by_frame(frames: int) -> None:
    """Whole-frame classes (RowScope.whole_frame): the class column's frames are the units (the
    frame without a car left out), named as the scope's unit; with fewer than MIN_UNITS frames the
    rows are kept without an interval where keep_few asks, and left out otherwise."""
    groups = {v: [f"{v}/seed{s}" for s in (0, 1)] for v in ("ssim", "msssim")}
    tables = {"full": {r: class_column_table(v == "msssim", frames) for v in groups for r in groups[v]}}
    scope = RowScope(whole_frame=True, unit="kitti2015 frames", keep_few=True)
    rows = {r.cls: r for r in network_rows(tables, groups, CFG, 80.0, pairing={"msssim": None}, scope=scope)}
    assert list(rows) == [FULL_FRAME, "car"]
    car = rows["car"]
    assert car.diff == pytest.approx(-0.1) and car.n == frames - 1 and car.unit == "kitti2015 frames"
    assert _units_text(car) == f"{frames - 1} kitti2015 frames × 2 seed pairs"
    if frames - 1 >= MIN_UNITS:
        assert (car.low, car.high) == pytest.approx((-0.1, -0.1)) and car.excludes_zero
    else:
        assert not car.has_interval and "no interval" in car.method and car.t_low is None
        assert network_rows(tables, groups, CFG, 80.0, scope=RowScope(whole_frame=True)) == []
    runs = {"cost start": {"ssim": "ssim/seed0", "msssim": "msssim/seed0"}}
    (_, opt_car) = optimum_rows(tables, runs, CFG, 80.0, scope=scope, instrument="SGM")
    assert opt_car.instrument == "SGM cost start" and opt_car.diff == pytest.approx(-0.1)
    assert Row.from_dict(opt_car.as_dict()) == opt_car
    assert [r.cls for r in network_rows(tables, groups, CFG, 80.0)] == [FULL_FRAME] * (frames >= MIN_UNITS)


def test_t_quantile_and_welch_interval_known_values() -> None:
    assert t_quantile(0.975, 2) == pytest.approx(4.302653, abs=1e-4)
    assert t_quantile(0.975, 4) == pytest.approx(2.776445, abs=1e-4)
    assert t_quantile(0.975, 1e6) == pytest.approx(1.959964, abs=1e-3)
    # Equal sd and n: df = 2(n - 1) = 4; half-width t(4)·sqrt(2·sd²/n).
    diff, low, high = welch_interval((1.0, 0.1, 3), (0.9, 0.1, 3))
    half = 2.776445 * np.sqrt(2 * 0.01 / 3)
    assert (diff, low, high) == pytest.approx((0.1, 0.1 - half, 0.1 + half), abs=1e-4)


def test_the_committed_monocular_table_parses_to_its_numbers() -> None:
    stats = _parse_monocular_table(ROOT / "studies/results/monocular/table.md")
    assert stats["mono"]["ssim"]["windshield"] == (0.4897, 0.0643, 3)
    assert stats["mono_stereo"]["msssim"][FULL_FRAME] == (0.2020, 0.0041, 3)
    rows = {(r.instrument, r.cls): r for r in seed_rows(stats, "ssim", 0.95)}
    assert rows[("mono networks", "windshield")].diff == pytest.approx(0.4483 - 0.4897)
    assert ("stereo networks", "windshield") not in rows  # the pipeline's own rows compare those


def test_monocular_json_per_seed_and_a_bad_table(tmp_path: Path) -> None:
    path = tmp_path / "table.json"
    seeds = {"ssim": {"car": [0.3, 0.4, 0.5]}, "msssim": {"car": [0.2, 0.3, 0.4]}}
    path.write_text(json.dumps({"seeds": [0, 1, 2], "modes": {"mono": seeds}}))
    stats = read_monocular(path, tmp_path / "absent.md")
    assert stats["mono"]["ssim"]["car"] == pytest.approx([0.3, 0.4, 0.5])
    # Per-seed values of the same seeds are pairs: the paired t over the differences (all -0.1: 0 wide).
    (row,) = seed_rows(stats, "ssim", 0.95)
    assert row.method.startswith("paired by seed (3 pairs)") and row.seeds == 3
    assert (row.diff, row.low, row.high) == pytest.approx((-0.1, -0.1, -0.1))
    assert read_monocular(tmp_path / "none.json", tmp_path / "none.md") == {}
    bad = tmp_path / "table.md"
    bad.write_text(
        "Mean ± sd over seeds [0, 1].\n\n| mode | variant | abs_rel |\n|---|---|---|\n"
        "| mono | ssim | 0.2 ± x |\n"
    )
    with pytest.raises(DataError, match=r"table\.md: row \['mono', 'ssim'\], column 'abs_rel'"):
        _parse_monocular_table(bad)


GOOD = {"instrument": "optimum w10", "class": "windshield", "diff": -0.02, "low": -0.05, "high": 0.01}


@pytest.mark.parametrize(
    "content, message",
    [
        ("{not json", "verdict rows file is not JSON"),
        ('{"rows": []}', "needs a JSON list of rows"),
        (json.dumps([{**GOOD, "n": 3}]), "needs the keys"),
        (json.dumps([{**GOOD, "n": 3, "method": "m", "extra": 1}]), "needs the keys"),
        (
            json.dumps([{**GOOD, "n": 3, "method": "m", "low": None}]),
            "low and high are both numbers or both null",
        ),
        (json.dumps([{**GOOD, "n": 3, "method": "m", "low": 0.0}]), "needs low <= diff <= high"),
        (json.dumps([{**GOOD, "n": 0, "method": "m"}]), "n must be a positive integer"),
        (json.dumps([{**GOOD, "n": 3, "method": "m", "diff": "x"}]), "diff must be a finite number"),
    ],
)
def test_malformed_external_rows_are_one_line_naming_the_file(
    tmp_path: Path, content: str, message: str
) -> None:
    path = tmp_path / "verdict.json"
    path.write_text(content)
    with pytest.raises(DataError) as err:
        read_external_rows(path)
    assert str(err.value).startswith(str(path)) and message in str(err.value) and "\n" not in str(err.value)


def test_external_rows_read_and_absent_file(tmp_path: Path) -> None:
    path = tmp_path / "verdict.json"
    path.write_text(json.dumps([{**GOOD, "n": 14, "method": "paired bootstrap over ROIs"}]))
    (row,) = read_external_rows(path)
    assert row == Row(
        "optimum w10", "windshield", -0.02, -0.05, 0.01, 14, "paired bootstrap over ROIs", "external"
    )
    assert read_external_rows(tmp_path / "absent.json") == []


def test_only_one_optimum_instrument_from_independent_rows_is_pooled() -> None:
    z = 1.959964
    rows = [
        Row("optimum w10", "glass", -0.1, -0.1 - z * 0.01, -0.1 + z * 0.01, 50, "m", "optimum"),
        Row("optimum w10", "glass", -0.3, -0.3 - z * 0.01, -0.3 + z * 0.01, 20, "m", "external"),
        Row("stereo networks", "glass", -0.1, -0.2, 0.0, 50, "m", "network"),
        Row("stereo networks", "glass", -0.3, -0.4, -0.2, 20, "m", "external"),
        Row("optimum w3", "glass", -0.3, -0.4, -0.2, 20, "m", "optimum"),
    ]
    (pooled,) = pooled_rows(rows)
    assert pooled.instrument == "optimum w10, pooled" and pooled.kind == "pooled" and pooled.n == 70
    # Equal variances: the plain mean, its standard error 0.01/sqrt(2).
    assert pooled.diff == pytest.approx(-0.2)
    assert pooled.high - pooled.diff == pytest.approx(z * 0.01 / np.sqrt(2), rel=1e-4)


def test_sentences_from_known_rows() -> None:
    rows = [
        Row("stereo networks", "windshield", -0.04, -0.13, 0.06, 66, "m", "network"),
        Row("mono networks", "windshield", -0.04, -0.17, 0.09, 3, "m", "seeds"),
        Row("optimum w10", "windshield", 0.01, -0.04, 0.02, 66, "m", "optimum"),
        Row("optimum w3", "car", -0.1, -0.16, -0.05, 8, "m", "optimum"),
        Row("optimum w30", "car", 0.1, 0.04, 0.16, 8, "m", "optimum"),
    ]
    assert _class_sentence("windshield", rows) == (
        "windshield: MS-SSIM's error is lower in 2 of 3 instruments; no interval excludes 0."
    )
    assert _class_sentence("car", rows) == (
        "car: MS-SSIM's error is lower in 1 of 2 instruments; intervals excluding 0: "
        "optimum w3 (lower), optimum w30 (higher)."
    )
    pooled = Row("optimum w10, pooled", "windshield", -0.012, -0.02, -0.004, 80, "m", "pooled")
    assert _class_sentence("windshield", [*rows, pooled]).endswith(
        "no interval excludes 0; optimum w10, pooled: \u22120.012 [\u22120.020, \u22120.004]."
    )
    # Another study's row of the same instrument is named with its source (the method before ":").
    real = Row("optimum w3", "car", -0.02, -0.03, -0.01, 16, "real pairs: over ROIs", "external")
    assert (real.label, rows[3].label) == ("optimum w3, real pairs", "optimum w3")
    assert _class_sentence("car", [*rows, real]).endswith(
        "optimum w3 (lower), optimum w30 (higher), optimum w3, real pairs (lower)."
    )
    assert Row("x", "car", 0, -1, 1, 5, "no colon", "external").label == "x, another study"
    data = verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM")
    assert data["classes"] == ["car", "windshield"] and list(data["sentences"]) == data["classes"]
    md = "\n".join(verdict_lines(data))
    assert "| car | optimum w30 | +0.100 [+0.040, +0.160] * | – | 8 ROIs | m |" in md


def test_the_verdict_figure_is_a_png_with_and_without_rows(tmp_path: Path) -> None:
    from msdepth.readers import read_json_object
    from msdepth.reporting.figures import verdict_figure

    rows = [
        Row("stereo networks", FULL_FRAME, -0.002, -0.012, 0.008, 40, "m", "network"),
        Row("stereo networks", "windshield", -0.04, -0.13, 0.06, 66, "m", "network"),
        Row("optimum w10", "windshield", -0.01, -0.04, -0.002, 66, "m", "optimum"),
        Row("optimum w10", "windshield", -0.02, -0.05, 0.01, 14, "m", "external"),
    ]
    compare_json = tmp_path / "compare.json"
    compare_json.write_text(json.dumps({"verdict": verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM")}))
    data = read_json_object(compare_json, "comparison")["verdict"]
    assert any(r["kind"] == "pooled" for r in data["rows"])  # the two optimum w10 rows
    for name, verdict in (("verdict.png", data), ("empty.png", None)):
        path = verdict_figure(verdict, tmp_path / name)
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["compare.json", "empty.png", "verdict.png"]
    with pytest.raises(DataError, match="absent.json: missing; run the compare stage first"):
        read_json_object(tmp_path / "absent.json", "comparison", "run the compare stage first")
    compare_json.write_text("[1]")
    with pytest.raises(DataError, match="compare.json: expected a JSON object, got list"):
        read_json_object(compare_json, "comparison")


def test_the_monocular_study_writes_per_seed_values_the_verdict_reads(tmp_path: Path) -> None:
    import importlib.util

    spec = importlib.util.spec_from_file_location("monocular_study", ROOT / "studies" / "monocular.py")
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    params = {"variants": ["ssim", "msssim"], "train": {"seeds": [0, 1]}}
    for i, run in enumerate(study.runs_of(params)):  # ssim/seed0, ssim/seed1, msssim/seed0, msssim/seed1
        for suite, body in (
            ("full", {"cap80": {"abs_rel": 0.2 + 0.01 * i}}),
            ("roi", {"cap80": {"by_class": {"car": {"abs_rel": 0.4 - 0.1 * (i >= 2) + 0.01 * i}}}}),
        ):
            path = tmp_path / "metrics" / suite / f"{run}.json"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(body))
    values = {"modes": {"mono": study.seed_values(tmp_path, params, 80.0)}}
    assert values["modes"]["mono"]["ssim"] == {
        FULL_FRAME: pytest.approx([0.2, 0.21]),
        "car": pytest.approx([0.4, 0.41]),
    }
    (tmp_path / "table.json").write_text(json.dumps(values))
    rows = {
        r.cls: r for r in seed_rows(read_monocular(tmp_path / "table.json", tmp_path / "x.md"), "ssim", 0.95)
    }
    assert rows["car"].diff == pytest.approx(-0.08) and rows[FULL_FRAME].diff == pytest.approx(0.02)


def test_display_names_of_one_two_and_three_variants() -> None:
    assert display_names(["ssim", "msssim"], "ssim") == ("MS-SSIM", "SSIM")
    assert display_names(["ssim"], "ssim") == ("MS-SSIM", "SSIM")  # external rows are MS-SSIM − SSIM
    assert display_names(["ssim", "msssim", "mix"], "ssim") == ("each other variant", "SSIM")


def test_an_external_reflective_row_gets_its_panel_after_the_known_classes(tmp_path: Path) -> None:
    from msdepth.reporting.figures import verdict_figure

    rows = [
        Row("stereo networks", "sign", -0.05, -0.19, 0.06, 26, "m", "network"),
        Row("optimum w10", "reflective", -0.03, -0.05, -0.01, 28568, "m", "external"),
        Row("stereo networks", FULL_FRAME, -0.002, -0.012, 0.008, 40, "m", "network"),
    ]
    data = verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM")
    assert data["classes"] == [FULL_FRAME, "sign", "reflective"]
    assert data["sentences"]["reflective"] == (
        "reflective: MS-SSIM's error is lower in 1 of 1 instrument; "
        "intervals excluding 0: optimum w10, another study (lower)."
    )
    assert verdict_figure(data, tmp_path / "v.png").read_bytes()[:4] == b"\x89PNG"


def test_a_row_without_an_interval_is_counted_but_never_excludes_or_pools(tmp_path: Path) -> None:
    """A class with fewer independent units than MIN_UNITS (one real frame) has no interval: its
    row says so, is never marked and never pooled."""
    path = tmp_path / "verdict.json"
    bare = {**GOOD, "class": "reflective", "low": None, "high": None, "n": 1, "method": "real pairs: 1 frame"}
    path.write_text(json.dumps([bare]))
    (row,) = read_external_rows(path)
    assert not row.has_interval and not row.excludes_zero
    assert interval_cell(row) == "\u22120.020 (no interval)"
    pipeline = Row("optimum w10", "reflective", -0.03, -0.05, -0.01, 40, "m", "optimum")
    assert pooled_rows([row, pipeline]) == []
    assert "no interval (too few independent units): optimum w10, real pairs (n=1)" in _class_sentence(
        "reflective", [row]
    )


def test_rows_of_other_settings_are_shown_apart_and_never_pooled() -> None:
    """After `dvc exp run -S msssim.kernel_size=7` a study's committed k=3 rows stay apart."""
    k3, k7 = "msssim: kernel_size=3; ssim: kernel_size=3", "msssim: kernel_size=7; ssim: kernel_size=3"
    rows = [
        Row("optimum w10", "car", -0.02, -0.03, -0.01, 40, "m", "optimum", settings=k7),
        Row("optimum w10", "car", -0.05, -0.06, -0.04, 16, "real pairs: ROIs", "external", settings=k3),
        Row("mono networks", "car", -0.01, -0.02, 0.0, 3, "m", "seeds"),  # no settings recorded
    ]
    data = verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM", settings=k7)
    kept = [Row.from_dict(d) for d in data["rows"]]
    assert [r.apart for r in kept] == ["", f"made with {k3}", "its settings are not recorded"]
    assert not any(r.kind == "pooled" for r in kept)  # the k=3 real row is not pooled with k=7
    assert data["sentences"]["car"].startswith("car: MS-SSIM's error is lower in 1 of 1 instrument")
    md = "\n".join(verdict_lines(data))
    assert "Made under other settings" in md and f"made with {k3}" in md
    # Under the same settings the two optimum rows pool.
    same = verdict_data(
        [rows[0], dataclasses.replace(rows[1], settings=k7)], 80.0, 0.95, "MS-SSIM", "SSIM", k7
    )
    assert [d["kind"] for d in same["rows"]][-1] == "pooled"


def test_the_summary_table_holds_each_familys_headline_instrument() -> None:
    rows = [
        Row(
            "stereo networks", "windshield", -0.036, -0.068, -0.002, 66, "paired by seed", "network", seeds=3
        ),
        Row("optimum w10", "windshield", -0.01, -0.03, 0.01, 66, "m", "optimum"),
        Row("optimum w3", "windshield", -0.05, -0.07, -0.03, 66, "m", "optimum"),
        Row("optimum w10 on kitti2015", "car", -0.02, -0.04, 0.0, 9, "m", "optimum"),
    ]
    headline = headline_instruments(10.0, ["kitti2015"])
    data = verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM", headline=headline)
    cells = data["summary"]["windshield"]
    assert cells["stereo networks"]["diff"] == -0.036
    assert cells["loss's own optimum, w10"]["instrument"] == "optimum w10"
    assert cells["optimum w10, kitti2015 frames"] is None
    assert data["summary"]["car"]["optimum w10, kitti2015 frames"]["instrument"] == "optimum w10 on kitti2015"
    lines = summary_lines(data)
    assert lines[2] == "| car | – | – | \u22120.020 [\u22120.040, +0.000], n = 9 ROIs |"
    assert lines[3] == (
        "| windshield | \u22120.036 [\u22120.068, \u22120.002] *, n = 66 ROIs × 3 seed pairs | "
        "\u22120.010 [\u22120.030, +0.010], n = 66 ROIs | – |"
    )


def test_the_committed_network_rows_are_the_mean_of_the_per_seed_paired_differences() -> None:
    """Each stereo-network row of metrics/compare.json is paired by seed: its difference is the mean
    of the per-seed differences, each the mean over the class's ROIs (images) of MS-SSIM − SSIM in
    the per-unit tables of the same seed (metrics/{roi,full}/<variant>/seed<S>.csv; an extra set's
    row, ``stereo networks on <set>``, those below metrics/sets/<set>/full/)."""
    import pandas as pd

    data = json.loads((ROOT / "metrics" / "compare.json").read_text(encoding="utf-8"))
    rows = [Row.from_dict(d) for d in data["verdict"]["rows"] if d["kind"] == "network"]
    assert rows and all(r.method.startswith(f"paired by seed ({len(data['seeds'])} pairs)") for r in rows)
    assert {r.instrument for r in rows} == {"stereo networks", "stereo networks on eigen"}
    for r in rows:
        suite, key = ("full", "frame") if r.cls == FULL_FRAME else ("roi", "roi")
        root = (
            ROOT
            / "metrics"
            / (f"sets/{r.instrument.split(' on ')[1]}/full" if " on " in r.instrument else suite)
        )
        per_seed = []
        for seed in data["seeds"]:
            a, b = (
                pd.read_csv(root / v / f"seed{seed}.csv", dtype={"frame": str}) for v in ("msssim", "ssim")
            )
            a, b = (t[t["cap"] == 80] for t in (a, b))
            if suite == "roi":
                a, b = (t[t["class"] == r.cls] for t in (a, b))
            diff = a.set_index(key)["abs_rel"] - b.set_index(key)["abs_rel"]
            per_seed.append(diff.mean())
        assert r.per_seed == pytest.approx(per_seed, abs=1e-9), (r.instrument, r.cls)
        assert r.diff == pytest.approx(np.mean(per_seed), abs=1e-9) and r.low < r.diff < r.high
        assert r.t_low < r.diff < r.t_high


def test_the_monocular_studys_settings_come_from_its_json_or_its_table(tmp_path: Path) -> None:
    from msdepth.reporting.verdict import SETTINGS_LINE, read_monocular_settings

    committed = read_monocular_settings(tmp_path / "absent.json", ROOT / "studies/results/monocular/table.md")
    assert committed == "msssim: kernel_size=3, levels=4, weights=wang; ssim: kernel_size=3, padding=valid"
    (tmp_path / "table.md").write_text(f"# t\n\n{SETTINGS_LINE}`msssim: kernel_size=7`\n")
    assert read_monocular_settings(tmp_path / "absent.json", tmp_path / "table.md") == "msssim: kernel_size=7"
    (tmp_path / "table.json").write_text(json.dumps({"modes": {}, "settings": "msssim: kernel_size=5"}))
    assert read_monocular_settings(tmp_path / "table.json", tmp_path / "table.md") == "msssim: kernel_size=5"
    assert read_monocular_settings(tmp_path / "none.json", tmp_path / "none.md") == ""


def frames_table(shift: bool, frames: int) -> pd.DataFrame:
    """Two car ROIs in each of ``frames`` frames; MS-SSIM 0.1 below SSIM on each."""
    t = pd.DataFrame(
        {
            "roi": range(2 * frames),
            "image": np.repeat([f"{i:06d}_10" for i in range(frames)], 2),
            "class": "car",
        }
    )
    t["cap"] = 80
    for m in METRICS:
        t[m] = 0.3 + 0.01 * np.arange(2 * frames) - 0.1 * shift
    return t


@pytest.mark.parametrize("frames", [5, 4])
def test_rois_are_counted_and_drawn_by_their_frames(frames: int) -> None:
    """Two ROIs per frame: the rows count the frames as the independent units (below MIN_UNITS
    frames no interval, however many ROIs) and say so: ``10 ROIs in 5 frames``."""
    tables = {"roi": {"o/ssim/w3": frames_table(False, frames), "o/msssim/w3": frames_table(True, frames)}}
    runs = {"w3": {"ssim": "o/ssim/w3", "msssim": "o/msssim/w3"}}
    groups = {v: [f"{v}/seed{s}" for s in (0, 1)] for v in ("ssim", "msssim")}
    net = {"roi": {r: frames_table(v == "msssim", frames) for v in groups for r in groups[v]}}
    kept = RowScope(keep_few=True)
    (opt,) = optimum_rows(tables, runs, CFG, 80.0, scope=kept)
    (row,) = network_rows(net, groups, CFG, 80.0, pairing={"msssim": None}, scope=kept)
    for r in (opt, row):
        assert r.n == 2 * frames and r.unit == f"ROIs in {frames} frames" and r.diff == pytest.approx(-0.1)
        assert r.has_interval == (frames >= MIN_UNITS)
    assert _units_text(row) == f"{2 * frames} ROIs in {frames} frames × 2 seed pairs"
    assert _units_text(opt) == f"{2 * frames} ROIs in {frames} frames"
    if frames >= MIN_UNITS:
        assert (
            "frames (each with all its ROIs)" in opt.method
            and "frames (each with all its ROIs)" in row.method
        )
    else:
        assert optimum_rows(tables, runs, CFG, 80.0) == [] and network_rows(net, groups, CFG, 80.0) == []
