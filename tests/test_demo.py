"""`make demo` on the bundled scene: text -> safe camera path + report + plots, offline, on CPU."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cinenerf_ns.cli.demo import main
from cinenerf_ns.scenes import DEMO_SCENE


@pytest.mark.slow
def test_demo_plans_from_text_on_bundled_scene(tmp_path):
    assert DEMO_SCENE.exists(), "the bundled demo scene is part of the package (cinenerf_ns/assets/room0.npz)"
    assert DEMO_SCENE.stat().st_size <= 15e6
    s = main(["--output-dir", str(tmp_path)])
    cam = json.loads((tmp_path / "demo_0.json").read_text())
    assert cam["camera_path"] and len(cam["camera_path"]) / cam["seconds"] == pytest.approx(cam["fps"])
    rep = json.loads((tmp_path / "demo_report.json").read_text())
    c = rep["candidates"][0]
    assert c["exact_clearance"]["min_clearance"] > 0  # exact clearance, camera radius included
    assert c["max_look_at_error_deg"] < 1e-3
    for png in ("demo_clearance.png", "demo_topdown.png"):
        assert (tmp_path / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the text resolved through the scene's own labels to points near each other's objects, not the origin
    goal, look = np.array(rep["go_to"]["point"]), np.array(rep["look_at"]["point"])
    assert "armchair" in rep["go_to"]["resolved"] and "lamp" in rep["look_at"]["resolved"]
    assert np.linalg.norm(goal - look) > 0.05
    assert s["report"] == str(tmp_path / "demo_report.json")
    # the CPU preview of the planned shot: 15 fps over the path's duration, first and last poses included
    p = s["preview"]
    assert p["frames"] == max(2, round(cam["seconds"] * 15)) and p["width"] == 480 and p["height"] == 270
    assert p["frame_index"][0] == 0 and p["frame_index"][-1] == len(cam["camera_path"]) - 1
    assert (tmp_path / "demo.mp4").read_bytes()[4:8] == b"ftyp"
    assert (tmp_path / "demo_sheet.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_missing_scene_is_refused_with_its_path_as_typed(tmp_path, capsys):
    """`python -m cinenerf_ns.cli.demo --scene <missing>`: exit 2 with the path quoted as typed (never rich markup),
    no traceback, and no silent fallback to the procedural room."""
    from cinenerf_ns.cli.demo import entrypoint

    scene = tmp_path / "a[/x] [red]:smile:" / "room.npz"
    with pytest.raises(SystemExit) as e:
        entrypoint(["--scene", str(scene), "--output-dir", str(tmp_path / "out"), "--no-preview"])
    cap = capsys.readouterr()
    assert e.value.code == 2 and "Traceback" not in cap.err
    assert f"scene not found: {scene} " in cap.err
    assert not (tmp_path / "out").exists()
