"""End-to-end evaluation on the bundled room: text -> object -> planned shot, scored against the TRUE geometry."""
from __future__ import annotations

import json

import pytest

from cinenerf_ns.scenes import ASSETS, DEMO_SCENE


@pytest.mark.slow
def test_eval_room_shots_are_safe_against_the_true_geometry(tmp_path):
    if not DEMO_SCENE.exists():
        pytest.skip("bundled demo scene missing")
    from benchmarks.eval_room import main

    s = main(["--scene", str(DEMO_SCENE), "--dataset", str(ASSETS / "room0_gt"), "--starts", "1",
              "--out", str(tmp_path), "--no-record"])
    assert s["objects"] == 8 and s["shots"] == 8
    assert s["planned"] >= 7
    # the safety claim, checked against the analytic room (camera radius included), not the splat
    assert s["planned_with_positive_true_clearance"] == s["planned"]
    assert s["planned_inside_room"] == s["planned"]  # starts from the training cameras' box: inside the walls
    assert s["look_err_target_max_deg"] < 1e-6
    rep = json.loads((tmp_path / "eval_room.json").read_text())
    assert len(rep["selection"]) == 8 and all("iou" in r for r in rep["selection"])
    for f in ("eval_room.md", "eval_room_topdown.png", "eval_room_clearance.png"):
        assert (tmp_path / f).stat().st_size > 0
