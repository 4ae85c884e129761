"""Check that every module path and name a doc mentions exists: backticked names, and the x/y.py paths of its drawings;
and that the docstrings of a package's modules name no module that is gone (x/y.py paths, module.Class names).

    python scripts/check_doc_names.py docs/ARCHITECTURE.md README.md cinenerf_ns

A name counts as existing when some file under cinenerf_ns/, scripts/, benchmarks/, tests/ or the repository root
defines it (def, class, an assignment or a dataclass field) or, for paths, when a file or folder ends with that path.
Names of files a run reads or writes (.json, .yml, .mp4, ...) are skipped. Exit status 1 lists the missing ones.
"""
from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SOURCES = [p for d in ("cinenerf_ns", "scripts", "benchmarks", "tests") for p in (REPO / d).rglob("*")
           if p.is_file() and p.suffix in (".py", ".c", ".md", ".toml", ".npz")]
SOURCES += [p for p in REPO.iterdir() if p.is_file()]
TEXT = "\n".join(p.read_text(errors="ignore") for p in SOURCES if p.suffix in (".py", ".c", ".toml"))
PATHS = ["/" + str(p.relative_to(REPO)) for p in SOURCES] + ["/" + str(p.relative_to(REPO)) + "/" for p in
                                                              (REPO / "cinenerf_ns").rglob("*") if p.is_dir()]


EXTERNAL = {"ViewerControl",  # nerfstudio's
            "bin/", "demo_output/"}  # made by `make` and the demo


def path_exists(name: str) -> bool:
    name = name.strip("/")
    return any(p.endswith("/" + name) or p.endswith("/" + name + "/") for p in PATHS)


def defined_words(text: str) -> set:
    """The words ``text`` defines (def, class, an assignment, a quoted string): the words for which
    defines_reference(word, text) holds, found in one pass. Its three alternatives are look-aheads at every line start
    and every quote, so matches may overlap as that search's do."""
    found = re.findall(r"^(?=\s*(?:def|class)\s+(\w+)\b)", text, re.M)
    found += re.findall(r"^(?=\s*(?:self\.)?(\w+)\s*[:=])", text, re.M)
    return set(found) | set(re.findall(r"\"(?=(\w+)\")", text))


def defines_reference(word: str, text: str) -> bool:
    """Whether ``text`` defines ``word``: one regular-expression search of the whole text."""
    n = re.escape(word)
    return bool(re.search(rf"^\s*(def|class)\s+{n}\b|^\s*(self\.)?{n}\s*[:=]|\"{n}\"", text, re.M))


DEFINED = defined_words(TEXT)


def name_exists(name: str) -> bool:
    """A name the repository defines (its last part) or mentions dotted."""
    last = name.split(".")[-1]
    defined = last in DEFINED if re.fullmatch(r"\w+", last) else defines_reference(last, TEXT)
    return name in EXTERNAL or (len(name.split(".")) > 1 and name in TEXT) or defined


# What docstrings may name without it being a file here: other projects' modules and files.
EXTERNAL_MODULES = {"nerfstudio", "viewer_legacy", "cameras", "models", "yaml", "nn", "linalg", "torch", "np",
                    "multiprocessing", "clarabel", "viser", "lpip", "nerfstudio_dataparser.py"}
# Stale names in docstrings of files being edited elsewhere (issue 35): (file, name) pairs; to be emptied.
STALE_ALLOWED: set = set()


def docstrings(path: Path) -> str:
    """Every docstring of a Python file (module, classes, functions), joined."""
    tree = ast.parse(path.read_text())
    kinds = (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)
    return "\n".join(d for n in ast.walk(tree) if isinstance(n, kinds) for d in [ast.get_docstring(n, clean=False)]
                     if d)


def check_docstrings(root: Path) -> list:
    """(file, name) of the module paths (x/y.py, x.c) and module.Class names the docstrings under ``root`` give that
    name no file of the repository (nor another project's module, EXTERNAL_MODULES)."""
    missing = []
    for p in sorted(root.rglob("*.py")):
        text = docstrings(p)
        rel = str(p.resolve().relative_to(REPO)) if p.resolve().is_relative_to(REPO) else str(p)
        paths = {w for w in re.findall(r"\b[\w/]{2,}\.(?:py|c)\b", text)
                 if not path_exists(w) and w.split("/")[0] not in EXTERNAL_MODULES}
        mods = {f"{a}.{b}" for a, b in re.findall(r"\b([a-z_][a-z0-9_]*)\.([A-Z]\w*)\b", text)
                if a not in EXTERNAL_MODULES and not (path_exists(a + ".py") or path_exists(a + "/"))}
        missing += [(rel, w) for w in sorted(paths | mods) if (rel, w) not in STALE_ALLOWED]
    return missing


def check(doc: Path) -> list:
    text = doc.read_text()
    missing = []
    words = set(re.findall(r"`([^`\s]+)`", text))
    words |= set(re.findall(r"\b[\w/]+\.(?:py|c)\b", text))
    for w in sorted(words):
        w = re.sub(r"\(.*$", "", w).rstrip(",;:")
        if not w or w.startswith(("-", "$", "~", ".", "http")) or "=" in w or w.startswith("ns-"):
            continue
        if re.search(r"\.(json|yml|yaml|mp4|png|gif|ckpt|ply|npz|pt)$", w) or "<" in w or "*" in w:
            continue  # files a run reads or writes, not files of the repository
        if w in EXTERNAL:
            continue
        if re.search(r"\.(py|c|md|toml)$", w) or w.endswith("/"):
            ok = path_exists(w)
        elif re.fullmatch(r"[A-Za-z_][\w.]*", w):
            parts = w.split(".")
            ok = name_exists(w) or path_exists("/".join(parts) + ".py") or path_exists("/".join(parts) + "/")
        else:
            continue
        if not ok:
            missing.append(w)
    return missing


def main(args: list) -> int:
    """Prints every missing name of the given docs (a file: the names it mentions; a folder: its modules'
    docstrings); 1 when there is one."""
    bad = {d: [f"{f}: docstring names {w}" for f, w in check_docstrings(Path(d))] if Path(d).is_dir()
           else check(Path(d)) for d in args}
    for d, m in bad.items():
        for w in m:
            print(f"{d}: {w}")
    return 1 if any(bad.values()) else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
