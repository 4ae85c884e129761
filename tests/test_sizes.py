"""Size limits of the package (issue 35's targets): no module of cinenerf_ns/ over MAX_MODULE_LINES lines, no function
or method over MAX_FUNCTION_LINES (decorators and docstring included). A module or function that grows past them is
split along a real seam, not allow-listed."""
from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "cinenerf_ns"
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 100

# Functions over the limit in files being reworked elsewhere (issue 35, 2026-11-27): to be split there and removed
# from this list (the test fails once one of them is within the limit, so the list only shrinks).
ALLOWED_LONG_FUNCTIONS: set = set()


def _modules():
    return sorted(PACKAGE.rglob("*.py"))


def _long_functions():
    out = {}
    for p in _modules():
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = min([node.lineno] + [d.lineno for d in node.decorator_list])
                n = node.end_lineno - first + 1
                if n > MAX_FUNCTION_LINES:
                    out[(str(p.relative_to(REPO)), node.name)] = n
    return out


def test_no_module_over_the_limit():
    sizes = {str(p.relative_to(REPO)): len(p.read_text().splitlines()) for p in _modules()}
    long = {k: n for k, n in sizes.items() if n > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


def test_no_function_over_the_limit():
    long = _long_functions()
    new = {k: n for k, n in long.items() if k not in ALLOWED_LONG_FUNCTIONS}
    assert not new, f"functions over {MAX_FUNCTION_LINES} lines: {new}"
    stale = ALLOWED_LONG_FUNCTIONS - long.keys()
    assert not stale, f"within the limit now, remove from ALLOWED_LONG_FUNCTIONS: {sorted(stale)}"
