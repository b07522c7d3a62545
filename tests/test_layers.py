"""The layers of the package: a lower layer never imports a higher one, and nothing imports in
a circle.

Every ``import`` statement of the package's source is read — at module level, under
``TYPE_CHECKING`` and inside functions alike — and each import of a ``realitygap`` module is
checked against the layer table of ``docs/architecture.md``:

* across the package, ``core`` < ``controllers``, ``estimators`` < ``robots`` < ``envs`` <
  ``baselines`` < ``diagnosis`` < the top (``cards``, ``cli``, ``experiments``, ``calibrate``);
  the independent generator (``realitygap.independent``) shares no code with ``robots`` or
  ``diagnosis``;
* inside ``diagnosis``, ``logs`` < ``problem`` and the adapter contract < ``fit`` < ``stages``
  < ``verdict`` < the robots' adapters and their registry < the pipeline (``diagnose``) <
  ``validation``, ``report`` < ``cli``: generic code sees a robot only through the contract.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# import package → source folder (pyproject's package-dir)
FOLDERS = {
    "realitygap.robots": "robots",
    "realitygap.estimators": "estimators",
    "realitygap.controllers": "controllers",
    "realitygap.envs": "envs",
    "realitygap.baselines": "baselines",
    "realitygap.diagnosis": "diagnosis",
    "realitygap": "realitygap",
}

# (prefix, rank): the longest matching prefix gives a module's layer
PACKAGE_LAYERS: tuple[tuple[str, int], ...] = (
    # The bare package (its __init__ imports only ``cards`` and registers the envs by import
    # path) and ``cards`` (names the envs' classes, policies and realities by import path and
    # imports none of them) import nothing above ``core``: they are floor modules, which any
    # layer may import. The prefix "realitygap" therefore ranks at the floor, and every other
    # top-level module is listed at the top by name (one left out would rank at the floor, so
    # its imports of the layers above are reported).
    ("realitygap", 0),
    ("realitygap.cards", 0),
    ("realitygap.core", 0),
    ("realitygap.controllers", 1),
    ("realitygap.estimators", 1),
    ("realitygap.robots", 2),
    ("realitygap.envs", 3),
    ("realitygap.baselines", 4),
    ("realitygap.diagnosis", 5),
    ("realitygap.calibrate", 6),
    ("realitygap.cli", 6),
    ("realitygap.experiments", 6),
    ("realitygap.independent", 6),
    ("realitygap.samples", 6),
)

DIAGNOSIS_LAYERS: tuple[tuple[str, int], ...] = (
    ("realitygap.diagnosis.logs", 0),
    ("realitygap.diagnosis.problem", 1),
    ("realitygap.diagnosis.adapters", 1),  # the package and its contract
    ("realitygap.diagnosis.adapters.contract", 1),
    ("realitygap.diagnosis.fit", 2),
    ("realitygap.diagnosis.stages", 3),
    ("realitygap.diagnosis.budget", 3),  # the answer: reads fits and residuals, not stages
    ("realitygap.diagnosis.verdict", 4),
    ("realitygap.diagnosis.adapters.registry", 5),
    ("realitygap.diagnosis.adapters.diffdrive", 5),
    ("realitygap.diagnosis.adapters.arm", 5),
    ("realitygap.diagnosis.adapters.climber", 5),
    ("realitygap.diagnosis.export", 5),  # reads a diagnosis's parts, not diagnose()
    ("realitygap.diagnosis.settings", 6),
    ("realitygap.diagnosis.diagnose", 6),
    ("realitygap.diagnosis.validation", 7),
    ("realitygap.diagnosis.report", 7),
    ("realitygap.diagnosis.cli", 8),
    ("realitygap.diagnosis", 9),  # the package's lazy exports
)

INDEPENDENT = "realitygap.independent"


def _rank(module: str, table: tuple[tuple[str, int], ...]) -> tuple[str, int] | None:
    best: tuple[str, int] | None = None
    for prefix, rank in table:
        if (module == prefix or module.startswith(prefix + ".")) and (
            best is None or len(prefix) > len(best[0])
        ):
            best = (prefix, rank)
    return best


def source_modules(root: Path = ROOT) -> dict[str, Path]:
    """Every module of the package: dotted name → file."""
    out: dict[str, Path] = {}
    for package, folder in FOLDERS.items():
        base = root / folder
        for path in sorted(base.rglob("*.py")):
            rel = path.relative_to(base).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            name = ".".join([package, *parts])
            if (
                package == "realitygap"
                and parts
                and parts[0]
                in {
                    "robots",
                    "estimators",
                    "controllers",
                    "envs",
                    "baselines",
                    "diagnosis",
                }
            ):
                continue
            out[name] = path
    return out


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def imports(module: str, path: Path) -> Iterator[tuple[str, int, bool]]:
    """``(imported module, line, runs at run time)`` for every import statement of a module
    (``from pkg import name`` counts as ``pkg.name`` when that is a module)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"

    def walk(node: ast.AST, runtime: bool) -> Iterator[tuple[str, int, bool]]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for sub in child.body:
                    yield from walk_one(sub, False)
                for sub in child.orelse:
                    yield from walk_one(sub, runtime)
                continue
            yield from walk_one(child, runtime)

    def walk_one(node: ast.AST, runtime: bool) -> Iterator[tuple[str, int, bool]]:
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, node.lineno, runtime
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base if is_package else base[:-1]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join([*base, *([node.module] if node.module else [])])
            else:
                mod = node.module or ""
            for a in node.names:
                yield f"{mod}.{a.name}", node.lineno, runtime
            yield mod, node.lineno, runtime
        yield from walk(node, runtime)

    yield from walk(tree, True)


def _resolve(name: str, modules: dict[str, Path]) -> str | None:
    """The package module ``name`` refers to (itself, or the module holding the attribute)."""
    while name:
        if name in modules:
            return name
        name = name.rpartition(".")[0]
    return None


def import_graph(root: Path = ROOT) -> dict[str, list[tuple[str, int, bool]]]:
    modules = source_modules(root)
    graph: dict[str, list[tuple[str, int, bool]]] = {}
    for module, path in modules.items():
        edges: dict[str, tuple[str, int, bool]] = {}
        for name, line, runtime in imports(module, path):
            if not name.startswith("realitygap"):
                continue
            target = _resolve(name, modules)
            if target is None or target == module:
                continue
            if target not in edges or (runtime and not edges[target][2]):
                edges[target] = (target, line, runtime)
        graph[module] = list(edges.values())
    return graph


def violations(root: Path = ROOT) -> list[str]:
    """Every import of a higher layer by a lower one, as ``"file:line: a imports b"``."""
    graph = import_graph(root)
    modules = source_modules(root)
    out: list[str] = []
    for module, edges in graph.items():
        src = _rank(module, PACKAGE_LAYERS)
        for target, line, _ in edges:
            where = f"{modules[module].relative_to(root)}:{line}: {module} imports {target}"
            if module.startswith(INDEPENDENT) and (
                target.startswith("realitygap.robots") or target.startswith("realitygap.diagnosis")
            ):
                out.append(f"{where} (the independent generator shares no code with them)")
                continue
            dst = _rank(target, PACKAGE_LAYERS)
            if src and dst and dst[1] > src[1]:
                out.append(f"{where} (layer {src[0]} below {dst[0]})")
                continue
            if module.startswith("realitygap.diagnosis.") and target.startswith(
                "realitygap.diagnosis."
            ):
                a, b = _rank(module, DIAGNOSIS_LAYERS), _rank(target, DIAGNOSIS_LAYERS)
                if a and b and b[1] > a[1]:
                    out.append(f"{where} ({a[0]} is below {b[0]})")
    return sorted(out)


def cycles(root: Path = ROOT) -> list[list[str]]:
    """Strongly connected groups of modules that import each other at run time."""
    graph = {m: [t for t, _, runtime in e if runtime] for m, e in import_graph(root).items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def strong(v: str) -> None:  # Tarjan, iterative enough for a package's depth
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, []):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return out


def test_no_lower_layer_imports_a_higher_one() -> None:
    found = violations()
    assert not found, "layer violations:\n" + "\n".join(found)


def test_no_import_cycle() -> None:
    found = cycles()
    assert not found, "modules that import each other at run time:\n" + "\n".join(
        " ↔ ".join(c) for c in found
    )


def test_every_diagnosis_module_has_a_layer() -> None:
    missing = [
        m
        for m in source_modules()
        if m.startswith("realitygap.diagnosis.") and _rank(m, DIAGNOSIS_LAYERS) is None
    ]
    assert not missing


def test_the_checker_sees_function_local_and_type_checking_imports(tmp_path: Path) -> None:
    """The checker is not fooled by an import hidden in a function or a TYPE_CHECKING block."""
    for folder in FOLDERS.values():
        (tmp_path / folder).mkdir(parents=True, exist_ok=True)
    (tmp_path / "realitygap" / "core").mkdir()
    (tmp_path / "realitygap" / "core" / "geo.py").write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from realitygap.envs.e import E\n"
        "def f():\n    from realitygap.robots import r\n    return r\n"
    )
    (tmp_path / "envs" / "e.py").write_text("E = 1\n")
    (tmp_path / "robots" / "r.py").write_text("import realitygap.core.geo\n")
    (tmp_path / "diagnosis" / "logs").mkdir()
    (tmp_path / "diagnosis" / "logs" / "log.py").write_text(
        "from realitygap.diagnosis.adapters.diffdrive import adapter\n"
    )
    (tmp_path / "diagnosis" / "adapters" / "diffdrive").mkdir(parents=True)
    (tmp_path / "diagnosis" / "adapters" / "diffdrive" / "adapter.py").write_text("")
    found = violations(tmp_path)
    assert any("core.geo imports realitygap.envs.e" in v for v in found)
    assert any("core.geo imports realitygap.robots.r" in v for v in found)
    assert any(
        "logs.log imports realitygap.diagnosis.adapters.diffdrive.adapter" in v for v in found
    )
    assert cycles(tmp_path) == [["realitygap.core.geo", "realitygap.robots.r"]]


@pytest.mark.parametrize("package", sorted(FOLDERS))
def test_every_package_folder_is_read(package: str) -> None:
    assert any(m == package or m.startswith(package + ".") for m in source_modules())


MAX_MODULE_LINES = 800


def test_diagnosis_modules_stay_readable() -> None:
    """No module of the diagnosis grows past a size a newcomer reads in one sitting."""
    long = {
        name: n
        for name, path in source_modules().items()
        if name.startswith("realitygap.diagnosis")
        and (n := len(path.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES
    }
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"
