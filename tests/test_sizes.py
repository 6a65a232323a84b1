"""Size limits on every product file: no file, class or function too long, no import cycle.

Read from the source with `ast` over controller/ and drivers/; each failure names the offender.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PRODUCT = ("controller", "drivers")

MAX_FILE_LINES = 1000
MAX_CLASS_LINES = 500
MAX_FUNCTION_LINES = 150


def product_files() -> list[Path]:
    """Every Python file of the product, sorted."""
    return sorted(p for d in PRODUCT for p in (ROOT / d).rglob("*.py"))


def module_name(path: Path) -> str:
    """The dotted module name of a product file (a package's `__init__` is the package)."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def span(node: ast.AST) -> int:
    """The number of source lines a class or function spans, decorators included."""
    first = min([node.lineno] + [d.lineno for d in getattr(node, "decorator_list", [])])  # type: ignore[attr-defined]
    end = node.end_lineno  # type: ignore[attr-defined]
    assert end is not None
    return int(end) - int(first) + 1


def oversized(path: Path) -> list[str]:
    """The limits a file breaks, one line per offender naming the file, the thing and its size."""
    text = path.read_text()
    rel = path.relative_to(ROOT)
    bad = []
    n_lines = len(text.splitlines())
    if n_lines > MAX_FILE_LINES:
        bad.append(f"{rel}: {n_lines} lines (file limit {MAX_FILE_LINES})")
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.ClassDef) and span(node) > MAX_CLASS_LINES:
            bad.append(
                f"{rel}:{node.lineno} class {node.name}: {span(node)} lines "
                f"(class limit {MAX_CLASS_LINES})"
            )
        elif (
            isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and span(node) > MAX_FUNCTION_LINES
        ):
            bad.append(
                f"{rel}:{node.lineno} function {node.name}: {span(node)} lines "
                f"(function limit {MAX_FUNCTION_LINES})"
            )
    return bad


def import_graph() -> dict[str, set[str]]:
    """For each product module, the product modules it imports (anywhere in the file).

    `from package import name` counts as importing `package.name` when that is a module, else
    `package`.
    """
    modules = {module_name(p): p for p in product_files()}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        edges: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                targets = [
                    f"{node.module}.{a.name}"
                    if f"{node.module}.{a.name}" in modules
                    else node.module
                    for a in node.names
                ]
            for target in targets:
                # the nearest product module the name lies in
                while target and target not in modules:
                    target = target.rpartition(".")[0]
                if target and target != name:
                    edges.add(target)
        graph[name] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_file_class_or_function_too_long() -> None:
    bad = [line for path in product_files() for line in oversized(path)]
    assert not bad, "\n".join(bad)


def test_no_import_cycle() -> None:
    found = cycles(import_graph())
    assert not found, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in found)


def test_the_limits_see_an_offender(tmp_path: Path) -> None:
    probe = tmp_path / "probe.py"
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES + 1))
    probe.write_text(f"def long_one() -> None:\n{body}\n")
    original = ROOT
    try:
        globals()["ROOT"] = tmp_path
        bad = oversized(probe)
    finally:
        globals()["ROOT"] = original
    assert len(bad) == 1 and "function long_one" in bad[0]


def test_the_cycle_check_sees_a_cycle() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(graph) == [["a", "b", "c"]]
