"""An exception no check foresaw, at the top of an entry point (issue 56, deliverable 4): one line
naming the command, its arguments and the exception's type, exit 1, and the full traceback in a log
file whose path the line names. Injected here into msdepth commands, a stage and a study; a source
scan holds every stage and study script to the one wrapper (run_stage, run_main)."""

from __future__ import annotations

import re
import runpy
import sys
from pathlib import Path

import pytest

from msdepth import __main__ as cli
from msdepth.cli import example, experiments
from msdepth.errors import LOG_DIR_ENV, DataError, run_main
from msdepth.evaluation import results
from msdepth.pipeline.paths import run_stage

ROOT = Path(__file__).resolve().parents[1]
LINE = re.compile(
    r"^error: (?P<called>.+): unexpected (?P<type>\w+)(: (?P<message>.*))?; traceback in (?P<log>\S+)$"
)


def _boom(*args: object, **kwargs: object) -> None:
    raise ZeroDivisionError("injected \x1b[31mred\x1b[0m\nsecond line")


@pytest.fixture
def logs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    folder = tmp_path / "logs"
    folder.mkdir()
    monkeypatch.setenv(LOG_DIR_ENV, str(folder))
    return folder


def _one_line(err: str, called: str, logs: Path) -> None:
    """``err`` is one line naming ``called`` and ZeroDivisionError, with its message escaped, and the
    log file it names (in ``logs``) holds the traceback."""
    lines = err.splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    found = LINE.match(lines[0])
    assert found, lines[0]
    assert found["called"].startswith(called) and found["type"] == "ZeroDivisionError", lines[0]
    assert (
        found["message"] == "injected \\x1b[31mred\\x1b[0m second line"
    )  # no escape sequence reaches the terminal
    log = Path(found["log"])
    assert log.parent == logs and "Traceback (most recent call last)" in log.read_text()
    assert "_boom" in log.read_text()


@pytest.mark.parametrize(
    ("module", "name", "argv"),
    [
        (experiments, "run", ["experiments", "--json", "x.json"]),
        (cli, "_predict", ["predict", "in.png", "--model", "m.pt", "--out", "out"]),
        (cli, "_export_onnx", ["export-onnx", "--model", "m.pt", "--out", "m.onnx"]),
    ],
    ids=["experiments", "predict", "export-onnx"],
)
def test_a_command_reports_an_unexpected_exception_in_one_line(
    module: object, name: str, argv: list[str], logs: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    monkeypatch.setattr(module, name, _boom)
    assert cli.main(argv) == 1
    _one_line(capsys.readouterr().err, f"msdepth {' '.join(argv)}", logs)


def test_the_example_command_reports_an_unexpected_exception_in_one_line(
    tmp_path: Path, logs: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    (tmp_path / "params.yaml").write_text("")  # the defaults
    monkeypatch.setattr(example, "_make_example", _boom)
    assert example.main(["--root", str(tmp_path)]) == 1
    _one_line(capsys.readouterr().err, f"msdepth.cli.example --root {tmp_path}", logs)


def test_a_stage_reports_an_unexpected_exception_in_one_line(
    tmp_path: Path, logs: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    stage = runpy.run_path(str(ROOT / "stages" / "validate_params.py"))["validate_params"]
    monkeypatch.setitem(stage.__globals__, "write_checked", _boom)
    monkeypatch.chdir(tmp_path)
    assert run_stage(stage, params_path=ROOT / "params.yaml") == 1
    _one_line(capsys.readouterr().err, "stage validate_params", logs)


def test_a_study_reports_an_unexpected_exception_in_one_line(
    logs: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    monkeypatch.setattr(results, "load_suite_metrics", _boom)  # imported by the study as it starts
    monkeypatch.setattr(sys, "argv", ["studies/power.py", "--root", str(ROOT)])
    with pytest.raises(SystemExit) as exit_:
        runpy.run_path(str(ROOT / "studies" / "power.py"), run_name="__main__")
    assert exit_.value.code == 1
    _one_line(capsys.readouterr().err, f"studies/power.py --root {ROOT}", logs)


def test_run_main_keeps_a_known_error_and_its_exit_codes(capsys) -> None:
    def known() -> int:
        raise DataError("a.png: no such image file")

    assert run_main("studies/x.py", known) == 1
    assert capsys.readouterr().err == "error: a.png: no such image file\n"
    assert run_main("studies/x.py", lambda: 0) == 0 and run_main("studies/x.py", lambda: None) is None
    with pytest.raises(KeyboardInterrupt):
        run_main("studies/x.py", lambda: (_ for _ in ()).throw(KeyboardInterrupt()))


def test_a_log_folder_that_cannot_be_written_is_said_in_the_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    monkeypatch.setenv(LOG_DIR_ENV, str(tmp_path / "missing"))
    assert run_main("studies/x.py", _boom) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unexpected ZeroDivisionError" in err
    assert "its traceback could not be written (No such file or directory)" in err


@pytest.mark.parametrize("folder", ["stages", "studies"])
def test_every_stage_and_study_script_runs_under_the_one_wrapper(folder: str) -> None:
    wrapper = "run_stage" if folder == "stages" else "run_main"
    missing = []
    for script in sorted((ROOT / folder).glob("*.py")):
        main_block = script.read_text(encoding="utf-8").partition('if __name__ == "__main__":')[2]
        # the fingerprints stage runs before validate_params and reads no params: run_main
        own = "run_main" if script.name == "fingerprints.py" else wrapper
        if f"sys.exit({own}(" not in main_block:
            missing.append(script.name)
    assert missing == []
