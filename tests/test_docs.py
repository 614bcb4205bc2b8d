"""The README and docs/: short, linked, and saying what CI runs (issue 29)."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "benchmarks" / "README.md"]
README_MAX_LINES = 200
# Markdown links and images: [text](target) and ![alt](target).
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
# Words that speak of how a text was measured rather than of the project.
BANNED = re.compile(r"\bsessions?\b|this machine", re.IGNORECASE)


def relative_links(path: Path) -> list[str]:
    """Targets of the links in a markdown file that point into the repository."""
    targets = LINK.findall(path.read_text(encoding="utf-8"))
    return [t for t in targets if not re.match(r"[a-z][a-z0-9+.-]*:", t)]


def anchors(path: Path) -> set[str]:
    """GitHub's anchors for the headings of a markdown file (outside code blocks)."""
    text = re.sub(r"```.*?```", "", path.read_text(encoding="utf-8"), flags=re.DOTALL)
    headings = re.findall(r"^#+ (.+)$", text, re.MULTILINE)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in headings}


def fenced_commands(text: str) -> list[str]:
    """The non-comment lines of the ```bash blocks in a markdown text."""
    blocks = re.findall(r"```bash\n(.*?)```", text, re.DOTALL)
    lines = (line.strip() for block in blocks for line in block.splitlines())
    return [line for line in lines if line and not line.startswith("#")]


def test_readme_is_short() -> None:
    lines = README.read_text(encoding="utf-8").count("\n")
    assert lines <= README_MAX_LINES, f"README.md has {lines} lines (at most {README_MAX_LINES})"


def test_readme_reaches_its_quick_start_within_30_lines() -> None:
    """The question and the generated one-line answer come first, then the Quick start (issue 67)."""
    lines = README.read_text(encoding="utf-8").splitlines()
    start = lines.index("## Quick start")
    assert start < 30, f"README.md: '## Quick start' is at line {start + 1} (at most 30)"
    answer = "\n".join(lines[:start])
    assert "<!-- answer: written by the report stage" in answer and "<!-- end of answer -->" in answer


@pytest.mark.parametrize("path", [README, *DOCS], ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_exist(path: Path) -> None:
    missing = []
    for target in relative_links(path):
        file, _, anchor = target.partition("#")
        dest = path.parent / file if file else path
        if not dest.exists() or (anchor and dest.suffix == ".md" and anchor not in anchors(dest)):
            missing.append(target)
    assert not missing, f"{path.relative_to(ROOT)} links to missing files or headings: {missing}"


def test_readme_quick_start_matches_ci() -> None:
    """Command 1 installs as .ci/run does, command 2 is .ci/run's fast tier of tests in the venv
    (activated first: a new shell has no msdepth), and the second tier that README names is .ci/run's too."""
    commands = fenced_commands(README.read_text(encoding="utf-8"))
    install, tests = commands[0], commands[1]
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    ci_steps = [line.strip() for line in ci.splitlines() if not line.strip().startswith("#")]
    assert install == (
        "python3 -m venv .venv && . .venv/bin/activate && pip install torch==2.13.0 && "
        'pip install -c constraints.txt -e ".[test]" && dvc repro'
    )
    assert "python3 -m venv .venv" in ci_steps
    assert ". .venv/bin/activate" in ci_steps
    assert "python -m pip install -q torch==2.13.0" in ci_steps
    assert 'python -m pip install -q -c constraints.txt -e ".[test]"' in ci_steps
    activate, tests = tests.split(" && ")
    assert activate == ". .venv/bin/activate" and tests == 'python -m pytest -q -m "not slow"'
    assert tests in ci_steps
    assert "`python -m pytest -q -m slow`" in README.read_text(encoding="utf-8")
    assert "python -m pytest -q -m slow" in ci_steps


@pytest.mark.parametrize("path", [README, *DOCS], ids=lambda p: str(p.relative_to(ROOT)))
def test_no_talk_of_sessions(path: Path) -> None:
    text = path.read_text(encoding="utf-8")
    hits = [line for line in text.splitlines() if BANNED.search(line)]
    assert not hits, f"{path.relative_to(ROOT)}: {hits}"


def test_constraints_pin_every_dependency() -> None:
    """constraints.txt pins each pyproject dependency (and test extra) to a version in its range."""
    tomllib = pytest.importorskip("tomllib")
    from packaging.requirements import Requirement

    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    wanted = [Requirement(r) for r in project["dependencies"] + project["optional-dependencies"]["test"]]
    pins = {}
    for line in (ROOT / "constraints.txt").read_text(encoding="utf-8").splitlines():
        if line and not line.startswith("#"):
            name, _, version = line.partition("==")
            pins[name.lower().replace("_", "-")] = version
    for req in wanted:
        version = pins.get(req.name.lower().replace("_", "-"))
        assert version is not None, f"constraints.txt does not pin {req.name}"
        assert req.specifier.contains(version, prereleases=True), f"{req.name}=={version} is outside {req}"


def test_the_results_page_lists_every_study_script_and_results_readme() -> None:
    """docs/results.md's section "The studies" names every script in studies/ (as `name`) and links
    each studies/results folder that has a README: a new study is not left undocumented."""
    text = (ROOT / "docs" / "results.md").read_text(encoding="utf-8")
    section = text[text.index("## The studies") :]
    section = section[: section.index("\n## ", 1)]
    scripts = sorted(p.name for p in (ROOT / "studies").iterdir() if p.suffix in (".py", ".sh"))
    assert scripts and [s for s in scripts if f"`{s}`" not in section] == []
    readmes = sorted((ROOT / "studies" / "results").glob("*/README.md"))
    assert (
        readmes and [r for r in readmes if f"studies/results/{r.parent.name}/README.md" not in section] == []
    )
