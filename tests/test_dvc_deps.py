"""dvc.yaml's code deps follow the imports: each stage lists exactly the files its script imports.

:mod:`msdepth.pipeline.dvcyaml` writes them (``python -m msdepth.pipeline.dvcyaml``); these tests check that
dvc.yaml is what it writes, and the import tracing itself on a toy package.
"""

from __future__ import annotations

import ast
import subprocess
from pathlib import Path

import pytest
import yaml
from conftest import dvc_status

from msdepth.errors import DataError
from msdepth.pipeline import paths as pipeline
from msdepth.pipeline.dvcyaml import COMMAND, TAGGED, _code_deps, _import_closure, _tagged_path, generate

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "msdepth"


def test_dvc_yaml_is_what_the_generator_writes():
    text = (ROOT / "dvc.yaml").read_text()
    if generate(ROOT) != text:
        pytest.fail(f"dvc.yaml's code deps differ from the stages' imports: run `{COMMAND}`", pytrace=False)


def test_no_package_module_imports_a_stage_script():
    """The stages call into the package, never the other way: a stage is one hop from dvc.yaml."""
    for path in (ROOT / "src").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            names += [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            assert not [n for n in names if n.split(".")[0] == "stages"], path
        assert "run_path(" not in path.read_text() and "spec_from_file_location(" not in path.read_text(), (
            path
        )


@pytest.fixture
def toy(tmp_path: Path) -> Path:
    """A package ``msdepth`` (under tmp_path/src) using every import form the closure must follow,
    a registry package that imports its modules by name, and a TYPE_CHECKING-only import."""
    files = {
        "stages/run.py": "import sys\nfrom msdepth.stages import job\nimport msdepth.plain\n",
        "src/msdepth/__init__.py": "",
        "src/msdepth/plain.py": "import os\nfrom . import plugins\n",
        "src/msdepth/plugins/__init__.py": "import importlib\nimportlib.import_module(__name__ + '.a')\n",
        "src/msdepth/plugins/a.py": "",
        "src/msdepth/plugins/b.py": "from ..errors import X\n",
        "src/msdepth/stages/__init__.py": "",
        "src/msdepth/stages/job.py": "from .. import errors\nfrom ..data.kitti import read\n"
        "def f():\n    from ..lazy import g\n    from . import helper\n",
        "src/msdepth/stages/helper.py": "from msdepth.data import pairs\n",
        "src/msdepth/errors.py": "",
        "src/msdepth/lazy.py": "from .data import *\nif TYPE_CHECKING:\n    from . import unused\n",
        "src/msdepth/data/__init__.py": "",
        "src/msdepth/data/kitti.py": "",
        "src/msdepth/data/pairs.py": "from . import kitti\n",
        "src/msdepth/data/unused.py": "",
        "src/msdepth/unused.py": "import msdepth_other\n",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    return tmp_path


def test_closure_follows_relative_absolute_and_function_level_imports(toy: Path):
    closure = _import_closure(toy / "stages" / "run.py", toy / "src")
    found = sorted(p.relative_to(toy / "src" / "msdepth").as_posix() for p in closure)
    assert found == [
        "__init__.py",
        "data/__init__.py",
        "data/kitti.py",
        "data/pairs.py",
        "errors.py",
        "lazy.py",
        "plain.py",
        "plugins/__init__.py",
        "plugins/a.py",
        "plugins/b.py",
        "stages/__init__.py",
        "stages/helper.py",
        "stages/job.py",
    ]


TOY_YAML = """\
# header comment
stages:
  run:  # the stage
    matrix:
      x: [1, 2]
    cmd: python stages/run.py ${item.x}
    deps:  # code first
      - stages/run.py
      - src/msdepth/unused.py
      # data below
      - data/in.txt  # kept
    outs:
      - out.txt
      - old/place.csv:  # = EVAL_FRAMES
          cache: false

  fresh:
    cmd: python stages/run.py
    outs:
      - src/not_a_dep.txt
"""


def test_generator_rewrites_only_the_code_deps(toy: Path):
    """The code deps at the head of each deps list become the closure (a package folder whose every
    module is imported listed as the folder); comments and every other line keep their bytes; a
    stage without deps gets them after its cmd."""
    (toy / "dvc.yaml").write_text(TOY_YAML)
    code = [
        "stages/run.py",
        "src/msdepth/__init__.py",
        "src/msdepth/data/__init__.py",
        "src/msdepth/data/kitti.py",
        "src/msdepth/data/pairs.py",
        "src/msdepth/errors.py",
        "src/msdepth/lazy.py",
        "src/msdepth/plain.py",
        "src/msdepth/plugins",
        "src/msdepth/stages",
    ]
    assert _code_deps(toy, "stages/run.py") == code
    listed = "".join(f"      - {c}\n" for c in code)
    expected = (
        TOY_YAML.replace("      - stages/run.py\n      - src/msdepth/unused.py\n", listed)
        .replace("    cmd: python stages/run.py\n", "    cmd: python stages/run.py\n    deps:\n" + listed)
        .replace("old/place.csv:", "data/index/eval_frames.csv:")
    )
    assert generate(toy) == expected
    (toy / "dvc.yaml").write_text(expected)
    assert generate(toy) == expected  # a fixed point


def test_tagged_paths_come_from_the_pipeline_module():
    assert _tagged_path("EVAL_FRAMES") == "data/index/eval_frames.csv"
    assert _tagged_path("model_path(RUN)") == "models/${item.variant}/seed${item.seed}/model.pt"
    assert _tagged_path('run_dir("constant") / "x.npy"') == "outputs/constant/x.npy"
    assert _tagged_path("disparities_path(optimum_run(VARIANT, WEIGHT))") == (
        "outputs/optimum/${item.variant}/w${item.weight}/disparities.npy"
    )
    assert _tagged_path('suite_path("full", "prior", ".csv", set_metrics_dir(SET))') == (
        "metrics/sets/${item.set}/full/prior.csv"
    )
    for bad, message in [
        ("__import__('os')", "is not a name or path function"),
        ("pipeline.log", "is not a name or path function"),
        ("SUITE_NAMES", "is not a path"),
        ("model_path(", "was never closed"),
    ]:
        with pytest.raises(DataError, match=message):
            _tagged_path(bad)


def test_every_file_the_pipeline_module_defines_is_written_into_dvc_yaml():
    """Each path constant and path function of msdepth.pipeline.paths names a file that dvc.yaml tracks:
    its copies there are tagged `# = NAME`, so that they are written from the one definition (every
    name of a tag counts: ``suite_path("full", RUN, ".csv", set_metrics_dir(SET))`` uses two)."""
    tags = {
        node.id
        for line in (ROOT / "dvc.yaml").read_text().splitlines()
        if (m := TAGGED.match(line + "\n"))
        for node in ast.walk(ast.parse(m.group(5), mode="eval"))
        if isinstance(node, ast.Name)
    }
    not_tracked = {  # folders of outs; a file in an out folder; resume state; untracked timings; hand-written
        *("INDEX_DIR", "MODELS", "METRICS", "HEADLINE", "SETS_HEADLINE", "PLOTS", "run_dir", "mean_path"),
        *("CHECKPOINTS", "checkpoint_path", "TRAIN_LOGS", "train_timing_path", "README"),
    }
    defined = {
        name
        for name, value in vars(pipeline).items()
        if not name.startswith("_")
        and (
            isinstance(value, Path)
            or (callable(value) and getattr(value, "__annotations__", {}).get("return") in (Path, "Path"))
        )
    }
    assert defined - not_tracked - tags == set() and "model_path" in tags


def test_generator_refuses_a_code_dep_after_the_data_deps(toy: Path):
    (toy / "dvc.yaml").write_text(
        TOY_YAML.replace("      - data/in.txt  # kept\n", "      - data/in.txt\n      - src/x.py\n")
    )
    with pytest.raises(DataError, match="stage run: code dep src/x.py follows other deps"):
        generate(toy)


def test_the_command_checks_and_writes(toy: Path, capsys):
    from msdepth.pipeline.dvcyaml import main

    (toy / "dvc.yaml").write_text(TOY_YAML)
    assert main(["--root", str(toy), "--check"]) == 1
    assert f"generated parts out of date (run, fresh): run `{COMMAND}`" in capsys.readouterr().err
    assert (toy / "dvc.yaml").read_text() == TOY_YAML
    assert main(["--root", str(toy)]) == 0 and main(["--root", str(toy), "--check"]) == 0
    assert (toy / "dvc.yaml").read_text() == generate(toy)


def test_figures_and_evaluation_code_are_no_training_dep():
    """Redrawing a figure or changing a metric must never retrain (or re-infer) a model."""
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    later = ("src/msdepth/reporting", "src/msdepth/evaluation/suites.py", "src/msdepth/evaluation/metrics.py")
    later += ("src/msdepth/evaluation/baselines.py",)
    for name in ("train", "infer"):
        assert not [d for d in stages[name]["deps"] if d.startswith(later)], name


def test_reading_params_depends_on_no_loss_code():
    """The variants' configs are apart from their terms, so a change to the loss code (e.g. the
    MS-SSIM kernels) re-runs only the stages that train or build a model, not every stage."""
    closure = {
        p.relative_to(ROOT / "src" / PACKAGE).as_posix()
        for p in _import_closure(ROOT / "stages" / "validate_params.py", ROOT / "src")
    }
    assert "config/variants/ssim.py" in closure and "config/params.py" in closure
    assert not {f for f in closure if f.startswith(("losses/", "geometry/", "networks/"))}


def test_a_stage_that_reads_the_data_through_an_index_depends_on_the_data():
    """An index names paths, not contents: without ``${data.root}`` a re-render left cost_curves and
    optimum with the previous data's results (issue 40: the s_min that "flipped" on a rerun)."""
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    indexes = ("data/index/eval_frames.csv", "data/index/sets", "data/index/train_pairs.txt")
    readers = [
        name
        for name, stage in stages.items()
        if any(dep in indexes or dep.startswith("data/index/sets/") for dep in stage.get("deps", []))
    ]  # a set stage reads its own set's index, data/index/sets/<set>.csv
    assert {"infer", "cost_curves", "optimum", "eval_set"} <= set(readers)
    assert [name for name in readers if "${data.root}" not in stages[name]["deps"]] == []


def _covers(path: str, paths: set[str]) -> bool:
    """Whether ``path`` is one of ``paths``, lies under one, or holds one (a folder dep)."""
    path = path.rstrip("/")
    return any(p == path or p.startswith(path + "/") or path.startswith(p + "/") for p in paths)


def stale_entries(status: dict, tracked: set[str], outs: set[str]) -> list[str]:
    """The stale lock entries in ``dvc status --json``'s ``status``: a changed param, or a changed dep
    that git tracks (code, split lists) and no stage writes (``outs``). A dep that is another stage's
    output is the pipeline's own (metrics/ is committed, and retrained on another CPU it holds other
    bytes), and one that is simply not built here ("deleted") is not stale either."""
    stale = []
    for stage, changes in status.items():
        for change in changes:
            deps = change.get("changed deps", {}) if isinstance(change, dict) else {}
            for path, state in deps.items():
                if isinstance(state, dict):  # params.yaml's keys
                    stale.append(f"{stage}: {path} {state}")
                elif state != "deleted" and _covers(path, tracked) and not _covers(path, outs):
                    stale.append(f"{stage}: {path} {state}")
    return stale


def stale_lock_entries(root: Path) -> list[str]:
    """Why ``root``'s dvc.lock is not the one `dvc repro` would commit (empty if it is): a locked dep
    that git tracks and no stage writes, or a locked param whose current value differs from the lock."""
    listed = subprocess.run(["git", "ls-files"], cwd=root, capture_output=True, text=True, check=True)
    stages = (yaml.safe_load((root / "dvc.lock").read_text()) or {}).get("stages", {})
    outs = {out["path"] for stage in stages.values() for out in stage.get("outs", [])}
    return stale_entries(dvc_status(root), set(listed.stdout.split()), outs)


def test_a_retrained_output_under_git_is_not_a_stale_lock():
    """Issue 53: `dvc repro` on another CPU writes other bytes into committed outputs (metrics/); a
    stage reading them is the pipeline's business, only code and params make the lock stale."""
    tracked = {"src/msdepth/losses/ssim.py", "data_lists/eigen.txt", "metrics/train/ssim/seed0.json"}
    outs = {"metrics/train/ssim/seed0.json", "models/ssim/seed0/model.pt"}
    status = {
        "compare": [{"changed deps": {"metrics/train": "modified"}}, {"changed outs": {"x": "modified"}}],
        "infer@ssim-0": [{"changed deps": {"models/ssim/seed0/model.pt": "modified"}}],
        "train@ssim-0": [{"changed outs": {"models/ssim/seed0/model.pt": "modified"}}, "always changed"],
        "index": [{"changed deps": {"data_lists": "deleted"}}],
    }
    assert stale_entries(status, tracked, outs) == []
    status["train@ssim-0"].append({"changed deps": {"src/msdepth/losses": "modified"}})
    status["index"].append({"changed deps": {"params.yaml": {"data.height": "modified"}}})
    assert stale_entries(status, tracked, outs) == [
        "train@ssim-0: src/msdepth/losses modified",
        "index: params.yaml {'data.height': 'modified'}",
    ]


@pytest.mark.skipif(not (ROOT / ".git").exists(), reason="needs the git checkout (tracked files)")
def test_dvc_lock_is_current_with_the_tracked_code_and_params():
    """A fresh clone's `dvc repro` leaves git clean only if dvc.lock holds today's code and params:
    a code edit without a relock would rerun every stage importing it and rewrite dvc.lock."""
    stale = stale_lock_entries(ROOT)
    if stale:
        pytest.fail(
            "dvc.lock is stale (relock with `dvc repro`, which must reproduce the locked outputs):\n  "
            + "\n  ".join(stale[:20]),
            pytrace=False,
        )


def test_no_stage_depends_on_a_studys_file() -> None:
    """Every row of the verdict is the pipeline's own: no stage reads what only a study writes
    (issues 54 and 55), so `dvc repro` reproduces every output from params, code and data."""
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    found = [
        f"{name}: {dep}"
        for name, stage in stages.items()
        for dep in stage.get("deps", [])
        if str(dep).startswith("studies/")
    ]
    assert found == []
