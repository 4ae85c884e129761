"""The house's layering, read from the source (every import statement, also inside functions): planner/ imports nothing
of nerfstudio, gsplat, viser or the rest of the package; no module outside cli/ imports cli/; the method never imports
the viewer (its panel is attached through an entry point)."""
import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "cinenerf_ns"


def _imports(path: Path):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.module


def _modules(sub: str):
    return sorted((PKG / sub).rglob("*.py")) if sub else sorted(PKG.rglob("*.py"))


@pytest.mark.parametrize("path", _modules("planner"), ids=lambda p: str(p.relative_to(PKG)))
def test_planner_imports_only_itself_and_libraries(path):
    bad = [m for m in _imports(path) if m.split(".")[0] in ("nerfstudio", "gsplat", "viser")
           or (m.startswith("cinenerf_ns") and not m.startswith("cinenerf_ns.planner"))]
    assert not bad, f"{path.name} imports {bad}"


def test_nothing_outside_cli_imports_cli():
    bad = {str(p.relative_to(PKG)): m for p in _modules("") if "cli" not in p.relative_to(PKG).parts[:1]
           for m in _imports(p) if m.startswith("cinenerf_ns.cli")}
    assert not bad, bad


def test_method_never_imports_the_viewer():
    bad = {str(p.relative_to(PKG)): m for p in _modules("method") for m in _imports(p)
           if m.startswith("cinenerf_ns.viewer")}
    assert not bad, bad


def test_planner_public_names_resolve():
    """Every name cinenerf_ns.planner exports (__all__) exists in the module it points to."""
    import cinenerf_ns.planner as planner

    for name in planner.__all__:
        assert getattr(planner, name) is not None, name
    with pytest.raises(AttributeError):
        planner.no_such_name  # noqa: B018


def test_planner_modules_import_no_private_name_of_another():
    """A name two planner modules share is public (issue 35): no ``from .x import _name`` inside planner/."""
    bad = [(str(p.relative_to(PKG)), node.module, a.name) for p in _modules("planner")
           for node in ast.walk(ast.parse(p.read_text())) if isinstance(node, ast.ImportFrom)
           for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
    assert not bad, bad
