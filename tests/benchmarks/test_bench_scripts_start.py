"""Every script in benchmarks/ starts: its imports resolve and `--help` exits 0 (in this process, where torch is
imported already). A moved module once left bench_corridor_qp.py unable to start."""
import runpy
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = sorted(str(p.relative_to(REPO)) for p in (REPO / "benchmarks").glob("*.py")
                 if p.name.startswith(("bench_", "eval_")))


def test_every_benchmark_script_starts(monkeypatch, capsys):
    assert len(SCRIPTS) >= 10
    monkeypatch.chdir(REPO)
    monkeypatch.setattr(sys, "path", list(sys.path))  # the scripts put the repository on it
    bad = []
    for path in SCRIPTS:
        monkeypatch.setattr(sys, "argv", [path, "--help"])
        try:
            runpy.run_path(path, run_name="__main__")
            bad.append(f"{path}: --help did not exit")
        except SystemExit as e:
            if e.code not in (0, None):
                bad.append(f"{path}: exit {e.code}")
        except Exception as e:  # noqa: BLE001 - every script's failure is listed, not only the first
            bad.append(f"{path}: {type(e).__name__}: {e}")
        out = capsys.readouterr().out
        if "usage:" not in out:
            bad.append(f"{path}: --help printed no usage")
    assert not bad, bad


@pytest.mark.slow
def test_bench_ab_compares_a_tree_with_itself(tmp_path):
    """bench_ab.py end to end on a tiny room: two warm workers (the repository against itself, one side with another
    PlannerConfig setting) answer the same blocks, and it prints both sides' statistics and the block ratios. A bad
    tree or config field is refused before any worker starts."""
    r = subprocess.run([sys.executable, "benchmarks/bench_ab.py", "--tree-a", ".", "--tree-b", ".", "--family",
                        "procedural", "--n-gaussians", "3000", "--pairs", "4", "--block", "2", "--config-b",
                        "plan_cpu_threads=None"], cwd=REPO,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "A .: median" in r.stdout and "B . plan_cpu_threads=None: median" in r.stdout
    assert "block ratio B/A: median" in r.stdout and "over 2 blocks" in r.stdout
    r = subprocess.run([sys.executable, "benchmarks/bench_ab.py", "--tree-a", str(tmp_path), "--tree-b", "."],
                       cwd=REPO, capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "must hold cinenerf_ns/ and benchmarks/" in r.stderr
    r = subprocess.run([sys.executable, "benchmarks/bench_ab.py", "--tree-a", ".", "--tree-b", ".", "--config-b",
                        "no_such_field=1"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "PlannerConfig has no field 'no_such_field'" in r.stderr
