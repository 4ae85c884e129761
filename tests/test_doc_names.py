"""scripts/check_doc_names.py: the docs and the package's docstrings name only modules and names that exist."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))
import check_doc_names  # noqa: E402


def test_docs_and_docstrings_name_what_exists():
    docs = ["docs/ARCHITECTURE.md", "README.md", "docs/PLANNER_DEFAULTS.md", "cinenerf_ns/planner/__init__.py",
            "cinenerf_ns"]
    r = subprocess.run([sys.executable, "scripts/check_doc_names.py", *docs], cwd=REPO, capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stdout


def test_a_docstring_naming_a_gone_module_is_reported(tmp_path):
    (tmp_path / "m.py").write_text('"""Built by corridor.py and viser_view.ViserView; see search/astar.py, '
                                   'nerfstudio/viewer/viewer.py and torch.Tensor."""\n\ndef f():\n'
                                   '    """Uses trajectory.py."""\n')
    found = sorted(w for _, w in check_doc_names.check_docstrings(tmp_path))
    assert found == ["corridor.py", "trajectory.py", "viser_view.ViserView"]
