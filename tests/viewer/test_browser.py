"""Real-browser test: the standalone viewer with the real planner on a small procedural room, on
localhost, driven by headless Chromium over the Chrome DevTools Protocol. Fills the text boxes with
object names, clicks Plan, checks the path node exists and that the browser's camera moves over time
(positions the browser itself reports back), clicks Export and checks the file. Screenshots go to
$CINENERF_ARTIFACTS when set, else to the test's pytest tmp dir (artifacts/)."""
from __future__ import annotations

import hashlib
import json
import os
import socket
import time
from pathlib import Path

import numpy as np
import pytest

from cdp import CHROMIUM

pytestmark = [pytest.mark.browser, pytest.mark.slow]

if not os.path.exists(CHROMIUM):
    pytest.skip(f"needs Chromium at {CHROMIUM} (apt-get install chromium chromium-driver)", allow_module_level=True)
try:
    import websockets.sync.client  # noqa: F401
except ImportError:  # pragma: no cover
    pytest.skip("needs the websockets package (a viser dependency)", allow_module_level=True)

INPUT_FOR = """
(name) => {
  const l = [...document.querySelectorAll('label')].find(e => e.innerText.trim() === name);
  let n = l;
  for (let i = 0; i < 6 && n; i++) {
    n = n.parentElement;
    const inp = n && n.querySelector('input:not([type=hidden])');
    if (inp) return inp;
  }
  return null;
}
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def type_into(b, label: str, text: str) -> None:
    ok = b.js(f"(() => {{ const e = ({INPUT_FOR})({json.dumps(label)}); if (!e) return false; e.focus(); e.select(); return true; }})()")
    assert ok, f"no input labelled {label}"
    b.insert_text(text)
    b.js(f"({INPUT_FOR})({json.dumps(label)}).blur()")


def click(b, text: str) -> None:
    ok = b.js(
        f"(() => {{ const e = [...document.querySelectorAll('button')].find(x => x.innerText.trim() === {json.dumps(text)});"
        " if (!e) return false; e.click(); return true; })()"
    )
    assert ok, f"no button {text}"


@pytest.fixture()
def viewer(tmp_path):
    from cinenerf_ns.viewer.standalone import StandaloneConfig, StandaloneViewer

    v = StandaloneViewer(StandaloneConfig(load_config="procedural:3000", port=free_port(), host="127.0.0.1",
                                          data=tmp_path / "data", grid_resolution=64))
    assert v.planner.wait_ready(120), v.panel.status
    yield v
    v.close()


def test_plan_fly_export_in_headless_chromium(viewer, tmp_path):
    from cdp import Chromium

    b = Chromium(viewer.url)
    try:
        b.wait_js("document.body && document.body.innerText.includes('Export camera path')", 60)
        assert viewer.server.get_clients(), "the browser did not connect"
        client = next(iter(viewer.server.get_clients().values()))
        reported = []  # camera poses the browser reports back (proves the browser's camera moved)
        client.camera.on_update(lambda cam: reported.append((time.perf_counter(), np.array(cam.position))))

        type_into(b, "Go to", "potted plant")
        type_into(b, "Look at", "sofa")
        assert wait(lambda: viewer.ui.goto.value == "potted plant" and viewer.ui.look_at.value == "sofa")
        viewer.panel.config.loop = False
        viewer.panel.config.speed = 0.5  # a longer flight: screenshots must land while it is under way, even on a busy box
        click(b, "Plan")
        assert wait(lambda: "Planned" in viewer.panel.status, 60), viewer.panel.status
        assert "with the cinenerf_ns planner" in viewer.panel.status
        # the candidate dropdown lists duration and min clearance of each candidate
        assert all(" s, clearance " in o for o in viewer.ui.candidate.options), viewer.ui.candidate.options
        # the path node exists on the server and in the browser's scene tree
        names = [getattr(h, "name", "") for h in viewer.ui._nodes["shot"]]
        assert "/cine/shot/path" in names
        assert b.wait_js("document.body.innerText.includes('Planned')", 20)
        # the browser camera moves over time while the shot plays (autoplay at the shot's real speed)
        n_before = len(reported)
        artifacts = Path(os.environ.get("CINENERF_ARTIFACTS") or tmp_path / "artifacts")
        artifacts.mkdir(parents=True, exist_ok=True)
        shots = []
        for i in range(5):
            time.sleep(0.3)
            shots.append(b.screenshot(artifacts / f"browser_flight_{i}.png"))
        digests = {hashlib.sha1(p.read_bytes()).hexdigest() for p in shots}
        assert len(digests) > 1, "the rendered view did not change while flying"
        shot = viewer.panel.shot
        end = shot.positions[-1] * viewer.cfg.scale  # viser coordinates
        # the browser reports its camera back (throttled by the client); it must reach the shot's end
        assert wait(lambda: viewer.panel.state == "ready", 30)
        assert wait(lambda: any(np.linalg.norm(p - end) < 1e-3 for _, p in reported[n_before:]), 20), (
            f"browser camera never reported the shot's end {end}: {[p for _, p in reported[n_before:]]}")
        moved = [p for _, p in reported[n_before:]]
        assert len(moved) >= 2 and np.linalg.norm(moved[-1] - reported[n_before - 1][1]) > 1.0

        # export through the GUI
        type_into(b, "Export name", "browser-take")
        click(b, "Export camera path")
        out = tmp_path / "data" / "camera_paths" / "browser-take.json"
        assert wait(lambda: out.exists(), 20), viewer.panel.status
        data = json.loads(out.read_text())
        assert len(data["camera_path"]) > 10 and data["render_width"] == 1920
        assert b.wait_js("document.body.innerText.includes('ns-render camera-path')", 20)

        # bad input from the browser: readable message, viewer keeps running
        type_into(b, "Go to", "the unicorn")
        click(b, "Plan")
        assert b.wait_js("document.body.innerText.includes('no object matches')", 20)
        b.screenshot(artifacts / "browser_final.png")
    finally:
        b.close()


def wait(pred, timeout=10.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.05)
    return False
