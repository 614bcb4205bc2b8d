"""The experiments table of ``msdepth experiments`` (issue 43): ``dvc exp show --json`` read as one row
per experiment with each variant's kernel size and mean over seeds, within 120 columns.

DVC names a metric's column ``<file>:<key>`` (``metrics/headline/mean/msssim.json:abs_rel``) and
cannot rename it, so ``dvc exp show`` with the same columns is about 260 characters wide; here the
columns are ``<variant> k`` and ``<key> <variant>``. The input is DVC's own JSON: a list of
revisions (the workspace, then each baseline commit), each with ``data.params`` and ``data.metrics``
and its ``experiments``, each a named list of ``revs`` of the same shape.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from typing import Any, Sequence

from msdepth.errors import DataError
from msdepth.io import read_bounded
from msdepth.pipeline.paths import mean_path

MAX_JSON_BYTES = 64 << 20  # dvc exp show --json of ten experiments is about 150 KB
DEFAULT_KEYS = ("abs_rel", "windshield")
PARAMS_FILE = "params.yaml"
MISSING = "-"
# Rows x columns of the table: 60,000 rows of 1,000 variants' columns took 2 GB and 26 s, then failed.
MAX_CELLS = 1_000_000
SOURCE = "dvc exp show --json"


@dataclass(frozen=True)
class Experiment:
    """One row: its label as DVC prints it, its ``params.yaml`` data and its metrics by file."""

    label: str
    params: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)


def _parse_json(data: bytes, source: str) -> list:
    """``dvc exp show --json``'s output ``data`` as a list of revisions; one DataError naming ``source``
    when it is larger than :data:`MAX_JSON_BYTES`, not UTF-8 JSON, or not a list of records."""
    if len(data) > MAX_JSON_BYTES:
        raise DataError(f"{source}: larger than {MAX_JSON_BYTES >> 20} MiB: not dvc exp show --json output")
    try:
        records = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise DataError(f"{source}: not UTF-8 text (byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise DataError(f"{source}: not JSON: {exc.msg} (line {exc.lineno}, column {exc.colno})") from None
    except RecursionError:
        raise DataError(f"{source}: not JSON: nested too deeply") from None
    except ValueError as exc:  # e.g. an integer of more digits than Python converts (4300)
        raise DataError(f"{source}: not JSON this table can read: {_first_sentence(exc)}") from None
    if not isinstance(records, list) or not all(isinstance(r, dict) for r in records):
        raise DataError(f"{source}: expected a list of revisions, as dvc exp show --json prints")
    return records


def _first_sentence(exc: Exception) -> str:
    return str(exc).split(";")[0].split(": ")[0]


def read_json(path: str | os.PathLike) -> list:
    """The revisions of a saved ``dvc exp show --json`` output: a regular file of at most
    :data:`MAX_JSON_BYTES` (:func:`msdepth.io.read_bounded`: a FIFO would block the read forever, a
    larger file is refused before it is read), parsed by :func:`_parse_json`."""
    return _parse_json(read_bounded(path, "JSON", MAX_JSON_BYTES, allow_empty=True), str(path))


def _dvc_command() -> list[str]:
    """The command line that runs DVC: ``dvc`` on the PATH, else this Python's ``dvc`` module; one
    DataError when neither is there."""
    found = shutil.which("dvc")
    if found:
        return [found]
    if importlib.util.find_spec("dvc") is not None:
        return [sys.executable, "-m", "dvc"]
    raise DataError("dvc not found: install it (pip install dvc) or pass a saved output with --json FILE")


def run_exp_show() -> list:
    """The revisions ``dvc exp show --json`` prints in the current folder; one DataError when DVC is
    missing, fails (its last line of error output) or prints no such JSON."""
    command = [*_dvc_command(), "exp", "show", "--json"]
    try:
        proc = subprocess.run(command, capture_output=True)
    except OSError as exc:
        raise DataError(f"dvc exp show --json: cannot run {command[0]}: {exc.strerror or exc}") from None
    if proc.returncode:
        lines = proc.stderr.decode("utf-8", "replace").strip().splitlines() or ["no error output"]
        raise DataError(f"dvc exp show --json failed (exit {proc.returncode}): {lines[-1].strip()}")
    return _parse_json(proc.stdout, "dvc exp show --json")


def _data(record: dict) -> tuple[dict, dict]:
    """A revision's ``params.yaml`` data and ``{metrics file: its data}`` (empty where it has none)."""
    data = _mapping(record.get("data"))
    params = _mapping(_mapping(_mapping(data.get("params")).get(PARAMS_FILE)).get("data"))
    metrics = {
        str(name): entry["data"]
        for name, entry in _mapping(data.get("metrics")).items()
        if isinstance(entry, dict) and isinstance(entry.get("data"), dict)
    }
    return params, metrics


def _mapping(value: Any) -> dict:
    """``value`` where it is a mapping, else an empty one (DVC's JSON read defensively)."""
    return value if isinstance(value, dict) else {}


def _list(value: Any) -> list:
    """``value`` where it is a list, else an empty one."""
    return value if isinstance(value, list) else []


def _text(record: dict, key: str, source: str, where: str) -> str:
    """``record[key]`` where it is a string ("" where absent or null); one DataError naming ``source``
    for any other type (a number, NaN, a list): DVC writes names and revs as strings."""
    value = record.get(key)
    if value is None:
        return ""
    if not isinstance(value, str):
        raise DataError(f"{source}: {where} has a {key} that is a {type(value).__name__}, not a string")
    return value


def experiments(records: Sequence[dict], source: str = SOURCE) -> list[Experiment]:
    """The rows in DVC's order: each top-level revision (``workspace``, a baseline by its branch
    name, else its short sha), then its experiments' revisions as ``<short sha> [name]``. A name or
    rev that is not a string is one DataError naming ``source``."""
    rows = []
    for number, record in enumerate(records, 1):
        where = f"revision {number}"
        rev = _text(record, "rev", source, where)
        label = _text(record, "name", source, where) or (rev if rev == "workspace" else rev[:7])
        rows.append(Experiment(label, *_data(record)))
        for experiment in _list(record.get("experiments")):
            if not isinstance(experiment, dict):
                continue
            group = _text(experiment, "name", source, f"an experiment of {where}")
            for entry in _list(experiment.get("revs")):
                if not isinstance(entry, dict):
                    continue
                name = _text(entry, "name", source, f"an experiment of {where}") or group
                sha = _text(entry, "rev", source, f"an experiment of {where}")[:7]
                rows.append(Experiment(f"{sha} [{name}]" if name else sha, *_data(entry)))
    return rows


def variants(rows: Sequence[Experiment]) -> list[str]:
    """The variants of the rows' ``params.yaml`` (its ``variants`` list), in order of first use."""
    found: dict[str, None] = {}  # ordered, and a lookup in constant time: linear in the rows' lists
    for row in rows:
        listed = row.params.get("variants")
        for name in listed if isinstance(listed, list) else []:
            if isinstance(name, str):
                found.setdefault(name)
    return list(found)


def cell(value: Any) -> str:
    """A value as DVC prints it: numbers to 5 significant digits, :data:`MISSING` where absent."""
    if value is None or isinstance(value, (dict, list)):
        return MISSING
    if isinstance(value, float):
        return f"{value:.5g}"
    return str(value)


def lookup(data: dict, key: str) -> Any:
    """``data[key]``, or a nested value by a dotted key (``roi.road``) as DVC flattens them."""
    if key in data:
        return data[key]
    node: Any = data
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def table(rows: Sequence[Experiment], keys: Sequence[str] = DEFAULT_KEYS) -> list[list[str]]:
    """The header and one line of cells per row: experiment, ``<variant> k`` per variant, then
    ``<key> <variant>`` per key and variant (the mean from ``metrics/headline/mean/<variant>.json``)."""
    names = variants(rows)
    files = {v: mean_path(v).as_posix() for v in names}
    header = ["Experiment", *(f"{v} k" for v in names), *(f"{k} {v}" for k in keys for v in names)]
    if (len(rows) + 1) * len(header) > MAX_CELLS:
        raise DataError(
            f"{SOURCE}: {len(rows)} experiments x {len(header)} columns is over {MAX_CELLS:,} cells, "
            "more than a table can show; pass fewer --keys or fewer experiments"
        )
    lines = [header]
    for row in rows:
        kernels = [
            cell(row.params[v].get("kernel_size")) if isinstance(row.params.get(v), dict) else MISSING
            for v in names
        ]
        means = [cell(lookup(row.metrics.get(files[v], {}), k)) for k in keys for v in names]
        lines.append([row.label, *kernels, *means])
    return lines


def _printable(text: str) -> str:
    """``text`` with each character that is not printable escaped as Python writes it (``\\x1b``,
    ``\\n``, ``\\u202e``, a lone surrogate ``\\ud800``): a label from DVC's JSON cannot move the
    cursor, recolour the terminal, reorder the line or start a forged row."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)


def format_table(lines: Sequence[Sequence[str]], markdown: bool = False) -> str:
    """``lines`` (header first) as aligned text, columns two spaces apart, or as a markdown table;
    the first column left-aligned, the others right-aligned. Every cell is :func:`_printable` (and a
    markdown cell's ``|`` escaped)."""
    lines = [
        [_printable(c).replace("|", "\\|") if markdown else _printable(c) for c in line] for line in lines
    ]
    widths = [max(len(line[i]) for line in lines) for i in range(len(lines[0]))]

    def aligned(line: Sequence[str]) -> list[str]:
        cells = zip(line, widths, strict=True)
        return [c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(cells)]

    if not markdown:
        return "\n".join("  ".join(aligned(line)).rstrip() for line in lines) + "\n"
    rule = ["-" * widths[0], *("-" * (w - 1) + ":" for w in widths[1:])]
    out = [lines[0], rule, *lines[1:]]
    return "\n".join(f"| {' | '.join(aligned(line) if line is not rule else rule)} |" for line in out) + "\n"
