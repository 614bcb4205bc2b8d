"""No function over 60 lines in src/, stages/, benchmarks/ or studies/ (the project's standard).

A function's length runs from its ``def`` line to the last line of its body; decorators are not
counted, nested functions are checked on their own (and count towards the enclosing one).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("src", "stages", "benchmarks", "studies")
MAX_LINES = 60


def long_functions(source: str, limit: int = MAX_LINES) -> list[tuple[str, int, int]]:
    """``(qualified name, def line, lines)`` of every function in ``source`` longer than ``limit``."""
    found: list[tuple[str, int, int]] = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f"{prefix}{child.name}"
                lines = child.end_lineno - child.lineno + 1
                if lines > limit:
                    found.append((name, child.lineno, lines))
                visit(child, f"{name}.<locals>.")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")
            else:
                visit(child, prefix)

    visit(ast.parse(source), "")
    return found


def _function(name: str, lines: int, indent: str = "") -> str:
    """The source of a function ``lines`` long, its ``def`` line included."""
    return f"{indent}def {name}():\n" + "".join(f"{indent}    x{i} = {i}\n" for i in range(lines - 1))


def test_the_checker_counts_from_the_def_line_to_the_end_of_the_body() -> None:
    source = "@decorator\n" + _function("at_limit", 60)  # 61 with its decorator, which is not counted
    source += "class C:\n" + _function("method", 61, "    ")
    source += "def outer():\n" + _function("inner", 61, "    ") + "    return inner\n"
    found = {name: lines for name, _, lines in long_functions(source)}
    assert found == {"C.method": 61, "outer": 63, "outer.<locals>.inner": 61}
    assert long_functions(_function("f", 61), limit=61) == []


def test_no_function_over_60_lines() -> None:
    over = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            for name, line, lines in long_functions(path.read_text(), MAX_LINES):
                over.append(f"{rel}:{line} {name}: {lines} lines")
    assert not over, f"functions over {MAX_LINES} lines (split them into named steps):\n" + "\n".join(over)
