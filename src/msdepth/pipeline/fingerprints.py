"""What each stage's code does, as a small file that DVC tracks in place of the code's source bytes.

A stage's code is its script (``stages/<x>.py``) and the transitive closure of the ``msdepth``
modules it imports, found statically with ``ast`` (every ``import`` statement, including those
inside functions, and the ``__init__.py`` of every package on the way). Its fingerprint,
``data/fingerprints/<x>.txt``, lists each of those files with the sha256 of its syntax tree:

- without docstrings (every statement that is a bare string: module, class, function and
  attribute docstrings), and without comments, formatting and line numbers, which the tree never
  holds: an edit of those leaves every byte of the fingerprint as it was;
- with every name, literal (``3`` -> ``4`` changes it; ``1.0`` -> ``1.00`` does not: the same
  value), operator and annotation (a dataclass's fields come from its annotations): any edit that
  can change what the code does changes it;
- in a form that is the same on Python 3.10 to 3.13: the tree is written field by field, sorted,
  leaving out empty lists and ``None`` (3.12 added ``type_params=[]`` to every function and class,
  and 3.13's ``ast.dump`` leaves out empty fields), and with each f-string's text in one piece
  between its fields (3.12 and 3.13 split it, a format spec's above all, into other parts), so a
  fresh clone's ``dvc repro`` on another Python reruns nothing for a source written in syntax
  those versions share.

The ``fingerprints`` stage (``stages/fingerprints.py``) writes them on every ``dvc repro``
(``always_changed``: it reads only the sources, in about a second) and rewrites a file only when
its bytes change; every other stage depends on its own file, so DVC reruns it exactly when its
code's behaviour may have changed. Stages that share a script share its file.

What the fingerprint does not see: the Python and library versions (as source deps never did), and
a docstring's text at run time (``__doc__``: the stages' ``--help`` only).
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import re
import sys
from pathlib import Path

from msdepth.errors import DataError, MsdepthError
from msdepth.io import remove_stale_temps, write_text
from msdepth.pipeline.paths import FINGERPRINTS
from msdepth.readers import read_text_file

PACKAGE = "msdepth"
STAGES = Path("stages")
SCRIPT = STAGES / "fingerprints.py"  # the stage that writes the fingerprints (none of its own)
HEADER = (
    "# The behaviour of {script}'s code (msdepth.pipeline.fingerprints): each file it runs, with the\n"
    "# sha256 of its syntax tree without docstrings. Comments, docstrings and formatting leave it as is.\n"
)


def module_file(name: str, src: Path) -> Path | None:
    """The file of module ``name`` (``a.b`` -> ``src/a/b.py`` or ``src/a/b/__init__.py``), if any."""
    base = src.joinpath(*name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def parse(path: Path) -> tuple[str, ast.Module]:
    """The text of the Python file ``path`` and its syntax tree; one DataError line if it is not Python."""
    text = read_text_file(path, "Python source")
    try:
        return text, ast.parse(text, filename=str(path))
    except SyntaxError as exc:
        raise DataError(f"{path}: not valid Python (line {exc.lineno}: {exc.msg})") from None


def _skipped_nodes(tree: ast.AST) -> set[int]:
    """The ids of the nodes inside ``if TYPE_CHECKING:`` blocks, which never run."""
    return {
        id(n)
        for block in ast.walk(tree)
        if isinstance(block, ast.If) and "TYPE_CHECKING" in ast.unparse(block.test)
        for stmt in block.body
        for n in ast.walk(stmt)
    }


class Sources:
    """The source files of one run, each read and parsed once (a closure walks most of them, and
    every stage's closure the same ones)."""

    def __init__(self) -> None:
        self.parsed: dict[Path, tuple[str, ast.Module]] = {}
        self.hashes: dict[Path, str] = {}
        self.imports: dict[tuple[Path, str | None], set[str]] = {}

    def parse(self, path: Path) -> tuple[str, ast.Module]:
        """:func:`parse` of ``path``, once."""
        if path not in self.parsed:
            self.parsed[path] = parse(path)
        return self.parsed[path]

    def hash(self, path: Path) -> str:
        """The sha256 of ``path``'s :func:`canonical` syntax tree, once."""
        if path not in self.hashes:
            self.hashes[path] = hashlib.sha256(canonical(self.parse(path)[1]).encode("utf-8")).hexdigest()
        return self.hashes[path]


def imported_modules(
    path: Path, module: str | None, src: Path, package: str = PACKAGE, sources: Sources | None = None
) -> set[str]:
    """The ``package`` modules that the file ``path`` (module ``module``; None for a script) imports.

    ``from X import y`` counts ``X`` and, when ``y`` is a submodule, ``X.y`` too; relative imports
    are resolved against the module's package.
    """
    is_package = path.name == "__init__.py"
    found: set[str] = set()
    text, tree = (sources or Sources()).parse(path)
    skipped = _skipped_nodes(tree)
    registry = r"\b(pkgutil\.iter_modules|importlib\.import_module)\(|\bRegistry\(__name__\b"
    if is_package and re.search(registry, text):
        # A package that imports its own modules by name (a registry, msdepth.config.variants._registry's
        # Registry): count them all.
        found.update(f"{module}.{p.stem}" for p in path.parent.glob("*.py") if p.name != "__init__.py")
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                if module is None:
                    raise DataError(f"{path}: a relative import in a script")
                parts = module.split(".") if is_package else module.split(".")[:-1]
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join(parts + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            found.add(base)
            found.update(f"{base}.{a.name}" for a in node.names if module_file(f"{base}.{a.name}", src))
    return {m for m in found if m == package or m.startswith(package + ".")}


def import_closure(
    script: Path, src: Path, package: str = PACKAGE, sources: Sources | None = None
) -> set[Path]:
    """Every source file that running ``script`` executes from ``package``: the modules it imports,
    theirs in turn, and each one's parent packages' ``__init__.py`` (``sources``: files parsed already)."""
    files: set[Path] = set()
    todo: list[tuple[Path, str | None]] = [(script, None)]
    sources = sources or Sources()
    while todo:
        path, module = todo.pop()
        if (path, module) not in sources.imports:
            sources.imports[path, module] = imported_modules(path, module, src, package, sources)
        for name in sources.imports[path, module]:
            parts = name.split(".")
            for i in range(1, len(parts) + 1):  # importing a.b.c runs a/__init__ and a/b/__init__ first
                sub = ".".join(parts[:i])
                file = module_file(sub, src)
                if file is None:
                    raise DataError(f"{path}: imports {sub}, which has no file under {src}")
                if file not in files:
                    files.add(file)
                    todo.append((file, sub))
    return files


def _is_docstring(node: object) -> bool:
    """Whether ``node`` is a statement that is only a string: a docstring, which does nothing."""
    return (
        isinstance(node, ast.Expr)
        and isinstance(node.value, ast.Constant)
        and isinstance(node.value.value, str)
    )


def _fstring_parts(values: list[ast.expr]) -> list[ast.expr]:
    """An f-string's parts without empty strings and with adjacent strings joined: Python 3.12 and
    3.13 split the same f-string's text (a format spec's above all) differently from 3.11."""
    parts: list[ast.expr] = []
    for value in values:
        if isinstance(value, ast.Constant) and isinstance(value.value, str):
            if not value.value:
                continue
            if parts and isinstance(parts[-1], ast.Constant):
                parts[-1] = ast.Constant(value=parts[-1].value + value.value)
                continue
        parts.append(value)
    return parts


def canonical(node: object) -> str:
    """``node`` (a syntax tree, a list of them or a field's value) as text: every field but the
    positions, without docstring statements, without fields that are empty lists or None, and with
    f-strings' parts in one form (so that the text is the same on every Python from 3.10 to 3.13:
    see the module's docstring).

    >>> canonical(ast.parse("x = 1  # one"))
    "Module(body=[Assign(targets=[Name(ctx=Store(), id='x')], value=Constant(value=1))])"
    """
    if isinstance(node, ast.FormattedValue) and isinstance(node.format_spec, ast.Constant):
        spec = ast.JoinedStr(values=[node.format_spec])  # 3.13 may leave out the JoinedStr
        node = ast.FormattedValue(value=node.value, conversion=node.conversion, format_spec=spec)
    if isinstance(node, ast.JoinedStr):
        node = ast.JoinedStr(values=_fstring_parts(node.values))
    if isinstance(node, ast.AST):
        fields = [(name, getattr(node, name, None)) for name in sorted(node._fields)]
        shown = [f"{name}={canonical(value)}" for name, value in fields if value is not None and value != []]
        return f"{type(node).__name__}({', '.join(shown)})"
    if isinstance(node, list):
        return f"[{', '.join(canonical(item) for item in node if not _is_docstring(item))}]"
    return repr(node)


def behaviour_hash(path: Path) -> str:
    """The sha256 of the Python file ``path``'s :func:`canonical` syntax tree."""
    return Sources().hash(path)


def fingerprint_path(script: str | Path) -> Path:
    """The fingerprint file of stage script ``stages/<x>.py``: ``data/fingerprints/<x>.txt``."""
    return FINGERPRINTS / f"{Path(script).stem}.txt"


def fingerprint_text(root: Path, script: str | Path, sources: Sources | None = None) -> str:
    """The fingerprint of stage script ``script`` (relative to the project folder ``root``): one line
    per file it runs (the script first, then its import closure, sorted), the file relative to
    ``root`` and the sha256 of its syntax tree (:func:`behaviour_hash`)."""
    path, sources = root / script, sources or Sources()
    closure = import_closure(path, root / "src", sources=sources)
    files = [path, *sorted(closure, key=lambda p: p.relative_to(root).as_posix())]
    lines = [f"{f.relative_to(root).as_posix()} {sources.hash(f)}\n" for f in files]
    return HEADER.format(script=Path(script).as_posix()) + "".join(lines)


def stage_scripts(root: Path) -> list[str]:
    """The stage scripts under ``root`` that have a fingerprint: ``stages/*.py`` but :data:`SCRIPT`."""
    return [
        p.relative_to(root).as_posix() for p in sorted((root / STAGES).glob("*.py")) if p != root / SCRIPT
    ]


def write_fingerprints(root: Path) -> list[str]:
    """Write every stage script's fingerprint under ``root`` / :data:`FINGERPRINTS` and remove those of
    scripts that no longer exist; only a file whose bytes change is written. Returns the changed
    files (relative to ``root``)."""
    folder = root / FINGERPRINTS
    folder.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(folder)  # a killed run's: they would be part of the folder DVC records
    sources = Sources()
    wanted = {fingerprint_path(s): fingerprint_text(root, s, sources) for s in stage_scripts(root)}
    changed = []
    for name, text in wanted.items():
        path = root / name
        if not path.is_file() or read_text_file(path, "fingerprint") != text:
            write_text(path, text)
            changed.append(name.as_posix())
    for path in sorted(folder.glob("*.txt")):
        if path.relative_to(root) not in wanted:
            path.unlink()
            changed.append(path.relative_to(root).as_posix())
    return changed


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Write the stage scripts' fingerprints (``--root``: the project folder); one error line and
    exit code 1 on a file that is not Python or a missing module."""
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Write data/fingerprints/<x>.txt, the behaviour of stages/<x>.py's code, for each stage.",
        epilog="Run by `dvc repro` on every run (dvc.yaml: always_changed); reads no params.",
    )
    parser.add_argument("--root", type=Path, default=Path("."), help="the project folder (stages/, src/)")
    args = parser.parse_args(argv)
    try:
        changed = write_fingerprints(args.root)
    except (MsdepthError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"fingerprints: {', '.join(changed) + ' written' if changed else 'unchanged'}")
    return 0
