"""Rooms one can live in (docs/architecture.md): no module over 900 lines, no function over 150,
and an import inside a function only where it must be, saying why: an optional extra (`# optional
extra: bokeh`) or start-up cost (`# start-up: ...`, what it keeps off a command's start), at most
8 % of all the project's imports. Read from the source with ast."""

import ast
from pathlib import Path

ROOT = Path(__file__).parents[1]
SOURCES = ("analytic", "worker", "broker", "schemas", "models", "gainfarm")
MODULE_LINES = 900
FUNCTION_LINES = 150
INNER_SHARE = 0.08
REASONS = ("optional extra", "start-up")


def _modules() -> list[tuple[Path, str, ast.Module]]:
    found = []
    for folder in SOURCES:
        for path in sorted((ROOT / folder).rglob("*.py")):
            text = path.read_text()
            found.append((path, text, ast.parse(text, str(path))))
    return found


def _where(path: Path, node: ast.AST) -> str:
    return f"{path.relative_to(ROOT)}:{getattr(node, 'lineno', 0)}"


def _inner_imports(tree: ast.Module) -> list[ast.Import | ast.ImportFrom]:
    inner = []
    for function in ast.walk(tree):
        if isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef)):
            inner += [
                node
                for node in ast.walk(function)
                if isinstance(node, (ast.Import, ast.ImportFrom))
            ]
    return list({id(node): node for node in inner}.values())  # a nested function's counted once


def test_no_module_is_over_its_bound() -> None:
    long = [
        f"{path.relative_to(ROOT)}: {len(text.splitlines())} lines"
        for path, text, _ in _modules()
        if len(text.splitlines()) > MODULE_LINES
    ]
    assert long == []


def test_no_function_is_over_its_bound() -> None:
    long = [
        f"{_where(path, node)} {node.name}: {node.end_lineno - node.lineno + 1} lines"
        for path, _, tree in _modules()
        for node in ast.walk(tree)
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
        and node.end_lineno - node.lineno + 1 > FUNCTION_LINES
    ]
    assert long == []


def test_an_import_inside_a_function_says_why_and_they_are_few() -> None:
    every, unexplained, inner_count = 0, [], 0
    for path, text, tree in _modules():
        lines = text.splitlines()
        every += sum(isinstance(node, (ast.Import, ast.ImportFrom)) for node in ast.walk(tree))
        for node in _inner_imports(tree):
            inner_count += 1
            said = " ".join(lines[_block_start(lines, node.lineno) : node.end_lineno]).lower()
            if not any(reason in said for reason in REASONS):
                unexplained.append(_where(path, node))
    assert unexplained == []
    assert inner_count <= INNER_SHARE * every, f"{inner_count} of {every} imports in functions"


def _block_start(lines: list[str], lineno: int) -> int:
    """The index of the comment line (or the line) just above the run of imports that holds the
    one at `lineno`: one comment (of one line or more) says why for a block of them."""
    index = lineno - 2
    while index >= 0 and lines[index].strip().startswith(("import ", "from ", ")")):
        index -= 1
    while index > 0 and lines[index - 1].strip().startswith("#"):  # a comment of many lines
        index -= 1
    return max(index, 0)
