"""``msdepth experiments``: ``dvc exp show``'s experiments as one compact table (issue 43).

Each row is an experiment (the workspace, the baseline, each ``dvc exp run``), with each variant's
kernel size and its mean over seeds of ``--keys`` (:mod:`msdepth.reporting.experiments`): within 120
columns for two variants, where ``dvc exp show`` cannot rename its 40-character metric columns.
"""

from __future__ import annotations

import argparse
import sys
from typing import Callable

from msdepth.reporting.experiments import DEFAULT_KEYS

LOCK_FILE = "dvc.lock"


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
    from msdepth.reporting.experiments import (
        SOURCE,
        STALE,
        experiments,
        format_table,
        mark_stale,
        mean_keys,
        read_json,
        read_lock,
        run_exp_show,
        table,
        unknown_keys,
    )

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
