"""``msdepth experiments`` (issue 43): ``dvc exp show --json`` as one row per experiment with each
variant's kernel size and mean abs_rel and windshield abs_rel, within 120 columns. The table is read
from a saved output (tests/data/exp_show.json: the workspace and baseline after
``dvc exp run -S msssim.kernel_size=7``, trimmed to the columns read); DVC itself is never run here,
its stand-in is a Python one-liner."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest
from conftest import unblocking

from msdepth.__main__ import main
from msdepth.cli import experiments as exp

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
        (None, "no such JSON file"),
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
    assert code == 1 and len(err) == 1 and "over the limit of 1,024 bytes for JSON files" in err[0]


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
    monkeypatch.setattr(exp, "_dvc_command", lambda: [sys.executable, "-c", script])
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
    monkeypatch.setattr(exp, "_dvc_command", lambda: [sys.executable, "-c", script])
    code, out, _ = _run(capsys)
    assert code == 0 and [line.split()[0] for line in out] == ["Experiment", "workspace", "main", "fd2fe2b"]


# Issue 56: hostile saved outputs. Each is one line on stderr, or a table whose every cell is printable.


def _revision(name: object = "main", variants: list | None = None, revs: int = 0) -> dict:
    params = {"params.yaml": {"data": {"variants": variants or ["ssim"]}}}
    entries = [{"rev": f"{i:040x}", "name": f"e{i}"} for i in range(revs)]
    return {"rev": "a" * 40, "name": name, "data": {"params": params}, "experiments": [{"revs": entries}]}


def _saved(tmp_path: Path, text: str) -> str:
    path = tmp_path / "show.json"
    path.write_text(text, encoding="utf-8")
    return str(path)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ('[{"rev": "workspace", "x": ' + "9" * 5000 + "}]", "integer string conversion"),
        ('[{"rev": "workspace", "name": NaN}]', "revision 1 has a name that is a float, not a string"),
        ('[{"rev": ["a"]}]', "revision 1 has a rev that is a list, not a string"),
        ('[{"rev": "b", "experiments": [{"revs": [{"rev": 7}]}]}]', "an experiment of revision 1 has a rev"),
    ],
)
def test_a_hostile_value_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture, text: str, expected: str
) -> None:
    # A 5,000-digit integer ended in a ValueError traceback; NaN and a list were printed as labels.
    path = _saved(tmp_path, text)
    code, out, err = _run(capsys, "--json", path)
    assert code == 1 and out == [] and len(err) == 1
    assert err[0].startswith(f"error: {path}: ") and expected in err[0], err


@pytest.mark.parametrize("markdown", [False, True])
def test_labels_cannot_forge_rows_or_drive_the_terminal(
    tmp_path: Path, capsys: pytest.CaptureFixture, markdown: bool
) -> None:
    # A label's escape sequences and newlines were printed raw: it could clear the screen and add rows;
    # a lone surrogate ended in a UnicodeEncodeError traceback on a UTF-8 terminal.
    label = "\x1b[2J\nforged  1  2\u202e|\ud800"
    code, out, err = _run(
        capsys, "--json", _saved(tmp_path, json.dumps([_revision(label)])), *(["--md"] * markdown)
    )
    assert code == 0 and err == [] and len(out) == 2 + markdown
    assert all(line.isprintable() for line in out)
    assert "\\x1b[2J\\nforged  1  2\\u202e" + ("\\|" if markdown else "|") + "\\ud800" in out[-1]


def test_the_distinct_variant_check_is_linear() -> None:
    # It was a list membership test per name: 1,000 variants over 60,000 rows took 26 s.
    calls = 0

    class Counted(str):
        __hash__ = str.__hash__

        def __eq__(self, other: object) -> bool:
            nonlocal calls
            calls += 1
            return str.__eq__(self, other)

    names = [Counted(f"v{i}") for i in range(3000)]
    rows = [exp.Experiment("main", {"variants": names}), exp.Experiment("w", {"variants": names[::-1]})]
    assert exp.variants(rows) == names
    assert calls < 3 * len(names)


def test_a_table_over_the_cell_bound_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    # 1,000 variants x 60,000 rows took 2.15 GB and 26 s before a MemoryError.
    variants = [f"v{i}" for i in range(1000)]
    path = _saved(tmp_path, json.dumps([_revision("main", variants, revs=400)]))
    code, out, err = _run(capsys, "--json", path)
    assert code == 1 and out == [] and len(err) == 1
    assert "401 experiments x 3001 columns is over 1,000,000 cells" in err[0]


def test_a_fifo_or_a_folder_is_refused_without_blocking(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    # A FIFO as --json blocked the read forever.
    fifo = tmp_path / "show.json"
    os.mkfifo(fifo)
    with unblocking(fifo):
        code, out, err = _run(capsys, "--json", str(fifo))
    assert code == 1 and len(err) == 1 and "not a regular file" in err[0]
    code, out, err = _run(capsys, "--json", str(tmp_path))
    assert code == 1 and len(err) == 1 and "a folder, not a file" in err[0]


# Issue 68: limits checked while reading, naming the file; stale rows marked; unknown keys warned.


def test_the_cell_bound_is_checked_before_any_row_is_built_and_names_the_file(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The bound was checked after every row was built, and named "dvc exp show --json", not the file.
    built = []
    monkeypatch.setattr(exp, "Experiment", lambda *a: built.append(a))
    path = _saved(tmp_path, json.dumps([_revision("main", [f"v{i}" for i in range(1000)], revs=400)]))
    code, out, err = _run(capsys, "--json", path)
    assert code == 1 and built == [] and len(err) == 1
    assert err[0].startswith(f"error: {path}: 401 experiments x 3001 columns"), err


def test_a_file_of_millions_of_empty_records_is_refused_before_parsing(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    # 20 million {} records (60 MB) ran to 6.3 GB and a timeout.
    monkeypatch.setattr(exp.json, "loads", lambda *a, **k: pytest.fail("parsed"))
    path = _saved(tmp_path, "[" + ",".join(["{}"] * 100_000) + "]")
    code, out, err = _run(capsys, "--json", path)
    assert code == 1 and out == [] and len(err) == 1
    assert err[0].startswith(f"error: {path}: up to 200,000 JSON values in 300,001 bytes"), err


def test_a_long_label_or_value_is_cut_not_padded_into_every_row(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    # A 3 MB label padded every row to 3 MB: a MemoryError at 3.9 GB.
    record = _revision("x" * 100_000, revs=3)
    record["data"]["params"]["params.yaml"]["data"]["ssim"] = {"kernel_size": "k" * 100_000}
    code, out, err = _run(capsys, "--json", _saved(tmp_path, json.dumps([record])))
    assert code == 0 and err == [] and len(out) == 5
    assert max(len(line) for line in out) < 2 * exp.MAX_CELL_CHARS + 60
    assert out[1].startswith("x" * (exp.MAX_CELL_CHARS - 3) + "...")


def test_an_unknown_key_is_warned_about(capsys: pytest.CaptureFixture) -> None:
    # The user guide's --keys a1 roi.road printed a column of "-" without a word.
    code, out, err = _run(capsys, "--json", str(SAMPLE), "--keys", "a1", "roi.road")
    assert code == 0 and len(out) == 4
    assert err == [
        "warning: --keys roi.road: no experiment's mean file has it (keys there: abs_rel, a1, windshield)"
    ]


def _lock(tmp_path: Path, kernel: int) -> Path:
    lock = tmp_path / "dvc.lock"
    stage = {"cmd": "python stages/train.py", "params": {"params.yaml": {"msssim": {"kernel_size": kernel}}}}
    lock.write_text(json.dumps({"schema": "2.0", "stages": {"train@msssim-0": stage}}))  # JSON is YAML
    return lock


def test_a_workspace_row_older_than_its_params_is_marked_stale(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    # After an interrupted `dvc exp run -S msssim.kernel_size=7` the workspace row read "msssim k 7"
    # with the k=3 run's numbers, unmarked.
    records = exp.read_json(SAMPLE)
    records[0]["data"]["params"]["params.yaml"]["data"]["msssim"] = {"kernel_size": 7}
    path = _saved(tmp_path, json.dumps(records))
    code, out, err = _run(capsys, "--json", path, "--lock", str(_lock(tmp_path, 3)))
    assert code == 0 and out[1].startswith("workspace (stale)") and out[2].startswith("main ")
    assert (
        len(err) == 1
        and err[0].startswith("warning: workspace (stale): its params differ")
        and "msssim" in err[0]
    )
    code, out, err = _run(capsys, "--json", path, "--lock", str(_lock(tmp_path, 7)))
    assert code == 0 and out[1].split()[0] == "workspace" and "stale" not in out[1] and err == []


def test_the_lock_is_read_when_dvc_runs_here(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    records = exp.read_json(SAMPLE)
    records[0]["data"]["params"]["params.yaml"]["data"]["msssim"] = {"kernel_size": 7}
    path = _saved(tmp_path, json.dumps(records))
    script = f"import sys; sys.stdout.write(open({path!r}).read())"
    monkeypatch.setattr(exp, "_dvc_command", lambda: [sys.executable, "-c", script])
    monkeypatch.chdir(tmp_path)
    _lock(tmp_path, 3)
    code, out, err = _run(capsys)
    assert code == 0 and out[1].startswith("workspace (stale)") and len(err) == 1
