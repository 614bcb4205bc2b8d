"""``msdepth experiments``: ``dvc exp show --json`` as one compact table (issue 43).

One row per experiment (the workspace, each baseline commit, each ``dvc exp run``) with each
variant's kernel size and its mean over seeds of ``--keys``: within 120 columns, where DVC names a
metric's column ``<file>:<key>`` and cannot rename it (about 260 characters for the same columns).
DVC's JSON is a list of revisions, each with ``data.params``, ``data.metrics`` and its
``experiments``, each a named list of ``revs`` of the same shape.

The input is bounded while it is read: a file of more JSON values than DVC writes in its bytes is
refused before it is parsed, the table's cells are counted before any row is built, and labels and
values are cut to :data:`MAX_CELL_CHARS`. A workspace row whose params differ from those
``dvc.lock`` records is marked :data:`STALE` (:func:`mark_stale`).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from msdepth.errors import DataError, MsdepthError
from msdepth.pipeline.paths import mean_path
from msdepth.readers import check_json_density, read_bounded, read_text_file

LOCK_FILE = "dvc.lock"

MAX_JSON_BYTES = 64 << 20  # dvc exp show --json of ten experiments is about 150 KB
# DVC's JSON spends over 10 bytes on each value: a file averaging under this many bytes per value
# (20 million "{}" took 6.3 GB) is refused before it is parsed (msdepth.readers.check_json_density).
MIN_BYTES_PER_VALUE = 6
# Each JSON object parses to a dict of ~200 bytes or more: 5 million records of 11 bytes each (57 MB)
# took 1.1 GB before the cell limit refused them. DVC spends ~400 objects of ~130 bytes on a revision,
# so 64 MiB of its output holds about 500,000: more is refused before parsing, bounding the dicts.
MAX_OBJECTS = 500_000
DEFAULT_KEYS = ("abs_rel", "windshield")
PARAMS_FILE = "params.yaml"
MISSING = "-"
# Rows x columns of the table: 60,000 rows of 1,000 variants' columns took 2 GB and 26 s, then failed.
MAX_CELLS = 1_000_000
MAX_LOCK_BYTES = 64 << 20  # the project's dvc.lock is about 0.3 MB
MAX_CELL_CHARS = 60  # a longer label or value is cut, so one 3 MB label cannot pad every row
SOURCE = "dvc exp show --json"
STALE = " (stale)"


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
    check_json_density(data, source, MIN_BYTES_PER_VALUE)
    objects = data.count(b"{")
    if objects > MAX_OBJECTS:
        raise DataError(
            f"{source}: up to {objects:,} JSON objects, over {MAX_OBJECTS:,}: more revisions than a table "
            "can show (dvc exp show spends about 400 objects on each); nothing was parsed"
        )
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
    :data:`MAX_JSON_BYTES` (:func:`msdepth.readers.read_bounded`: a FIFO would block the read forever, a
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


def experiments(
    records: Sequence[dict], source: str = SOURCE, keys: Sequence[str] = DEFAULT_KEYS
) -> list[Experiment]:
    """The rows in DVC's order: each top-level revision (``workspace``, a baseline by its branch
    name, else its short sha), then its experiments' revisions as ``<short sha> [name]``, each label
    cut to :data:`MAX_CELL_CHARS`. One DataError naming ``source`` for a name or rev that is not a
    string, or, before any row is built, for a table of ``keys`` over :data:`MAX_CELLS` cells."""
    _check_cells(records, source, keys)
    rows = []
    for number, record in enumerate(records, 1):
        where = f"revision {number}"
        rev = _text(record, "rev", source, where)
        label = _text(record, "name", source, where) or (rev if rev == "workspace" else rev[:7])
        rows.append(Experiment(_clipped(label), *_data(record)))
        for experiment in _list(record.get("experiments")):
            if not isinstance(experiment, dict):
                continue
            group = _text(experiment, "name", source, f"an experiment of {where}")
            for entry in _list(experiment.get("revs")):
                if not isinstance(entry, dict):
                    continue
                name = _text(entry, "name", source, f"an experiment of {where}") or group
                sha = _text(entry, "rev", source, f"an experiment of {where}")[:7]
                rows.append(Experiment(_clipped(f"{sha} [{name}]" if name else sha), *_data(entry)))
    return rows


def _revisions(records: Sequence[dict]) -> Iterator[dict]:
    """Each revision of ``records`` (a top-level one, then its experiments'), as :func:`experiments`
    reads them."""
    for record in records:
        yield record
        for experiment in _list(record.get("experiments")):
            if isinstance(experiment, dict):
                yield from (e for e in _list(experiment.get("revs")) if isinstance(e, dict))


def _check_cells(records: Sequence[dict], source: str, keys: Sequence[str]) -> None:
    """DataError naming ``source`` when the table of ``records`` would be over :data:`MAX_CELLS`
    cells: counted from the revisions and their ``variants`` before any row is built."""
    count, found = 0, {}
    for revision in _revisions(records):
        count += 1
        listed = _data(revision)[0].get("variants")
        found.update((n, None) for n in (listed if isinstance(listed, list) else []) if isinstance(n, str))
    _check_size(count, 1 + len(found) * (1 + len(keys)), source)


def _check_size(rows: int, columns: int, source: str) -> None:
    if (rows + 1) * columns > MAX_CELLS:
        raise DataError(
            f"{source}: {rows} experiments x {columns} columns is over {MAX_CELLS:,} cells, "
            "more than a table can show; pass fewer --keys or fewer experiments"
        )


def _clipped(text: str) -> str:
    """``text`` cut to :data:`MAX_CELL_CHARS` characters, its end marked ``...``."""
    return text if len(text) <= MAX_CELL_CHARS else text[: MAX_CELL_CHARS - 3] + "..."


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
    return _clipped(str(value))


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


def table(
    rows: Sequence[Experiment], keys: Sequence[str] = DEFAULT_KEYS, source: str = SOURCE
) -> list[list[str]]:
    """The header and one line of cells per row: experiment, ``<variant> k`` per variant, then
    ``<key> <variant>`` per key and variant (the mean from ``metrics/headline/mean/<variant>.json``);
    a DataError naming ``source`` over :data:`MAX_CELLS` cells."""
    names = variants(rows)
    files = {v: mean_path(v).as_posix() for v in names}
    header = ["Experiment", *(f"{v} k" for v in names), *(_clipped(f"{k} {v}") for k in keys for v in names)]
    _check_size(len(rows), len(header), source)
    lines = [header]
    for row in rows:
        kernels = [
            cell(row.params[v].get("kernel_size")) if isinstance(row.params.get(v), dict) else MISSING
            for v in names
        ]
        means = [cell(lookup(row.metrics.get(files[v], {}), k)) for k in keys for v in names]
        lines.append([row.label, *kernels, *means])
    return lines


def unknown_keys(rows: Sequence[Experiment], keys: Sequence[str]) -> list[str]:
    """The ``keys`` found in no row's mean file of any variant (a typo, or a key the mean files do
    not have, such as ``roi.road``): each would be a column of ``-`` only."""
    files = [mean_path(v).as_posix() for v in variants(rows)]
    found = {k for row in rows for f in files for k in keys if lookup(row.metrics.get(f, {}), k) is not None}
    return [k for k in keys if k not in found]


def mean_keys(rows: Sequence[Experiment]) -> list[str]:
    """The top-level keys of the rows' mean files, in order of first use (for a warning's hint)."""
    files = [mean_path(v).as_posix() for v in variants(rows)]
    return list(dict.fromkeys(k for row in rows for f in files for k in row.metrics.get(f, {})))


def stale_params(row: Experiment, lock: Any) -> list[str]:
    """The params (dotted keys of ``params.yaml``) whose value in ``row`` differs from the value a
    stage of ``lock`` (dvc.lock's data) last ran with: the row's metrics are older than its params
    (an interrupted ``dvc exp run -S``, an edit not yet reproduced). Empty where ``lock`` has none."""
    stages = _mapping(_mapping(lock).get("stages"))
    differing: dict[str, None] = {}
    for stage in stages.values():
        locked = _mapping(_mapping(_mapping(stage).get("params")).get(PARAMS_FILE))
        for key, value in locked.items():
            current = lookup(row.params, str(key))  # absent: a trimmed record, not a changed param
            if current is not None and current != value:
                differing.setdefault(str(key))
    return list(differing)


def mark_stale(rows: list[Experiment], lock: Any) -> list[str]:
    """Mark the ``workspace`` row :data:`STALE` when its params differ from ``lock``'s
    (:func:`stale_params`), in place; the differing params (empty when it is not stale)."""
    for number, row in enumerate(rows):
        if row.label == "workspace":
            differing = stale_params(row, lock)
            if differing:
                rows[number] = Experiment(row.label + STALE, row.params, row.metrics)
            return differing
    return []


def read_lock(path: str | os.PathLike) -> Any:
    """The data of the ``dvc.lock`` at ``path`` (None where there is none), read as params files are
    (:func:`msdepth.config.params_yaml.read_data_file`'s bounds); one DataError naming it otherwise."""
    from msdepth.config.params_yaml import parse

    if not Path(path).is_file():
        return None
    text = read_text_file(path, "DVC lock", MAX_LOCK_BYTES)
    try:
        return parse(text)
    except MsdepthError as exc:
        raise DataError(f"{path}: not a readable dvc.lock ({' '.join(str(exc).split())})") from None


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


def experiments_command(add_parser: Callable[..., argparse.ArgumentParser]) -> None:
    """Add the ``experiments`` subcommand with ``add_parser`` (``msdepth``'s subparsers' own method)."""
    e = add_parser(
        "experiments",
        help="each experiment's kernel sizes and mean abs_rel and windshield per variant, one table",
        description="Run 'dvc exp show --json' in the current folder (or read its saved output with --json) "
        "and print one row per experiment (workspace, baseline, '<sha> [name]' per experiment, in DVC's "
        "order): each variant's kernel size ('<variant> k'), then per key and variant the mean over seeds "
        "from metrics/headline/mean/<variant>.json ('<key> <variant>', 5 significant digits; '-' where "
        "absent).",
    )
    e.add_argument("--json", dest="json_file", metavar="FILE", help="saved 'dvc exp show --json' output")
    e.add_argument(
        "--keys",
        nargs="+",
        default=list(DEFAULT_KEYS),
        metavar="KEY",
        help="keys of the mean files (abs_rel, a1, roi, masks, a class name), dotted for nested ones; "
        "a key no mean file has is warned about "
        f"(default: {' '.join(DEFAULT_KEYS)})",
    )
    e.add_argument("--md", action="store_true", help="print a markdown table")
    e.add_argument(
        "--lock",
        metavar="FILE",
        help="the dvc.lock the workspace row is checked against: a row whose params differ from those "
        f"its metrics were made with is marked stale (default: ./{LOCK_FILE} when DVC is run here, "
        "none with --json)",
    )
    e.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Print the table of ``msdepth experiments`` to stdout; on stderr a warning for each key no
    mean file has, and for a workspace row whose metrics are older than its params (./dvc.lock)."""
    source = args.json_file or SOURCE
    records = read_json(args.json_file) if args.json_file else run_exp_show()
    rows = experiments(records, source, args.keys)
    lock = args.lock or (None if args.json_file else LOCK_FILE)
    stale = mark_stale(rows, read_lock(lock)) if lock else []
    print(format_table(table(rows, args.keys, source), markdown=args.md), end="")
    known = mean_keys(rows)
    for key in unknown_keys(rows, args.keys) if known else []:
        print(
            f"warning: --keys {key}: no experiment's mean file has it (keys there: {', '.join(known)})",
            file=sys.stderr,
        )
    if stale:
        print(
            f"warning: workspace{STALE}: its params differ from those its metrics were made with "
            f"({lock}: {', '.join(stale[:5])}); run `dvc exp run` or `dvc repro` to update them",
            file=sys.stderr,
        )
    return 0
