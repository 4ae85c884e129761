"""0 getattr / hasattr on shots (issue 35): a shot's score, rank, goal note, dynamics, clearance, corridor and timings
are fields of ``Shot`` (planner/shots/shot.py), read as fields everywhere. Read from the source (AST) of the package,
the benchmarks and the scripts.

"Holds a shot" is decided by name, as a reader would: the first argument of getattr / hasattr is a shot when it is
(or indexes) a name in SHOT_NAMES (``shot``, ``shots[0]``, ``s``, ``r.shot``, ``best``, ...), or ``self`` inside the
classes ``Shot`` / ``RankedShot``. The short names (``s``, ``r``) hold shots in the viewer and CLI loops; nothing
else in the package reads attributes of an object so named by string."""
import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHOT_NAMES = {"shot", "shots", "sh", "s", "r", "ranked", "best", "cand", "cands", "candidate", "candidates"}
SHOT_CLASSES = {"Shot", "RankedShot"}


def _root(node: ast.AST) -> tuple:
    """(root name, last attribute) of an expression such as ``res.shots[2]`` -> ('res', 'shots')."""
    last = None
    while isinstance(node, (ast.Attribute, ast.Subscript, ast.Call)):
        if isinstance(node, ast.Attribute) and last is None:
            last = node.attr
        node = node.value if not isinstance(node, ast.Call) else node.func
    return (node.id if isinstance(node, ast.Name) else None), last


def shot_attribute_calls(source: str, filename: str = "<src>") -> list:
    """['file:line getattr(shot, ...)', ...]: getattr / hasattr calls whose first argument holds a shot."""
    out = []

    def visit(node: ast.AST, cls: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef):
                visit(child, child.name)
                continue
            if (isinstance(child, ast.Call) and isinstance(child.func, ast.Name)
                    and child.func.id in ("getattr", "hasattr") and child.args):
                arg = child.args[0]
                root, last = _root(arg)
                if (root in SHOT_NAMES or last in SHOT_NAMES
                        or (root == "self" and last is None and cls in SHOT_CLASSES)):
                    out.append(f"{filename}:{child.lineno} {child.func.id}({ast.unparse(arg)}, ...)")
            visit(child, cls)

    visit(ast.parse(source, filename=filename), "")
    return out


def test_the_scan_finds_planted_shot_attribute_reads():
    """The scan can fail: each planted read is found, reads of other objects are not."""
    planted = '''
score = getattr(shot, "score", None)
if hasattr(shots[0], "timings"):
    pass
note = getattr(res.shots[2], "goal_moved", None)
corridor = getattr(r.shot, "corridor", None)
t = [getattr(s, "rank", 0) for s in shots]

class Shot:
    def __post_init__(self):
        for name in ("look_at", "goal"):
            getattr(self, name)

class Config:
    def validate(self):
        getattr(self, "x")  # a config reading its own fields: not a shot
pad = getattr(index, "pad", 0.0)
'''
    found = shot_attribute_calls(planted)
    assert [f.split(" ", 1)[1] for f in found] == [
        "getattr(shot, ...)", "hasattr(shots[0], ...)", "getattr(res.shots[2], ...)", "getattr(r.shot, ...)",
        "getattr(s, ...)", "getattr(self, ...)"], found


def test_no_getattr_or_hasattr_on_shots():
    files = [p for d in ("cinenerf_ns", "benchmarks", "scripts") for p in sorted((REPO / d).rglob("*.py"))]
    assert len(files) > 100
    bad = [f for p in files for f in shot_attribute_calls(p.read_text(), str(p.relative_to(REPO)))]
    assert not bad, bad
