"""dvc.yaml's code deps follow the imports: each stage lists exactly the files its script imports.

A stage's code is its script (``python stages/<x>.py`` in ``cmd``) and the transitive closure of
the ``msdepth`` modules it imports, found statically with ``ast`` (every ``import`` statement,
including those inside functions, and the ``__init__.py`` of every package on the way). A source
file missing from a stage's deps lets ``dvc repro`` serve results of old code; a listed file the
stage does not import re-runs it for nothing.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "msdepth"


def module_file(name: str, src: Path) -> Path | None:
    """The file of module ``name`` (``a.b`` -> ``src/a/b.py`` or ``src/a/b/__init__.py``), if any."""
    base = src.joinpath(*name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def imported_modules(path: Path, module: str | None, src: Path, package: str = PACKAGE) -> set[str]:
    """The ``package`` modules that the file ``path`` (module ``module``; None for a script) imports.

    ``from X import y`` counts ``X`` and, when ``y`` is a submodule, ``X.y`` too; relative imports
    are resolved against the module's package.
    """
    is_package = path.name == "__init__.py"
    found: set[str] = set()
    tree = ast.parse(path.read_text(), filename=str(path))
    skipped = {  # `if TYPE_CHECKING:` blocks never run
        id(n)
        for block in ast.walk(tree)
        if isinstance(block, ast.If) and "TYPE_CHECKING" in ast.unparse(block.test)
        for stmt in block.body
        for n in ast.walk(stmt)
    }
    registry = r"\b(pkgutil\.iter_modules|importlib\.import_module)\(|\bRegistry\(__name__\b"
    if is_package and re.search(registry, path.read_text()):
        # A package that imports its own modules by name (a registry, msdepth.variants._registry's
        # Registry): count them all.
        found.update(f"{module}.{p.stem}" for p in path.parent.glob("*.py") if p.name != "__init__.py")
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                if module is None:
                    raise AssertionError(f"{path}: a relative import in a script")
                parts = module.split(".") if is_package else module.split(".")[:-1]
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join(parts + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            found.add(base)
            found.update(f"{base}.{a.name}" for a in node.names if module_file(f"{base}.{a.name}", src))
    return {m for m in found if m == package or m.startswith(package + ".")}


def import_closure(script: Path, src: Path, package: str = PACKAGE) -> set[Path]:
    """Every source file that running ``script`` executes from ``package``: the modules it imports,
    theirs in turn, and each one's parent packages' ``__init__.py``."""
    files: set[Path] = set()
    todo = [(script, None)]
    while todo:
        path, module = todo.pop()
        for name in imported_modules(path, module, src, package):
            parts = name.split(".")
            for i in range(1, len(parts) + 1):  # importing a.b.c runs a/__init__ and a/b/__init__ first
                sub = ".".join(parts[:i])
                file = module_file(sub, src)
                if file is None:
                    raise AssertionError(f"{path}: imports {sub}, which has no file under {src}")
                if file not in files:
                    files.add(file)
                    todo.append((file, sub))
    return files


def stage_scripts(dvc_yaml: dict) -> dict[str, str]:
    """``{stage name: its script}`` for every stage whose cmd is ``python stages/<x>.py ...``."""
    scripts = {}
    for name, stage in dvc_yaml["stages"].items():
        match = re.match(r"python (stages/\S+\.py)\b", stage["cmd"])
        assert match, f"dvc.yaml: stage {name}: cmd {stage['cmd']!r} does not run a stage script"
        scripts[name] = match.group(1)
    return scripts


def deps_problems(root: Path) -> tuple[list[str], list[str]]:
    """(missing, extra): ``stage: file`` for each imported file a stage does not list (nor a folder
    above it), and for each listed code file (or file under a listed folder) it does not import."""
    dvc_yaml = yaml.safe_load((root / "dvc.yaml").read_text())
    missing, extra = [], []
    for name, script in stage_scripts(dvc_yaml).items():
        code = {script} | {
            p.relative_to(root).as_posix() for p in import_closure(root / script, root / "src")
        }
        deps = [d for d in dvc_yaml["stages"][name].get("deps", []) if isinstance(d, str)]
        for file in sorted(code):
            if not any(file == d or file.startswith(d.rstrip("/") + "/") for d in deps):
                missing.append(f"{name}: {file}")
        for dep in deps:
            if not dep.startswith(("src/", "stages/")):
                continue
            listed = (
                [dep]
                if not (root / dep).is_dir()
                else [p.relative_to(root).as_posix() for p in (root / dep).rglob("*.py")]
            )
            extra += [f"{name}: {f}" for f in sorted(listed) if f not in code]
    return missing, extra


def test_every_stage_lists_exactly_the_code_it_imports():
    missing, extra = deps_problems(ROOT)
    report = []
    if missing:
        report += [f"{len(missing)} (stage, imported file) pair(s) missing from dvc.yaml's deps:"]
        report += [f"  {m}" for m in missing]
    if extra:
        report += [f"{len(extra)} code dep(s) listed in dvc.yaml that the stage does not import:"]
        report += [f"  {e}" for e in extra]
    if report:
        pytest.fail("\n".join(report), pytrace=False)


def test_no_stage_script_imports_the_whole_pipeline():
    """``msdepth.pipeline`` imports every stage's wiring: a stage importing it would depend on all."""
    for script in stage_scripts(yaml.safe_load((ROOT / "dvc.yaml").read_text())).values():
        closure = import_closure(ROOT / script, ROOT / "src")
        assert ROOT / "src" / PACKAGE / "pipeline.py" not in closure, script


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


def test_deps_check_reports_both_directions(toy: Path):
    closure = sorted(
        p.relative_to(toy).as_posix()
        for p in import_closure(toy / "stages" / "run.py", toy / "src")
        if p.name != "pairs.py"
    )
    stage = {"cmd": "python stages/run.py A", "deps": ["stages/run.py", *closure, "src/msdepth/unused.py"]}
    (toy / "dvc.yaml").write_text(yaml.safe_dump({"stages": {"run": stage}}))
    assert deps_problems(toy) == (["run: src/msdepth/data/pairs.py"], ["run: src/msdepth/unused.py"])
    # A listed folder covers what is under it, and then must hold nothing the stage does not import.
    stage["deps"] = ["stages/run.py", "src/msdepth"]
    (toy / "dvc.yaml").write_text(yaml.safe_dump({"stages": {"run": stage}}))
    assert deps_problems(toy) == ([], ["run: src/msdepth/data/unused.py", "run: src/msdepth/unused.py"])


def test_figures_and_evaluation_code_are_no_training_dep():
    """Redrawing a figure or changing a metric must never retrain (or re-infer) a model."""
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    later = {
        f"src/msdepth/{m}.py" for m in ("figures", "evaluate", "metrics", "compare", "stats", "baselines")
    }
    for name in ("train", "infer"):
        assert not later & set(stages[name]["deps"]), name


def test_reading_params_depends_on_no_loss_code():
    """The variants' configs are apart from their terms, so a change to the loss code (e.g. the
    MS-SSIM kernels) re-runs only the stages that train or build a model, not every stage."""
    closure = {
        p.relative_to(ROOT / "src" / PACKAGE).as_posix()
        for p in import_closure(ROOT / "stages" / "validate_params.py", ROOT / "src")
    }
    assert "variants/ssim.py" in closure and "config.py" in closure
    loss_code = {"losses.py", "warp.py", "_ssim_kernels.py"}
    assert not {f for f in closure if f in loss_code or f.startswith("appearance/")}
