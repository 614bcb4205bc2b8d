"""The stage scripts' command lines: ``--help`` runs nothing, bad arguments are a usage error."""

from __future__ import annotations

import runpy
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import python_env, run_script, stage

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(
    {stage["cmd"].split()[1] for stage in yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"].values()}
)


@pytest.mark.parametrize("script", SCRIPTS)
def test_help_prints_usage_and_runs_nothing(script: str, tmp_path: Path, monkeypatch, capsys):
    """In this process (the imports are paid once), where there is no params.yaml: a stage that
    ran would fail, or write, there."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", [script, "--help"])
    with pytest.raises(SystemExit) as exit_:
        runpy.run_path(str(ROOT / script), run_name="__main__")
    assert exit_.value.code == 0
    out, err = capsys.readouterr()
    assert out.startswith(f"usage: {script} [-h]") and err == ""
    assert list(tmp_path.iterdir()) == []


def test_help_from_the_command_line(tmp_path: Path):
    proc = run_script("stages/train.py", "--help", cwd=tmp_path)
    assert proc.returncode == 0 and proc.stdout.startswith("usage: stages/train.py [-h] VARIANT SEED")
    assert list(tmp_path.iterdir()) == []


def test_usage_errors_exit_2_before_reading_params(tmp_path: Path, monkeypatch, capsys):
    from msdepth.pipeline.paths import run_stage

    figures, train = stage("figures").figures, stage("train").train

    monkeypatch.chdir(tmp_path)
    assert run_stage(train, "ssim") == 2
    assert "error: the following arguments are required: SEED" in capsys.readouterr().err
    assert run_stage(figures, "extra") == 2
    assert "unrecognized arguments: extra" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_prepare_data_dry_run_of_the_synthetic_set_writes_nothing(tmp_path: Path):
    (tmp_path / "params.yaml").write_text("data: {source: synthetic}\n")
    proc = run_script("stages/prepare_data.py", "--dry-run", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("dry run: would render the synthetic set under data/synthetic: 12 drive(s)")
    assert [p.name for p in tmp_path.iterdir()] == ["params.yaml"]


def test_reading_params_imports_neither_torch_nor_numpy(tmp_path: Path):
    """Every stage reads its params: the loss variants' configs come without their terms."""
    # mix has no per-pixel cost: optimum.start cost (the default) would refuse it.
    (tmp_path / "params.yaml").write_text("variants: [ssim, msssim, mix]\noptimum: {start: sgbm}\n")
    code = (
        "import sys; from msdepth.pipeline.paths import load_params; p = load_params('params.yaml'); "
        "heavy = [m for m in ('torch', 'numpy', 'msdepth.losses.appearance') if m in sys.modules]; "
        "print(sorted(p.appearance), heavy)"
    )
    env = python_env()
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == "['mix', 'msssim', 'ssim'] []\n"


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ("msssim: {kernel_size: 4}", "msssim.kernel_size: must be a positive odd integer, got 4"),
        ("train: {learning_rate: fast}", "train.learning_rate: expected a number, got 'fast'"),
        ("trian: {epochs: 3}", "unknown parameter(s) ['trian']"),
        ("train: {epcohs: 3}", "unknown parameter(s) ['train.epcohs']"),
        (
            "ssim: {kernel_size: 9}",
            "ssim.kernel_size: 9 px windows do not fit the coarsest training scale (8x24 px) "
            "with valid padding",
        ),
        ("mix: {alfa: 0.5}", "unknown parameter(s) ['mix.alfa']"),
    ],
)
def test_validate_params_rejects_a_bad_value_or_unknown_key_in_one_line(
    tmp_path: Path, monkeypatch, capsys, params: str, message: str
):
    from msdepth.pipeline.paths import run_stage

    CHECKED, validate_params = stage("validate_params").CHECKED, stage("validate_params").validate_params

    monkeypatch.chdir(tmp_path)
    (tmp_path / "params.yaml").write_text(params + "\n")
    assert run_stage(validate_params) == 1
    assert capsys.readouterr().err == f"error: params.yaml: {message}\n"
    assert [p.name for p in tmp_path.iterdir()] == ["params.yaml"]
    (tmp_path / "params.yaml").write_text("msssim: {kernel_size: 5}\n")
    assert run_stage(validate_params) == 0
    written = CHECKED.read_bytes()
    (tmp_path / "params.yaml").write_text("msssim: {kernel_size: 7}\ntrain: {seeds: [4]}\n")
    assert run_stage(validate_params) == 0 and CHECKED.read_bytes() == written  # whatever the params


def test_a_stage_first_removes_the_temps_a_killed_stage_left_in_the_output_folders(
    tmp_path: Path, monkeypatch
) -> None:
    # Item 12: a stage killed mid-write (kill -9) left e.g. models/<run>/.model.pt.<random>.pt for good.
    from msdepth.pipeline.paths import run_stage

    monkeypatch.chdir(tmp_path)
    (tmp_path / "params.yaml").write_bytes((ROOT / "params.yaml").read_bytes())
    stale = [
        "models/ssim/seed0/.model.pt.msdepth-tmp-k1ll3d_9.pt",
        "checkpoints/ssim/seed0/.checkpoint.pt.msdepth-tmp-abcd1234.pt",
        "metrics/full/ssim/.seed0.json.msdepth-tmp-abcd1234.json",
        "data/cache/.train_pairs.npy.msdepth-tmp-abcd1234.npy",
    ]
    kept = [
        "models/ssim/seed0/.model.pt.k1ll3d_9.pt",  # a name without the mark: not the project's
        "metrics/full/ssim/.seed0.json.msdepth-tmp-abcd1234.json.orig",
        "data/kitti/.x.png.msdepth-tmp-abcd1234.png",  # the data roots are the renderer's and downloader's
    ]
    for name in stale + kept:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("x")
    assert run_stage(stage("validate_params").validate_params) == 0
    assert [name for name in stale + kept if (tmp_path / name).exists()] == kept
