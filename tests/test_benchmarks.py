"""The benchmark scripts still run (tiny sizes, one repeat): CI does not time them, but a broken
benchmark would only be found when a GPU session needs it."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import run_script

ROOT = Path(__file__).resolve().parents[1]


def _script(path: Path, *args: str, cwd: Path) -> str:
    """Run the Python script ``path`` in ``cwd`` with this tree's msdepth; its stdout (it must succeed)."""
    proc = run_script(path, *args, cwd=cwd, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def _run(script: str, *args: str) -> str:
    """``benchmarks/<script>`` from the repository root."""
    return _script(ROOT / "benchmarks" / script, *args, cwd=ROOT)


def _study(script: str, *args: str, cwd: Path) -> str:
    """``studies/<script>`` in the project folder ``cwd`` (a tiny generated set)."""
    return _script(ROOT / "studies" / script, *args, cwd=cwd)


def test_loss_benchmark_prints_the_ratios_to_pytorch_msssim() -> None:
    pytest.importorskip("pytorch_msssim")
    # 176 px: pytorch-msssim's 5-level Gaussian-11 MS-SSIM needs more than 160.
    out = _run(
        "loss.py", "--batch", "1", "--height", "176", "--width", "176", "--repeats", "1", "--threads", "1"
    )
    assert "| ours MS-SSIM box k3 L4 |" in out and "| pytorch-msssim ms_ssim |" in out
    assert "pytorch-msssim / ours (training config, box k3 L4):" in out


# A tiny network on tiny images: the benchmarks' code paths in seconds.
TINY = "--height 32 --width 96 --width-multiplier 0.0625".split()


@pytest.mark.slow
def test_train_step_benchmark_with_the_speed_switches() -> None:
    switches = "--kernels 3,11 --repeats 1 --amp bf16 --channels-last --profile 1".split()
    out = _run("train_step.py", "--batch", "1", *TINY, *switches)
    assert "amp bf16, channels_last True" in out
    # the profile table, GPU columns empty on a CPU
    assert "| MS-SSIM k11 |" in out.split("GPU busy share")[1]
    for name in ("SSIM k3", "MS-SSIM k3", "MS-SSIM k11"):
        assert f"| {name} |" in out
    assert "images/s:" in out


def test_train_step_benchmark_loss_only() -> None:
    out = _run("train_step.py", "--batch", "1", *TINY, *"--kernels 11 --repeats 1 --loss-only".split())
    assert out.startswith("loss forward+backward only, batch 1x3x32x96")
    assert "| MS-SSIM k11 |" in out


@pytest.mark.slow
def test_train_loop_benchmark() -> None:
    loop = "--pairs 4 --epochs 1 --repeats 1 --warmup 0 --sync 2".split()
    out = _run("train_loop.py", "--batch", "2", *TINY, *loop)
    assert out.startswith("training loop, 4 pairs x 1 epochs, batch 2x3x32x96")
    for name in ("ssim sync 1", "ssim sync 2", "msssim sync 1", "msssim sync 2"):
        assert f"| {name} |" in out
    assert "images/s: ssim sync 1 " in out


@pytest.mark.slow
def test_parallel_trainings_benchmark_times_both_ways() -> None:
    """The trainings one after the other and side by side, each in its own process, and the
    throughput of the latter as the inverse of their per-round ratio."""
    sizes = "--pairs 4 --epochs 1 --repeats 1 --batch 2".split()
    out = _run("parallel_trainings.py", *TINY, *sizes)
    assert out.startswith("trainings of ssim, msssim: 4 pairs x 1 epochs each")
    rows = {line.split("|")[1].strip(): line for line in out.splitlines() if line.startswith("| ")}
    assert any(name.startswith("one after the other, ") for name in rows)
    ratio = float(rows["side by side, 1 thread each"].split("|")[3])
    throughput = float(out.rsplit("one after the other: ", 1)[1].split("x")[0])
    assert ratio > 0 and throughput == pytest.approx(1 / ratio, rel=0.01)


def test_ratios_are_paired_within_rounds() -> None:
    """Each round's candidate is divided by the same round's baseline, so drift between rounds
    (here the baseline slows down 8x) does not enter the ratio; the IQR shows the rest."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        from _timing import Timings, table
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    timings = Timings({"base": [1.0, 2.0, 4.0, 8.0], "cand": [1.1, 2.4, 4.4, 8.8]})
    mid, low, high = timings.ratio("cand", "base")
    assert mid == pytest.approx(1.1) and low == pytest.approx(1.1) and high == pytest.approx(1.125)
    assert timings.ratio("base", "base") == (1.0, 1.0, 1.0)
    assert "| cand | 3400.00 | 1.100 | 1.100-1.125 |" in table(timings, "base")
    assert "| cand | 3400.00 | 1.100 | 1.100-1.125 | 1.1 |" in table(timings, "base", anchor="base")


def test_train_step_benchmark_by_network() -> None:
    out = _run("train_step.py", "--batch", "1", *TINY, "--repeats", "1", "--networks")
    assert out.startswith("SSIM training step by network, batch 1x3x32x96")
    for name in ("norm none, heads independent", "norm group, heads residual"):
        assert f"| {name} |" in out


def test_recipes_benchmark_times_each_recipe_against_the_default() -> None:
    tiny = ("data.height=64", "data.width=64", "model.width_multiplier=0.0625", "train.batch_size=2")
    out = _run("recipes.py", "--repeats", "1", *(f"--set={kv}" for kv in tiny))
    assert out.startswith("training step, 64x64, model x0.0625")
    for name in ("default", "full resolution loss", "resnet18", "batch 1"):
        assert f"| {name} |" in out
    assert "time per image / default's: default 1.00, full resolution loss" in out


def test_cpu_bytes_benchmark_hashes_each_settings_weights_in_a_fresh_process() -> None:
    """Two rounds at one thread count train the same bytes (the hash agrees, "same bytes: yes"),
    with and without a setting. Whether MKL_CBWR changes them depends on the CPU (not on an AMD
    EPYC's training path; on an Intel Xeon's it is), so only each row's own agreement is asserted."""
    out = _run("cpu_bytes.py", "--pairs", "8", "--threads", "1", "--repeats", "2",
               "--settings", "none,MKL_CBWR=COMPATIBLE")  # fmt: skip
    rows = {line.split(" | ")[0][2:]: line for line in out.splitlines() if line.startswith("| ")}
    assert rows["none"].endswith("| yes |") and rows["MKL_CBWR=COMPATIBLE"].endswith("| yes |")
    for name in ("none", "MKL_CBWR=COMPATIBLE"):
        digest = rows[name].split(" | ")[1].split(",")[0]
        assert len(digest) == 12 and int(digest, 16) >= 0, name


# The studies' tests' tiny size, as --set overrides; 8 evaluation frames give the ROI classes 3
# boxes or more.
TINY_STUDY = {
    "data.height": "32",
    "data.width": "96",
    "data.synthetic.seed": "3",
    "data.synthetic.drives": "1",
    "data.synthetic.train_pairs": "8",
    "data.synthetic.eval_frames": "8",
    "data.synthetic.height": "48",
    "data.synthetic.width": "160",
    "model.width_multiplier": "0.0625",
    "train.epochs": "2",
    "train.batch_size": "4",
    "train.seeds": "[0]",
    "msssim.levels": "3",
}


@pytest.fixture(scope="module")
def study_set(tmp_path_factory) -> Path:
    """A tiny project folder from studies/prepare_set.py: params, rendered set, index, ROIs, cache
    (what `dvc repro cache rois` leaves, the studies' input)."""
    work = tmp_path_factory.mktemp("study")
    _study("prepare_set.py", "--out", str(work), *(f"--set={k}={v}" for k, v in TINY_STUDY.items()), cwd=work)
    for made in (
        "params.yaml",
        "data/index/eval_frames.csv",
        "data/index/rois.csv",
        "data/cache/train_pairs.npy",
    ):
        assert (work / made).is_file(), made
    return work


@pytest.mark.slow
def test_learning_study_smoke(study_set: Path, tmp_path: Path) -> None:
    """studies/learning.py end to end on a tiny generated set: trains, evaluates per epoch, summarises."""
    shutil.copytree(study_set, tmp_path, dirs_exist_ok=True)
    stdout = _study(
        "learning.py",
        "--variants",
        "ssim",
        "msssim:5",
        "--seeds",
        "0",
        "--out",
        "out",
        "--jobs",
        "1",
        cwd=tmp_path,
    )
    assert "| msssim:5 | 0 |" in stdout and "| ssim | 1 |" in stdout
    import json

    run = json.loads((tmp_path / "out" / "msssim_k5_seed0.json").read_text())
    assert [h["epoch"] for h in run["history"]] == [1, 2] and 0 <= run["history"][0]["variation_ratio"]
    # Goal 3's measure per epoch and in the summary: each class's ROI abs_rel beside the constant's.
    assert set(run["history"][-1]["roi_by_class"]) == set(run["roi_by_class"])
    assert "ROI abs_rel per class" in stdout and "| constant |" in stdout
    assert (tmp_path / "out" / "curves.png").stat().st_size > 0


@pytest.mark.slow
def test_objects_gpu_script_runs_tiny_on_the_cpu_without_matplotlib_or_dvclive(tmp_path: Path) -> None:
    """studies/objects_gpu.sh, the prepared GPU run for issue 17's goal 3, at the tiny size on the
    CPU, with matplotlib and dvclive made unimportable as on the GPU machine's image."""
    blocked = tmp_path / "blocked"
    for name in ("matplotlib", "dvclive"):
        (blocked / name).mkdir(parents=True)
        (blocked / name / "__init__.py").write_text(f"raise ImportError('{name} is not installed here')\n")
    tiny = TINY_STUDY
    # The script's own variables carry these; the rest of the tiny size goes through EXTRA.
    own = {"data.synthetic.height", "data.synthetic.width", "data.height", "data.width"}
    own |= {"model.width_multiplier", "data.synthetic.train_pairs", "train.epochs"}
    env = dict(
        os.environ,
        PYTHONPATH=str(blocked),
        OUT=str(tmp_path / "out"),
        WORK=str(tmp_path / "work"),
        DEVICE="cpu",
        RENDER=f"{tiny['data.synthetic.height']}x{tiny['data.synthetic.width']}",
        INPUT=f"{tiny['data.height']}x{tiny['data.width']}",
        WIDTH=tiny["model.width_multiplier"],
        EPOCHS="1",
        PAIRS=tiny["data.synthetic.train_pairs"],
        VARIANTS="ssim",
        EXTRA=" ".join(f"{k}={v}" for k, v in tiny.items() if k not in own),
    )
    proc = subprocess.run(
        ["bash", str(ROOT / "studies" / "objects_gpu.sh")],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert "ROI abs_rel per class" in proc.stdout and "| constant |" in proc.stdout
    assert (tmp_path / "out" / "ssim_seed0.json").is_file()
    trained = yaml.safe_load((tmp_path / "work" / "params.yaml").read_text())["train"]
    assert (trained["learning_rate"], trained["schedule"]) == (3.0e-4, "cosine")  # the screen's best recipe
    assert "no curves.png" in proc.stderr and not (tmp_path / "out" / "curves.png").exists()


def test_optimum_benchmark_prints_every_path_beside_the_previous_implementation() -> None:
    """Per size and variant: the constant start (the baseline), the cost start alone, the cost and
    sgbm paths and SGBM alone (the anchor column), and the default path's line."""
    tiny = ("--iterations", "1", "--repeats", "1", "--warmup", "0", "--threads", "1")
    out = _run("optimum.py", "--sizes", "32x64", "48x96", *tiny)
    assert out.startswith("optimum: constant start 3 levels x 1 steps, matched starts 2 levels x 1 steps")
    for size in ("32 x 64", "48 x 96"):
        section = out.split(f"{size}: seconds per pair")[1].split("seconds per pair (true")[0]
        for name in ("SSIM k3", "MS-SSIM k3", "MS-SSIM k11"):
            head = f"| time / {name} constant | IQR of the ratio | time / SGBM alone |"
            table = section.split(head)[1].split("\n\n")[0]
            rows = [line.split(" | ")[0] for line in table.splitlines() if line.startswith("| ")]
            paths = ("constant", "cost start", "cost", "sgbm")
            assert rows == [f"| {name} {path}" for path in paths] + ["| SGBM alone"], table
            assert f"{name}, the default path (cost): " in table


def test_optimum_benchmark_selects_paths_and_variants() -> None:
    """--paths and --variants time only those rows (and the anchor); the ratios are to the first."""
    tiny = ("--iterations", "1", "--repeats", "1", "--warmup", "0", "--threads", "1")
    out = _run("optimum.py", "--sizes", "32x64", "--paths", "sgbm", "--variants", "msssim:5", *tiny)
    rows = [line.split(" | ")[0] for line in out.splitlines() if line.startswith("| ")]
    assert rows == ["| candidate", "| MS-SSIM k5 sgbm", "| SGBM alone"]
    assert "time / MS-SSIM k5 sgbm |" in out and "default path" not in out


def test_monocular_study_scores_stereo_runs_median_scaled(study_set: Path, tmp_path: Path, monkeypatch):
    """studies/monocular.py's stereo rows median-scaled as the monocular runs are: a run at twice
    the GT and one at half of it both score 0 after scaling, with scale ratios 0.5 and 2."""
    from msdepth.data.eval_index import read_eval_index
    from msdepth.evaluation.suites import load_frames
    from msdepth.io import save_npz

    shutil.copytree(study_set, tmp_path, dirs_exist_ok=True)
    monkeypatch.chdir(tmp_path)
    frames = load_frames(read_eval_index(Path("data/index/eval_frames.csv")))
    for run, factor in (("ssim/seed0", 2.0), ("msssim/seed0", 0.5)):
        save_npz(tmp_path / "outputs" / run / "depth.npz", **{f.name: factor * f.gt_depth for f in frames})
    monkeypatch.chdir(ROOT)  # the study moves into the project and back
    monkeypatch.syspath_prepend(str(ROOT / "studies"))
    import monocular

    params = {"variants": ["ssim", "msssim"], "train": {"seeds": [0]}}
    rows = monocular.scaled_stereo_rows(tmp_path, params, 80)
    assert [r[:3] for r in rows] == [["stereo, median-scaled", v, "0.0000"] for v in ("ssim", "msssim")]
    assert [r[9] for r in rows] == ["0.5000", "2.0000"] and Path.cwd() == ROOT
    assert {len(r) for r in rows} == {12}  # table.md's columns
    assert all(cell in ("0.0000", "–") for r in rows for cell in r[3:7])  # every ROI class exact too


def test_ab_reads_the_last_images_per_second_line() -> None:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        from ab import images_per_second, table
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    out = "x\nimages/s: old 1.0\n| t |\nimages/s: ssim sync 1 12.5, msssim sync 50 10.0\n"
    assert images_per_second(out) == {"ssim sync 1": 12.5, "msssim sync 50": 10.0}
    rows = table([({"a": 10.0}, {"a": 12.0}), ({"a": 10.0}, {"a": 8.0}), ({"a": 10.0}, {"a": 11.0})])
    assert "| a | 10.00 | 11.00 | 1.100 | 0.800-1.200 |" in rows


@pytest.mark.slow
@pytest.mark.skipif(not (ROOT / ".git").exists(), reason="needs the git checkout (a worktree of the base)")
def test_ab_benchmark_against_this_commit() -> None:
    loop = "--batch 2 --pairs 4 --epochs 1 --repeats 1 --warmup 0".split()
    out = _run("ab.py", "--base", "HEAD", "--rounds", "2", "--", "train_loop.py", *TINY, *loop)
    assert "round 2/2: base {'ssim sync 1'" in out
    assert "| msssim sync 50 |" in out and "this / base (median)" in out
    worktrees = subprocess.run(["git", "-C", str(ROOT), "worktree", "list"], capture_output=True, text=True)
    assert "msdepth-ab-" not in worktrees.stdout  # the base's worktree is removed


@pytest.mark.slow
def test_objects_study_smoke(study_set: Path, tmp_path: Path) -> None:
    """studies/objects.py end to end on a tiny generated set: trains past two marks, scores each
    (exact-mask classes, the car boxes' correlation with the prior, image dependence), writes the
    summary, curve and strip; --report redraws them from the run without training."""
    import json

    shutil.copytree(study_set, tmp_path, dirs_exist_ok=True)
    args = ("--out", "out", "--steps", "4", "--every", "2", "--threads", "1")
    stdout = _study("objects.py", *args, cwd=tmp_path)
    history = json.loads((tmp_path / "out" / "history.json").read_text())
    assert [h["step"] for h in history] == [2, 4]
    assert {"car_mask", "windshield_mask", "car_prior_corr", "variation_ratio"} <= set(history[-1])
    assert all(h["seconds_per_step"] > 0 for h in history)  # the recipe's step time, scoring excluded
    assert "| s/step |" in stdout and "| prior |" in stdout and "| 4 |" in stdout
    for name in ("curve.png", "strip.png", "summary.md", "work/disp_2.npy", "work/disp_4.npy"):
        assert (tmp_path / "out" / name).stat().st_size > 0, name
    before = (tmp_path / "out" / "work" / "model.pt").stat().st_mtime_ns
    assert "| 4 |" in _study("objects.py", *args, "--report", cwd=tmp_path)
    assert (tmp_path / "out" / "work" / "model.pt").stat().st_mtime_ns == before  # nothing trained
    table = _study("objects.py", "--table", "--out", str(tmp_path), cwd=tmp_path)
    # The mark nearest 1,200 steps and the last: here both the 4th step, so one row.
    assert table.count("| out |") == 1 and "| out | 4 |" in table
    # A crop-trained run (train.crop_scale 2): its own pair cache at twice the size, the final model
    # scored on the whole images and on crop-sized tiles.
    from msdepth.config.params import params_from_dict, read_params_file

    data = params_from_dict(read_params_file(tmp_path / "params.yaml")).data
    crop = ("--out", "crop", "--steps", "2", "--every", "2", "--threads", "1", "--set", "train.crop_scale=2")
    _study("objects.py", *crop, "--tiles", cwd=tmp_path)
    assert (tmp_path / "crop" / "work" / f"pairs_{2 * data.height}x{2 * data.width}.npy").stat().st_size > 0
    tiles = json.loads((tmp_path / "crop" / "tiles.json").read_text())
    assert set(tiles) == {"whole", "tiles"} and tiles["whole"] != tiles["tiles"]
    assert all(0 < t["abs_rel"] < 10 for t in tiles.values())


def test_set_jobs_benchmark_times_threads_against_processes(tmp_path: Path) -> None:
    """The lean default's five instruments over generated frames, one job of 2 threads against 2
    jobs of 1 thread, per frame, with their ratio."""
    (tmp_path / "p.yaml").write_text(
        "optimum:\n  iterations: 2\n  refine_iterations: 2\n  levels: 1\n  refine_levels: 1\n"
    )
    args = ["--frames", str(tmp_path / "none"), "--size", "48x160", "--threads", "2", "--copies", "1"]
    out = _run("set_jobs.py", *args, "--repeats", "1", "--params", str(tmp_path / "p.yaml"))
    assert out.startswith("4 frames (generated, x1), 5 instruments")
    rows = {line.split("|")[1].strip(): line.split("|") for line in out.splitlines() if line.startswith("| ")}
    assert float(rows["1 job x 2 threads"][3]) == 1.0 and float(rows["2 jobs x 1 thread"][2]) > 0


@pytest.mark.parametrize(
    "args, words",
    [
        (["--base=--orphan"], "error: --base: '--orphan' is not a git revision"),
        (["--base=-b"], "error: --base: '-b' is not a git revision"),
        (["--base", "HEAD", "--rounds", "0"], "error: --rounds: must be >= 1, got 0"),
        (["--base", "no-such-revision-xyz"], "error: --base no-such-revision-xyz: cannot check it out: "),
    ],
)
def test_ab_refuses_a_bad_base_or_rounds_in_one_line(args: list[str], words: str, capsys) -> None:
    """An option-looking --base is refused before git is called (git printed its 14-line usage); a
    revision git cannot check out is git's reason in one line."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        from ab import main
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    assert main([*args, "train_loop.py"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(words) and err.count("\n") == 1, err
