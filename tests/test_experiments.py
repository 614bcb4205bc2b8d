"""``msdepth experiments`` (issue 43): ``dvc exp show --json`` as one row per experiment with each
variant's kernel size and mean abs_rel and windshield abs_rel, within 120 columns. The table is read
from a saved output (tests/data/exp_show.json: the workspace and baseline after
``dvc exp run -S msssim.kernel_size=7``, trimmed to the columns read); DVC itself is never run here,
its stand-in is a Python one-liner."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from msdepth.__main__ import main
from msdepth.reporting import experiments as exp

SAMPLE = Path(__file__).resolve().parent / "data" / "exp_show.json"
WIDEST = 120  # issue 43: the README's table, two variants and the default keys


def _run(capsys: pytest.CaptureFixture, *argv: str) -> tuple[int, list[str], list[str]]:
    code = main(["experiments", *argv])
    out, err = capsys.readouterr()
    return code, out.splitlines(), err.splitlines()


def test_the_sample_reads_as_one_row_per_experiment(capsys: pytest.CaptureFixture) -> None:
    code, out, err = _run(capsys, "--json", str(SAMPLE))
    assert code == 0 and err == []
    assert out[0].split("  ")[0] == "Experiment"
    header = [c for c in out[0].split("  ") if c.strip()]
    assert [c.strip() for c in header] == [
        "Experiment",
        "ssim k",
        "msssim k",
        "abs_rel ssim",
        "abs_rel msssim",
        "windshield ssim",
        "windshield msssim",
    ]
    rows = [line.split() for line in out[1:]]
    assert rows == [
        ["workspace", "3", "7", "0.18637", "0.18659", "0.75172", "0.72606"],
        ["main", "3", "3", "0.18637", "0.18396", "0.75172", "0.7161"],
        ["fd2fe2b", "[scrap-whey]", "3", "7", "0.18637", "0.18659", "0.75172", "0.72606"],
    ]


@pytest.mark.parametrize("markdown", [False, True])
def test_lines_fit_in_120_columns(capsys: pytest.CaptureFixture, markdown: bool) -> None:
    code, out, _ = _run(capsys, "--json", str(SAMPLE), *(["--md"] if markdown else []))
    assert code == 0 and len(out) == 4 + markdown
    assert max(len(line) for line in out) <= WIDEST


def test_markdown_table(capsys: pytest.CaptureFixture) -> None:
    code, out, _ = _run(capsys, "--json", str(SAMPLE), "--md")
    assert code == 0
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in out]
    assert cells[0][:3] == ["Experiment", "ssim k", "msssim k"]
    assert set("".join(cells[1])) <= {"-", ":"}
    assert cells[4] == ["fd2fe2b [scrap-whey]", "3", "7", "0.18637", "0.18659", "0.75172", "0.72606"]


def test_absent_values_and_other_keys() -> None:
    records = exp.read_json(SAMPLE)
    del records[1]["data"]["metrics"]["metrics/headline/mean/msssim.json"]
    records[0]["data"]["params"]["params.yaml"]["data"]["msssim"] = {}
    lines = exp.table(exp.experiments(records), ["a1", "nothing"])
    assert lines[0][3:] == ["a1 ssim", "a1 msssim", "nothing ssim", "nothing msssim"]
    assert lines[1][2] == "-" and lines[2][4] == "-" and lines[2][5:] == ["-", "-"]


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (None, "no such file"),
        (b"{not json", "not JSON"),
        (b'{"rev": "workspace"}', "expected a list of revisions"),
        (b"\xff\xfe", "not UTF-8"),
    ],
)
def test_a_bad_file_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture, content: bytes | None, expected: str
) -> None:
    path = tmp_path / "show.json"
    if content is not None:
        path.write_bytes(content)
    code, out, err = _run(capsys, "--json", str(path))
    assert code == 1 and out == [] and len(err) == 1
    assert err[0].startswith("error: ") and str(path) in err[0] and expected in err[0]


def test_an_oversized_file_is_refused_before_parsing(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(exp, "MAX_JSON_BYTES", 1024)
    path = tmp_path / "show.json"
    path.write_bytes(b"[" + b" " * 2048 + b"]")
    code, _, err = _run(capsys, "--json", str(path))
    assert code == 1 and len(err) == 1 and "larger than" in err[0]


@pytest.mark.parametrize(
    ("script", "expected"),
    [
        ("import sys; print('dvc broke', file=sys.stderr); sys.exit(3)", "failed (exit 3): dvc broke"),
        ("print('not json')", "not JSON"),
    ],
)
def test_a_failing_dvc_is_one_line(
    capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch, script: str, expected: str
) -> None:
    monkeypatch.setattr(exp, "dvc_command", lambda: [sys.executable, "-c", script])
    code, out, err = _run(capsys)
    assert code == 1 and out == [] and len(err) == 1
    assert err[0].startswith("error: dvc exp show --json") and expected in err[0]


def test_a_missing_dvc_is_one_line(capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(exp.shutil, "which", lambda name: None)
    monkeypatch.setattr(exp.importlib.util, "find_spec", lambda name: None)
    code, _, err = _run(capsys)
    assert code == 1 and len(err) == 1 and err[0].startswith("error: dvc not found")


def test_dvc_output_is_read_from_its_stdout(
    capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    script = f"import sys; sys.stdout.write(open({str(SAMPLE)!r}).read())"
    monkeypatch.setattr(exp, "dvc_command", lambda: [sys.executable, "-c", script])
    code, out, _ = _run(capsys)
    assert code == 0 and [line.split()[0] for line in out] == ["Experiment", "workspace", "main", "fd2fe2b"]
