"""The ``msdepth`` package's import graph: no cycle, and no module reaching into another's private names.

The graph is static (``ast``), with the same reading of imports as dvc.yaml's code deps
(:func:`msdepth.pipeline.fingerprints.imported_modules`): every ``import`` statement, including those
inside functions, and a registry package's imports of its own modules by name; ``if TYPE_CHECKING:``
blocks never run and are left out. An import of a module's own enclosing package is left out too:
Python runs a package's ``__init__`` before any of its modules, whether or not the module names it,
so that edge is always there and only its reverse (a package importing its modules) is a choice.

The packages are layered (:data:`LAYERS`, drawn in docs/design.md): a module may import its own
package and the packages of lower layers, never a package of its own layer or a higher one, so
that e.g. the optimum cannot reach training code and a network cannot reach a loss.

Run ``python tests/test_imports.py`` to print the modules per package, the imports between
packages, and any cycle, upward import or private-name import it finds.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

from msdepth.pipeline.fingerprints import PACKAGE, imported_modules, module_file

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"


def modules(src: Path, package: str = PACKAGE) -> dict[str, Path]:
    """``{module name: file}`` for every module of ``package`` under ``src``."""
    found = {}
    for path in sorted((src / package).rglob("*.py")):
        parts = list(path.relative_to(src).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        found[".".join(parts)] = path
    return found


def import_graph(src: Path, package: str = PACKAGE) -> dict[str, set[str]]:
    """``{module: the package's modules it imports}``, without edges to its own enclosing packages."""
    graph = {}
    for name, path in modules(src, package).items():
        own = {".".join(name.split(".")[:i]) for i in range(1, name.count(".") + 1)}
        graph[name] = {m for m in imported_modules(path, name, src, package) if m != name and m not in own}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (each sorted; Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for succ in sorted(graph.get(node, ())):
            if succ not in index:
                visit(succ)
                low[node] = min(low[node], low[succ])
            elif succ in on_stack:
                low[node] = min(low[node], index[succ])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return sorted(found)


def _resolve(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    """The absolute module name of a ``from X import ...`` statement in ``module``."""
    if not node.level:
        return node.module or ""
    parts = module.split(".") if is_package else module.split(".")[:-1]
    parts = parts[: len(parts) - (node.level - 1)]
    return ".".join(parts + ([node.module] if node.module else []))


def private_imports(src: Path, package: str = PACKAGE) -> list[str]:
    """``module: name`` for each private name (``_x``, not a module) that a module of ``package``
    imports from, or reads as an attribute of, another module of the package."""
    found = []
    for name, path in modules(src, package).items():
        tree = ast.parse(path.read_text(), filename=str(path))
        bound: dict[str, str] = {}  # local name -> the package module it is bound to
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                base = _resolve(node, name, path.name == "__init__.py")
                if base != package and not base.startswith(package + "."):
                    continue
                for alias in node.names:
                    if module_file(f"{base}.{alias.name}", src):
                        bound[alias.asname or alias.name] = f"{base}.{alias.name}"
                    elif alias.name.startswith("_") and base != name:
                        found.append(f"{name}: from {base} import {alias.name}")
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.asname and alias.name.startswith(package + "."):
                        bound[alias.asname] = alias.name
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and node.value.id in bound
                and node.attr.startswith("_")
                and not node.attr.startswith("__")
                and not module_file(f"{bound[node.value.id]}.{node.attr}", src)
            ):
                found.append(f"{name}: {node.value.id}.{node.attr} (of {bound[node.value.id]})")
    return sorted(set(found))


# Lowest first. A top-level module counts as its own package (``errors``, ``io``, ``__main__``).
LAYERS = (
    ("errors",),  # the one-line errors every entry point prints
    ("io", "readers", "stats"),  # atomic writers (JSON, text, PNG, npy); bounded readers; statistics
    ("outputs",),  # the output policy: what a command may write into a user's folder
    ("config",),  # the typed params and each loss variant's settings (no torch)
    ("geometry", "pipeline"),  # warping, cameras, disparity <-> depth; the pipeline's paths
    ("data",),  # KITTI's formats and readers, stereo folders, layouts and owners, indexes, ROIs
    ("render", "download"),  # the synthetic set's renderer; KITTI's download
    ("prepare",),  # the prepare_data stage: render, download or check a stereo folder
    ("networks",),  # the depth and pose networks and their files
    ("losses",),  # SSIM and MS-SSIM, appearance terms, Monodepth's and Monodepth2's objectives
    ("training", "evaluation"),  # training a network; inference, suites, metrics, baselines
    ("optimum",),  # the losses' own optimum, scored as a run
    ("analysis",),  # the comparison as data: paired statistics, the verdict's rows, each loss's own best
    ("reporting",),  # compare.md, the results page, the figures
    ("cli",),  # the msdepth command's subcommands
    ("__main__",),  # the msdepth command
)
RANK = {package: rank for rank, layer in enumerate(LAYERS) for package in layer}


def package_of(module: str) -> str:
    """The first-level package (or top-level module) of ``module``: ``msdepth.a.b`` -> ``a``."""
    return module.split(".")[1] if "." in module else ""


def package_graph(graph: dict[str, set[str]]) -> dict[tuple[str, str], int]:
    """``{(importing package, imported package): number of module imports}``, across packages."""
    edges: dict[tuple[str, str], int] = {}
    for module, imported in graph.items():
        for other in imported:
            a, b = package_of(module), package_of(other)
            if a and b and a != b:
                edges[a, b] = edges.get((a, b), 0) + 1
    return edges


def upward_imports(graph: dict[str, set[str]], rank: dict[str, int] = RANK) -> list[str]:
    """``module -> module`` for each import of a package in the importer's layer or a higher one."""
    return sorted(
        f"{m} -> {o}"
        for m, imported in graph.items()
        for o in imported
        if package_of(m) and package_of(o) and package_of(m) != package_of(o)
        if rank[package_of(o)] >= rank[package_of(m)]
    )


def test_every_package_has_a_layer():
    packages = {package_of(m) for m in modules(SRC)} - {""}
    assert packages == set(RANK), f"not in LAYERS: {packages - set(RANK)}; gone: {set(RANK) - packages}"


def test_no_package_imports_its_own_layer_or_a_higher_one():
    found = upward_imports(import_graph(SRC))
    assert found == [], "imports that go up (or sideways) in LAYERS:\n" + "\n".join(found)


def test_no_import_cycle_in_src():
    found = cycles(import_graph(SRC))
    assert found == [], "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_no_module_imports_another_modules_private_names():
    found = private_imports(SRC)
    assert found == [], "private names imported across modules:\n" + "\n".join(found)


def study_edges(studies: Path) -> list[str]:
    """``script: what`` for each studies/ script that imports another script of the folder or
    changes ``sys.path`` (an edge the package graph cannot see): what several share belongs in the
    package, under the layering test."""
    scripts = {p.stem for p in studies.glob("*.py")}
    found = []
    for path in sorted(studies.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            names += [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else []
            found += [f"{path.name}: imports {n}" for n in names if n.split(".")[0] in scripts]
            call = node.func if isinstance(node, ast.Call) else None
            if isinstance(call, ast.Attribute) and ast.unparse(call).startswith("sys.path."):
                found.append(f"{path.name}: {ast.unparse(call)}")
    return found


def test_no_study_imports_another_or_changes_the_import_path(tmp_path: Path):
    assert study_edges(ROOT / "studies") == []
    (tmp_path / "a.py").write_text("import sys\nsys.path.insert(0, '.')\nfrom b import f\n")
    (tmp_path / "b.py").write_text("import a, numpy\n")
    assert sorted(study_edges(tmp_path)) == ["a.py: imports b", "a.py: sys.path.insert", "b.py: imports a"]


@pytest.fixture
def toy(tmp_path: Path) -> Path:
    """A package with a two-module cycle through a function-level import, a package that imports
    its own module (no cycle), a TYPE_CHECKING-only back edge (no cycle) and private-name uses."""
    files = {
        "__init__.py": "",
        "a.py": "from . import b\n",
        "b.py": "def f():\n    from .a import x\n",
        "c.py": "from typing import TYPE_CHECKING\nfrom .b import _hidden\nif TYPE_CHECKING:\n"
        "    from .d import T\n",
        "d.py": "from . import c\nimport msdepth.b as bee\nbee._peek()\nc.__name__\n",
        "pkg/__init__.py": "from .mod import run\n",
        "pkg/mod.py": "from . import _helper\nfrom ._helper import go\nfrom .. import pkg\n"
        "from .mod import _self\n",
        "pkg/_helper.py": "",
    }
    for name, text in files.items():
        (tmp_path / "msdepth" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "msdepth" / name).write_text(text)
    return tmp_path


def test_the_checks_find_what_they_should_on_a_toy_package(toy: Path):
    assert cycles(import_graph(toy)) == [["msdepth.a", "msdepth.b"]]
    graph = import_graph(toy)
    # pkg.mod imports the top-level package (its own enclosing one: not counted); d imports b and c.
    assert package_graph(graph) == {("c", "b"): 1, ("d", "b"): 1, ("d", "c"): 1, ("a", "b"): 1, ("b", "a"): 1}
    rank = {"a": 0, "b": 1, "c": 2, "d": 3, "pkg": 4}
    assert upward_imports(graph, rank) == ["msdepth.a -> msdepth.b"]
    assert upward_imports(graph, {**rank, "c": 1}) == ["msdepth.a -> msdepth.b", "msdepth.c -> msdepth.b"]
    assert private_imports(toy) == [
        "msdepth.c: from msdepth.b import _hidden",
        "msdepth.d: bee._peek (of msdepth.b)",
    ]


if __name__ == "__main__":
    found, graph = modules(SRC), import_graph(SRC)
    for layer in LAYERS:
        for package in layer:
            names = sorted(m for m in found if package_of(m) == package)
            lines = sum(len(found[m].read_text().splitlines()) for m in names)
            print(f"layer {RANK[package]} {package}: {len(names)} modules, {lines} lines")
    for (a, b), count in sorted(package_graph(graph).items(), key=lambda e: (-RANK[e[0][0]], e[0])):
        print(f"{a} -> {b} ({count} imports)")
    for line in upward_imports(graph):
        print("upward:", line)
    for cycle in cycles(graph):
        print("cycle:", " <-> ".join(cycle))
    for line in private_imports(SRC):
        print("private name:", line)
    sys.exit(0)
