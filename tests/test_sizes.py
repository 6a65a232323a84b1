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


def module_name(path: Path, root: Path | None = None) -> str:
    """The dotted module name of a product file (a package's `__init__` is the package)."""
    parts = list(path.relative_to(ROOT if root is None else root).with_suffix("").parts)
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


def is_package(path: Path) -> bool:
    """Whether a product file is a package's `__init__`."""
    return path.name == "__init__.py"


def ancestors(name: str) -> list[str]:
    """The enclosing packages of a dotted name, outermost first: a.b.c -> [a, a.b]."""
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def absolute(importer: str, package: bool, module: str | None, level: int) -> str:
    """The absolute module a (possibly relative) `from` import names."""
    if level == 0:
        return module or ""
    base = importer if package else importer.rpartition(".")[0]
    for _ in range(level - 1):
        base = base.rpartition(".")[0]
    return f"{base}.{module}" if module else base


def import_graph(files: list[Path] | None = None, root: Path | None = None) -> dict[str, set[str]]:
    """For each product module, the product modules whose code runs or is read when it imports.

    Python runs a package's `__init__` before any module in it, so importing `a.b.c` depends on
    the packages `a` and `a.b` too, except those enclosing the importer itself (already imported
    when the importer runs). `from package import name` reads the package's namespace: it
    depends on the package's `__init__` wherever the importer lives, and on `package.name` when
    that is a module. Relative imports are resolved.
    """
    root = ROOT if root is None else root
    paths = product_files() if files is None else files
    modules = {module_name(p, root): p for p in paths}

    def nearest(target: str) -> str:
        while target and target not in modules:
            target = target.rpartition(".")[0]
        return target

    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        package = is_package(path)
        own = set(ancestors(name)) | ({name} if package else set())
        implied: set[str] = set()  # enclosing packages, run first unless they enclose us
        direct: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    implied.update(ancestors(alias.name))
                    direct.add(alias.name)
            elif isinstance(node, ast.ImportFrom):
                source = absolute(name, package, node.module, node.level)
                implied.update(ancestors(source))
                direct.add(source)
                if source in modules and is_package(modules[source]):
                    direct.update(f"{source}.{alias.name}" for alias in node.names)
        targets = {nearest(t) for t in implied - own} | {nearest(t) for t in direct}
        graph[name] = {t for t in targets if t and t != name}
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


def write_tree(root: Path, files: dict[str, str]) -> list[Path]:
    """Write a small source tree under root, return its files."""
    paths = []
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        paths.append(path)
    return paths


def test_the_cycle_check_sees_a_cycle_through_a_package_init(tmp_path: Path) -> None:
    # the package's __init__ imports driver; driver reads a sibling through the package's
    # namespace, so importing the sibling this way runs (or re-enters) the __init__
    files = write_tree(
        tmp_path,
        {
            "pkg/__init__.py": "from pkg.driver import Driver\n",
            "pkg/driver.py": "from pkg import profile\nclass Driver: ...\n",
            "pkg/profile.py": "X = 1\n",
        },
    )
    assert cycles(import_graph(files, tmp_path)) == [["pkg", "pkg.driver"]]


def test_the_cycle_check_sees_a_relative_import_of_the_package(tmp_path: Path) -> None:
    files = write_tree(
        tmp_path,
        {
            "pkg/__init__.py": "from .driver import Driver\n",
            "pkg/driver.py": "from . import profile\nclass Driver: ...\n",
            "pkg/profile.py": "X = 1\n",
        },
    )
    assert cycles(import_graph(files, tmp_path)) == [["pkg", "pkg.driver"]]


def test_the_cycle_check_sees_an_outside_import_that_runs_a_package_init(tmp_path: Path) -> None:
    # importing pkg.profile from outside runs pkg/__init__, which imports user
    files = write_tree(
        tmp_path,
        {
            "pkg/__init__.py": "from pkg.driver import Driver\n",
            "pkg/driver.py": "import user\nclass Driver: ...\n",
            "pkg/profile.py": "X = 1\n",
            "user.py": "from pkg.profile import X\n",
        },
    )
    assert cycles(import_graph(files, tmp_path)) == [["pkg", "pkg.driver", "user"]]


def test_the_cycle_check_passes_a_sibling_imported_by_its_module_name(tmp_path: Path) -> None:
    files = write_tree(
        tmp_path,
        {
            "pkg/__init__.py": "from pkg.driver import Driver\n",
            "pkg/driver.py": "from pkg.profile import X\nimport pkg.profile\nclass Driver: ...\n",
            "pkg/profile.py": "X = 1\n",
        },
    )
    graph = import_graph(files, tmp_path)
    assert graph["pkg.driver"] == {"pkg.profile"}
    assert cycles(graph) == []
