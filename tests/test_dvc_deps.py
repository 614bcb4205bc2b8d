"""dvc.yaml's code deps: each stage depends on its script's fingerprint, what its code does.

:mod:`msdepth.pipeline.fingerprints` writes the fingerprints (the import closure, each file's syntax
tree without docstrings) and :mod:`msdepth.pipeline.dvcyaml` dvc.yaml's deps on them
(``python -m msdepth.pipeline.dvcyaml``); these tests check that dvc.yaml is what it writes, the
import tracing on a toy package, and that a comment or a docstring changes no fingerprint while a
changed constant does.
"""

from __future__ import annotations

import ast
import hashlib
import os
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml
from conftest import dvc_status

from msdepth.errors import DataError
from msdepth.io import TEMP_MARK
from msdepth.pipeline import paths as pipeline
from msdepth.pipeline.dvcyaml import COMMAND, TAGGED, _code_deps, _tagged_path, generate
from msdepth.pipeline.fingerprints import (
    SCRIPT,
    Sources,
    canonical,
    fingerprint_path,
    fingerprint_text,
    import_closure,
    stage_scripts,
    write_fingerprints,
)

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "msdepth"


def test_dvc_yaml_is_what_the_generator_writes():
    text = (ROOT / "dvc.yaml").read_text()
    if generate(ROOT) != text:
        pytest.fail(f"dvc.yaml's generated parts are out of date: run `{COMMAND}`", pytrace=False)


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
    closure = import_closure(toy / "stages" / "run.py", toy / "src")
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


def neutral_edit(path: Path) -> None:
    """Edit ``path``'s comments, docstrings and layout, nothing it does: a docstring where there was
    none, then more words in it and in the first function's, a comment and blank lines."""
    text = path.read_text()
    tree = ast.parse(text)
    if not ast.get_docstring(tree):
        text = f'"""A new docstring."""\n{text}'
    lines = text.replace('"""', '"""Edited: ', 1).splitlines(keepends=True)
    function = next((n for n in ast.walk(ast.parse(text)) if isinstance(n, ast.FunctionDef)), None)
    if function is not None and ast.get_docstring(function):
        at = function.body[0].lineno - 1
        lines[at] = lines[at].replace('"""', '"""More words. ', 1)
    edited = "# a comment\n\n" + "".join(lines).replace("\n\n", "\n\n\n  # an indented comment\n\n", 1)
    assert ast.dump(ast.parse(edited)) != ast.dump(tree)  # the docstrings did change
    path.write_text(edited + "\n\n# the end\n")


def behaviour_edit(path: Path) -> str:
    """Change the first integer literal in a function of ``path`` (``n`` -> ``n + 1``, a change in what
    the code does); the edited line."""
    text = path.read_text()
    for function in (n for n in ast.walk(ast.parse(text)) if isinstance(n, ast.FunctionDef)):
        for node in ast.walk(function):
            if isinstance(node, ast.Constant) and type(node.value) is int and node.lineno == node.end_lineno:
                lines = text.splitlines(keepends=True)
                line = lines[node.lineno - 1].encode()  # the offsets count UTF-8 bytes
                line = line[: node.col_offset] + str(node.value + 1).encode() + line[node.end_col_offset :]
                lines[node.lineno - 1] = line.decode()
                path.write_text("".join(lines))
                return lines[node.lineno - 1]
    raise AssertionError(f"{path}: no integer literal in a function")


def test_canonical_trees_see_behaviour_not_comments_docstrings_or_layout():
    def same(a: str, b: str) -> bool:
        return canonical(ast.parse(a)) == canonical(ast.parse(b))

    code = 'def f(x: int = 2) -> int:\n    """Doc."""\n    y = x + 1  # one\n    return y\n'
    assert same(code, "def f(x:int=2)->int:\n    y=x+1\n\n    return (y)")
    assert same(code, code.replace('"""Doc."""', '"""Other."""\n    "an attribute docstring"'))
    assert same("x = 1.0", "x = 1.00") and same("x = 'a'", 'x = "a"')
    for other in ("x + 2", "x - 1", "x + 1.0", "z + 1"):  # a constant, an operator, a type, a name
        assert not same(code, code.replace("x + 1", other)), other
    assert not same(code, code.replace("x: int", "x: float"))  # a dataclass's fields are annotations
    assert not same("def f(): return 1", "def f(): f'{print()}'\n")  # an f-string runs code
    # No positions, no empty fields: the same text on Python 3.10 to 3.13 (3.12 added type_params=[]).
    expected = "Module(body=[FunctionDef(args=arguments(), body=[Pass()], name='f')])"
    assert canonical(ast.parse("def f(): pass")) == expected
    # f-strings as 3.12 (an empty string after a nested field) and 3.13 (a bare format spec) may parse them
    nested, bare, split = ast.parse("f'{x:{y}}'"), ast.parse("f'{x:.2f}'"), ast.parse("f'a{x}b'")
    nested.body[0].value.values[0].format_spec.values.append(ast.Constant(value=""))
    bare.body[0].value.values[0].format_spec = bare.body[0].value.values[0].format_spec.values[0]
    split.body[0].value.values[-1:] = [ast.Constant(value=""), ast.Constant(value="b")]
    for code, tree in [("f'{x:{y}}'", nested), ("f'{x:.2f}'", bare), ("f'a{x}b'", split)]:
        assert canonical(tree) == canonical(ast.parse(code)), code
    assert not same("f'{x:.2f}'", "f'{x:.3f}'") and not same("f'a{x}b'", "f'a{x}c'")


@pytest.fixture(scope="module")
def tree(tmp_path_factory) -> Path:
    """A copy of the project's stages/ and src/ and the fingerprints of every stage script in it."""
    root = tmp_path_factory.mktemp("tree")
    for name in ("stages", "src"):
        shutil.copytree(ROOT / name, root / name, ignore=shutil.ignore_patterns("__pycache__"))
    return root


def _fingerprints(root: Path) -> dict[str, str]:
    sources = Sources()
    return {script: fingerprint_text(root, script, sources) for script in stage_scripts(root)}


def test_a_comment_or_docstring_in_io_changes_no_fingerprint_and_a_constant_every_importers(tree: Path):
    """Issue 67: every stage imports msdepth.io; a comment, a docstring or a blank line there reruns
    none (the train stages included), a changed constant in one of its functions reruns every one."""
    io, before = tree / "src" / "msdepth" / "io.py", _fingerprints(tree)
    assert "stages/train.py" in before and all("\nsrc/msdepth/io.py " in t for t in before.values())
    original = io.read_text()
    neutral_edit(io)
    assert io.read_text() != original and _fingerprints(tree) == before
    behaviour_edit(io)
    after = _fingerprints(tree)
    assert [s for s in before if after[s] == before[s]] == []
    changed = {line for s in before for line in set(after[s].splitlines()) ^ set(before[s].splitlines())}
    assert {line.split()[0] for line in changed} == {"src/msdepth/io.py"}


def test_the_fingerprints_stage_rewrites_only_what_changed(toy: Path):
    """Each file's bytes change only with its stage's code, so DVC reruns only that stage; the file
    of a script that is gone is removed, and a killed write's temp file; no absolute path or time
    is written."""
    (toy / "stages" / "other.py").write_text("import msdepth.errors\n")
    (toy / "stages" / "fingerprints.py").write_text("import msdepth.plain\n")  # it has none
    assert write_fingerprints(toy) == ["data/fingerprints/other.txt", "data/fingerprints/run.txt"]
    folder = toy / pipeline.FINGERPRINTS
    text = (folder / "other.txt").read_text()
    assert text.splitlines()[2:] == [
        f"stages/other.py {Sources().hash(toy / 'stages' / 'other.py')}",
        f"src/msdepth/__init__.py {hashlib.sha256(b'Module()').hexdigest()}",
        f"src/msdepth/errors.py {hashlib.sha256(b'Module()').hexdigest()}",
    ]
    os.utime(folder / "run.txt", (0, 0))
    (folder / "gone.txt").write_text("")
    killed = folder / f".run.txt{TEMP_MARK}abcd1234.txt"  # a write killed before its rename
    killed.write_text("half")
    assert write_fingerprints(toy) == ["data/fingerprints/gone.txt"]
    assert (folder / "run.txt").stat().st_mtime == 0 and not (folder / "gone.txt").exists()
    assert not killed.exists()
    (toy / "src" / "msdepth" / "plain.py").write_text("import os\nfrom . import plugins\nos.sep\n")
    assert write_fingerprints(toy) == ["data/fingerprints/run.txt"]
    assert sorted(p.name for p in folder.iterdir()) == ["other.txt", "run.txt"]


def test_a_source_that_is_not_python_is_one_line_naming_it(toy: Path, capsys):
    from msdepth.pipeline.fingerprints import main

    (toy / "src" / "msdepth" / "lazy.py").write_text("def f(:\n")
    assert main(["--root", str(toy)]) == 1
    err = capsys.readouterr().err
    assert err == f"error: {toy}/src/msdepth/lazy.py: not valid Python (line 1: invalid syntax)\n"
    (toy / "src" / "msdepth" / "lazy.py").write_text("import msdepth.missing\n")
    assert main(["--root", str(toy)]) == 1
    assert "imports msdepth.missing, which has no file under" in capsys.readouterr().err
    assert not list((toy / pipeline.FINGERPRINTS).glob("*.txt"))


TOY_YAML = """\
# header comment
stages:
  fingerprints:
    cmd: python stages/fingerprints.py
    always_changed: true
    outs:
      - data/fingerprints

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
    """The code deps at the head of each deps list (source files, as dvc.yaml listed them before the
    fingerprints) become the script's fingerprint; comments and every other line keep their bytes; a
    stage without deps gets it after its cmd; the fingerprints stage gets none."""
    (toy / "dvc.yaml").write_text(TOY_YAML)
    assert (
        _code_deps("stages/run.py") == ["data/fingerprints/run.txt"] and _code_deps(SCRIPT.as_posix()) == []
    )
    listed = "      - data/fingerprints/run.txt\n"
    expected = (
        TOY_YAML.replace("      - stages/run.py\n      - src/msdepth/unused.py\n", listed)
        .replace("    cmd: python stages/run.py\n", "    cmd: python stages/run.py\n    deps:\n" + listed)
        .replace("old/place.csv:", "data/index/eval_frames.csv:")
    )
    assert generate(toy) == expected
    (toy / "dvc.yaml").write_text(expected)
    assert generate(toy) == expected  # a fixed point


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("    always_changed: true\n", ""), "stage fingerprints: needs 'always_changed: true' and no deps"),
        (
            ("    always_changed: true\n", "    always_changed: true\n    deps:\n      - src/msdepth\n"),
            "no deps",
        ),
        (("python stages/fingerprints.py", "python stages/run.py"), "0 stages run stages/fingerprints.py"),
        (("python stages/run.py ${item.x}", "python stages/sub/run.py"), "stages/sub/run.py: a stage script"),
    ],
)
def test_generator_refuses_a_fingerprints_stage_that_may_not_run(toy: Path, edit: tuple, message: str):
    """Without always_changed, DVC would run the fingerprints stage once and then trust stale
    fingerprints; with deps, their bytes would be back in dvc.lock."""
    (toy / "dvc.yaml").write_text(TOY_YAML.replace(*edit))
    with pytest.raises(DataError, match=message):
        generate(toy)


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
        "REAL_SETS_COMPARE",  # a study's committed result, read for the README only: no stage's dependency
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


def _closure(script: str) -> set[str]:
    """The files (relative to src/msdepth) that the stage script ``script`` imports."""
    src = ROOT / "src"
    return {p.relative_to(src / PACKAGE).as_posix() for p in import_closure(ROOT / script, src)}


def test_figures_and_evaluation_code_are_no_training_dep():
    """Redrawing a figure or changing a metric must never retrain (or re-infer) a model: the train
    and infer scripts' fingerprints hold no comparison, reporting or metric code."""
    later = (
        "analysis/",
        "reporting/",
        "evaluation/suites.py",
        "evaluation/metrics.py",
        "evaluation/baselines.py",
    )
    for script in ("stages/train.py", "stages/infer.py"):
        assert not [f for f in _closure(script) if f.startswith(later)], script


def test_reading_params_depends_on_no_loss_code():
    """The variants' configs are apart from their terms, so a change to the loss code (e.g. the
    MS-SSIM kernels) re-runs only the stages that train or build a model, not every stage."""
    closure = _closure("stages/validate_params.py")
    assert "config/variants/ssim.py" in closure and "config/params.py" in closure
    assert not {f for f in closure if f.startswith(("losses/", "geometry/", "networks/"))}


def test_every_stage_depends_on_its_scripts_fingerprint_first():
    """Each stage's first dep is the fingerprint of the script its cmd runs, and no stage lists a
    source file (whose bytes, comments included, would re-run it)."""
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    for name, stage in stages.items():
        script = stage["cmd"].split()[1]
        if script == SCRIPT.as_posix():
            assert stage["always_changed"] is True and "deps" not in stage
            continue
        assert stage["deps"][0] == fingerprint_path(script).as_posix(), name
        assert not [d for d in stage["deps"] if d.startswith(("src/", "stages/"))], name


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


def stale_fingerprints(root: Path, locked: dict) -> list[str]:
    """The stages of the dvc.lock entries ``locked`` whose locked fingerprint is not the one their
    code gives today. `dvc status` cannot tell: it compares the fingerprint files on disk, which
    only the fingerprints stage refreshes, so each is computed here from the sources."""
    stages = yaml.safe_load((root / "dvc.yaml").read_text())["stages"]
    scripts = {name: stage["cmd"].split()[1] for name, stage in stages.items()}
    sources, md5s, stale = Sources(), {}, []
    for stage, entry in locked.items():
        script = scripts.get(stage.split("@")[0])
        if script in (None, SCRIPT.as_posix()):
            continue  # a stage no longer in dvc.yaml: dvc status names it
        if script not in md5s:
            md5s[script] = hashlib.md5(fingerprint_text(root, script, sources).encode()).hexdigest()
        path = fingerprint_path(script).as_posix()
        dep = next((d for d in entry.get("deps", []) if d["path"] == path), None)
        if dep is None or dep.get("md5") != md5s[script]:
            stale.append(f"{stage}: {path} {'not locked' if dep is None else 'modified'}")
    return stale


def stale_lock_entries(root: Path) -> list[str]:
    """Why ``root``'s dvc.lock is not the one `dvc repro` would commit (empty if it is): a locked dep
    that git tracks and no stage writes, a locked param whose current value differs from the lock,
    or a locked fingerprint that is not what the stage's code does today."""
    listed = subprocess.run(["git", "ls-files"], cwd=root, capture_output=True, text=True, check=True)
    stages = (yaml.safe_load((root / "dvc.lock").read_text()) or {}).get("stages", {})
    outs = {out["path"] for stage in stages.values() for out in stage.get("outs", [])}
    return stale_entries(dvc_status(root), set(listed.stdout.split()), outs) + stale_fingerprints(
        root, stages
    )


def test_a_stale_fingerprint_in_the_lock_is_found_without_running_the_stage(toy: Path):
    """A code change that no `dvc repro` has seen leaves the fingerprint file on disk as it was, so
    `dvc status` is clean; the lock check recomputes the fingerprint and names the stage. A comment
    is no change."""
    (toy / "dvc.yaml").write_text(TOY_YAML)
    text = fingerprint_text(toy, "stages/run.py")
    dep = {"path": "data/fingerprints/run.txt", "hash": "md5", "md5": hashlib.md5(text.encode()).hexdigest()}
    locked = {"run@1": {"deps": [dep]}, "fresh": {"deps": []}, "fingerprints": {}, "gone": {}}
    assert stale_fingerprints(toy, locked) == ["fresh: data/fingerprints/run.txt not locked"]
    del locked["fresh"]
    neutral_edit(toy / "src" / "msdepth" / "data" / "pairs.py")
    assert stale_fingerprints(toy, locked) == []
    (toy / "src" / "msdepth" / "data" / "pairs.py").write_text("from . import kitti\nkitti = None\n")
    assert stale_fingerprints(toy, locked) == ["run@1: data/fingerprints/run.txt modified"]


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
