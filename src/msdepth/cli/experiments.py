"""``msdepth experiments``: ``dvc exp show``'s experiments as one compact table (issue 43).

Each row is an experiment (the workspace, the baseline, each ``dvc exp run``), with each variant's
kernel size and its mean over seeds of ``--keys`` (:mod:`msdepth.reporting.experiments`): within 120
columns for two variants, where ``dvc exp show`` cannot rename its 40-character metric columns.
"""

from __future__ import annotations

import argparse
from typing import Callable

from msdepth.reporting.experiments import DEFAULT_KEYS


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
        help="keys of the mean files, dotted for nested ones, e.g. roi.road "
        f"(default: {' '.join(DEFAULT_KEYS)})",
    )
    e.add_argument("--md", action="store_true", help="print a markdown table")
    e.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Print the table of ``msdepth experiments`` to stdout."""
    from msdepth.reporting.experiments import (
        SOURCE,
        experiments,
        format_table,
        read_json,
        run_exp_show,
        table,
    )

    records = read_json(args.json_file) if args.json_file else run_exp_show()
    rows = experiments(records, args.json_file or SOURCE)
    print(format_table(table(rows, args.keys), markdown=args.md), end="")
    return 0
