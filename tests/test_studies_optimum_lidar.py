"""studies/optimum_sweep.py and studies/score_lidar.py end to end on the smallest inputs they accept
(issue 54): the sweep on two rendered frames at 48 x 160 and a few Adam steps, the LiDAR scoring on
a hand-made scan whose GT is known pixel by pixel, on a scan of the synthetic LiDAR simulator and on
the shared real KITTI sample (skipped where ``../shared/real-samples`` is absent). Neither script
writes a file: both print a markdown table, and a bad argument or input file is one ``error:`` line.
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

ROOT = Path(__file__).resolve().parents[1]
REAL = Path(__file__).resolve().parents[2] / "shared" / "real-samples" / "kitti-object-pair"

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
    """The sweep's scoring (its ``rendered`` frames, ``scores``): a disparity equal to the GT scores
    abs_rel, D1 and EPE 0 and a1 1 over the frame and in every box and mask class; twice the GT's
    disparity (half its depth) scores abs_rel 0.5 and a1 0 everywhere."""
    from msdepth.config.params import apply_overrides, params_from_dict, read_params_file

    sweep = _study("optimum_sweep")
    tiny = ["data.synthetic.height=48", "data.synthetic.width=160"]
    params = params_from_dict(apply_overrides(read_params_file(ROOT / "params.yaml"), tiny))
    _, frames, rois = sweep.rendered(params, 2)
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


# ------------------------------------------------------------------------------- score_lidar.py

# A hand-made rig: the camera is the LiDAR turned (its x forward is the camera's z), focal F px,
# principal point (1, 1) in KITTI's 1-based convention, so that the point (x, -c x / F, -r x / F)
# lands on pixel (row r, column c) with depth x. The image is 4 x 6.
F, SHAPE = 10.0, (4, 6)
RIG = {
    "P2": [F, 0, 1, 0, 0, F, 1, 0, 0, 0, 1, 0],
    "R0_rect": [1, 0, 0, 0, 1, 0, 0, 0, 1],
    "Tr_velo_to_cam": [0, -1, 0, 0, 0, 0, -1, 0, 1, 0, 0, 0],
}
# (row, column, depth): rows 0-1 at 10 m, row 2 at 40 m; on (3, 0) two points, the nearer (20 m)
# wins; (3, 1) is beyond the 80 m cap; the point behind the sensor and the one right of the image
# are dropped. GT within the cap: 12 x 10 m, 1 x 20 m, 6 x 40 m, 19 points.
POINTS = [(r, c, 10.0) for r in (0, 1) for c in range(6)] + [(2, c, 40.0) for c in range(6)]
POINTS += [(3, 0, 30.0), (3, 0, 20.0), (3, 1, 100.0), (3, 2, -10.0), (0, 7, 10.0)]


def _calib_text(entries: dict[str, list[float]]) -> str:
    """An object-benchmark ``calib.txt`` holding ``entries``."""
    return "".join(f"{k}: " + " ".join(f"{v:.12e}" for v in np.ravel(vs)) + "\n" for k, vs in entries.items())


def _rig(folder: Path) -> tuple[Path, Path, np.ndarray]:
    """The hand-made scan and calibration written in ``folder``, and the exact depth map: the
    nearest point's depth on each pixel with one, 0 elsewhere."""
    from msdepth.data.kitti import write_velodyne

    write_velodyne(folder / "scan.bin", np.array([(x, -c * x / F, -r * x / F, 0.5) for r, c, x in POINTS]))
    (folder / "calib.txt").write_text(_calib_text(RIG))
    exact = np.zeros(SHAPE, np.float32)
    for r, c, x in POINTS:
        if 0 < x and c < SHAPE[1] and (exact[r, c] == 0 or x < exact[r, c]):
            exact[r, c] = x
    return folder / "scan.bin", folder / "calib.txt", exact


def _score(folder: Path, maps: dict[str, np.ndarray], *extra: str) -> dict[str, dict[str, str]]:
    """score_lidar.py on the rig in ``folder`` and the depth maps ``maps`` (saved there as
    ``<name>.npy``): its rows by their first cell; the folder holds nothing new afterwards."""
    for name, depth in maps.items():
        np.save(folder / f"{name}.npy", depth)
    before = sorted(folder.iterdir())
    args = ["--scan", "scan.bin", "--calib", "calib.txt", *(f"{n}.npy" for n in maps), *extra]
    proc = run_script("studies/score_lidar.py", *args, cwd=folder)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr[-3000:]
    assert sorted(folder.iterdir()) == before
    return {row["depth map"]: row for row in _table(proc.stdout)}


def _cells(row: dict[str, str]) -> tuple[str, ...]:
    return row["GT points"], row["abs_rel"], row["rmse"], row["a1"]


def test_score_lidar_known_answers_on_a_hand_made_scan(tmp_path: Path) -> None:
    """Against 19 GT points known by hand: the exact map scores 0 (the nearer of two points on a
    pixel wins; a point behind the sensor, off the image or beyond the cap is not GT), half the depth
    abs_rel 0.5, an empty map (0 = beyond the writer's range) is read as the cap; the oracle
    constant is the median GT depth, 10 m. --cap 120 admits the 100 m point."""
    _, _, exact = _rig(tmp_path)
    rows = _score(tmp_path, {"exact": exact, "half": exact / 2, "empty": np.zeros(SHAPE, np.float32)})
    assert list(rows) == ["oracle constant (median GT depth)", "exact.npy", "half.npy", "empty.npy"]
    # The constant 10 m: |20 - 10| / 20 and 6 x 30 / 40 over 19; rmse sqrt((100 + 6 x 900) / 19); 12 of 19.
    assert _cells(rows["oracle constant (median GT depth)"]) == ("", "0.263", "17.01", "0.632")
    assert _cells(rows["exact.npy"]) == ("19", "0.000", "0.00", "1.000")
    # rmse: sqrt((12 x 100 + 400 + 6 x 1600) / 19) / 2 = 12.14
    assert _cells(rows["half.npy"]) == ("19", "0.500", "12.14", "0.000")
    # 80 m: (12 x 70 / 10 + 60 / 20 + 6 x 40 / 40) / 19 = 93 / 19; rmse sqrt(72000 / 19)
    assert _cells(rows["empty.npy"]) == ("19", "4.895", "61.56", "0.000")
    wide = _score(tmp_path, {"exact": exact}, "--cap", "120")
    assert _cells(wide["exact.npy"]) == ("20", "0.000", "0.00", "1.000")


def test_score_lidar_agrees_with_the_renderer_on_a_simulated_scan(tmp_path: Path) -> None:
    """The synthetic LiDAR's scan of a rendered 96 x 320 frame, with the synthetic rig written as an
    object-benchmark calib.txt: the renderer's own depth (as the LiDAR's forward distance) scores
    abs_rel near 0 (0.008 measured: edges, sub-pixel), the camera's depth (0.27 m nearer: the mount)
    and the oracle constant clearly worse. Glass rays all dropped: a return through glass is the
    interior behind it, which the renderer's depth does not show."""
    from msdepth import render
    from msdepth.data.kitti import KITTI_BASELINE, write_velodyne
    from msdepth.render import velodyne_sim
    from msdepth.render.street import build_scene

    seed, (h, w) = 3, (96, 320)
    frame = render.render_frame(seed, 1, 0, h, w)
    scan = velodyne_sim.simulate(
        build_scene(render.frame_rng(seed, 1, 0)), frame.focal, w, velodyne_sim.scan_rng(seed, 1, 0), 1.0
    )
    write_velodyne(tmp_path / "scan.bin", scan.points)
    proj = render.calib_text(h, w, raw=True).split("P_rect_02:")[1].splitlines()[0].split()
    velo_to_cam = np.hstack([velodyne_sim.VELO_TO_CAM_R, velodyne_sim.VELO_TO_CAM_T[:, None]])
    calib = {"P2": [float(v) for v in proj], "R0_rect": np.eye(3), "Tr_velo_to_cam": velo_to_cam}
    (tmp_path / "calib.txt").write_text(_calib_text(calib))
    with np.errstate(divide="ignore"):
        z = np.where(frame.disp > 0, frame.focal * KITTI_BASELINE / frame.disp, 0).astype(np.float32)
    lidar_x = np.where(z > 0, z - velodyne_sim.VELO_TO_CAM_T[2], 0).astype(np.float32)
    rows = _score(tmp_path, {"lidar_x": lidar_x, "camera_z": z})
    points, abs_rel, _, a1 = _cells(rows["lidar_x.npy"])
    assert int(points) > 10_000 and float(abs_rel) < 0.012 and float(a1) > 0.99, rows
    assert float(rows["camera_z.npy"]["abs_rel"]) > 0.025, rows
    assert float(rows["oracle constant (median GT depth)"]["abs_rel"]) > 0.3, rows


def test_score_lidar_on_the_real_kitti_sample(tmp_path: Path) -> None:
    """The shared real object-benchmark pair's scan and calib.txt (skipped where absent): its 17,815
    points within 80 m in the 375 x 1242 image; the map equal to them scores 0, half of it 0.5."""
    if not REAL.is_dir():
        pytest.skip("../shared/real-samples is not available")
    from msdepth.studies.real_samples import lidar_gt

    gt = lidar_gt(REAL / "lidar.bin", REAL / "calib.txt", (375, 1242))
    (tmp_path / "scan.bin").symlink_to(REAL / "lidar.bin")
    (tmp_path / "calib.txt").symlink_to(REAL / "calib.txt")
    rows = _score(tmp_path, {"exact": gt, "half": gt / 2})
    assert _cells(rows["exact.npy"]) == ("17815", "0.000", "0.00", "1.000")
    points, abs_rel, _, a1 = _cells(rows["half.npy"])
    assert (points, abs_rel, a1) == ("17815", "0.500", "0.000")


def _bad_input(case: str, exact: np.ndarray) -> list[str]:
    """The arguments of ``case``, its files made in the current folder (which holds the hand-made
    rig and ``exact.npy``)."""
    argv = ["--scan", "scan.bin", "--calib", "calib.txt", "exact.npy"]
    if case == "raw calibration":
        Path("calib.txt").write_text("calib_time: 09-Jan-2012\nP_rect_02: " + "1 " * 12 + "\n")
    elif case == "missing depth map":
        argv.append("missing.npy")  # after a good one: every map is checked before any row
    elif case == "text as depth map":
        Path("notes.npy").write_text("not an array\n")
        argv.append("notes.npy")
    elif case == "3-D depth map":
        np.save("cube.npy", exact[..., None])
        argv.append("cube.npy")
    elif case == "empty scan":
        Path("scan.bin").write_bytes(b"")  # a scan of no point
    elif case == "missing scan":
        argv[1] = "gone.bin"
    else:
        argv += ["--cap", "0"]
    return argv


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("raw calibration", "calib.txt: not an object-benchmark calib.txt: needs P2 (12 values), R0_rect"),
        ("missing depth map", "missing.npy: not a readable .npy depth map"),
        ("text as depth map", "notes.npy: not a readable .npy depth map"),
        ("3-D depth map", "cube.npy: a depth map must be a 2-D array of depths (m), got float32 (4, 6, 1)"),
        ("empty scan", "scan.bin: no LiDAR point lands in the 4x6 image of exact.npy within (0.001, 80) m"),
        ("missing scan", "gone.bin: no such Velodyne scan file"),
        ("zero cap", "--cap: must be a depth (m) above 0.001, got 0.0"),
    ],
)
def test_score_lidar_refuses_a_bad_input_in_one_line(
    case: str, expected: str, tmp_path: Path, monkeypatch, capsys
) -> None:
    """A raw day's calibration (no P2, R0_rect, Tr_velo_to_cam), a depth map that is missing, not
    an .npy or not 2-D, a scan with no point in the image, a missing scan, a cap of 0: one
    ``error:`` line naming the file or argument, exit 1, nothing on stdout (each once ended in an
    unexpected KeyError, FileNotFoundError, ValueError or an empty median's warnings)."""
    monkeypatch.chdir(tmp_path)
    _, _, exact = _rig(tmp_path)
    np.save("exact.npy", exact)
    argv = _bad_input(case, exact)
    study = _study("score_lidar")
    _one_error_line(
        run_main("studies/score_lidar.py", lambda: study.main(argv)), capsys.readouterr(), expected
    )
