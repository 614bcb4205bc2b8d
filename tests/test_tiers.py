"""Every test that runs DVC on a copied project is in the second tier (``-m slow``), so a new
end-to-end test cannot land in README's command 2 (``-m "not slow"``) unnoticed.

A test runs DVC when it, a module function it calls, or a fixture of its module that it takes calls
one of conftest's DVC helpers or builds a ``python -m dvc`` command line itself. It is in the second
tier when it is decorated ``@pytest.mark.slow`` or its module sets ``pytestmark = pytest.mark.slow``.
"""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parent
# conftest's helpers that run DVC, or build the project copy DVC runs in (tests/conftest.py).
DVC_HELPERS = frozenset({"dvc", "dvc_status", "project", "require_dvc", "run_checked", "stage_env"})
# A command line of its own, `[sys.executable, "-m", "dvc", ...]` (a module constant: the checker's
# own functions do not spell it).
DVC_MODULE = ("-m", "dvc")
# Tests that run DVC read-only on this checkout itself (no project copy, a few seconds): they
# belong in README's command 2, which is where a stale dvc.lock must be caught.
ON_THE_CHECKOUT = frozenset({"test_dvc_deps.py::test_dvc_lock_is_current_with_the_tracked_code_and_params"})


def _is_slow_mark(node: ast.AST) -> bool:
    """``pytest.mark.slow``, or a list or tuple holding it."""
    if isinstance(node, (ast.List, ast.Tuple)):
        return any(_is_slow_mark(e) for e in node.elts)
    return ast.unparse(node) == "pytest.mark.slow"


def _runs_dvc_itself(func: ast.FunctionDef, helpers: set[str]) -> bool:
    """Whether ``func``'s body calls one of ``helpers`` or spells :data:`DVC_MODULE`."""
    for node in ast.walk(func):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in helpers:
            return True
        if isinstance(node, (ast.List, ast.Tuple)):
            words = [e.value for e in node.elts if isinstance(e, ast.Constant)]
            if any(tuple(words[i : i + 2]) == DVC_MODULE for i in range(len(words) - 1)):
                return True
    return False


def _conftest_names(tree: ast.Module) -> set[str]:
    """The names the module imports from conftest (a local ``project`` may be another function)."""
    return {
        alias.asname or alias.name
        for node in tree.body
        if isinstance(node, ast.ImportFrom) and node.module == "conftest"
        for alias in node.names
    }


def unmarked_dvc_tests(source: str) -> list[str]:
    """The names of the tests in the test module ``source`` that run DVC and are not marked slow."""
    tree = ast.parse(source)
    if any(
        isinstance(node, ast.Assign)
        and any(isinstance(t, ast.Name) and t.id == "pytestmark" for t in node.targets)
        and _is_slow_mark(node.value)
        for node in tree.body
    ):
        return []
    funcs = {node.name: node for node in tree.body if isinstance(node, ast.FunctionDef)}
    # Grow the set of DVC-running functions until calls and fixture arguments add none.
    running = DVC_HELPERS & _conftest_names(tree)
    while True:
        more = {
            name
            for name, func in funcs.items()
            if name not in running
            and (_runs_dvc_itself(func, running) or {a.arg for a in func.args.args} & running)
        }
        if not more:
            break
        running |= more
    return [
        name
        for name, func in funcs.items()
        if name.startswith("test_") and name in running and not any(map(_is_slow_mark, func.decorator_list))
    ]


def test_the_checker_finds_a_test_that_runs_dvc_directly_through_a_helper_or_a_fixture() -> None:
    head = "import pytest\nimport sys\nfrom conftest import project, run_checked\n"
    source = head + (
        "def _build(p):\n    return project(p)\n"
        "@pytest.fixture\ndef repo(tmp_path):\n    return _build(tmp_path)\n"
        "def test_fixture(repo):\n    pass\n"
        "def test_helper(tmp_path):\n    _build(tmp_path)\n"
        "def test_command(tmp_path):\n    cmd = [sys.executable, '-m', 'dvc', 'repro']\n"
        "def test_direct(tmp_path):\n    run_checked(['git', 'init'], tmp_path)\n"
        "@pytest.mark.slow\ndef test_marked(repo):\n    pass\n"
        "def test_unit():\n    assert project is not None\n"
    )
    assert unmarked_dvc_tests(source) == ["test_fixture", "test_helper", "test_command", "test_direct"]
    assert unmarked_dvc_tests(source + "pytestmark = [pytest.mark.slow]\n") == []
    # A module's own ``project`` (test_geometry's projection) is not conftest's.
    assert unmarked_dvc_tests("from msdepth.geometry import project\ndef test_p():\n    project(1)\n") == []


def test_every_test_that_runs_dvc_is_marked_slow() -> None:
    unmarked = [
        f"{path.name}::{name}"
        for path in sorted(TESTS.glob("test_*.py"))
        for name in unmarked_dvc_tests(path.read_text())
    ]
    missing = ON_THE_CHECKOUT - set(unmarked)
    assert not missing, f"ON_THE_CHECKOUT names tests that no longer run DVC unmarked: {sorted(missing)}"
    unmarked = [name for name in unmarked if name not in ON_THE_CHECKOUT]
    assert not unmarked, (
        "these tests run DVC on a copied project but would run in the fast tier; mark them "
        "@pytest.mark.slow (or the module: pytestmark = pytest.mark.slow):\n" + "\n".join(unmarked)
    )
