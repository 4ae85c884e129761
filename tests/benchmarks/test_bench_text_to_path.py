"""benchmarks/bench_text_to_path.py runs end to end on a small procedural room (a smoke test of the script, not a
timing: it broke once when the viewer's locate started returning what it matched)."""
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_text_to_path_bench_plans_every_request():
    r = subprocess.run([sys.executable, "benchmarks/bench_text_to_path.py", "--scene", "procedural:3000",
                        "--requests", "3", "--candidates", "1", "--no-warm"],
                       cwd=REPO, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert "3/3 requests planned" in r.stdout, r.stdout[-2000:]
    assert "failures" not in r.stdout
