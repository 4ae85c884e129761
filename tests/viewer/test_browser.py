"""Real-browser test: the standalone viewer with the real planner on a small procedural room, on
localhost, driven by headless Chromium over the Chrome DevTools Protocol. Checks the console on load, makes
fast scripted edits and clicks Plan (the boxes must end up showing what the server planned with), fills the
text boxes with object names, clicks Plan, checks the path node exists and that the browser's camera moves over
time (positions the browser itself reports back), exports twice (two files), renders a preview video and
sends a nonsense query (an error naming the scene's objects). Screenshots and timings.json go to
$CINENERF_ARTIFACTS when set, else to the test's pytest tmp dir (artifacts/)."""
from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path
from typing import Optional

import numpy as np
import pytest
from _xdist import free_port
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


def type_into(b, label: str, text: str, viewer=None, handle: str = "", notes: Optional[dict] = None) -> None:
    """Types into the box labelled ``label`` as a person does. With ``viewer`` and ``handle`` (the page panel's
    ``view`` attribute of that box) it waits until the server holds the text before the next action, as a person
    looks at the box before moving on.

    viser 1.1.1's client sends GUI messages through one 50 ms throttle that keeps only the latest pending message
    (client/src/WebsocketUtils.ts) and drops messages while its websocket reconnects; on a starved 2-core box its
    timer can fire late, so an edit followed by another action can be replaced. The wait makes each edit land
    before the next; an edit that has not reached the server after 20 s is typed once more (said in ``notes``) and
    must then arrive: a pipeline that never delivers still fails."""
    def put() -> None:
        ok = b.js(f"(() => {{ const e = ({INPUT_FOR})({json.dumps(label)}); if (!e) return false; "
                  "e.focus(); e.select(); return true; })()")
        assert ok, f"no input labelled {label}"
        b.insert_text(text)
        b.js(f"({INPUT_FOR})({json.dumps(label)}).blur()")

    put()
    if viewer is None:
        time.sleep(0.12)  # longer than the client's 50 ms GUI-message throttle (see fast_edits)
        return

    def arrived() -> bool:
        panels = list(viewer.panels.panels.values())  # the page's current panel (a reconnect makes a new one)
        return len(panels) == 1 and getattr(panels[0].view, handle).value == text

    if wait(arrived, 20):
        return
    seen = [getattr(p.view, handle).value for p in viewer.panels.panels.values()]
    if notes is not None:
        notes.setdefault("retyped", []).append({"box": label, "text": text, "server_had": seen,
                                                "clients": len(viewer.server.get_clients())})
    put()
    assert wait(arrived, 20), (f"'{label}' typed twice as {text!r}; the server's panels hold {seen} "
                               f"({len(viewer.server.get_clients())} clients, box shows {box_values(b)})")


def fast_edits(b) -> None:
    """Scripted edits through the browser's real input pipeline, milliseconds apart, then Plan: clear Go to, type
    into it, type into Look at, click (viser's client keeps only the latest of GUI messages 50 ms apart)."""
    select = "(() => {{ const e = ({f})({n}); e.focus(); e.select(); return true; }})()"
    b.js(select.format(f=INPUT_FOR, n=json.dumps("Go to")))
    b.call("Input.dispatchKeyEvent", type="keyDown", key="Backspace", code="Backspace", windowsVirtualKeyCode=8)
    b.call("Input.dispatchKeyEvent", type="keyUp", key="Backspace", code="Backspace", windowsVirtualKeyCode=8)
    b.insert_text("sofa")
    b.js(select.format(f=INPUT_FOR, n=json.dumps("Look at")))
    b.insert_text("potted plant")
    click(b, "Plan")


# The one console error a page may show, and only once: viser 1.1.1's own. Its client builds the Gaussian-splat mesh
# (client/src/Splatting/GaussianSplatsHelpers.ts, createGaussianMeshProps) with a quad whose "position" attribute has
# 2 components per vertex and leaves the mesh frustum-culled; three.js's culling reads x, y, z of each vertex, the
# 4th vertex's z lies past the array's end (undefined -> NaN), and computeBoundingSphere logs this error the first
# time the splat is drawn, whatever the splat holds. test_the_allowed_console_error_is_viser_s_own pins it on a bare
# viser server; nothing the server sends changes it (the mesh has no server-side options).
VISER_SPLAT_NAN = "THREE.BufferGeometry.computeBoundingSphere(): Computed radius is NaN"


def console_errors(b) -> tuple:
    """(ours, viser's): the page's console errors and uncaught exceptions, split into those we answer for and the
    allowed viser splat-mesh message (see VISER_SPLAT_NAN)."""
    errors = [c for c in b.console if c[0] in ("error", "exception", "assert")]
    viser_own = [c for c in errors if c[0] == "error" and c[1].startswith(VISER_SPLAT_NAN)]
    return [c for c in errors if c not in viser_own], viser_own


def first_splat_frame(b, timeout: float, settle: float) -> None:
    """Reads the page's events until the splat is first drawn (viser's own VISER_SPLAT_NAN message marks that moment)
    or ``timeout`` s pass, then ``settle`` s more for console messages that follow it."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not console_errors(b)[1]:
        b.pump(0.25)
    b.pump(settle)


def box_values(b) -> tuple:
    return tuple(b.js(f"({INPUT_FOR})({json.dumps(k)}).value") for k in ("Go to", "Look at"))


def click(b, text: str) -> None:
    ok = b.js(
        "(() => { const e = [...document.querySelectorAll('button')]"
        f".find(x => x.innerText.trim() === {json.dumps(text)});"
        " if (!e) return false; e.click(); return true; })()"
    )
    assert ok, f"no button {text}"


@pytest.fixture()
def viewer(tmp_path):
    from cinenerf_ns.planner.shots.planner import PlannerConfig
    from cinenerf_ns.viewer.standalone import StandaloneConfig, StandaloneViewer

    v = StandaloneViewer(StandaloneConfig(load_config="procedural:3000", port=free_port(), host="127.0.0.1",
                                          output_dir=tmp_path / "data",
                                          planner=PlannerConfig(grid_resolution=64)))
    assert v.planner.wait_ready(120), v.panels.status
    yield v
    v.close()


def test_plan_fly_export_in_headless_chromium(viewer, tmp_path):
    from cdp import Chromium

    b = Chromium(viewer.url)
    artifacts = Path(os.environ.get("CINENERF_ARTIFACTS") or tmp_path / "artifacts")
    artifacts.mkdir(parents=True, exist_ok=True)
    timings = {}
    t_start = time.perf_counter()

    def mark(phase: str) -> None:  # seconds since the test began, per phase (timings.json)
        timings.setdefault("phase_s", {})[phase] = round(time.perf_counter() - t_start, 2)

    try:
        try:
            b.wait_js("document.body && document.body.innerText.includes('Export camera path')", 60)
        except TimeoutError:
            # seen once in 8 fresh-clone runs (2026-11-28): say what the page was doing, for the next one to read
            state = b.js("JSON.stringify({ready: document.readyState, url: location.href, "
                         "text: (document.body ? document.body.innerText : '').slice(0, 300)})", timeout=10)
            b.screenshot(artifacts / "browser_no_panel.png")
            raise AssertionError(f"no panel after 60 s: page {state}; viser clients {len(viewer.server.get_clients())}"
                                 f", panels {list(viewer.panels.panels)}, refused pages {viewer.panels.refused}, "
                                 f"refused connections {sorted(viewer.guard.refused_clients)}"
                                 f"; console {b.console[-10:]}") from None
        assert viewer.server.get_clients(), "the browser did not connect"
        mark("panel_shown")
        first_splat_frame(b, timeout=30, settle=0.5)  # (the session's last check reads the whole console again)
        ours, viser_own = console_errors(b)
        assert ours == [], f"console errors on load: {ours}"
        assert len(viser_own) <= 1, viser_own  # one splat mesh: logged once
        timings["console_errors_on_load"] = [c[1][:120] for c in ours + viser_own]
        b.screenshot(artifacts / "browser_first_view.png")
        lo, hi = viewer.loaded.start_region  # the opening view: inside the room (procedural start region)
        assert np.all(viewer.panels.home.position >= lo) and np.all(viewer.panels.home.position <= hi)

        mark("first_view")
        pp = page_panel(viewer)  # this page's own panel
        # fast scripted edits then Plan: whatever reached the server, the boxes end up showing what was planned
        before = pp.status
        # its shot plays at 4x: a flight keeps software WebGL drawing flat out (about 1.4 of the box's 2 cores), and
        # this part checks the boxes, not the flight
        pp.config.speed = 4.0
        fast_edits(b)
        assert wait(lambda: pp.status != before and pp.status_level != "busy", 30)
        planned = pp._last_texts
        assert wait(lambda: box_values(b) == tuple(planned), 10), (
            f"boxes show {box_values(b)}, the server planned with {planned}")
        assert f"go to '{planned[0]}'" in pp.status or "'Go to' is empty" in pp.status
        timings["fast_edits_planned_with"] = list(planned)
        reported = []  # camera poses the browser reports back (proves the browser's camera moved)

        mark("fast_edits_planned")
        type_into(b, "Go to", "potted plant", viewer, "goto", timings)
        type_into(b, "Look at", "sofa", viewer, "look_at", timings)
        pp = page_panel(viewer)  # the page's panel now (the same one unless the page reconnected)
        client = next(iter(viewer.server.get_clients().values()))
        client.camera.on_update(lambda cam: reported.append((time.perf_counter(), np.array(cam.position))))
        assert pp.view.goto.value == "potted plant" and pp.view.look_at.value == "sofa"
        pp.config.loop = False
        # a longer flight: screenshots must land while it is under way, even on a busy box
        pp.config.speed = 0.25
        # the camera reports from here on belong to this flight: autoplay starts with the plan, and on a busy box the
        # flight can be over before the checks below begin (the end was then reported before they counted)
        n_before = len(reported)
        start_pos = np.array(client.camera.position)  # where the browser's camera was when Plan was clicked
        mark("typed")
        t0 = time.perf_counter()
        click(b, "Plan")
        # this plan's own status (the fast edits' plan may have left a 'Planned' one that the click has not yet
        # replaced)
        assert wait(lambda: "Planned" in pp.status and "go to 'potted plant'" in pp.status, 60), (
            pp.status)
        timings["plan_click_to_planned_s"] = t_planned = time.perf_counter() - t0
        # the browser camera moves over time while the shot plays (autoplay at the shot's real speed): screenshots
        # first, while the flight is surely under way (a screenshot takes seconds on a loaded 2-core box)
        mark("planned")
        shots, states = [], []
        for i in range(3):
            time.sleep(0.3)
            shots.append(b.screenshot(artifacts / f"browser_flight_{i}.png"))
            states.append((round(time.perf_counter() - t0 - t_planned, 2), pp.state,
                           pp.frames_sent))
        timings["flight_screenshots_s_after_planned"] = [x[0] for x in states]
        mark("screenshots")
        # the rest of the flight at 4x, as the Speed slider sets it mid-flight: the end must still be reached
        pp.set_speed(4.0)
        digests = {hashlib.sha1(p.read_bytes()).hexdigest() for p in shots}
        assert len(digests) > 1, ("the rendered view did not change while flying (s after Planned, state, frames): "
                                  f"{states}")
        assert box_values(b) == ("potted plant", "sofa")
        assert "go to 'potted plant' matched the object 'potted plant'" in pp.status
        assert "cinenerf_ns planner" in pp.view.details_text  # internals in the details fold
        assert "lower score is better" in pp.status
        # the candidate dropdown lists duration and min clearance of each candidate
        assert all(" s, clearance " in o for o in pp.view.candidate.options), pp.view.candidate.options
        # the path node exists on the server and in the browser's scene tree
        names = [getattr(h, "name", "") for h in pp.view._nodes["shot"]]
        assert {"/cine/shot/path", "/cine/shot/start_label", "/cine/shot/end_label"} <= set(names)
        assert b.wait_js("document.body.innerText.includes('Planned')", 20)
        shot = pp.shot
        end = shot.positions[-1] * viewer.cfg.scale  # viser coordinates
        # the browser reports its camera back (throttled by the client); it must reach the shot's end
        mark("checks")
        assert wait(lambda: pp.state == "ready", 30)
        assert wait(lambda: any(np.linalg.norm(p - end) < 1e-3 for _, p in reported[n_before:]), 20), (
            f"browser camera never reported the shot's end {end}: {[p for _, p in reported[n_before:]]}")
        moved = [p for _, p in reported[n_before:]]
        # (not reported[n_before - 1]: with no report before the flight that index wrapped to the last one)
        assert len(moved) >= 2 and np.linalg.norm(moved[-1] - start_pos) > 1.0

        mark("flight_over")
        pp.view.overview_box.value = True  # the "Top-down overview" toggle (server side: the box is in a fold)
        time.sleep(1.0)  # what lies above the start region is cut away for this page alone (a message to it)
        b.screenshot(artifacts / "browser_overview.png")
        assert viewer.splat_above[0].visible  # the server's state, and so every other page, keeps it
        pp.view.overview_box.value = False

        mark("overview")
        exports_preview_and_nonsense(b, viewer, tmp_path, timings)
        mark("exports")
        b.screenshot(artifacts / "browser_final.png")
        ours, viser_own = console_errors(b)  # the whole session: planning, flying, exports, preview, a bad query
        assert ours == [] and len(viser_own) <= 1, f"console errors during the session: {ours + viser_own}"
    finally:
        b.close()
        (artifacts / "timings.json").write_text(json.dumps(timings, indent=1))
        print("browser timings:", json.dumps(timings))


def exports_preview_and_nonsense(b, viewer, tmp_path, timings) -> None:
    """Two exports (two files, the second renamed and said), the preview video, a nonsense query."""
    pp = page_panel(viewer)
    # export through the GUI, twice: two files, the second with a numbered name, said on the page
    type_into(b, "Export name", "browser-take", viewer, "export_name", timings)
    click(b, "Export camera path")
    out = tmp_path / "data" / "camera_paths" / "browser-take.json"
    assert wait(lambda: out.exists(), 20), pp.status
    click(b, "Export camera path")
    out2 = out.with_name("browser-take-2.json")
    assert wait(lambda: out2.exists(), 20), pp.status
    for f in (out, out2):
        data = json.loads(f.read_text())
        assert len(data["camera_path"]) > 10 and data["render_width"] == 1920
    assert b.wait_js("document.body.innerText.includes(\"'browser-take.json' already exists\")", 20)
    shown = "data/camera_paths/browser-take-2.json"  # relative to the output folder's parent: no absolute server path
    assert b.wait_js(f"document.body.innerText.includes({json.dumps(shown)})", 20)
    assert not b.js(f"document.body.innerText.includes({json.dumps(str(tmp_path))})")
    assert b.wait_js("document.body.innerText.includes('No ns-render command')", 20)  # no run: said, no placeholder

    # the preview video of the selected candidate, rendered on the CPU in the background
    t0 = time.perf_counter()
    click(b, "Preview video")
    video = tmp_path / "data" / "previews" / "browser-take.mp4"
    assert wait(lambda: "Preview of candidate 1 written" in pp.status, 300), pp.status
    timings["preview_click_to_written_s"] = time.perf_counter() - t0
    assert video.is_file() and video.stat().st_size > 1000
    assert b.wait_js("document.body.innerText.includes('data/previews/browser-take.mp4')", 20)
    assert b.wait_js("document.body.innerText.includes('Download preview')", 20)

    # nonsense from the browser: an error naming the scene's objects; the viewer keeps running
    type_into(b, "Go to", "the unicorn", viewer, "goto", timings)
    click(b, "Plan")
    assert b.wait_js("document.body.innerText.includes(\"no object matches 'the unicorn'\")", 20)
    assert b.wait_js("document.body.innerText.includes('objects: armchair, floor lamp')", 20)


def page_panel(viewer):
    """The panel of the one browser page (each page has its own)."""
    assert wait(lambda: len(viewer.panels.panels) == 1, 30), "the page got no panel"
    return next(iter(viewer.panels.panels.values()))


def wait(pred, timeout=10.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.05)
    return False


def test_the_allowed_console_error_is_viser_s_own():
    """The console error the viewer tests allow comes from viser's client, not from what we send: a bare viser server
    logs nothing, and after one valid 4-Gaussian splat (finite centres, isotropic covariances) it logs exactly that
    message, once. When a viser release stops logging it, this fails: then drop the allowance (VISER_SPLAT_NAN)."""
    import viser
    from cdp import Chromium

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    b = None
    try:
        b = Chromium(f"http://127.0.0.1:{server.get_port()}")
        b.wait_js("document.readyState === 'complete'", 60)
        assert wait(lambda: len(server.get_clients()) == 1, 30), "the browser did not connect"
        b.frames(60)  # the empty scene drawn for 60 frames
        b.pump(0.3)
        assert console_errors(b) == ([], []), b.console
        centres = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 0.5]], np.float32)
        server.scene.add_gaussian_splats("/splat", centers=centres,
                                         covariances=np.tile(np.eye(3, dtype=np.float32) * 0.01, (4, 1, 1)),
                                         rgbs=np.full((4, 3), 0.5, np.float32), opacities=np.ones((4, 1), np.float32))
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and not console_errors(b)[1]:
            b.pump(0.25)
        b.frames(60)  # 60 more frames of the splat: a message logged per frame would show 60 times
        b.pump(0.3)
        ours, viser_own = console_errors(b)
        assert ours == [] and len(viser_own) == 1, b.console
    finally:
        if b is not None:
            b.close()
        server.stop()


def test_the_bundled_room_opens_at_a_training_camera_without_console_errors(tmp_path, monkeypatch):
    """`cinesplat-viewer` with no --load-config (the bundled room, 404,782 Gaussians): no console error but viser's own
    splat-mesh message, and the browser's camera opens at the opening view, the position of one of the room's
    training cameras (the export stores their centres)."""
    from cdp import Chromium

    from cinenerf_ns.viewer import standalone
    from cinenerf_ns.viewer.standalone import StandaloneConfig, StandaloneViewer

    # The viewer asks for the text-query warm-up of the room (latent smoothing and 11 labels: 30-60 s of torch on this
    # box, beside the page's software rendering); this test checks the page, so the warm-up is recorded, not run. Its
    # stop at close() is checked by test_standalone.py::test_ctrl_c_during_the_text_query_warm_up_exits_cleanly and
    # test_semantic_scene.py::test_warm_stops_between_labels_when_asked.
    warm_asked = []
    monkeypatch.setattr(standalone, "warm_semantics", lambda loaded, **kw: warm_asked.append((loaded, kw)))
    viewer = StandaloneViewer(StandaloneConfig(port=free_port(), host="127.0.0.1", output_dir=tmp_path / "data"),
                              plan_fn=lambda *a, **k: [])  # loading only: no planner preparation
    b = None
    try:
        assert len(warm_asked) == 1 and warm_asked[0][0] is viewer.loaded and viewer.loaded.semantics == "relevancy"
        assert warm_asked[0][1]["stop"] is viewer.warm_stop
        cams = viewer.loaded.cameras
        assert cams is not None and len(cams.centres) == 150
        np.testing.assert_allclose(viewer.panels.home.position, cams.centres[cams.typical()])
        b = Chromium(viewer.url)
        b.wait_js("document.body && document.body.innerText.includes('Export camera path')", 150)
        assert wait(lambda: len(viewer.server.get_clients()) == 1, 30), "the browser did not connect"
        client = next(iter(viewer.server.get_clients().values()))
        s = viewer.cfg.scale
        assert wait(lambda: np.allclose(client.camera.position, viewer.panels.home.position * s, atol=1e-6), 30), (
            f"browser camera at {client.camera.position / s}, opening view {viewer.panels.home.position}")
        np.testing.assert_allclose(client.camera.look_at, viewer.panels.home.look_at * s, atol=1e-6)
        first_splat_frame(b, timeout=60, settle=1.0)  # software WebGL: seconds
        ours, viser_own = console_errors(b)
        assert ours == [] and len(viser_own) <= 1, ours + viser_own
    finally:
        if b is not None:
            b.close()
        assert viewer.close(join_s=90), "a background computation of the viewer still runs after close()"


# the three inputs of the vector widget labelled `name` (INPUT_FOR's search, for three inputs)
VECTOR_INPUTS = INPUT_FOR.replace(
    "const inp = n && n.querySelector('input:not([type=hidden])');",
    "const inp = n ? [...n.querySelectorAll('input:not([type=hidden])')] : [];").replace(
    "if (inp) return inp;", "if (inp.length >= 3) return inp.slice(0, 3);")
assert VECTOR_INPUTS.count("slice(0, 3)") == 1 and "querySelectorAll" in VECTOR_INPUTS


def test_the_planning_region_fold_sets_the_box_from_the_page(viewer, tmp_path):
    """The "Planning region" fold in a real page: the box is drawn, corners typed into the vector inputs reach the
    server through the guard, Apply region prepares the planner again and the page says the rule ('user box')."""
    from cdp import Chromium

    b = Chromium(viewer.url)
    artifacts = Path(os.environ.get("CINENERF_ARTIFACTS") or tmp_path / "artifacts")
    artifacts.mkdir(parents=True, exist_ok=True)
    try:
        b.wait_js("document.body && document.body.innerText.includes('Planning region')", 60)
        pp = page_panel(viewer)
        assert wait(lambda: any(h.name == "/cine/region/box" for h in pp.view.region._nodes), 20)
        assert "chosen by: automatic: " in pp.view.region.rule_text
        # the fold's title: the innermost element that says it (the fold starts closed)
        assert b.js("(() => { const e = [...document.querySelectorAll('*')].filter(x => x.innerText && "
                    "x.innerText.trim() === 'Planning region').pop(); if (!e) return false; e.click(); "
                    "return true; })()"), "no 'Planning region' fold"
        assert b.wait_js(f"({VECTOR_INPUTS})('Low corner') !== null", 20), "the fold shows no corners"
        want = {"Low corner": (-0.8, -0.8, 0.05), "High corner": (0.5, 0.6, 0.95)}
        for label, values in want.items():
            handle = pp.view.region.lo if label == "Low corner" else pp.view.region.hi
            for tries in range(3):
                for k, v in enumerate(values):
                    b.js(f"(() => {{ const e = ({VECTOR_INPUTS})({json.dumps(label)})[{k}]; e.focus(); e.select(); "
                         "return true; })()")
                    b.insert_text(str(v))
                    b.js(f"({VECTOR_INPUTS})({json.dumps(label)})[{k}].blur()")
                    time.sleep(0.2)  # past the client's 50 ms GUI-message throttle
                if wait(lambda h=handle, v=values: np.allclose(h.value, v), 10):
                    break
            assert np.allclose(handle.value, values), (label, handle.value)
        click(b, "Apply region")
        assert wait(lambda: "chosen by: user box" in pp.status and pp.status_level == "ok", 120), pp.status
        assert b.wait_js("document.body.innerText.includes('chosen by: user box')", 20)
        info = viewer.planner.region_info()
        assert info.rule == "user box" and np.all(info.lo <= np.array(want["Low corner"]) + 1e-9)
        # the corners stay as typed (the box drawn is the prepared one, rounded out to whole voxels)
        assert b.js(f"({VECTOR_INPUTS})('High corner').map(e => e.value).join(' ')") == "0.5 0.6 0.95"
        b.pump(1.0)
        b.screenshot(artifacts / "browser_planning_region.png")
        ours, viser_own = console_errors(b)
        assert ours == [] and len(viser_own) <= 1, ours + viser_own
    finally:
        b.close()
