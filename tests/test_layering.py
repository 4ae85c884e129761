"""The house's layering, read from the source (every import statement, also inside functions): planner/ imports nothing
of nerfstudio, gsplat, viser or the rest of the package; no module outside cli/ imports cli/; the method never imports
the viewer (its panel is attached through an entry point)."""
import ast
import functools
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "cinenerf_ns"


@functools.lru_cache(maxsize=None)
def _tree(path: Path) -> ast.AST:
    """A module's syntax tree, parsed once per test process (the tests only read it)."""
    return ast.parse(path.read_text(), filename=str(path))


def _imports(path: Path):
    tree = _tree(path)
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
           for node in ast.walk(_tree(p)) if isinstance(node, ast.ImportFrom)
           for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
    assert not bad, bad


# ------------------------------------------------------------- inside planner/: context flows down (issue 35, item 1)
PLANNER = PKG / "planner"
LOWER = ("search", "geometry", "corridor", "trajectory", "scene")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _type_checking_imports(tree: ast.AST) -> set:
    """The import nodes under ``if TYPE_CHECKING:`` (annotations only: never executed)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and ast.unparse(node.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING"):
            out |= {id(n) for stmt in node.body for n in ast.walk(stmt) if isinstance(n, (ast.Import, ast.ImportFrom))}
    return out


def _import_graph(sources: dict, runtime_only: bool = False) -> dict:
    """{module: set of modules of ``sources`` it imports}. sources: {dotted module: (source text, is a package
    __init__)}. Every import statement counts, also inside functions and (unless ``runtime_only``) under
    TYPE_CHECKING; ``from pkg import name`` counts as an import of pkg.name when that is a module."""
    graph = {}
    for mod, (text, is_init) in sources.items():
        package = mod if is_init else mod.rsplit(".", 1)[0]
        tree = ast.parse(text)
        skip = _type_checking_imports(tree) if runtime_only else set()
        deps = set()
        for node in ast.walk(tree):
            if id(node) in skip:
                continue
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    base = ".".join(up + ([base] if base else []))
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in sources else base for a in node.names]
            else:
                continue
            deps |= {t for t in targets if t in sources and t != mod}
        graph[mod] = deps
    return graph


@functools.lru_cache(maxsize=None)
def _planner_import_graph(runtime_only: bool = False) -> dict:
    """The import graph of cinenerf_ns/planner's modules (see _import_graph); read once per test process (callers do
    not change it)."""
    return _import_graph({_module_name(p): (p.read_text(), p.name == "__init__.py") for p in _modules("planner")},
                         runtime_only)


def _package(mod: str) -> str:
    """The planner sub-package a module belongs to (a top-level planner module is its own)."""
    rest = mod.split(".")[2:]
    return rest[0] if rest else "__init__"


def test_lower_planner_packages_never_import_shots():
    """search/, geometry/, corridor/, trajectory/ and scene/ import nothing of shots/, not even under TYPE_CHECKING:
    they take the prepared planning space (space.py) or plain arrays."""
    bad = {m: sorted(d for d in deps if _package(d) == "shots")
           for m, deps in _planner_import_graph().items() if _package(m) in LOWER}
    assert not {m: d for m, d in bad.items() if d}, bad


def test_no_function_outside_shots_takes_a_planner():
    """0 functions outside shots/ take a Planner: no parameter annotated with Planner and none named ``planner``."""
    bad = []
    for p in _modules("planner"):
        if p.relative_to(PLANNER).parts[0] == "shots":
            continue
        for node in ast.walk(_tree(p)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                a = node.args
                for arg in a.posonlyargs + a.args + a.kwonlyargs + [x for x in (a.vararg, a.kwarg) if x]:
                    ann = ast.unparse(arg.annotation) if arg.annotation is not None else ""
                    if arg.arg == "planner" or "Planner" in ann.replace("PlannerConfig", ""):
                        bad.append(f"{p.relative_to(PKG)}:{node.lineno} {getattr(node, 'name', 'lambda')}({arg.arg})")
    assert not bad, bad


def _cycles(graph: dict) -> list:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index, low, on, stack, out, counter = {}, {}, set(), [], [], [0]
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def test_cycle_finder_finds_a_circle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_planner_import_graph_has_no_circle_spanning_packages():
    """The import graph of cinenerf_ns/planner (every import statement) has no circle through two sub-packages (a
    top-level planner module counts as its own package)."""
    bad = [c for c in _cycles(_planner_import_graph()) if len({_package(m) for m in c}) > 1]
    assert not bad, bad


def _package_graph(graph: dict) -> dict:
    """The module graph folded onto planner sub-packages: {package: set of other packages it imports}."""
    out = {}
    for m, deps in graph.items():
        out.setdefault(_package(m), set()).update(_package(d) for d in deps if _package(d) != _package(m))
    for deps in list(out.values()):
        for d in deps:
            out.setdefault(d, set())
    return out


def test_package_cycle_finder_counts_imports_inside_functions():
    """Planted: geometry.a imports corridor.b inside a function, corridor.b imports geometry.c at the top: no module
    circle, but geometry and corridor import each other; a TYPE_CHECKING import is left out of the runtime graph."""
    P = "cinenerf_ns.planner"
    planted = {f"{P}.geometry.a": ("def f():\n    from ..corridor.b import g\n", False),
               f"{P}.corridor.b": ("from ..geometry.c import h\n", False),
               f"{P}.geometry.c": ("", False),
               f"{P}.search.d": ("import typing\nif typing.TYPE_CHECKING:\n    from ..space import S\n", False),
               f"{P}.space": ("from .search import d\n", False),
               f"{P}.search": ("", True)}
    assert _cycles(_import_graph(planted)) == [[f"{P}.search.d", f"{P}.space"]]  # geometry.a, corridor.b, c: none
    assert _cycles(_package_graph(_import_graph(planted))) == [["corridor", "geometry"], ["search", "space"]]
    assert _cycles(_package_graph(_import_graph(planted, runtime_only=True))) == [["corridor", "geometry"]]


def test_planner_packages_import_each_other_one_way():
    """Issue 35: no two planner sub-packages (a top-level planner module counts as its own) import each other, through
    any chain of imports that run: at module level or inside functions."""
    bad = _cycles(_package_graph(_planner_import_graph(runtime_only=True)))
    assert not bad, bad


def test_type_only_package_circles_are_the_planning_space_s():
    """With annotations (TYPE_CHECKING imports) counted, the one package circle left is the planning space's: search/,
    geometry/ and corridor/ annotate the ``PlanningSpace`` they take, and space.py annotates the grids they build for it
    (AStarGrid, CoarseGrid, VoxelObstacles). Nothing imports across at run time (the test above); this keeps the
    type-only circle from growing."""
    pg = _package_graph(_planner_import_graph())
    assert _cycles(pg) == [["corridor", "geometry", "search", "space"]]
    runtime, circle = _package_graph(_planner_import_graph(runtime_only=True)), set(_cycles(pg)[0])
    type_only = sorted((a, b) for a in circle for b in (pg[a] - runtime[a]) & circle)
    assert type_only == [("corridor", "space"), ("geometry", "space"), ("search", "space"), ("space", "corridor"),
                         ("space", "search")], type_only
