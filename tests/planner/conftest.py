"""tests/planner mirrors cinenerf_ns/planner's sub-packages; the shared reference helpers (_geom_helpers.py,
_corridor_refs.py, _shot_scenes.py) and test modules that others reuse are importable from every sub-folder."""
import sys
from pathlib import Path

_HERE = Path(__file__).resolve().parent
for _d in [_HERE, *sorted(p for p in _HERE.iterdir() if p.is_dir() and not p.name.startswith((".", "_")))]:
    if str(_d) not in sys.path:
        sys.path.insert(0, str(_d))
