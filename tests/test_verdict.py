"""The verdict's rows (per class, every instrument), the table that lays them out (one function, every
renderer), and the sentences, on hand-made numbers with known answers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from msdepth.analysis.verdict import (
    FULL_FRAME,
    MIN_UNITS,
    Column,
    Row,
    RowScope,
    _class_sentence,
    display_names,
    headline_columns,
    instrument_columns,
    network_rows,
    optimum_rows,
    verdict_data,
    verdict_table,
)
from msdepth.config.params import CompareConfig
from msdepth.errors import DataError
from msdepth.evaluation.metrics import METRICS
from msdepth.reporting.verdict import (
    answer_sentence,
    interval_cell,
    short_answer,
    summary_lines,
    units_text,
    verdict_lines,
)
from msdepth.stats import t_quantile

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
    assert units_text(car) == f"{frames - 1} kitti2015 frames × 2 seed pairs"
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


def test_t_quantile_known_values() -> None:
    assert t_quantile(0.975, 2) == pytest.approx(4.302653, abs=1e-4)
    assert t_quantile(0.975, 4) == pytest.approx(2.776445, abs=1e-4)
    assert t_quantile(0.975, 1e6) == pytest.approx(1.959964, abs=1e-3)


def test_sentences_from_known_rows() -> None:
    rows = [
        Row("stereo networks", "windshield", -0.04, -0.13, 0.06, 66, "m", "network"),
        Row("optimum w10", "windshield", 0.01, -0.04, 0.02, 66, "m", "optimum"),
        Row("optimum w3", "car", -0.1, -0.16, -0.05, 8, "m", "optimum"),
        Row("optimum w30", "car", 0.1, 0.04, 0.16, 8, "m", "optimum"),
    ]
    assert _class_sentence("windshield", rows) == (
        "windshield: MS-SSIM's error is lower in 1 of 2 instruments; no interval excludes 0."
    )
    assert _class_sentence("car", rows) == (
        "car: MS-SSIM's error is lower in 1 of 2 instruments; intervals excluding 0: "
        "optimum w3 (lower), optimum w30 (higher)."
    )
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
        Row("optimum w10 on eigen", FULL_FRAME, -0.02, None, None, 3, "m", "optimum"),
    ]
    compare_json = tmp_path / "compare.json"
    compare_json.write_text(json.dumps({"verdict": verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM")}))
    data = read_json_object(compare_json, "comparison")["verdict"]
    for name, verdict in (("verdict.png", data), ("empty.png", None)):
        path = verdict_figure(verdict, tmp_path / name)
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["compare.json", "empty.png", "verdict.png"]
    with pytest.raises(DataError, match="absent.json: missing; run the compare stage first"):
        read_json_object(tmp_path / "absent.json", "comparison", "run the compare stage first")
    compare_json.write_text("[1]")
    with pytest.raises(DataError, match="compare.json: expected a JSON object, got list"):
        read_json_object(compare_json, "comparison")


def test_the_monocular_study_writes_per_seed_values(tmp_path: Path) -> None:
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
    assert values["modes"]["mono"]["msssim"]["car"] == pytest.approx([0.32, 0.33])


def test_display_names_of_one_two_and_three_variants() -> None:
    assert display_names(["ssim", "msssim"], "ssim") == ("MS-SSIM", "SSIM")
    assert display_names(["ssim"], "ssim") == ("MS-SSIM", "SSIM")  # no rows: the question's names
    assert display_names(["ssim", "msssim", "mix"], "ssim") == ("each other variant", "SSIM")


def test_a_set_class_gets_its_panel_after_the_known_classes(tmp_path: Path) -> None:
    from msdepth.reporting.figures import verdict_figure

    rows = [
        Row("stereo networks", "sign", -0.05, -0.19, 0.06, 26, "m", "network"),
        Row("optimum w10 on kitti2012", "reflective", -0.03, -0.05, -0.01, 28, "m", "optimum"),
        Row("stereo networks", FULL_FRAME, -0.002, -0.012, 0.008, 40, "m", "network"),
    ]
    data = verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM")
    assert data["classes"] == [FULL_FRAME, "sign", "reflective"]
    assert data["sentences"]["reflective"] == (
        "reflective: MS-SSIM's error is lower in 1 of 1 instrument; "
        "intervals excluding 0: optimum w10 on kitti2012 (lower)."
    )
    assert verdict_figure(data, tmp_path / "v.png").read_bytes()[:4] == b"\x89PNG"


def test_a_row_without_an_interval_is_counted_but_never_excludes_zero() -> None:
    """A class with fewer independent units than MIN_UNITS (an extra set of a few frames) has no
    interval: its row says so and is never marked."""
    row = Row("optimum w10 on kitti2012", "reflective", -0.02, None, None, 1, "m; no interval", "optimum")
    assert not row.has_interval and not row.excludes_zero
    assert interval_cell(row) == "\u22120.020 (no interval)"
    assert "no interval (too few independent units): optimum w10 on kitti2012 (n=1)" in _class_sentence(
        "reflective", [row]
    )


def test_a_new_column_is_one_entry_and_every_renderer_shows_it(tmp_path: Path) -> None:
    """The verdict table is data: a Column added to the headline columns appears in the summary
    table, its sentence and short answer, with no renderer changed; the figure lays out the same
    table with one column per instrument."""
    from msdepth.reporting.figures import verdict_figure

    rows = [
        Row("stereo networks", "car", -0.02, -0.04, 0.01, 40, "m", "network"),
        Row("optimum best", "car", -0.05, -0.07, -0.03, 40, "m", "optimum"),
    ]
    base = headline_columns(10.0)
    extra = Column("optimum at each variant's best weight", "optimum", "optimum best")
    without = verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM", columns=base)
    data = verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM", columns=[*base, extra])
    assert "optimum at each variant's best weight" not in "\n".join(summary_lines(without))
    assert summary_lines(data)[0].endswith("| optimum at each variant's best weight |")
    assert summary_lines(data)[2].endswith("| \u22120.050 [\u22120.070, \u22120.030] *, n = 40 ROIs |")
    assert "optimum at each variant's best weight: lower on 1 of 1 surface class" in answer_sentence(data)
    assert "optimum at each variant's best weight lower on 1 of 1 class, 1 interval" in short_answer(data)
    assert data["summary"]["car"][extra.header]["instrument"] == "optimum best"
    assert verdict_table(rows, [extra], ["car", "glass"]) == [("car", [rows[1]]), ("glass", [None])]
    assert [c.instrument for c in instrument_columns(rows[::-1])] == ["stereo networks", "optimum best"]
    assert verdict_figure(data, tmp_path / "v.png").read_bytes()[:4] == b"\x89PNG"


def test_the_summary_table_holds_each_familys_headline_instrument() -> None:
    rows = [
        Row(
            "stereo networks", "windshield", -0.036, -0.068, -0.002, 66, "paired by seed", "network", seeds=3
        ),
        Row("optimum w10", "windshield", -0.01, -0.03, 0.01, 66, "m", "optimum"),
        Row("optimum w3", "windshield", -0.05, -0.07, -0.03, 66, "m", "optimum"),
        Row("optimum w10 on kitti2015", "car", -0.02, -0.04, 0.0, 9, "m", "optimum"),
    ]
    columns = headline_columns(10.0, ["kitti2015"])
    data = verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM", columns=columns)
    cells = data["summary"]["windshield"]
    assert cells["stereo networks"]["diff"] == -0.036
    assert cells["loss's own optimum, w10"]["instrument"] == "optimum w10"
    assert cells["optimum w10, kitti2015 frames"] is None
    assert data["summary"]["car"]["optimum w10, kitti2015 frames"]["instrument"] == "optimum w10 on kitti2015"
    lines = summary_lines(data)
    assert lines[2] == "| car | – | – | – | \u22120.020 [\u22120.040, +0.000], n = 9 ROIs |"
    assert lines[3] == (
        "| windshield | \u22120.036 [\u22120.068, \u22120.002] *, n = 66 ROIs × 3 seed pairs | "
        "\u22120.010 [\u22120.030, +0.010], n = 66 ROIs | – | – |"
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
    assert units_text(row) == f"{2 * frames} ROIs in {frames} frames × 2 seed pairs"
    assert units_text(opt) == f"{2 * frames} ROIs in {frames} frames"
    if frames >= MIN_UNITS:
        assert (
            "frames (each with all its ROIs)" in opt.method
            and "frames (each with all its ROIs)" in row.method
        )
    else:
        assert optimum_rows(tables, runs, CFG, 80.0) == [] and network_rows(net, groups, CFG, 80.0) == []
