"""A/B of one benchmark script between an earlier commit and this checkout, rounds interleaved.

    python benchmarks/ab.py --base 6157c7b --rounds 3 -- train_loop.py --epochs 2 --warmup 0

The base commit is checked out into a temporary git worktree (removed afterwards). Each round runs
``benchmarks/<script> <args>`` once in each tree, with that tree's own ``src/`` and params, the
order alternating between rounds so that drift falls on both sides. The script's last
``images/s: name value, name value`` line is read; the table gives per candidate the median
images/s of each side and the median and range over rounds of the round's ratio this / base
(above 1: this checkout is faster). Run on idle cores; nothing else should share them.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GIT = ["git", "-C", str(ROOT)]
RATE = re.compile(r"(.+?) ([0-9.]+)$")


def images_per_second(output: str) -> dict[str, float]:
    """``{candidate: images/s}`` from the last ``images/s:`` line of a benchmark's output."""
    lines = [line for line in output.splitlines() if line.startswith("images/s:")]
    if not lines:
        raise SystemExit(f"error: no 'images/s:' line in the benchmark's output:\n{output[-2000:]}")
    rates = {}
    for item in lines[-1].removeprefix("images/s:").split(","):
        match = RATE.match(item.strip())
        if match:
            rates[match.group(1)] = float(match.group(2))
    return rates


def run_in(tree: Path, script: str, args: list[str]) -> dict[str, float]:
    """One run of ``tree/benchmarks/script`` with ``tree``'s package; its images/s per candidate."""
    env = {**os.environ, "PYTHONPATH": str(tree / "src")}
    cmd = [sys.executable, str(tree / "benchmarks" / script), *args]
    proc = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(f"error: {tree}: {' '.join(cmd[1:])} failed:\n{proc.stderr[-3000:]}")
    return images_per_second(proc.stdout)


def rounds(base_tree: Path, script: str, args: list[str], count: int) -> list[tuple[dict, dict]]:
    """``count`` rounds of (base rates, this checkout's rates), alternating which runs first."""
    results = []
    for r in range(count):
        order = [("base", base_tree), ("this", ROOT)] if r % 2 == 0 else [("this", ROOT), ("base", base_tree)]
        rates = {side: run_in(tree, script, args) for side, tree in order}
        print(f"round {r + 1}/{count}: base {rates['base']}, this {rates['this']}", flush=True)
        results.append((rates["base"], rates["this"]))
    return results


def table(results: list[tuple[dict, dict]]) -> str:
    """Per candidate both sides' median images/s and the ratio this / base over rounds."""
    lines = [
        "| candidate | base images/s | this images/s | this / base (median) | range |",
        "|---|---|---|---|---|",
    ]
    for name in results[0][0]:
        if not all(name in this for _, this in results):
            continue
        base = [b[name] for b, _ in results]
        this = [t[name] for _, t in results]
        ratios = [t / b for b, t in zip(base, this, strict=True)]
        lines.append(
            f"| {name} | {statistics.median(base):.2f} | {statistics.median(this):.2f} | "
            f"{statistics.median(ratios):.3f} | {min(ratios):.3f}-{max(ratios):.3f} |"
        )
    return "\n".join(lines)


def this_checkout() -> str:
    """This checkout's commit, marked when the working tree differs from it."""
    head = subprocess.run(
        [*GIT, "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    dirty = subprocess.run(
        [*GIT, "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True
    )
    return head + (" with uncommitted changes" if dirty.stdout.strip() else "")


def main(argv: list[str] | None = None) -> int:
    """Check the base out, run the rounds, print the table; the worktree is removed in any case."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, help="the earlier commit (any git revision)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("script", help="a script under benchmarks/ that prints an 'images/s:' line")
    ap.add_argument("args", nargs=argparse.REMAINDER, help="its arguments (after --)")
    args = ap.parse_args(argv)
    if args.base.startswith("-") or not args.base.strip():
        # git would read it as one of its own options (--orphan: its usage, 14 lines)
        print(f"error: --base: {args.base!r} is not a git revision", file=sys.stderr)
        return 1
    if args.rounds < 1:
        print(f"error: --rounds: must be >= 1, got {args.rounds}", file=sys.stderr)
        return 1
    script_args = args.args[1:] if args.args[:1] == ["--"] else args.args
    with tempfile.TemporaryDirectory(prefix="msdepth-ab-") as tmp:
        tree = Path(tmp) / "base"
        add = subprocess.run(
            [*GIT, "worktree", "add", "--detach", str(tree), args.base], capture_output=True, text=True
        )
        if add.returncode:
            why = " ".join(add.stderr.split())  # git's lines, as one
            print(f"error: --base {args.base}: cannot check it out: {why}", file=sys.stderr)
            return 1
        try:
            command = " ".join([f"benchmarks/{args.script}", *script_args])
            print(f"A/B of {command}: base {args.base}, this {this_checkout()}")
            print(table(rounds(tree, args.script, script_args, args.rounds)))
        finally:
            subprocess.run([*GIT, "worktree", "remove", "--force", str(tree)], capture_output=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
