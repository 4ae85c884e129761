"""scripts/check_doc_names.py: the docs and the package's docstrings name only modules and names that exist."""
from __future__ import annotations

import re
import sys
from pathlib import Path

from hypothesis import given, strategies as st

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))
import check_doc_names  # noqa: E402


def test_docs_and_docstrings_name_what_exists(capsys, monkeypatch):
    monkeypatch.chdir(REPO)  # the paths as `make lint` gives them
    docs = ["docs/ARCHITECTURE.md", "README.md", "docs/PLANNER_DEFAULTS.md", "cinenerf_ns/planner/__init__.py",
            "cinenerf_ns"]
    assert check_doc_names.main(docs) == 0, capsys.readouterr().out


TEXT = check_doc_names.TEXT


@given(st.integers(0, len(TEXT)), st.integers(0, 3000))
def test_defined_words_are_the_words_the_search_finds(start, length):
    """On a piece of the repository's text (what the checker reads): every word of it, searched for one by one."""
    text = TEXT[start:start + length]
    words = set(re.findall(r"\w+", text))  # a word the text does not hold is found by neither
    assert check_doc_names.defined_words(text) == {w for w in words if check_doc_names.defines_reference(w, text)}


def test_defined_words_overlap_as_the_search_does():
    text = '"a"b"\nclass  K(x):\nself.y = 1\nz: int\n  w=2\nv .= 3\n'
    assert check_doc_names.defined_words(text) == {"a", "b", "K", "y", "z", "w"}
    assert all(check_doc_names.defines_reference(w, text) for w in "abKyzw")
    assert not any(check_doc_names.defines_reference(w, text) for w in ("v", "x", "self", "class", "int"))


def test_a_docstring_naming_a_gone_module_is_reported(tmp_path):
    (tmp_path / "m.py").write_text('"""Built by corridor.py and viser_view.ViserView; see search/astar.py, '
                                   'nerfstudio/viewer/viewer.py and torch.Tensor."""\n\ndef f():\n'
                                   '    """Uses trajectory.py."""\n')
    found = sorted(w for _, w in check_doc_names.check_docstrings(tmp_path))
    assert found == ["corridor.py", "trajectory.py", "viser_view.ViserView"]
