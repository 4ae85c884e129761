"""One naming rule for the pure-Python reference beside a compiled kernel (issue 35): ``*_reference``. No function of
the package is named after the language of a reference instead (``*_python``, ``*_torch``, ``*_numpy``, ``*_np``),
besides the conversions listed here."""
from __future__ import annotations

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# conversions, not references
CONVERSIONS = {"to_numpy", "from_numpy", "_numpy", "f64_numpy", "_lo_numpy", "segment_frame_np", "is_torch"}
# References still named the old way in files being reworked elsewhere (2026-11-27): to be renamed there, then removed
# from this list (the test fails once one is gone, so the list only shrinks).
ALLOWED: set = set()


def test_references_are_named_reference():
    found = set()
    for p in sorted((REPO / "cinenerf_ns").rglob("*.py")):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name not in CONVERSIONS and \
                    re.search(r"_(python|torch|numpy|np)$", node.name):
                found.add((str(p.relative_to(REPO)), node.name))
    assert found - ALLOWED == set(), f"name these *_reference: {sorted(found - ALLOWED)}"
    assert ALLOWED <= found, f"renamed already, remove from ALLOWED: {sorted(ALLOWED - found)}"
