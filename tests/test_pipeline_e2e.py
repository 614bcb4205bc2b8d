"""End to end: `dvc repro` of the real dvc.yaml with tiny params, then a kernel-size experiment.

Runs the actual stage scripts through DVC in a temporary git repository, so it catches
breakage in the wiring (deps, params, outs, foreach) as well as in the code.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from conftest import UP_TO_DATE, dvc_status, merge, project, require_dvc, run_checked, stage_env
from test_dvc_deps import behaviour_edit, neutral_edit

from msdepth.reporting.figures import STAGE_FIGURES

ROOT = Path(__file__).resolve().parents[1]
# The tests here run DVC on copied projects: the second tier (`-m slow`).
pytestmark = pytest.mark.slow

# The copied projects run with conftest.TINY: 2 epochs, two optimum weights (SWEEP), 3 frames.
SWEEP = ("1.0", "10.0")
OPTIMUM_RUNS = [f"optimum/{v}/w{w}" for v in ("ssim", "msssim") for w in SWEEP]


@pytest.fixture(scope="module")
def repo(tmp_path_factory) -> Path:
    require_dvc()
    work = project(tmp_path_factory.mktemp("pipeline"))
    run_checked([sys.executable, "-m", "dvc", "repro", "--quiet"], work)
    return work


RUNS = ("ssim/seed0", "msssim/seed0", "constant", "prior")


def test_repro_writes_every_suite_and_the_comparison(repo: Path):
    for suite in ("full", "roi", "gradients"):
        for run in RUNS:
            data = json.loads((repo / "metrics" / suite / f"{run}.json").read_text())
            assert "cap80" in data and "cap50" in data
            assert (repo / "metrics" / suite / f"{run}.csv").stat().st_size > 0
    full = json.loads((repo / "metrics" / "full" / "ssim" / "seed0.json").read_text())
    assert 0 < full["cap80"]["abs_rel"] < 10
    md = (repo / "metrics" / "compare.md").read_text()
    assert "| ssim |" in md
    # The Eigen split on the rendered scans: every run and baseline, after KITTI 2015's tables.
    for run in RUNS:
        eigen = json.loads((repo / "metrics" / "sets" / "eigen" / "full" / f"{run}.json").read_text())
        assert eigen["images"] == 3 and 0 < eigen["cap80"]["abs_rel"] < 10 and "cap50" in eigen
        assert "abs_rel" in json.loads(
            (repo / "metrics" / "headline" / "sets" / "eigen" / "full" / f"{run}.json").read_text()
        )
    assert md.index("# Eigen split") > md.index("## Full image, cap 80 m")
    index = (repo / "data" / "index" / "sets" / "eigen.csv").read_text()
    assert index.count(",velodyne,") == 3 and ",garg," in index
    compare = json.loads((repo / "metrics" / "compare.json").read_text())
    # The extra set's rows: the networks, the baselines and the network-free instruments (no network).
    instruments = {"SGM (ssim cost)", "SGM (msssim cost)", "SGBM", "optimum ssim w10", "optimum msssim w10"}
    rows = {"ssim", "msssim", "constant", "prior", *instruments}
    assert set(compare["sets"]["eigen"]["full"]["cap80"]) == rows
    assert set(compare["full"]["cap80"]) == {"ssim", "msssim", "constant", "prior"}
    assert (
        compare["seeds"] == [0] and compare["statistics"]["full"]["cap80"]["msssim"]["abs_rel"]["seeds"] == 1
    )
    assert (repo / "plots" / "train" / "ssim" / "seed0").is_dir()
    # Timings are kept apart from the tracked summary: a rerun elsewhere changes only them.
    summary = json.loads((repo / "metrics" / "train" / "ssim" / "seed0.json").read_text())
    timing = json.loads((repo / "logs" / "train" / "ssim" / "seed0.json").read_text())
    assert "seconds" not in summary and "resumed_from_epoch" not in summary and summary["steps"] == 8
    assert timing["seconds"] > 0 and timing["resumed_from_epoch"] == 0
    _check_optimum(repo, md, compare)
    figures = sorted(p.name for p in (repo / "plots" / "figures").iterdir())
    assert figures == sorted(STAGE_FIGURES)
    # `dvc plots show` writes a page that needs nothing from the internet.
    run_checked([sys.executable, "-m", "dvc", "plots", "show", "-o", "plots_html"], repo)
    page = (repo / "plots_html" / "index.html").read_text()
    assert "http://" not in page and "https://" not in page and page.count("<img") == len(figures)
    assert dvc_status(repo) == UP_TO_DATE


def _check_optimum(repo: Path, md: str, compare: dict) -> None:
    """The optimum stages: every variant and weight scored by every suite (the default weight on
    every frame, the others on optimum.sweep_frames), the compare section and the cost curves."""
    for run in OPTIMUM_RUNS:
        for suite in ("full", "roi", "gradients"):
            assert (repo / "metrics" / suite / f"{run}.csv").stat().st_size > 0, (suite, run)
        full = json.loads((repo / "metrics" / "full" / f"{run}.json").read_text())
        assert full["images"] == (3 if run.endswith("w10.0") else 2) and 0 < full["cap80"]["abs_rel"] < 10
        assert (repo / "outputs" / run / "depth.npz").is_file()
    section = md[md.index("# The losses' own optimum (no network)") :]
    assert "| optimum msssim w1 | 2 |" in section and "| optimum ssim w10 | 3 |" in section
    # The trained runs (labelled e.g. "ssim (image-blind)") and the baselines: every frame.
    assert re.search(r"^\| ssim[^|]* \| 3 \|", section, re.M) and "| prior | 3 |" in section
    assert "interval covers the choice of images" in section and "ROI abs rel per class" in section
    diff = compare["optimum"]["differences"]
    assert (
        set(diff) == {"optimum ssim w10", "optimum msssim w10", *MATCHERS}
        and diff["optimum ssim w10"]["full"]["abs_rel"]["n"] == 3
    )
    _check_matchers(repo, section, diff)
    for variant in ("ssim", "msssim"):
        curves = json.loads((repo / "metrics" / "cost_curves" / f"{variant}.json").read_text())
        assert len(curves["scales"]) == 25 and curves["classes"], variant
        for cls, summary in curves["classes"].items():
            assert summary["basin_low"] <= summary["s_min"] <= summary["basin_high"], cls
            assert len(curves["mean_curves"][cls]) == 25


MATCHERS = {"SGM (ssim cost)": "optimum/match/ssim", "SGM (msssim cost)": "optimum/match/msssim",
            "SGBM": "optimum/sgbm"}  # fmt: skip


def _check_matchers(repo: Path, section: str, diff: dict) -> None:
    """The match and sgbm stages: metrics only (no outputs), every frame, D1 and EPE in the full
    suite (the optimum's and the trained runs' too), the rows and their differences in compare.md."""
    for label, run in MATCHERS.items():
        full = json.loads((repo / "metrics" / "full" / f"{run}.json").read_text())
        assert full["images"] == 3 and 0 <= full["cap80"]["d1"] <= 1 and full["cap80"]["epe"] >= 0, run
        assert (repo / "metrics" / "roi" / f"{run}.csv").stat().st_size > 0
        assert not (repo / "outputs" / run).exists()
        assert re.search(
            rf"^\| {re.escape(label)} \| 3 \| [0-9.]+ \| [0-9.]+ \| [0-9.]+ \| [0-9.]+ \|", section, re.M
        )
        assert diff[label]["full"]["abs_rel"]["n"] == 3
    for run in ("ssim/seed0", OPTIMUM_RUNS[0]):
        assert "d1" in json.loads((repo / "metrics" / "full" / f"{run}.json").read_text())["cap80"], run


def test_push_and_pull_through_a_local_dvc_remote(repo: Path, tmp_path: Path):
    """Share the trained models and outputs: `dvc push` to a directory remote, clone, `dvc pull`,
    and `dvc repro` in the clone redoes only the cheap uncached stages, not the training."""
    dvc = [sys.executable, "-m", "dvc"]
    run_checked([*dvc, "remote", "add", "-d", "shared", str(tmp_path / "remote")], repo)
    run_checked([*dvc, "push", "--quiet"], repo)
    run_checked(["git", "add", "-A"], repo)
    run_checked(["git", "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-qm", "results"], repo)
    clone = tmp_path / "clone"
    run_checked(["git", "clone", "-q", str(repo), str(clone)], tmp_path)
    run_checked([*dvc, "pull", "--quiet"], clone)
    for out in (
        "models/ssim/seed0/model.pt",
        "models/msssim/seed0/model.pt",
        "outputs/msssim/seed0/depth.npz",
    ):
        assert (clone / out).read_bytes() == (repo / out).read_bytes(), out
    log = run_checked([*dvc, "repro"], clone)
    assert "Running stage 'train@" not in log and "Running stage 'infer@" not in log
    for suite in ("full", "roi", "gradients"):
        name = Path("metrics") / suite / "msssim" / "seed0.json"
        assert (clone / name).read_text() == (repo / name).read_text()


def test_killed_repro_reruns_to_identical_results(repo: Path, tmp_path: Path):
    """SIGKILL `dvc repro` (and its stage) mid-training; the next `dvc repro` completes and
    every metric equals the uninterrupted run's."""
    work = project(tmp_path)
    env = stage_env(work)
    proc = subprocess.Popen(
        [sys.executable, "-m", "dvc", "repro", "--quiet"],
        cwd=work,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    checkpoint = work / "checkpoints" / "ssim" / "seed0" / "checkpoint.pt"
    deadline = time.monotonic() + 300
    while not checkpoint.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, "the pipeline finished before it could be interrupted"
    os.killpg(proc.pid, signal.SIGKILL)  # dvc and the running stage, as a power cut would
    proc.wait()
    assert not (work / "metrics" / "compare.json").exists()
    run_checked([sys.executable, "-m", "dvc", "repro", "--quiet"], work)
    for suite in ("full", "roi", "gradients"):
        for run in RUNS:
            name = Path("metrics") / suite / f"{run}.json"
            assert (work / name).read_text() == (repo / name).read_text(), name
    # The training curves too: DVC deleted them before rerunning the stage, which resumed.
    for run in RUNS[:2]:
        curves = Path("plots") / "train" / run / "plots" / "metrics" / "train"
        for tsv in ("total.tsv", "appearance.tsv", "learning_rate.tsv"):
            assert (work / curves / tsv).read_text() == (repo / curves / tsv).read_text(), curves / tsv
    # Another checkout of the same commit and params: every file git would track and every hash
    # DVC records (the rendered data tree's included) equal, so its `git status` is clean.
    assert (work / "dvc.lock").read_text() == (repo / "dvc.lock").read_text()
    for folder in ("metrics", "plots", "data/index"):
        for path in sorted((repo / folder).rglob("*")):
            if path.is_file():
                rel = path.relative_to(repo)
                assert (work / rel).read_bytes() == path.read_bytes(), rel


# What `-S msssim.kernel_size=7` re-runs: the parameter check (it reads all of params.yaml; its
# output's bytes stay the same), the fingerprints and pretrained stages (they run every time; their
# outputs stay the same too), the MS-SSIM run's stages and the optimum's, and what compares them.
MSSSIM_STAGES = {
    "fingerprints",
    "validate_params",
    "pretrained",
    *(
        f"{stage}@msssim-0"
        for stage in ("train", "infer", "depth", "eval_full", "eval_roi", "eval_gradients")
    ),
    "eval_set@eigen-msssim-0",
    *(f"optimum@msssim-{w}" for w in SWEEP),
    "cost_curves@msssim",
    "match@msssim",  # SGM on its cost volume (SGBM's stage reads no variant's section)
    "match_set@eigen-msssim",  # the same instruments on the extra set
    "optimum_set@eigen-msssim-10.0",
    "compare",
    "report",
    "figures",
}


def test_kernel_size_experiment_reruns_only_msssim_then_the_way_back_and_applying_it(
    repo: Path, tmp_path: Path
):
    """docs/user-guide.md "Experiments": `dvc exp run -S msssim.kernel_size=7` runs exactly the
    MS-SSIM variant's stages (no SSIM run, no data stage, no baseline), the workspace then holds
    the experiment and compare.md names its kernel; the README's way back returns to the committed
    results on the CPU that made them, training nothing (`dvc status` up to date), and `dvc exp
    apply` brings the experiment back."""
    work = tmp_path / "exp"
    shutil.copytree(repo, work, symlinks=True)
    dvc = [sys.executable, "-m", "dvc"]
    for key, value in (("user.email", "t@t"), ("user.name", "t")):
        run_checked(["git", "config", key, value], work)
    run_checked(["git", "add", "-A"], work)
    run_checked(
        ["git", "commit", "-qm", "results", "--allow-empty"], work
    )  # an earlier test may have committed
    models = {run: work / "models" / run / "model.pt" for run in ("ssim/seed0", "msssim/seed0")}
    committed = {run: path.read_bytes() for run, path in models.items()}
    ssim_full = work / "metrics" / "full" / "ssim" / "seed0.json"
    ssim_metrics = ssim_full.read_text()
    compare = work / "metrics" / "compare.md"
    committed_json = json.loads((work / "metrics" / "compare.json").read_text())
    # TINY's msssim.levels is 3, not the default 4: the row names it beside the kernel.
    assert "| msssim (levels=3) |" in compare.read_text() and "k=7" not in compare.read_text()
    log = run_checked([*dvc, "exp", "run", "-n", "k7", "-S", "msssim.kernel_size=7"], work)
    ran = {line.split("'")[1] for line in log.splitlines() if line.startswith("Running stage '")}
    assert ran == MSSSIM_STAGES, sorted(ran ^ MSSSIM_STAGES)
    experiment = models["msssim/seed0"].read_bytes()
    assert experiment != committed["msssim/seed0"]
    assert models["ssim/seed0"].read_bytes() == committed["ssim/seed0"]
    assert ssim_full.read_text() == ssim_metrics
    md = compare.read_text().splitlines()
    assert any(
        line.startswith("Settings: ssim k=3, padding=valid; msssim k=7, levels=3, weights=wang")
        for line in md
    )
    assert sum(line.startswith("| msssim (k=7, levels=3) |") for line in md) >= 4  # KITTI and Eigen tables
    assert not any(line.startswith("| msssim |") for line in md)
    new_json = json.loads((work / "metrics" / "compare.json").read_text())
    assert new_json["settings"]["msssim"] == {"kernel_size": 7, "levels": 3, "weights": "wang"}
    # The README's `dvc metrics diff` line: only the means, and MS-SSIM's is compare.json's change.
    diff = [*dvc, "metrics", "diff", "--json", "--targets", "metrics/headline/mean"]
    means = json.loads(run_checked(diff, work))  # {file: {key: {old, new, diff}}}
    assert set(means) == {"metrics/headline/mean/msssim.json"}, means  # SSIM's mean unchanged
    change = means["metrics/headline/mean/msssim.json"]["abs_rel"]
    old, new = (c["full"]["cap80"]["msssim"]["abs_rel"] for c in (committed_json, new_json))
    assert (change["old"], change["new"]) == (old, new) and change["diff"] == pytest.approx(new - old)
    assert "k7" in run_checked([*dvc, "exp", "show", "--md", "--only-changed"], work)

    log = run_checked(["bash", "-c", _readme_command("git checkout HEAD")], work)
    assert "Running stage 'train@" not in log and "Running stage 'optimum@" not in log, log
    assert {run: path.read_bytes() for run, path in models.items()} == committed
    assert "k=7" not in compare.read_text()
    assert run_checked(["git", "status", "--porcelain"], work) == ""
    assert dvc_status(work) == UP_TO_DATE

    run_checked([*dvc, "exp", "apply", "k7"], work)
    assert models["msssim/seed0"].read_bytes() == experiment
    assert yaml.safe_load((work / "params.yaml").read_text())["msssim"]["kernel_size"] == 7


def test_a_comment_in_io_reruns_nothing_and_a_changed_constant_every_stage(repo: Path, tmp_path: Path):
    """Issue 67: stages depend on their code's fingerprint. A comment, a docstring and blank lines in
    src/msdepth/io.py, which every stage imports, leave `dvc status` up to date once the fingerprints
    stage has run (`dvc repro` runs it first; `dvc status` alone does not run it), and dvc.lock as it
    was; a changed constant in one of its functions marks every stage, the trained ones included,
    for its fingerprint only."""
    work = _copy(repo, tmp_path)
    io, lock = work / "src" / "msdepth" / "io.py", (work / "dvc.lock").read_text()
    neutral_edit(io)
    log = run_checked([sys.executable, "-m", "dvc", "repro"], work)
    ran = {line.split("'")[1] for line in log.splitlines() if line.startswith("Running stage '")}
    assert ran == set(UP_TO_DATE) and dvc_status(work) == UP_TO_DATE
    assert (work / "dvc.lock").read_text() == lock
    behaviour_edit(io)
    assert dvc_status(work) == UP_TO_DATE  # the fingerprints on disk are still the old code's
    run_checked([sys.executable, "-m", "dvc", "repro", "fingerprints"], work)
    status = dvc_status(work)
    stages = set(yaml.safe_load(lock)["stages"]) - {"fingerprints"}
    assert set(status) == stages | {"fingerprints"} and {"train@ssim-0", "train@msssim-0"} <= stages
    for stage in stages:
        changes = [c for c in status[stage] if c != "always changed"]
        assert [set(c) for c in changes] == [{"changed deps"}], (stage, changes)
        assert [path.startswith("data/fingerprints/") for path in changes[0]["changed deps"]] == [True], stage


def _readme_command(start: str) -> str:
    """The line of a README.md ```bash block that starts with ``start``, without its comment."""
    blocks = re.findall(r"```bash\n(.*?)```", (ROOT / "README.md").read_text(encoding="utf-8"), re.DOTALL)
    lines = [line for block in blocks for line in block.splitlines() if line.startswith(start)]
    assert len(lines) == 1, f"README.md: {len(lines)} commands start with {start!r}"
    return re.sub(r"\s+#.*$", "", lines[0])


def _commit_another_cpus_run(work: Path) -> str:
    """Commit ``work``'s results as if trained on another CPU: the committed dvc.lock names
    models whose bytes were never in this cache (each train stage's model hash, wherever the lock
    lists it, replaced by one of no file). The workspace keeps the lock of the run made here, as
    after README command 1 in a clone on another CPU; that lock's text is returned."""
    lock = work / "dvc.lock"
    mine = foreign = lock.read_text()
    for name, stage in yaml.safe_load(mine)["stages"].items():
        for out in stage["outs"] if name.startswith("train@") else []:
            if out["path"].startswith("models/"):
                other = hashlib.md5(f"another CPU's {out['md5']}".encode()).hexdigest()
                foreign = foreign.replace(out["md5"], other)
    assert foreign != mine
    lock.write_text(foreign)
    run_checked(["git", "add", "-A"], work)
    run_checked(["git", "commit", "-qm", "results trained on another CPU"], work)
    lock.write_text(mine)
    return mine


def test_the_readme_experiment_and_way_back_on_another_cpu(repo: Path, tmp_path: Path):
    """README "Usage" in a clone whose CPU trains other bytes than the committed run: the
    experiment and the way back, run as the README writes them, exit 0; the way back retrains
    the runs whose committed models this cache lacks (`dvc checkout` alone fails there, and DVC's
    run cache does not hold a stage with `cache: false` outs), leaving this CPU's own results of
    the committed params, as command 1 did, and a model for the README's `msdepth predict`."""
    work = _copy(repo, tmp_path)
    for key, value in (("user.email", "t@t"), ("user.name", "t")):
        run_checked(["git", "config", key, value], work)
    mine = _commit_another_cpus_run(work)
    model = work / "models" / "msssim" / "seed0" / "model.pt"
    own = model.read_bytes()
    run_checked(["bash", "-c", _readme_command("dvc exp run -S msssim.kernel_size=7")], work)
    assert model.read_bytes() != own
    log = run_checked(["bash", "-c", _readme_command("git checkout HEAD")], work)
    assert "Running stage 'train@msssim-0'" in log, log
    assert model.read_bytes() == own  # the same CPU and params train the same bytes
    assert (work / "dvc.lock").read_text() == mine
    assert run_checked(["git", "status", "--porcelain"], work) == " M dvc.lock\n"
    image = work / "data" / "synthetic" / "kitti2015" / "training" / "image_2" / "000000_10.png"
    predict = _readme_command("msdepth predict").replace("INPUT", str(image))
    predict = predict.replace("DIR", str(tmp_path / "out"))
    run_checked(["bash", "-c", f"python -m {predict}"], work)
    assert (tmp_path / "out" / "000000_10_disp.png").is_file()


def test_dvc_metrics_show_lists_the_headline_numbers_and_fits_a_terminal(repo: Path):
    shown = json.loads(run_checked([sys.executable, "-m", "dvc", "metrics", "show", "--json"], repo))
    files = {path for rev in shown.values() for path in rev.get("data", {})}
    assert files == {f"metrics/headline/{suite}/{run}.json" for suite in ("full", "roi") for run in RUNS} | {
        f"metrics/headline/sets/eigen/full/{run}.json" for run in RUNS
    } | {
        f"metrics/headline/{suite}/{run}.json"
        for suite in ("full", "roi")
        for run in [*OPTIMUM_RUNS, *MATCHERS.values()]
    } | {f"metrics/headline/mean/{variant}.json" for variant in ("ssim", "msssim")}
    table = run_checked([sys.executable, "-m", "dvc", "metrics", "show"], repo)
    assert max(map(len, table.splitlines())) <= 132, table  # tests/test_metrics_show.py: WIDEST
    mean = json.loads((repo / "metrics" / "headline" / "mean" / "ssim.json").read_text())
    # The three frames hold windshields and cars: their classes' columns.
    assert set(mean) == {"abs_rel", "a1", "roi", "masks", "windshield", "car"}
    full = json.loads((repo / "metrics" / "headline" / "full" / "ssim" / "seed0.json").read_text())
    assert set(full) == {"abs_rel", "a1"}
    roi = json.loads((repo / "metrics" / "headline" / "roi" / "ssim" / "seed0.json").read_text())
    assert set(roi) == {"roi", "masks"}  # the synthetic set has class maps


def _copy(repo: Path, tmp_path: Path) -> Path:
    """A copy of the module's project (its DVC cache included) to change without undoing it after."""
    work = tmp_path / "work"
    shutil.copytree(repo, work, symlinks=True)
    return work


def _workspace(repo: Path) -> dict[str, bytes]:
    """Every file of the workspace but DVC's and git's own, with its bytes."""
    return {
        p.relative_to(repo).as_posix(): p.read_bytes()
        for p in sorted(repo.rglob("*"))
        if p.is_file() and p.relative_to(repo).parts[0] not in (".git", ".dvc")
    }


@pytest.mark.parametrize(
    ("patch", "message"),
    [
        ({"msssim": {"kernel_size": 4}}, "msssim.kernel_size: must be a positive odd integer, got 4"),
        ({"trian": {"epochs": 3}}, "unknown parameter(s) ['trian']"),  # test_stages.py: more of each
    ],
)
def test_bad_params_fail_dvc_repro_first_and_delete_nothing(repo: Path, patch: dict, message: str):
    """DVC removes a stage's outputs just before running it: validate_params runs first (after
    fingerprints, which reads no params and removes nothing) and stops `dvc repro` with one line, so
    the trained models and tracked results stay as they were."""
    good = (repo / "params.yaml").read_text()
    before, git_before = _workspace(repo), run_checked(["git", "status", "--porcelain"], repo)
    (repo / "params.yaml").write_text(yaml.safe_dump(merge(yaml.safe_load(good), patch), sort_keys=False))
    env = stage_env(repo)
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "dvc", "repro"], cwd=repo, env=env, capture_output=True, text=True
        )
        after, git_after = _workspace(repo), run_checked(["git", "status", "--porcelain"], repo)
    finally:
        (repo / "params.yaml").write_text(good)
    assert proc.returncode != 0
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error: ")]
    assert errors == [f"error: params.yaml: {message}"], proc.stderr
    ran = [line.split("'")[1] for line in proc.stdout.splitlines() if line.startswith("Running stage '")]
    assert ran == ["fingerprints", "validate_params"], proc.stdout
    changed = {name for name in before.keys() | after.keys() if before.get(name) != after.get(name)}
    assert changed == {"params.yaml"}
    assert set(git_after.splitlines()) - set(git_before.splitlines()) <= {" M params.yaml"}
    assert dvc_status(repo) == UP_TO_DATE


def test_more_seeds_train_only_the_new_runs_and_widen_the_comparison(repo: Path, tmp_path: Path):
    repo = _copy(repo, tmp_path)  # the module's project stays at one seed for the tests that follow
    params = yaml.safe_load((repo / "params.yaml").read_text())
    params["train"]["seeds"] = [0, 1]
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    changed = set(json.loads(run_checked([sys.executable, "-m", "dvc", "status", "--json"], repo)))
    assert {"train@ssim-1", "train@msssim-1", "compare", "figures"} <= changed
    assert not any(stage.endswith("-0") for stage in changed), changed  # seed 0's runs stand
    before = (repo / "metrics" / "full" / "ssim" / "seed0.json").read_text()
    run_checked([sys.executable, "-m", "dvc", "repro", "--quiet"], repo)
    assert (repo / "metrics" / "full" / "ssim" / "seed0.json").read_text() == before
    seed1 = json.loads((repo / "metrics" / "full" / "ssim" / "seed1.json").read_text())
    assert seed1 != json.loads(before)  # another seed, another run
    compare = json.loads((repo / "metrics" / "compare.json").read_text())
    assert compare["seeds"] == [0, 1]
    d = compare["statistics"]["full"]["cap80"]["msssim"]["abs_rel"]
    assert (d["seeds"], d["reference_seeds"]) == (2, 2)
    assert set(compare["seed_spread"]["full"]["cap80"]["ssim"]["abs_rel"]["runs"]) == {
        "ssim/seed0",
        "ssim/seed1",
    }
    assert "Seed-to-seed spread" in (repo / "metrics" / "compare.md").read_text()


def test_a_new_variant_in_variants_trains_only_its_runs_and_joins_the_comparison(repo: Path, tmp_path: Path):
    """docs/design.md "Loss variants": listing a registered variant (Zhao et al.'s mix) in `variants` is
    all `dvc repro` needs (and, mix having no per-pixel cost, an optimum.start other than cost); the
    trained runs that exist stand, the new one is evaluated and compared."""
    repo = _copy(repo, tmp_path)  # the module's project keeps its two variants
    params = yaml.safe_load((repo / "params.yaml").read_text())
    params["variants"] = ["ssim", "msssim", "mix"]
    params["mix"]["levels"] = 3  # the tiny input's coarsest training scale is 4 x 12 px
    params["optimum"]["start"] = "sgbm"  # mix has no per-pixel cost to start from (the default: cost)
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    changed = set(json.loads(run_checked([sys.executable, "-m", "dvc", "status", "--json"], repo)))
    assert {"train@mix-0", "infer@mix-0", "compare"} <= changed
    # The new start re-runs the other variants' optimum (optimum.start is theirs too), nothing else.
    trained = [s for s in changed if ("@ssim" in s or "@msssim" in s) and not s.startswith("optimum@")]
    assert not trained and "match@mix" in changed, changed
    before = (repo / "metrics" / "full" / "msssim" / "seed0.json").read_text()
    run_checked([sys.executable, "-m", "dvc", "repro", "--quiet"], repo)
    assert (repo / "metrics" / "full" / "msssim" / "seed0.json").read_text() == before
    for suite in ("full", "roi", "gradients"):
        assert (repo / "metrics" / suite / "mix" / "seed0.json").is_file(), suite
    compare = json.loads((repo / "metrics" / "compare.json").read_text())
    assert "mix" in compare["statistics"]["full"]["cap80"]
    md = (repo / "metrics" / "compare.md").read_text()
    assert "mix" in md and "SGM (mix cost): skipped (variant mix has no per-pixel cost" in md
    assert "skipped" in json.loads((repo / "metrics" / "full" / "optimum" / "match" / "mix.json").read_text())


def test_train_stage_tracks_every_train_key_but_the_seeds():
    """The train stage lists train.* keys one by one (so that adding a seed keeps the other
    runs); a new TrainConfig field must be listed there too, or changing it would not retrain."""
    import dataclasses

    from msdepth.config.params import TrainConfig

    listed = {
        p
        for p in yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]["train"]["params"]
        if isinstance(p, str) and p.startswith("train.")
    }
    expected = {f"train.{f.name}" for f in dataclasses.fields(TrainConfig)} - {"train.seeds"}
    assert listed == expected


def test_torchrun_launcher_from_dvc_repro(repo: Path):
    """`train.launcher: torchrun` makes the train stage start 2 gloo ranks itself."""
    params = yaml.safe_load((repo / "params.yaml").read_text())
    params["train"].update(launcher="torchrun", nproc=2, batch_size=2)  # the same global batch of 4
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    env = stage_env(repo)
    proc = subprocess.run(
        [sys.executable, "-m", "dvc", "repro", "train@ssim-0"],
        cwd=repo,
        env=env,
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "2 ranks x batch 2 = global batch 4" in proc.stderr  # logged by rank 0 under torchrun
    summary = json.loads((repo / "metrics" / "train" / "ssim" / "seed0.json").read_text())
    assert summary["steps"] == 2 * 4  # 2 epochs of 16 pairs / global batch 4
    assert (
        run_checked([sys.executable, "-m", "dvc", "status", "train@ssim-0"], repo)
        .strip()
        .endswith("up to date.")
    )
