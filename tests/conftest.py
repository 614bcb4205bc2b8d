"""Fixtures and helpers shared by several test modules: tiny stereo pairs, the stage scripts, and
child processes: a script of this tree, or DVC in a copy of the project (the end-to-end tests)."""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import json
import os
import runpy
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import ModuleType, SimpleNamespace
from typing import Iterator

import numpy as np
import pytest
import yaml

from msdepth.io import write_png

ROOT = Path(__file__).resolve().parents[1]

# Size of the tiny training pairs: 32 x 64 keeps 3 MS-SSIM levels at the coarsest training scale.
PAIR_H, PAIR_W = 32, 64


@pytest.fixture(scope="session")
def pairs(tmp_path_factory) -> list[tuple[Path, Path]]:
    """Eight stereo pairs of PAIR_H x PAIR_W: a random texture and the same texture shifted by 2 px."""
    root = tmp_path_factory.mktemp("pairs")
    rng = np.random.default_rng(0)
    out = []
    for i in range(8):
        scene = rng.integers(0, 256, (PAIR_H, PAIR_W + 2, 3), dtype=np.uint8)
        left, right = root / f"l{i}.png", root / f"r{i}.png"
        write_png(left, scene[:, 2:])
        write_png(right, scene[:, :-2])
        out.append((left, right))
    return out


@functools.cache
def stage(name: str) -> SimpleNamespace:
    """The stage script ``stages/<name>.py`` loaded as a namespace (its ``__main__`` block not run):
    the scripts are not a package, and nothing in ``msdepth`` imports them."""
    return SimpleNamespace(**runpy.run_path(str(ROOT / "stages" / f"{name}.py")))


# ------------------------------------------------------------------- the committed state


def require_git_checkout(root: Path = ROOT) -> None:
    """Skip the calling test unless ``root`` is the top of a git checkout with a commit: the tests
    of what is committed read it from git's HEAD, not from a workspace a `dvc repro` may rewrite."""
    command = ["git", "-C", str(root), "rev-parse", "--show-toplevel", "HEAD"]
    proc = subprocess.run(command, capture_output=True)
    lines = proc.stdout.decode(errors="replace").splitlines()
    if proc.returncode != 0 or not lines or Path(lines[0]).resolve() != root.resolve():
        pytest.skip(f"{root} is not a git checkout with a commit (the committed files are read from git)")


def load_study(name: str) -> ModuleType:
    """studies/<name>.py as a module (the studies are scripts, not a package), its ``__main__`` block
    not run; a fresh module on every call."""
    spec = importlib.util.spec_from_file_location(f"study_{name}", ROOT / "studies" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def committed_file(root: Path, path: str) -> bytes | None:
    """The bytes of ``path`` (relative to ``root``, the top of a git checkout) in git's HEAD, or None
    where HEAD holds no such file: what a clone checks out, whatever a `dvc repro` rewrote since
    (on another CPU, the trained models' bytes and dvc.lock's hashes of them differ)."""
    proc = subprocess.run(["git", "-C", str(root), "show", f"HEAD:{path}"], capture_output=True)
    return proc.stdout if proc.returncode == 0 else None


# ------------------------------------------------------------------------- child processes


def python_env(src: Path = ROOT / "src", **extra: str) -> dict[str, str]:
    """This process's environment with ``src`` as PYTHONPATH (and ``extra``): a child Python
    imports that tree's msdepth, whatever an installed one points at."""
    return dict(os.environ, PYTHONPATH=str(src), **extra)


def run_script(
    script: str | Path, *args: str, cwd: Path, timeout: float = 120
) -> subprocess.CompletedProcess:
    """Run the Python script ``script`` (relative to the repository root, or absolute) in ``cwd``
    with this tree's msdepth; its exit status and output, whatever they are."""
    return subprocess.run(
        [sys.executable, str(ROOT / script), *args],
        cwd=cwd,
        env=python_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


# --------------------------------------------------------- a copy of the project, run by DVC

# Every copied project's params on top of params.yaml: the pipeline at a tiny size
# (test_pipeline_e2e.py, test_pipeline_folder.py, test_kitti_pipeline.py).
TINY = {
    "data": {
        "height": 32,
        "width": 96,
        "synthetic": {"drives": 2, "train_pairs": 16, "eval_frames": 3, "height": 48, "width": 160},
    },
    "model": {"width_multiplier": 0.0625},
    "train": {"epochs": 2, "batch_size": 4, "seeds": [0]},
    "msssim": {"levels": 3},
    # Two weights, the least a sweep may hold (a decade, holding smoothness_weight 10): each one
    # is a stage per variant. The first two frames' ROIs still give the car class its cost curve.
    "optimum": {
        "iterations": 3,
        "levels": 1,
        "refine_iterations": 3,  # the default start, cost: refined at the finest level only
        "refine_levels": 1,
        "sweep_frames": 2,
        "smoothness_sweep": [1.0, 10.0],
        "cost_frames": 2,
    },
}
# What a copy holds of this project: the pipeline, its code and lists, DVC's and git's settings.
PROJECT_FILES = ("dvc.yaml", "stages", "src", "data_lists", ".dvc", ".dvcignore", ".gitignore")


def save_tiny_model(path: Path) -> Path:
    """A randomly initialised MonodepthVGG(0.0625) (seed 0) saved at ``path`` as a model file for
    32 x 96 inputs: the CLI tests' model."""
    import torch

    from msdepth.networks.vgg import MonodepthVGG

    torch.manual_seed(0)
    state = {"model": MonodepthVGG(0.0625).eval().state_dict(), "criterion": {}, "width_multiplier": 0.0625}
    torch.save({**state, "height": 32, "width": 96, "variant": "tiny"}, path)
    return path


@contextlib.contextmanager
def unblocking(fifo: Path, after_s: float = 1.0) -> Iterator[None]:
    """Within the block, code blocked opening ``fifo`` to read it (waiting for a writer forever) is
    released after ``after_s`` seconds by a writer that opens and closes it, so that a test of a FIFO
    fails on its assertions rather than hanging; code that never blocks is left alone."""
    done = threading.Event()

    def release() -> None:
        if done.wait(after_s):
            return
        while not done.is_set():
            try:  # ENXIO while no reader has the FIFO open
                os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                time.sleep(0.05)

    thread = threading.Thread(target=release, daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()


def require_dvc() -> None:
    """Skip the calling test (or fixture) where DVC is not installed."""
    if shutil.which("dvc") is None and not (Path(sys.executable).parent / "dvc").exists():
        pytest.skip("dvc is not installed")


def merge(base: dict, patch: dict) -> dict:
    """``base`` with ``patch`` merged in, section by section (``base`` itself is changed)."""
    for k, v in patch.items():
        base[k] = merge(base.get(k, {}), v) if isinstance(v, dict) else v
    return base


def stage_env(project: Path) -> dict[str, str]:
    """The environment of DVC in a copied ``project``: its stages call ``python``, so this
    interpreter comes first on PATH, and they import the copy's own sources."""
    path = f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"
    return python_env(project / "src", PATH=path)


def run_checked(cmd: list[str], cwd: Path) -> str:
    """Run ``cmd`` in the copied project ``cwd`` (:func:`stage_env`); its stdout, the test failing
    with the output's tail unless it exits 0."""
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, env=stage_env(cwd))
    assert proc.returncode == 0, f"{' '.join(cmd)} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc.stdout


# `dvc status --json` of a pipeline that is up to date: the fingerprints stage parses the code and the
# pretrained stage hashes model.pretrained's file on every `dvc repro` (dvc.yaml: always_changed), so
# DVC always lists them.
UP_TO_DATE = {"fingerprints": ["always changed"], "pretrained": ["always changed"]}


def dvc_status(repo: Path) -> dict:
    """``dvc status --json`` in the copied project ``repo``."""
    return json.loads(run_checked([sys.executable, "-m", "dvc", "status", "--json"], repo))


def dvc(args: list[str], cwd: Path, ok: bool = True) -> subprocess.CompletedProcess:
    """``dvc <args>`` in the copied project ``cwd``; unless ``ok`` is False, the test fails
    with the output's tail unless it exits 0."""
    proc = subprocess.run(
        [sys.executable, "-m", "dvc", *args], cwd=cwd, capture_output=True, text=True, env=stage_env(cwd)
    )
    if ok:
        assert proc.returncode == 0, (
            f"dvc {' '.join(args)} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        )
    return proc


def project(work: Path, patch: dict | None = None, tiny: dict = TINY) -> Path:
    """A git repository at ``work`` holding a copy of this project's pipeline, its params.yaml
    with ``tiny`` and then ``patch`` merged in, all committed."""
    for name in PROJECT_FILES:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, work / name, ignore=shutil.ignore_patterns("__pycache__", "tmp", "cache"))
        else:
            (work / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(src, work / name)
    params = merge(merge(yaml.safe_load((ROOT / "params.yaml").read_text()), tiny), patch or {})
    (work / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    run_checked(["git", "init", "-q"], work)
    run_checked(["git", "add", "-A"], work)
    run_checked(["git", "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-qm", "init"], work)
    return work
