"""studies/objects.py's tiled inference of a crop-trained network (train.crop_scale > 1)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import load_study

from msdepth.io import write_png


@pytest.fixture(scope="module")
def objects():
    return load_study("objects")


def test_windows_cover_every_pixel_and_end_flush(objects) -> None:
    assert objects.window_starts(128, 64, 32) == [0, 32, 64]
    assert objects.window_starts(384, 192, 96) == [0, 96, 192]
    assert objects.window_starts(100, 64, 32) == [0, 32, 36]
    assert objects.window_starts(64, 64, 32) == [0]


def test_tiles_of_a_pointwise_network_give_back_its_whole_image_answer(objects, tmp_path: Path) -> None:
    """A 'network' whose disparity is each pixel's red channel: every tile agrees with every
    other where they overlap, so the tiled mean is exactly the whole image's answer; a network
    that sees its window (the window's mean) gives the mean of the windows covering each pixel."""
    rng = np.random.default_rng(0)
    path = tmp_path / "image.png"
    write_png(path, rng.integers(0, 256, (40, 96, 3), dtype=np.uint8))
    pointwise = objects.tiled_disparities(lambda b: [b[:, :1]], [path], (40, 96), (16, 32))
    from msdepth.data.pairs import to_tensor

    red = to_tensor(np.asarray(objects.kitti.read_image(path)))[0].numpy()
    assert pointwise.shape == (1, 40, 96)
    np.testing.assert_allclose(pointwise[0], red, rtol=0, atol=1e-6)
    windowed = objects.tiled_disparities(
        lambda b: [b[:, :1].mean(dim=(-2, -1), keepdim=True).expand_as(b[:, :1])], [path], (40, 96), (16, 32)
    )
    tops, lefts = objects.window_starts(40, 16, 8), objects.window_starts(96, 32, 16)
    covering = [
        red[t : t + 16, x : x + 32].mean()
        for t in tops
        for x in lefts
        if t <= 20 < t + 16 and x <= 50 < x + 32
    ]
    assert windowed[0, 20, 50] == pytest.approx(np.mean(covering), abs=1e-6)
    assert torch.is_grad_enabled()


def _history(path: Path, rows: dict[int, dict]) -> None:
    """A run's history.json: one scores dict per step (every column the tables read)."""
    import json

    keys = ("abs_rel", "car_mask", "windshield_mask", "glass_mask", "sign_mask", "car_prior_corr")
    keys += ("variation_ratio", "seconds_per_step")
    history = [{"step": step, **{k: scores.get(k, 0.5) for k in keys}} for step, scores in rows.items()]
    path.mkdir(parents=True)
    (path / "history.json").write_text(json.dumps(history), encoding="utf-8")


def test_run_names_give_recipe_variant_and_seed(objects) -> None:
    assert objects.run_key("busy_cosine3e-4_x4_msssim_seed1") == ("busy_cosine3e-4_x4", "msssim", 1)
    assert objects.run_key("cars3to8_near25_x1_seed12") == ("cars3to8_near25_x1", "ssim", 12)
    assert objects.run_key("busy_lr3e-4_smooth0.05") == ("busy_lr3e-4_smooth0.05", "ssim", 0)
    assert objects.run_key("crop2_x1_msssim") == ("crop2_x1", "msssim", 0)


def test_seed_tables_average_at_the_common_mark_and_pair_by_seed(objects, tmp_path: Path) -> None:
    """Hand-computed: SSIM seeds 0, 1 score car 0.30 and 0.20 at 2,400 steps, MS-SSIM 0.27 and
    0.19 (seed 1 stopped at 2,400, so 4,800 is no common mark): mean 0.25 and 0.23, differences
    -0.03 and -0.01, mean -0.02, t interval -0.02 +- 12.706 * 0.01414 / sqrt(2) = +-0.127; both
    seeds lower. A recipe with one seed gets no row."""
    screen = tmp_path / "screen"
    _history(screen / "r", {1200: {"car_mask": 0.9}, 2400: {"car_mask": 0.30}, 4800: {"car_mask": 0.1}})
    _history(screen / "r_seed1", {1200: {"car_mask": 0.9}, 2400: {"car_mask": 0.20}})
    _history(screen / "r_msssim", {2400: {"car_mask": 0.27}, 4800: {"car_mask": 0.1}})
    _history(screen / "r_msssim_seed1", {2400: {"car_mask": 0.19}})
    _history(screen / "lonely", {1200: {}})
    groups = objects._seed_groups(tmp_path)
    means = objects.seed_means_lines(groups)
    assert len(means) == 4
    ms_row, ssim_row = means[2].split(" | "), means[3].split(" | ")
    assert ms_row[:4] == ["| screen/r", "msssim", "0,1", "2400"] and ms_row[5] == "0.230"
    assert ssim_row[:4] == ["| screen/r", "ssim", "0,1", "2400"] and ssim_row[5] == "0.250"
    (row,) = objects.paired_lines(groups)[2:]
    cells = row.split(" | ")
    assert cells[:3] == ["| screen/r", "0,1", "2400"]
    assert cells[4] == "-0.020 [-0.147, +0.107] 2/2"
    assert cells[3] == "+0.000 [+0.000, +0.000] 0/2"


@pytest.mark.parametrize(
    "text, words",
    [
        ("{}", "needs a JSON list"),
        ('[{"step": "600"}]', "step must be an integer"),
        ('[{"step": 600, "abs_rel": 0.2}]', "step 600 has no number for car_mask"),
        ("[", "not JSON"),
    ],
)
def test_a_malformed_history_is_one_line_naming_the_file(
    objects, tmp_path: Path, text: str, words: str
) -> None:
    from msdepth.errors import DataError

    run = tmp_path / "screen" / "r_seed1"
    run.mkdir(parents=True)
    (run / "history.json").write_text(text, encoding="utf-8")
    with pytest.raises(DataError, match=words) as info:
        objects.seed_tables(tmp_path)
    assert str(run / "history.json") in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--every", "0"], "--every: must be a whole number >= 1, got 0"),
        (["--steps", "-5"], "--steps: must be a whole number >= 1, got -5"),
        (["--threads", "0"], "--threads: must be in 1.."),
        (["--threads", "-1"], "--threads: must be in 1.."),
        (["--threads", "-1", "--table"], "--threads: must be in 1.."),
    ],
)
def test_out_of_range_options_are_one_line_before_any_work(
    objects, tmp_path: Path, monkeypatch, capsys, argv: list[str], words: str
) -> None:
    """--every 0, --steps -5, --threads 0 or -1: one line naming the option, before the study claims
    its folder (no work folder is left behind) or sets torch's threads."""
    from msdepth.errors import run_main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "params.yaml").write_text("")
    monkeypatch.setattr(torch, "set_num_threads", lambda n: pytest.fail(f"set_num_threads({n}) reached"))
    out = tmp_path / "res"
    assert run_main("studies/objects.py", lambda: objects.main([*argv, "--out", str(out)])) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: {words}") and err.count("\n") == 1, err
    assert not out.exists()


def test_two_folders_of_one_seed_are_refused_naming_both(objects, tmp_path: Path, capsys) -> None:
    """r_seed1 and r_seed01 both parse as seed 1 of recipe r: --table refuses in one line naming both
    folders (it dropped one run without a word), and writes no table."""
    from msdepth.errors import run_main

    _history(tmp_path / "r", {1200: {}})
    _history(tmp_path / "r_seed1", {1200: {}})
    _history(tmp_path / "r_seed01", {1200: {}})
    assert run_main("studies/objects.py", lambda: objects.main(["--table", "--out", str(tmp_path)])) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "both are r ssim seed 1" in err, err
    assert str(tmp_path / "r_seed01") in err and str(tmp_path / "r_seed1") in err
    assert not (tmp_path / "table.md").exists()


def test_marks_of_another_run_are_dropped_when_training_starts_at_an_epoch(objects) -> None:
    """A history.json holds marks to epoch 6; training resumes at epoch 3 (its checkpoint) or starts
    anew (other params: epoch 1): the marks from that epoch on are not this run's and are dropped."""
    ev = objects.EvalSet([], [], None, np.zeros(0), np.zeros(0), {})
    params = objects.params_from_dict({"train": {"epochs": 100}})
    for start, kept in ((3, [1, 2]), (1, [])):
        history = [{"epoch": e, "step": 10 * e} for e in range(1, 7)]
        on_epoch = objects._recorder(params, ev, Path("unused"), history, 10, 100_000, 50_000)
        on_epoch(start, None, {})  # not a mark: nothing scored
        assert [h["epoch"] for h in history] == kept
