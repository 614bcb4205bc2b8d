"""The losses' own optimum (msdepth.optimum.solver) and ``msdepth optimum``, on known answers at tiny
sizes."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from msdepth.__main__ import main
from msdepth.cli.predict import _default_focal
from msdepth.config.params import Params, apply_overrides, kernel_variant, params_from_dict
from msdepth.data.pairs import to_tensor
from msdepth.errors import ConfigError, DataError, MsdepthError
from msdepth.evaluation.metrics import compute_errors
from msdepth.io import write_png
from msdepth.optimum.frames import add_cost_curves
from msdepth.optimum.solver import (
    COST_SCALES,
    S_MIN_TOLERANCE,
    _curve_minimum,
    basin,
    class_summary,
    cost_curve,
    level_sizes,
    minimum_index,
    objective,
    optimise,
    optimum_disparities,
)
from msdepth.outputs import _read_manifest
from msdepth.render import render_frame

VARIANTS = ("ssim", "msssim", "mix")
H, W, SHIFT = 48, 160, 12  # the plane: a 12 px disparity, 0.075 of the width (the start is 0.04)


def texture(height: int, width: int, seed: int = 0) -> np.ndarray:
    """A Lambertian textured plane's image: smooth blobs (coarse levels) plus fine grain (uint8 RGB)."""
    rng = np.random.default_rng(seed)
    coarse = cv2.resize(
        rng.random((height // 8, width // 8, 3)), (width, height), interpolation=cv2.INTER_CUBIC
    )
    fine = cv2.GaussianBlur(rng.random((height, width, 3)), (0, 0), 1.0)
    return (np.clip(0.6 * coarse + 0.8 * (fine - 0.5) + 0.2, 0, 1) * 255).astype(np.uint8)


def plane_pair(shift: int = SHIFT) -> tuple[np.ndarray, np.ndarray]:
    """A fronto-parallel plane at disparity ``shift`` px: left(x) = right(x - shift), both views."""
    scene = texture(H, W + shift)
    return scene[:, :W], scene[:, shift:]


def small(params: Params, **optimum) -> Params:
    """``params`` with the ``optimum`` keys given. The instrument's tests here check the constant
    start's coarse-to-fine solver at the weights as given (mix has no matched ``cost`` start), so
    ``start`` and ``smoothness_width`` are ``constant`` and 0 unless a test asks otherwise."""
    optimum = {"start": "constant", "smoothness_width": 0, **optimum}
    return dataclasses.replace(params, optimum=dataclasses.replace(params.optimum, **optimum))


@pytest.mark.parametrize("variant", VARIANTS)
def test_a_textured_plane_s_constant_disparity_is_recovered_within_2_percent(variant: str) -> None:
    params = small(Params(), levels=2, iterations=30)
    (disp,) = optimum_disparities([plane_pair()], params, variant, progress=False)
    # Columns left of the shift see nothing of theirs in the right view (the border is replicated).
    interior = disp[4:-4, SHIFT + 4 : -4] * W
    assert np.median(interior) == pytest.approx(SHIFT, rel=0.02)
    assert np.mean(interior) == pytest.approx(SHIFT, rel=0.03)  # a few pixels of the blobs' flanks lag


def test_on_a_rendered_pair_the_optimum_is_far_below_the_constant() -> None:
    frame = render_frame(2017, 1, 0, 64, 192)
    params = small(Params(), levels=2, iterations=60)
    (disp,) = optimum_disparities([(frame.left, frame.right)], params, "ssim", progress=False)
    valid = frame.disp > 0
    gt = frame.focal * 0.54 / frame.disp[valid]
    optimum = frame.focal * 0.54 / (disp[valid] * 192)
    constant = np.full_like(gt, frame.focal * 0.54 / np.median(frame.disp[valid]))
    ours, theirs = compute_errors(gt, optimum)["abs_rel"], compute_errors(gt, constant)["abs_rel"]
    assert ours < 0.5 * theirs, (ours, theirs)


def test_the_result_is_deterministic_and_each_pair_s_own() -> None:
    params = small(Params(), levels=2, iterations=10)
    pair = plane_pair()
    other = plane_pair(5)
    first = optimum_disparities([pair], params, "msssim", progress=False)[0]
    again = optimum_disparities([pair], params, "msssim", progress=False)[0]
    assert first.tobytes() == again.tobytes()
    batched = optimum_disparities([other, pair], small(params, batch_size=2), "msssim", progress=False)[1]
    np.testing.assert_allclose(batched, first, atol=1e-5)  # its batch mate does not move it


def test_only_the_ms_ssim_optimum_depends_on_msssim_kernel_size() -> None:
    base = small(Params(), levels=1, iterations=5)
    k7 = dataclasses.replace(
        base, appearance={**base.appearance, "msssim": dataclasses.replace(base.msssim, kernel_size=7)}
    )
    pair = [plane_pair()]
    for variant, changes in (("ssim", False), ("msssim", True)):
        a = optimum_disparities(pair, base, variant, progress=False)[0]
        b = optimum_disparities(pair, k7, variant, progress=False)[0]
        assert (a.tobytes() != b.tobytes()) is changes, variant


def test_the_optimum_minimises_the_objective_with_its_own_smoothness_weight() -> None:
    params = Params()
    criterion = objective(params, "ssim", 2.5)
    assert criterion.loss_cfg.smoothness_weight == 2.5 and criterion.loss_cfg.alpha == params.loss.alpha
    assert objective(params, "ssim").loss_cfg.smoothness_weight == params.optimum.smoothness_weight
    assert objective(params, "mix") is not None  # a registered variant that is not trained
    assert not any(p.requires_grad for p in objective(params, "msssim").parameters())
    with pytest.raises(ConfigError, match="unknown variant 'nope'"):
        objective(params, "nope")


def test_the_loss_falls_at_every_level() -> None:
    left, right = (to_tensor(x)[None] for x in plane_pair())
    trace: list[list[float]] = []
    optimise(
        left, right, objective(Params(), "ssim"), small(Params(), levels=2, iterations=20).optimum, trace
    )
    assert len(trace) == 2 and all(steps[-1] < steps[0] for steps in trace)


def test_level_sizes_halve_down_to_24_px() -> None:
    assert level_sizes(125, 414, 3) == [(31, 103), (62, 207), (125, 414)]
    assert level_sizes(48, 160, 4) == [(24, 80), (48, 160)]
    assert level_sizes(20, 40, 3) == [(20, 40)]  # a small image keeps its own size


@pytest.mark.parametrize("variant", VARIANTS)
def test_a_lambertian_plane_s_cost_curve_is_lowest_at_s_1(variant: str) -> None:
    left, right = (to_tensor(x) for x in plane_pair())
    gt = np.full((H, W), float(SHIFT), np.float32)
    costs = cost_curve(left, right, gt, (60, 12, 100, 36), objective(Params(), variant))
    assert _curve_minimum(COST_SCALES, costs) == pytest.approx(1.0)
    low, high = basin(COST_SCALES, costs)
    assert 0.8 < low <= 1 <= high < 1.25  # a textured box: a narrow basin around the truth


def test_add_cost_curves_appends_each_box_s_curve_to_its_class() -> None:
    """One frame's boxes: the same curves as cost_curve per box, grouped by class after any already there."""
    left, right = plane_pair()
    gt = np.full((H, W), float(SHIFT), np.float32)
    criterion = objective(Params(), "ssim")
    boxes = [("car", (60, 12, 100, 36)), ("sign", (20, 4, 40, 20)), ("car", (100, 20, 140, 44))]
    curves = {"car": [np.zeros(len(COST_SCALES))]}
    add_cost_curves(curves, criterion, left, right, gt, boxes)
    assert sorted(curves) == ["car", "sign"] and [len(curves[c]) for c in ("car", "sign")] == [3, 1]
    added = [*curves["car"][1:], *curves["sign"]]
    for got, (_, box) in zip(added, [boxes[0], boxes[2], boxes[1]], strict=True):
        np.testing.assert_array_equal(got, cost_curve(to_tensor(left), to_tensor(right), gt, box, criterion))


def test_basin_and_class_summary_on_known_curves() -> None:
    scales = np.geomspace(0.5, 2, 9)  # 0.5, 0.59, 0.71, 0.84, 1, 1.19, 1.41, 1.68, 2
    costs = np.abs(np.log(scales / 1.19))
    assert _curve_minimum(scales, costs) == pytest.approx(scales[5])
    assert basin(scales, costs) == (pytest.approx(scales[5]), pytest.approx(scales[5]))
    flat = np.array([1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0])
    assert basin(scales, flat) == (pytest.approx(scales[2]), pytest.approx(scales[4]))
    summary = class_summary({"car": [flat, flat + 1]}, scales)
    # A tie: the point nearest s = 1 (scales[4]), not the first one (scales[2]).
    assert summary["car"]["rois"] == 2 and summary["car"]["s_min"] == pytest.approx(scales[4])
    assert summary["car"]["basin_ratio"] == pytest.approx(scales[4] / scales[2])


def _flat_basin() -> np.ndarray:
    """A cost curve over COST_SCALES (s = 1 at index 12) whose basin, indices 10-14, is flat at 0.1
    (as a sum of float32 terms, equal in exact arithmetic, leaves it)."""
    costs = 0.1 + 0.01 * np.abs(np.log(COST_SCALES)) ** 2
    costs[10:15] = 0.1
    return costs


@pytest.mark.parametrize("index", [10, 11, 13, 14])
def test_a_last_bit_in_a_flat_basin_does_not_move_s_min_or_the_basin(index: int) -> None:
    flat = _flat_basin()
    perturbed = flat.copy()
    perturbed[index] -= 1e-12  # below float32 rounding of a cost of 0.1 (~7e-9)
    assert int(np.argmin(perturbed)) == index  # a plain argmin follows the last bit ...
    for costs in (flat, perturbed):  # ... s_min stays at the point nearest s = 1
        assert minimum_index(COST_SCALES, costs) == 12 and _curve_minimum(COST_SCALES, costs) == 1.0
        assert basin(COST_SCALES, costs) == (COST_SCALES[10], COST_SCALES[14])


def test_s_min_tolerance_is_relative_to_the_lowest_cost_and_ties_go_to_the_smaller_s() -> None:
    costs = _flat_basin()
    costs[12] = 0.1 * (1 + 2 * S_MIN_TOLERANCE)  # clearly above: the truth is no longer a minimum
    assert _curve_minimum(COST_SCALES, costs) == COST_SCALES[11]  # 0.944 and 1.059 tie: the smaller
    costs[12] = 0.1 * (1 + 0.5 * S_MIN_TOLERANCE)  # within rounding of the minimum: a tie again
    assert _curve_minimum(COST_SCALES, costs) == 1.0
    # Scaled costs keep their s_min: the tolerance is a share of the cost, not an absolute.
    assert (
        _curve_minimum(COST_SCALES, 1e6 * costs) == 1.0 and _curve_minimum(COST_SCALES, 1e-6 * costs) == 1.0
    )
    # A curve flat within rounding: every s ties, s_min is 1 and the basin the whole grid.
    level = np.full(len(COST_SCALES), 0.1) + np.linspace(0, 1e-9, len(COST_SCALES))
    assert _curve_minimum(COST_SCALES, level) == 1.0
    assert basin(COST_SCALES, level) == (COST_SCALES[0], COST_SCALES[-1])


def test_a_bad_cost_curve_is_one_line() -> None:
    with pytest.raises(DataError, match="expected 25 finite costs"):
        _curve_minimum(COST_SCALES, np.full(len(COST_SCALES), np.nan))
    with pytest.raises(DataError, match="expected 25 finite costs"):
        basin(COST_SCALES, np.ones(3))


def test_the_optimum_section_is_checked() -> None:
    with pytest.raises(ConfigError, match="optimum.smoothness_sweep"):
        params_from_dict({"optimum": {"smoothness_sweep": [0.5, 1.0, 2.0]}})  # less than a decade
    with pytest.raises(ConfigError, match="optimum.smoothness_sweep"):
        params_from_dict({"optimum": {"smoothness_weight": 2.0}})  # not among the reported weights
    with pytest.raises(ConfigError, match="optimum.levels"):
        params_from_dict({"optimum": {"levels": 0}})
    raw = apply_overrides({}, ["optimum.iterations=7", "msssim.kernel_size=5"])
    assert raw == {"optimum": {"iterations": 7}, "msssim": {"kernel_size": 5}}
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        apply_overrides({}, ["optimum.iterations"])


def test_a_studies_variant_spec_sets_its_kernel_size_on_a_copy() -> None:
    raw = {"msssim": {"levels": 3}, "train": {"seeds": [0]}}
    name, out = kernel_variant(raw, "msssim:7")
    assert name == "msssim" and out == {"msssim": {"levels": 3, "kernel_size": 7}, "train": {"seeds": [0]}}
    assert raw == {"msssim": {"levels": 3}, "train": {"seeds": [0]}}  # the base stays for the next spec
    assert kernel_variant(raw, "ssim") == ("ssim", raw)
    assert kernel_variant({}, "ssim:5") == ("ssim", {"ssim": {"kernel_size": 5}})
    with pytest.raises(ConfigError, match="NAME:KERNEL_SIZE"):
        kernel_variant(raw, "msssim:big")


# ----------------------------------------------------------------------------- the CLI

FAST = ["--set", "optimum.iterations=3", "--set", "optimum.levels=1", "--quiet"]


def cli(*args) -> int:
    return main(["optimum", *map(str, args), *FAST])


def test_cli_writes_predict_s_outputs_at_the_left_image_s_resolution(tmp_path) -> None:
    left, right = plane_pair()
    write_png(tmp_path / "l.png", left)
    write_png(tmp_path / "r.png", right)
    out = tmp_path / "out"
    assert (
        cli(
            tmp_path / "l.png",
            tmp_path / "r.png",
            "--variant",
            "ssim",
            "--out",
            out,
            "--height",
            24,
            "--width",
            80,
        )
        == 0
    )
    disp = np.load(out / "l_ssim_disp.npy")
    assert disp.dtype == np.float32 and disp.shape == (H, W)
    depth = np.load(out / "l_ssim_depth.npy")
    np.testing.assert_allclose(depth, _default_focal(W) * 0.54 / disp, rtol=1e-5)
    assert cv2.imread(str(out / "l_ssim_disp.png")).shape == (H, W, 3)
    assert (
        cli(
            tmp_path / "l.png",
            tmp_path / "r.png",
            "--variant",
            "ssim",
            "--out",
            tmp_path / "o2",
            "--focal",
            100,
            "--baseline",
            0.5,
        )
        == 0
    )
    np.testing.assert_allclose(
        np.load(tmp_path / "o2" / "l_ssim_depth.npy") * np.load(tmp_path / "o2" / "l_ssim_disp.npy"),
        50,
        rtol=1e-5,
    )


def test_cli_keeps_both_variants_results_in_one_folder(tmp_path) -> None:
    # Issue 53: --variant ssim into the folder of a --variant msssim result replaced it unsaid.
    left, right = plane_pair()
    write_png(tmp_path / "l.png", left)
    write_png(tmp_path / "r.png", right)
    out = tmp_path / "out"
    for variant in ("msssim", "ssim"):
        assert cli(tmp_path / "l.png", tmp_path / "r.png", "--variant", variant, "--out", out) == 0
    names = [
        f"l_{v}{suffix}" for v in ("msssim", "ssim") for suffix in ("_depth.npy", "_disp.npy", "_disp.png")
    ]
    assert sorted(p.name for p in out.iterdir()) == sorted([".msdepth-optimum", *names])
    assert _read_manifest(out / ".msdepth-optimum") == set(names)
    ssim, msssim = np.load(out / "l_ssim_disp.npy"), np.load(out / "l_msssim_disp.npy")
    assert ssim.shape == msssim.shape == (H, W) and not np.array_equal(ssim, msssim)
    # a rerun of one variant rewrites its own files only
    before = (out / "l_msssim_disp.npy").read_bytes()
    assert cli(tmp_path / "l.png", tmp_path / "r.png", "--variant", "ssim", "--out", out) == 0
    assert (out / "l_msssim_disp.npy").read_bytes() == before


def test_cli_on_folders_names_each_bad_pair_and_does_the_others(tmp_path, capsys) -> None:
    left, right = plane_pair()
    for name in ("a", "b", "c", "d"):
        write_png(tmp_path / "L" / f"{name}.png", left)
    write_png(tmp_path / "R" / "a.png", right)
    write_png(tmp_path / "R" / "b.png", right[:, :-8])  # another size
    (tmp_path / "R" / "c.png").write_text("not an image")
    # d.png has no right image
    out = tmp_path / "out"
    assert (
        main(
            [
                "optimum",
                str(tmp_path / "L"),
                str(tmp_path / "R"),
                "--variant",
                "msssim",
                "--out",
                str(out),
                *FAST,
            ]
        )
        == 1
    )
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 3
    for name in ("b.png", "c.png", "d.png"):
        assert sum(name in line for line in errors) == 1, (name, errors)
    assert sorted(p.name for p in out.iterdir()) == [
        ".msdepth-optimum",
        "a_msssim_depth.npy",
        "a_msssim_disp.npy",
        "a_msssim_disp.png",
    ]


def test_cli_refuses_bad_arguments_in_one_line(tmp_path, capsys) -> None:
    assert cli(tmp_path / "none.png", tmp_path / "r.png", "--variant", "ssim", "--out", tmp_path) == 1
    assert "none.png: no such file" in capsys.readouterr().err
    write_png(tmp_path / "l.png", plane_pair()[0])
    assert cli(tmp_path / "l.png", tmp_path / "l.png", "--variant", "nope", "--out", tmp_path) == 1
    assert "unknown variant 'nope'" in capsys.readouterr().err
    assert (
        cli(tmp_path / "l.png", tmp_path / "l.png", "--variant", "ssim", "--out", tmp_path, "--height", 24)
        == 1
    )
    assert "height and width" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.npy"))


def test_cli_reads_the_params_file_and_its_overrides(tmp_path) -> None:
    (tmp_path / "p.yaml").write_text("optimum:\n  levels: 0\n")
    write_png(tmp_path / "l.png", plane_pair()[0])
    write_png(tmp_path / "r.png", plane_pair()[1])
    args = [tmp_path / "l.png", tmp_path / "r.png", "--variant", "ssim", "--out", tmp_path]
    assert main(["optimum", *map(str, args), "--params", str(tmp_path / "p.yaml")]) == 1  # levels 0
    assert cli(*args, "--params", tmp_path / "p.yaml") == 0  # FAST's optimum.levels=1 wins


def test_cli_without_a_params_file_takes_the_measured_stopping_rule(tmp_path, monkeypatch) -> None:
    """params.yaml's optimum.iterations (50, the dataclass default too) fits the pipeline's time
    budget; without a params file the command runs the measured rule, INSTRUMENT_ITERATIONS."""
    from msdepth.cli.optimum import INSTRUMENT_ITERATIONS, _read_params

    monkeypatch.chdir(tmp_path)  # no ./params.yaml
    assert INSTRUMENT_ITERATIONS == 100 and Params().optimum.iterations == 50
    assert _read_params(None, []).optimum.iterations == INSTRUMENT_ITERATIONS
    assert _read_params(None, ["optimum.iterations=7"]).optimum.iterations == 7
    (tmp_path / "params.yaml").write_text("optimum: {levels: 2}\n")
    assert _read_params(None, []).optimum.iterations == 50  # a params file's own default


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (
            b"optimum:\n  levels: 2\n  levels: 3\n",
            "p.yaml: optimum.levels: duplicate key (lines 2 and 3): keep one",
        ),
        (b"optimum:\n  start: caf\xe9\n", "p.yaml: not UTF-8 text (byte 0xe9 on line 2)"),
        (b"- 1\n- 2\n", "p.yaml: params: expected a mapping at the top level"),
        (
            b"optimum: &a\n  levels: 2\ncompare: *a\n",
            "p.yaml: compare: a YAML alias (of the value at line 1) is refused",
        ),
        (
            b"data: {kitti: {odometry_sequences: ['" + b"0" * 300 + b"']}}\n",
            "odometry sequence numbers of two digits",
        ),
    ],
)
def test_cli_params_go_through_the_hardened_reader(tmp_path, capsys, content: bytes, expected: str) -> None:
    # Issue 42 case 12: --params took the last of two duplicate keys, and a non-UTF-8 file, a top-level
    # list and aliases gave tracebacks or were accepted. Case 13: a 300-character sequence name passed.
    (tmp_path / "p.yaml").write_bytes(content)
    write_png(tmp_path / "l.png", plane_pair()[0])
    write_png(tmp_path / "r.png", plane_pair()[1])
    args = [tmp_path / "l.png", tmp_path / "r.png", "--variant", "ssim", "--out", tmp_path / "out"]
    assert main(["optimum", *map(str, args), "--params", str(tmp_path / "p.yaml")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and expected in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("extra", "expected"),
    [
        (
            ["--set", "optimum.levels=" + "9" * 100_000],
            "an integer written with 100000 characters is out of range",
        ),
        (["--set", "optimum.levels=4000000000"], "optimum.levels: must be in 1..12, got 4000000000"),
        (
            ["--set", "optimum.height=1000000000", "--set", "optimum.width=1000000000"],
            "optimum.height: must be",
        ),
        (["--set", "optimum.batch_size=100000"], "optimum.batch_size: must be in 1..64"),
        (
            ["--height", "100000", "--width", "100000"],
            "the working size 100000x100000 is over 4096 px a side",
        ),
    ],
)
def test_cli_sizes_are_bounded_in_one_short_line(tmp_path, capsys, extra: list[str], expected: str) -> None:
    # Issue 42 cases 8 and 12: these ended in MemoryError or cv2.error tracebacks, and a 100,000-digit
    # --set value was echoed whole.
    write_png(tmp_path / "l.png", plane_pair()[0])
    write_png(tmp_path / "r.png", plane_pair()[1])
    args = [tmp_path / "l.png", tmp_path / "r.png", "--variant", "ssim", "--out", tmp_path / "out"]
    assert main(["optimum", *map(str, args), *extra]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and len(err) < 300 and expected in err, err


def test_cli_pixel_limit_names_optimum_s_own_options(tmp_path, capsys) -> None:
    # Issue 42 case 12: the message named --max-megapixels, which optimum does not have.
    write_png(tmp_path / "l.png", np.zeros((4100, 4200, 3), np.uint8))
    write_png(tmp_path / "r.png", np.zeros((4100, 4200, 3), np.uint8))
    assert cli(tmp_path / "l.png", tmp_path / "r.png", "--variant", "ssim", "--out", tmp_path / "out") == 1
    err = capsys.readouterr().err
    assert "over the limit of 16.7772 megapixels" in err and "(give --height, --width)" in err
    assert "--max-megapixels" not in err


def test_cli_refuses_a_cost_volume_over_its_budget_in_one_line_per_pair(tmp_path, capsys) -> None:
    # Issue 42 case 8 with the cost start: 2400 x 1000 px is within the own-size pixel limit, but its
    # volume (721 disparities) would take ~12.9 GiB; the pair is refused, named, before any work.
    write_png(tmp_path / "l.png", np.zeros((1000, 2400, 3), np.uint8))
    write_png(tmp_path / "r.png", np.zeros((1000, 2400, 3), np.uint8))
    args = (
        tmp_path / "l.png",
        tmp_path / "r.png",
        "--variant",
        "ssim",
        "--start",
        "cost",
        "--set",
        "optimum.max_width=0",  # the default cap would match it at 600 x 250 px, well within
        "--out",
        tmp_path / "o",
    )
    assert cli(*args) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: {tmp_path / 'l.png'}: the cost volume of a 2400 x 1000 px pair at 721 ")
    assert "choose optimum.start sgbm or constant" in err and err.count("error:") == 1


# ----------------------------------------------------------------------------- the device


def test_the_refinement_runs_on_train_device_and_a_missing_cuda_is_one_line(tmp_path, capsys) -> None:
    """``train.device`` cpu gives the default's bytes; ``cuda`` where torch sees none is refused
    before any pair is matched, by the solver and by ``msdepth optimum --device cuda`` alike."""
    import torch

    params = small(Params(), iterations=3, levels=1)
    pair = [plane_pair()]
    on_cpu = optimum_disparities(pair, _device(params, "cpu"), "ssim", progress=False)[0]
    assert np.array_equal(on_cpu, optimum_disparities(pair, params, "ssim", progress=False)[0])
    if torch.cuda.is_available():
        pytest.skip("torch sees a CUDA device: test_the_cuda_refinement_matches_the_cpu_s covers it")
    with pytest.raises(MsdepthError, match="device cuda requested but torch sees no CUDA device"):
        optimum_disparities(pair, _device(params, "cuda"), "ssim", progress=False)
    write_png(tmp_path / "l.png", pair[0][0])
    write_png(tmp_path / "r.png", pair[0][1])
    args = [tmp_path / "l.png", tmp_path / "r.png", "--variant", "ssim", "--out", tmp_path / "out"]
    assert cli(*args, "--device", "cuda") == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "no CUDA device" in err
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(not __import__("torch").cuda.is_available(), reason="needs a CUDA device")
def test_the_cuda_refinement_matches_the_cpu_s() -> None:
    """On a GPU, the refinement's disparity agrees with the CPU's to float rounding (cuDNN sums in
    another order), and both recover the plane."""
    params = small(Params(), iterations=30, levels=2)
    pair = [plane_pair()]
    on_cpu = optimum_disparities(pair, _device(params, "cpu"), "msssim", progress=False)[0]
    on_gpu = optimum_disparities(pair, _device(params, "cuda"), "msssim", progress=False)[0]
    assert np.abs(on_gpu - on_cpu).max() < 1e-3
    assert np.median(on_gpu[4:-4, SHIFT + 4 : -4] * W) == pytest.approx(SHIFT, rel=0.02)


def _device(params: Params, device: str) -> Params:
    return dataclasses.replace(params, train=dataclasses.replace(params.train, device=device))


@pytest.mark.parametrize("weight", ["3", "0", "0.5"])
def test_cli_takes_any_smoothness_weight_the_pipeline_lists_follow_it(tmp_path, weight: str) -> None:
    """Issue 68: --set optimum.smoothness_weight=3 failed on optimum.set_weights, a list only the
    pipeline reads; on the command line the pipeline's weight lists follow the weight (0 too, which
    no sweep may hold), and a list the user sets is checked as given."""
    from msdepth.cli.optimum import _read_params

    write_png(tmp_path / "l.png", plane_pair()[0])
    write_png(tmp_path / "r.png", plane_pair()[1])
    args = [tmp_path / "l.png", tmp_path / "r.png", "--variant", "ssim", "--out", tmp_path / "out"]
    assert cli(*args, "--set", f"optimum.smoothness_weight={weight}") == 0
    assert _read_params(None, [f"optimum.smoothness_weight={weight}"]).optimum.smoothness_weight == float(
        weight
    )
    with pytest.raises(ConfigError, match=r"optimum\.set_weights: must be positive, distinct and hold"):
        _read_params(None, [f"optimum.smoothness_weight={weight}", "optimum.set_weights=[7]"])


def test_cli_colorbar_draws_every_variant_of_a_pair_on_one_scale(tmp_path) -> None:
    """--colorbar: the second variant's run into the folder redraws the first's PNG, both on one
    scale (the least minimum to the largest 95th percentile of the two maps), each with its bar;
    --vmax PX: the scale 0..PX."""
    from msdepth.cli.predict import color_scale, colorize_disparity

    left, right = plane_pair()
    write_png(tmp_path / "l.png", left)
    write_png(tmp_path / "r.png", right)
    out = tmp_path / "out"
    pair = [tmp_path / "l.png", tmp_path / "r.png"]
    for variant in ("msssim", "ssim"):
        assert cli(*pair, "--variant", variant, "--out", out, "--colorbar") == 0
    maps = {v: np.load(out / f"l_{v}_disp.npy") for v in ("msssim", "ssim")}
    lows, highs = zip(*(color_scale(d) for d in maps.values()), strict=True)
    assert len(set(highs)) == 2  # two scales of their own: the shared one differs from one of them
    for variant, disp in maps.items():
        drawn = cv2.cvtColor(cv2.imread(str(out / f"l_{variant}_disp.png")), cv2.COLOR_BGR2RGB)
        assert drawn.shape[1] > W  # the bar
        np.testing.assert_array_equal(drawn, colorize_disparity(disp, (min(lows), max(highs)), True))
    assert cli(*pair, "--variant", "ssim", "--out", tmp_path / "fixed", "--vmax", 5) == 0
    drawn = cv2.cvtColor(cv2.imread(str(tmp_path / "fixed" / "l_ssim_disp.png")), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(
        drawn, colorize_disparity(np.load(tmp_path / "fixed" / "l_ssim_disp.npy"), (0, 5))
    )


@pytest.mark.parametrize("vmax", ["0", "-1", "nan", "inf"])
def test_cli_vmax_out_of_range_is_one_line(tmp_path, capsys, vmax: str) -> None:
    write_png(tmp_path / "l.png", plane_pair()[0])
    write_png(tmp_path / "r.png", plane_pair()[1])
    args = [tmp_path / "l.png", tmp_path / "r.png", "--variant", "ssim", "--out", tmp_path / "out"]
    assert cli(*args, "--vmax", vmax) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: --vmax: must be a disparity in px") and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("side", [1, 2])
@pytest.mark.parametrize(
    ("start", "extra"), [("cost", []), ("cost", ["--height", 24, "--width", 24]), ("sgbm", [])]
)
def test_cli_a_tiny_pair_is_one_line_naming_it(tmp_path, capsys, side: int, start: str, extra: list) -> None:
    """Issue 68: a 1x1 or 2x2 pair through --start cost gave 'unexpected ValueError / RuntimeError';
    any start at the image's own size a line naming no file. Now one line naming the image."""
    rng = np.random.default_rng(side)
    for name in ("l.png", "r.png"):
        write_png(tmp_path / name, rng.integers(0, 255, (side, side, 3), dtype=np.uint8))
    args = [tmp_path / "l.png", tmp_path / "r.png", "--variant", "ssim", "--out", tmp_path / "out"]
    assert cli(*args, "--start", start, *extra) == 1
    first, *rest = capsys.readouterr().err.splitlines()
    assert first.startswith(
        f"error: {tmp_path / 'l.png'}: {side}x{side} px is below the optimum's 24 px a side"
    )
    assert rest == [f"wrote the optimum of 0 of 1 pair(s) to {tmp_path / 'out'}"]
