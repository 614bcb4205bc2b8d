"""dvc.yaml's generated parts: ``python -m msdepth.pipeline.dvcyaml`` writes them (``--check`` compares).

Two parts of dvc.yaml are written from the code, so that each is defined once:

- every stage's code dep: its script's fingerprint, ``data/fingerprints/<x>.txt`` for
  ``python stages/<x>.py`` in ``cmd`` (:mod:`msdepth.pipeline.fingerprints`: the syntax trees of
  the script and of its import closure, which the ``fingerprints`` stage writes on every run);
- every path that ends in ``# = EXPR``, from :mod:`msdepth.pipeline.paths`'s definition of that file
  (EXPR: one of its names, e.g. ``EVAL_FRAMES``, or a call of one of its path functions on
  ``RUN``, a matrix stage's run as dvc.yaml spells it: ``model_path(RUN)``, or on another matrix
  item: ``cost_curves_path(VARIANT)``).

In dvc.yaml a stage's code dep is the entry at the head of its ``deps`` list (source entries under
``stages/`` and ``src/`` there, as dvc.yaml listed them before the fingerprints, are replaced by
it). The ``fingerprints`` stage itself must be ``always_changed`` with no deps. The command
rewrites those lines and the tagged paths, nothing else: comments, order and every other key keep
their bytes (pyyaml would drop the comments, so the file is edited as text). A stage without
``deps`` gets the list after its ``cmd`` line.
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from pathlib import Path

import yaml

from msdepth.errors import DataError, MsdepthError
from msdepth.pipeline import fingerprints
from msdepth.readers import read_text_file

# The entries at the head of a stage's deps that the generator owns: its fingerprint, and source
# files (what a stage listed before the fingerprints, rewritten to its fingerprint).
CODE_PREFIXES = (f"{fingerprints.FINGERPRINTS.as_posix()}/", "stages/", "src/")
COMMAND = "python -m msdepth.pipeline.dvcyaml"


def _stage_scripts(dvc_yaml: dict) -> dict[str, str]:
    """``{stage name: its script}`` for every stage; each stage's cmd must run ``python stages/<x>.py``."""
    scripts = {}
    for name, stage in dvc_yaml["stages"].items():
        match = re.match(r"python (stages/\S+\.py)\b", str(stage.get("cmd", "")))
        if not match:
            raise DataError(f"dvc.yaml: stage {name}: cmd {stage.get('cmd')!r} does not run a stage script")
        scripts[name] = match.group(1)
    return scripts


def _code_deps(script: str) -> list[str]:
    """A stage's code dep: its script's fingerprint (none for the stage that writes them)."""
    if script == fingerprints.SCRIPT.as_posix():
        return []
    if Path(script).parent != fingerprints.STAGES:
        raise DataError(f"dvc.yaml: {script}: a stage script must lie in {fingerprints.STAGES}/")
    return [fingerprints.fingerprint_path(script).as_posix()]


def _check_fingerprint_stage(dvc_yaml: dict, scripts: dict[str, str]) -> None:
    """One stage runs :data:`msdepth.pipeline.fingerprints.SCRIPT`: always (``always_changed``), with
    no deps (it reads every source on each run, and listed sources would put their bytes back
    into dvc.lock)."""
    names = [n for n, s in scripts.items() if s == fingerprints.SCRIPT.as_posix()]
    if len(names) != 1:
        raise DataError(f"dvc.yaml: {len(names)} stages run {fingerprints.SCRIPT}, not one")
    stage = dvc_yaml["stages"][names[0]]
    if stage.get("always_changed") is not True or stage.get("deps"):
        raise DataError(f"dvc.yaml: stage {names[0]}: needs 'always_changed: true' and no deps")


def _stage_block(lines: list[str], name: str) -> tuple[int, int, str]:
    """(first line, end line, indent of its keys) of stage ``name`` under the top-level ``stages:``."""
    top = lines.index("stages:\n") if "stages:\n" in lines else None
    if top is None:
        raise DataError("dvc.yaml: no top-level 'stages:' line")
    keys = [x for x in lines[top + 1 :] if x.strip() and not x.lstrip().startswith("#")]
    pad = " " * (_indent(keys[0]) if keys else 2)
    starts = [
        i for i in range(top + 1, len(lines)) if re.match(rf"{pad}{re.escape(name)}:\s*(#.*)?$", lines[i])
    ]
    if not starts:
        raise DataError(f"dvc.yaml: no line '{name}:' under stages:")
    start = starts[0]
    indent = len(lines[start]) - len(lines[start].lstrip())
    end = start + 1
    while end < len(lines) and (
        not lines[end].strip() or lines[end].lstrip().startswith("#") or _indent(lines[end]) > indent
    ):
        end += 1
    while end > start + 1 and (not lines[end - 1].strip() or lines[end - 1].lstrip().startswith("#")):
        end -= 1  # comments and blank lines before the next stage belong to it
    key_indent = next((_indent(x) for x in lines[start + 1 : end] if x.strip()), indent + 2)
    return start, end, " " * key_indent


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


def _item(line: str) -> str | None:
    """The value of a YAML list item line (``- value  # comment``), else None."""
    match = re.match(r"\s*- ([^#\s]+)", line)
    return match.group(1).rstrip(":") if match else None


def _rewrite_stage(lines: list[str], name: str, deps: list[str]) -> list[str]:
    """``lines`` with the head of stage ``name``'s deps list replaced by ``deps``."""
    start, end, key = _stage_block(lines, name)
    deps_at = next((i for i in range(start + 1, end) if re.match(rf"{key}deps:\s*(#.*)?$", lines[i])), None)
    if deps_at is None:  # a new stage: its deps list goes after its cmd line
        cmd_at = next(
            (i for i in range(start + 1, end) if lines[i].startswith(f"{key}cmd: python stages/")), None
        )
        if cmd_at is None:
            raise DataError(f"dvc.yaml: stage {name}: no one-line 'cmd: python stages/...' to put deps after")
        return (
            lines[: cmd_at + 1] + [f"{key}deps:\n"] + [f"{key}  - {d}\n" for d in deps] + lines[cmd_at + 1 :]
        )
    first = last = deps_at + 1
    item_indent = " " * _indent(lines[first]) if first < end and _item(lines[first]) else f"{key}  "
    while last < end and (value := _item(lines[last])) is not None and value.startswith(CODE_PREFIXES):
        last += 1
    rest = last
    while rest < end and _indent(lines[rest]) >= len(item_indent) and lines[rest].strip():
        value = _item(lines[rest])
        if value is not None and value.startswith(CODE_PREFIXES):
            raise DataError(
                f"dvc.yaml: stage {name}: code dep {value} follows other deps: "
                "list the code deps (stages/, src/) first"
            )
        rest += 1
    return lines[:first] + [f"{item_indent}- {d}\n" for d in deps] + lines[last:]


TAGGED = re.compile(r"^(\s*- )(\S+?)(:?)(\s+# = )(.+?)\s*$")
# The matrix items that a tagged path may use, as dvc.yaml spells them.
ITEMS = {
    "VARIANT": "${item.variant}",
    "SEED": "${item.seed}",
    "SET": "${item.set}",
    "WEIGHT": "${item.weight}",
}


def _tagged_path(expr: str) -> str:
    """The path that a dvc.yaml line's ``# = EXPR`` names: EXPR is a public name of
    :mod:`msdepth.pipeline.paths`, a call of one of its functions on :data:`ITEMS` (``RUN``: a matrix
    stage's run, as dvc.yaml spells it; ``VARIANT``, ``SEED``, ``SET``, ``WEIGHT``: a matrix item) or on
    strings, or either joined with ``/`` to a string."""
    from msdepth.pipeline import paths as pipeline

    run = pipeline.run_name(ITEMS["VARIANT"], ITEMS["SEED"])  # type: ignore[arg-type]
    items = {**ITEMS, "RUN": run}

    def value(node: ast.expr) -> object:
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            return node.value
        if isinstance(node, ast.Name) and node.id in items:
            return items[node.id]
        if isinstance(node, ast.Name) and not node.id.startswith("_") and hasattr(pipeline, node.id):
            return getattr(pipeline, node.id)
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and not node.keywords:
            return value(node.func)(*[value(a) for a in node.args])  # type: ignore[operator]
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div):
            return Path(value(node.left)) / value(node.right)  # type: ignore[arg-type,operator]
        raise DataError(f"{ast.unparse(node)!r} is not a name or path function of msdepth.pipeline.paths")

    try:
        result = value(ast.parse(expr, mode="eval").body)
    except (SyntaxError, TypeError) as exc:
        raise DataError(f"{expr!r}: {exc}") from None
    if not isinstance(result, (str, Path)):
        raise DataError(f"{expr!r} is not a path")
    return Path(result).as_posix()


def _rewrite_tagged(lines: list[str]) -> list[str]:
    """``lines`` with the path of every line that ends in ``# = EXPR`` written from EXPR."""
    out = []
    for number, line in enumerate(lines, 1):
        match = TAGGED.match(line)
        if match:
            try:
                path = _tagged_path(match.group(5))
            except DataError as exc:
                raise DataError(f"dvc.yaml, line {number}: {exc}") from None
            line = f"{match.group(1)}{path}{match.group(3)}{match.group(4)}{match.group(5)}\n"
        out.append(line)
    return out


def generate(root: Path) -> str:
    """dvc.yaml under ``root`` with every stage's code dep written (its script's fingerprint) and
    every tagged path from its definition in :mod:`msdepth.pipeline.paths`."""
    path = root / "dvc.yaml"
    text = read_text_file(path, "pipeline")
    try:
        dvc_yaml = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise DataError(f"{path}: not valid YAML: {str(exc).splitlines()[0]}") from None
    lines = text.splitlines(keepends=True)
    scripts = _stage_scripts(dvc_yaml)
    _check_fingerprint_stage(dvc_yaml, scripts)
    for name, script in scripts.items():
        if deps := _code_deps(script):
            lines = _rewrite_stage(lines, name, deps)
    return "".join(_rewrite_tagged(lines))


def _changed_stages(old: str, new: str) -> list[str]:
    """The stages that differ between two versions of dvc.yaml."""
    before, after = yaml.safe_load(old)["stages"], yaml.safe_load(new)["stages"]
    return [n for n in after if before.get(n) != after[n]]


def main(argv: list[str] | None = None) -> int:
    """Write (or with ``--check`` only compare) dvc.yaml's generated parts; the exit code is 1 on a
    difference under ``--check`` or an error."""
    ap = argparse.ArgumentParser(
        prog=COMMAND, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--root", type=Path, default=Path("."), help="the project folder (holding dvc.yaml, stages/, src/)"
    )
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 if dvc.yaml differs")
    args = ap.parse_args(argv)
    path = args.root / "dvc.yaml"
    try:
        old, new = read_text_file(path, "pipeline"), generate(args.root)
    except (MsdepthError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    stages = _changed_stages(old, new) if old != new else []
    if args.check:
        if old != new:
            print(
                f"{path}: generated parts out of date ({', '.join(stages) or 'layout'}): run `{COMMAND}`",
                file=sys.stderr,
            )
            return 1
        print(f"{path}: generated parts up to date")
        return 0
    if old != new:
        from msdepth.io import write_text

        write_text(path, new)
    print(f"{path}: generated parts {'rewritten for ' + ', '.join(stages) if old != new else 'up to date'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
