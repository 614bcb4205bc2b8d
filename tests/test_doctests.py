"""The public science API's docstrings: structured (``Args:``, ``Returns:``) with an ``Example:`` that
runs here as a doctest, so an example whose printed output is wrong fails the fast tier.

Each ``>>>`` line is run in its module's namespace and its output compared with the docstring's.
"""

from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import pytest

# module -> its functions that must show a runnable example
SCIENCE_API = {
    "msdepth.losses.ssim": ("ssim", "ms_ssim"),
    "msdepth.evaluation.metrics": ("compute_errors", "stereo_errors"),  # stereo_errors: D1 and EPE
    "msdepth.geometry.depth": ("disparity_to_depth", "depth_to_disparity"),
    "msdepth.geometry.warp": ("warp",),
    "msdepth.stats": (
        "paired_t",
        "seed_bootstrap",
        "paired_seed_bootstrap",
        "seeds_needed",
        "detectable_difference",
    ),
    "msdepth.analysis.verdict": ("headline_columns", "verdict_table"),
    "msdepth.evaluation.box_errors": ("box_medians",),
    "msdepth.training.train": ("learning_rate",),
}
FLAGS = doctest.NORMALIZE_WHITESPACE  # the runner's below, and pytest's (pyproject.toml)
FUNCTIONS = [(module, name) for module, names in SCIENCE_API.items() for name in names]


@pytest.mark.parametrize(("module", "name"), FUNCTIONS, ids=[f"{m}.{n}" for m, n in FUNCTIONS])
def test_each_science_function_has_a_structured_docstring_with_an_example(module: str, name: str) -> None:
    doc = getattr(importlib.import_module(module), name).__doc__ or ""
    missing = [part for part in ("Args:", "Returns:", "Example:", ">>> ") if part not in doc]
    assert not missing, f"{module}.{name}: its docstring lacks {missing}"


def test_a_wrong_output_fails() -> None:
    """The runner above is not vacuous: an example whose output differs counts as a failure."""
    wrong = doctest.DocTestParser().get_doctest(">>> 1 + 1\n3\n", {}, "wrong", None, 0)
    runner = doctest.DocTestRunner()
    runner.run(wrong, out=lambda _: None)
    assert runner.failures == 1


def modules_with_examples() -> list[str]:
    """Every module of src/msdepth whose text holds a ``>>>`` example."""
    src = Path(__file__).resolve().parents[1] / "src"
    return sorted(
        ".".join(p.relative_to(src).with_suffix("").parts)
        for p in (src / "msdepth").rglob("*.py")
        if ">>> " in p.read_text(encoding="utf-8")
    )


@pytest.mark.parametrize("module", modules_with_examples())
def test_every_example_in_the_package_runs(module: str) -> None:
    """Every docstring example in src, the science API's among them, prints what it says."""
    tests = [t for t in doctest.DocTestFinder().find(importlib.import_module(module)) if t.examples]
    assert tests, f"{module}: '>>> ' in its text but no docstring example found"
    report: list[str] = []
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    for test in tests:
        runner.run(test, out=report.append)
    assert runner.failures == 0, "".join(report)


def test_the_science_api_s_modules_are_among_those_run() -> None:
    assert set(SCIENCE_API) <= set(modules_with_examples())


def test_plain_pytest_doctest_modules_uses_the_runners_flags() -> None:
    """`pytest --doctest-modules src/msdepth` reads its flags from pyproject.toml: the same as this
    runner's, so an example that passes here (verdict.answer_sentence's wrapped line) passes there."""
    import tomllib

    config = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    names = config["tool"]["pytest"]["ini_options"].get("doctest_optionflags", [])
    flags = 0
    for name in names:
        flags |= doctest.OPTIONFLAGS_BY_NAME[name]
    assert flags == FLAGS, names
