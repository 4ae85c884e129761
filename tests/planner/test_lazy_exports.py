"""planner/lazy_exports.py: a package's public names load their module on first use, and only then."""
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def test_names_load_their_module_on_first_use_only():
    code = ("import sys, cinenerf_ns.planner as p, cinenerf_ns.preview as q\n"
            "print('cinenerf_ns.planner.shots.planner' in sys.modules, 'torch' in sys.modules)\n"
            "print(p.Planner.__module__, 'cinenerf_ns.planner.shots.planner' in sys.modules)\n"
            "print(q.PreviewCameras.__module__, 'cinenerf_ns.preview.preview' in sys.modules)\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == ["False False", "cinenerf_ns.planner.shots.planner True",
                                     "cinenerf_ns.preview.cameras False"]


def test_unknown_names_and_dir():
    import cinenerf_ns.planner as p
    import cinenerf_ns.preview as q

    with pytest.raises(AttributeError, match="module 'cinenerf_ns.preview' has no attribute 'nothing_here'"):
        q.nothing_here
    assert set(q.__all__) <= set(dir(q)) and "__name__" in dir(q) and "preview_camera_path" in q.__all__
    assert "Planner" in p.__all__ and "Planner" in dir(p)
