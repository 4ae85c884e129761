"""benchmarks/bench_text_to_path.py runs end to end on a small procedural room (a smoke test of the script, not a
timing: it broke once when the viewer's locate started returning what it matched)."""
from benchmarks.bench_text_to_path import main


def test_text_to_path_bench_plans_every_request(capsys):
    main(["--scene", "procedural:3000", "--requests", "3", "--candidates", "1", "--no-warm"])
    out = capsys.readouterr().out
    assert "3/3 requests planned" in out, out[-2000:]
    assert "failures" not in out
