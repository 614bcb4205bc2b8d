"""CONTRIBUTING.md stays true: every path, test, ``msdepth`` name and command it gives exists, and the
layers and numbers it states are the ones the tests and ruff enforce."""

from __future__ import annotations

import importlib
import importlib.util
import re
from pathlib import Path

import pytest
from test_function_length import MAX_LINES
from test_imports import LAYERS

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "CONTRIBUTING.md"
TOP_FILES = {"params.yaml", "dvc.yaml", "dvc.lock", "pyproject.toml", "README.md", "CONTRIBUTING.md"}
FOLDERS = ("src/", "tests/", "stages/", "studies/", "docs/", "benchmarks/", ".ci/")
FENCE = re.compile(r"```\w*\n(.*?)```", re.DOTALL)


def spans(text: str) -> list[str]:
    """The inline code spans of a markdown text (fenced blocks left out)."""
    return re.findall(r"`([^`\n]+)`", FENCE.sub("", text))


def commands(text: str) -> list[str]:
    """Each command of the fenced blocks and of the inline spans that start with one."""
    lines = [line.strip() for block in FENCE.findall(text) for line in block.splitlines()]
    lines += [s for s in spans(text) if s.startswith(("python -m ", "ruff ", "dvc "))]
    return [part.strip() for line in lines if line for part in line.split("&&")]


def missing_paths(text: str, root: Path = ROOT) -> list[str]:
    """Repository paths the text names that do not exist; for a template (``stages/<x>.py``) the
    folder before the placeholder must."""
    found = []
    for span in spans(text):
        path = span.split("::")[0]
        if not re.fullmatch(r"[\w./<>-]+", path) or not (path in TOP_FILES or path.startswith(FOLDERS)):
            continue
        if not (root / path.split("<")[0]).exists():
            found.append(path)
    return found


def missing_tests(text: str, root: Path = ROOT) -> list[str]:
    """``tests/<file>.py::<test>`` the text names whose file has no such test function."""
    found = []
    for file, name in re.findall(r"`(tests/\w+\.py)::(\w+)`", text):
        source = root / file
        if not source.is_file() or not re.search(rf"^def {name}\(", source.read_text(encoding="utf-8"), re.M):
            found.append(f"{file}::{name}")
    return found


def _is_module(name: str) -> bool:
    """Whether ``name`` is an importable module (``msdepth.io.write_text`` is not: an attribute)."""
    try:
        return importlib.util.find_spec(name) is not None
    except (ModuleNotFoundError, ValueError):
        return False


def unresolved_names(text: str) -> list[str]:
    """``msdepth.<module>.<name>`` the text names that do not import or have no such attribute."""
    found = []
    for span in spans(text):
        if not re.fullmatch(r"msdepth(\.\w+)*", span):
            continue
        parts = span.split(".")
        # The longest importable module, then attributes.
        cut = next(i for i in range(len(parts), 0, -1) if _is_module(".".join(parts[:i])))
        obj = importlib.import_module(".".join(parts[:cut]))
        for attr in parts[cut:]:
            if not hasattr(obj, attr):
                found.append(span)
                break
            obj = getattr(obj, attr)
    return found


def unknown_commands(text: str, root: Path = ROOT) -> list[str]:
    """Commands that are neither a step of CI (``.ci/run``: ruff, pytest) nor a module of the
    package run with ``python -m`` (``dvc`` is DVC's own)."""
    ci = {line.strip() for line in (root / ".ci" / "run").read_text(encoding="utf-8").splitlines()}
    found = []
    for command in commands(text):
        module = re.match(r"python -m (msdepth[\w.]*)", command)
        if command.startswith("dvc "):
            continue
        if module:
            if not _is_module(module.group(1)):
                found.append(command)
        elif command not in ci and f"python -m {command}" not in ci:
            found.append(command)
    return found


def problems(text: str) -> list[str]:
    """Everything in ``text`` that does not exist."""
    return missing_paths(text) + missing_tests(text) + unresolved_names(text) + unknown_commands(text)


def test_every_path_test_name_and_command_of_the_guide_exists() -> None:
    assert problems(GUIDE.read_text(encoding="utf-8")) == []


def test_the_checks_find_what_is_not_there() -> None:
    text = (
        "`stages/<x>.py` `stages/nowhere.py` `tests/test_imports.py::test_no_such_test` "
        "`msdepth.io.no_such_writer` `msdepth.errors.DataError` `python -m msdepth.no_such_module`\n"
        "```bash\nruff check . && rm -rf /\n```\n"
    )
    assert problems(text) == [
        "stages/nowhere.py",
        "tests/test_imports.py::test_no_such_test",
        "msdepth.io.no_such_writer",
        "rm -rf /",
        "python -m msdepth.no_such_module",
    ]


def test_the_guide_states_the_enforced_layers_and_limits() -> None:
    text = GUIDE.read_text(encoding="utf-8")
    stated = re.search(r"lowest first:\n(.*?)\.\n", text, re.DOTALL)
    assert stated, "CONTRIBUTING.md: no 'lowest first:' line of layers"
    layers = [tuple(p.strip() for p in layer.split(",")) for layer in " ".join(stated[1].split()).split("<")]
    assert layers == [tuple(layer) for layer in LAYERS]
    assert f"**{MAX_LINES} lines.**" in text and f"longer than {MAX_LINES} lines" in text
    tomllib = pytest.importorskip("tomllib")
    ruff = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["ruff"]
    length = ruff["line-length"]
    assert re.search(rf"line length\s+{length}\b", text)


def test_the_readme_links_the_guide() -> None:
    assert "(CONTRIBUTING.md)" in (ROOT / "README.md").read_text(encoding="utf-8")
