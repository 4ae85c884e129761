"""The planning region in the viewer (issue 37): the planner side (PreparedPlanner.set_region: the planner's checks
before any work, re-prepared in the background, the rule that chose it), the panel's Apply / Reset / show logic over
a fake region source and view, the fold and the wireframe box on a viser server, and the region a compact export
stores (used by the viewer, checked when the file loads)."""
from __future__ import annotations

import threading

import numpy as np
import pytest
import torch
from viewer_fakes import FakeBackend, FakeView, wait_for

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.procedural import procedural_room
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.shots.planner import PlannerConfig
from cinenerf_ns.viewer.panel import CinePanel, PanelConfig
from cinenerf_ns.viewer.planner_backend import PreparedPlanner
from cinenerf_ns.viewer.region_box import RegionInfo

torch.set_num_threads(1)

# (box, what the planner says): the messages of cinesplat-plan --region (user_box.user_box / check_user_box)
BAD_BOXES = [
    (((0.0, 0.0, 0.0), (-1.0, 1.0, 1.0)), "is empty or inverted along x"),
    (((0.0, 0.0, 0.0), (1.0, 0.0, 1.0)), "is empty or inverted along y"),
    (((0.0, np.nan, 0.0), (1.0, 1.0, 1.0)), "must be 6 finite numbers"),
    (((50.0, 50.0, 50.0), (51.0, 51.0, 51.0)), "lies outside the scene"),
    (((0.1, 0.1, 0.1), (0.11, 0.5, 0.5)), "too small for the camera along x"),
]


@pytest.fixture(scope="module")
def room_planner():
    r = procedural_room(2000, seed=0)
    scene = EllipsoidScene.from_splat(r.means, r.quats, r.log_scales, r.opacity_logits, SceneConfig())
    cfg = PlannerConfig(grid_resolution=32, start_region=(r.free_lo + 0.03, r.free_hi - 0.03), candidate_workers=0)
    statuses, changes = [], []
    planner = PreparedPlanner(scene, cfg, on_status=lambda t, lv: statuses.append((t, lv)))
    planner.add_region_listener(lambda: changes.append(planner.region_info()))
    planner.start(background=True)
    assert planner.wait_ready(60)
    return r, planner, statuses, changes


def test_the_opening_region_and_its_rule_are_said(room_planner):
    r, planner, statuses, changes = room_planner
    info = planner.region_info()
    assert info.state == "ready" and info.generation == 0 and info.automatic
    assert info.rule == "automatic: training cameras"
    lo, hi = planner.planner.region()
    np.testing.assert_array_equal(info.lo, lo)
    np.testing.assert_array_equal(info.hi, hi)
    assert "It plans in the planning region (" in statuses[-1][0] and "training cameras" in statuses[-1][0]
    assert "chosen by: automatic: training cameras" in planner.prepare_detail
    assert changes and changes[-1].state == "ready"


@pytest.mark.parametrize("box,msg", BAD_BOXES)
def test_a_bad_box_is_refused_before_any_work_with_the_planners_message(room_planner, box, msg):
    r, planner, statuses, changes = room_planner
    before, n_status, n_changes, prepared = planner.region_info(), len(statuses), len(changes), planner.planner
    with pytest.raises(InvalidInputError, match=msg):
        planner.set_region(box)
    assert planner.region_info() is before and planner.planner is prepared and planner.ready
    assert len(statuses) == n_status and len(changes) == n_changes  # nothing started


def test_a_user_box_is_prepared_in_the_background_and_paths_stay_in_it(room_planner):
    r, planner, statuses, changes = room_planner
    lo, hi = np.asarray(r.free_lo) + 0.02, np.asarray(r.free_lo) + 0.6 * (np.asarray(r.free_hi) - r.free_lo)
    hi[2] = r.free_hi[2] - 0.02
    info = planner.set_region((lo, hi))
    assert info.state in ("preparing", "ready") and info.rule == "user box" and not info.automatic
    assert planner.wait_ready(60)
    got = planner.region_info()
    assert got.state == "ready" and got.rule == "user box" and got.generation == info.generation
    assert np.all(got.lo <= lo + 1e-9) and np.all(got.hi >= hi - 1e-9)  # the grid's box holds the box asked for
    np.testing.assert_array_equal(got.asked[0], lo)  # the fold shows the box as given
    np.testing.assert_array_equal(got.asked[1], hi)
    assert got.region_option() == '--region "' + " ".join(f"{v:.6g}" for v in (*lo, *hi)) + '"'
    assert np.all(got.hi - got.lo <= hi - lo + 2 * planner.planner.ready().grid.voxel_size + 1e-9)
    assert [c.state for c in changes[-2:]] == ["preparing", "ready"]
    goal, look = lo + 0.4 * (hi - lo), (lo + hi) / 2
    for shot in planner.plan(goal, look, seed=1, n_candidates=2):
        assert np.all(shot.positions >= got.lo - 1e-9) and np.all(shot.positions <= got.hi + 1e-9)
    assert planner.set_region(None).automatic
    assert planner.wait_ready(60) and planner.region_info().rule == "automatic: training cameras"


def test_a_region_asked_for_while_another_prepares_replaces_it(room_planner):
    r, planner, _, _ = room_planner
    lo, hi = np.asarray(r.free_lo) + 0.02, np.asarray(r.free_hi) - 0.02
    gate = threading.Event()
    orig = planner._prepare_now
    planner._prepare_now = lambda gen, config: (gate.wait(30), orig(gen, config))
    try:
        for k in range(20):  # a page clicking Apply again and again while one preparation runs
            planner.set_region((lo, hi - 0.01 * k))
        last = planner.set_region((lo, (lo + hi) / 2 + 0.3))
        alive = [t for t in threading.enumerate() if t.name == "cine-prepare"]
        assert len(alive) <= 2  # one preparing, one waiting to take the latest request
    finally:
        gate.set()
        planner._prepare_now = orig
    assert planner.wait_ready(60)
    assert planner.region_info().generation == last.generation and planner.region_info().state == "ready"
    np.testing.assert_allclose(planner.planner.config.bounds[1], (lo + hi) / 2 + 0.3)
    planner.set_region(None)
    assert planner.wait_ready(60)


class FakeRegion:
    """A region source: the box asked for is 'prepared' when ``finish()`` is called; bad boxes as the planner."""

    def __init__(self):
        self.info = RegionInfo(np.zeros(3), np.ones(3), "automatic: dense content", generation=0)
        self.listeners, self.asked = [], []

    def region_info(self):
        return self.info

    def set_region(self, bounds):
        from cinenerf_ns.planner.scene.user_box import user_box

        self.asked.append(bounds)
        if bounds is not None:
            lo, hi = user_box(bounds, "the planning region")
        else:
            lo = hi = None
        self.info = RegionInfo(lo, hi, "user box" if bounds is not None else "automatic", "preparing",
                               generation=self.info.generation + 1, automatic=bounds is None)
        for fn in self.listeners:  # as PreparedPlanner: the pages learn that a region is being prepared
            fn()
        return self.info

    def finish(self, error=""):
        i = self.info
        self.info = RegionInfo(i.lo if i.lo is not None else np.zeros(3), i.hi if i.hi is not None else np.ones(3),
                               i.rule if not i.automatic else "automatic: dense content", "error" if error else "ready",
                               error, i.generation, i.automatic)
        for fn in self.listeners:
            fn()

    def add_region_listener(self, fn):
        self.listeners.append(fn)


class RegionView(FakeView):
    def __init__(self):
        super().__init__()
        self.regions, self.boxes = [], []

    def show_region(self, info):
        self.regions.append(info)

    def draw_region(self, info):
        self.boxes.append(info)


def test_panel_apply_reset_and_show(tmp_path):
    src, view = FakeRegion(), RegionView()
    panel = CinePanel(FakeBackend(), view, PanelConfig(data_dir=tmp_path))
    panel.region_source = src
    src.add_region_listener(panel.region_changed)
    try:
        panel.region_changed()
        assert view.regions[-1] is src.info and view.boxes[-1] is src.info
        assert view.statuses == []  # the opening region: the viewer says it
        assert not panel.apply_region((0, 0, 0), (1, 1))  # a corner of 2 numbers
        assert "low corner" not in panel.status and "high corner must be 3 numbers" in panel.status
        assert not panel.apply_region((0, 0, 0), (-1, 1, 1))
        assert panel.status_level == "error" and "is empty or inverted along x" in panel.status
        assert view.regions[-1].generation == 0  # the fold shows the region in use again
        assert panel.apply_region((0, 0, 0), (2, 1, 1))
        assert panel.status_level == "busy" and "(0, 0, 0)..(2, 1, 1) (user box): preparing" in panel.status
        src.finish()
        assert panel.status_level == "ok" and "chosen by: user box" in panel.status
        assert 'cinesplat-plan --region "0 0 0 2 1 1"' in panel.status
        assert not panel.apply_region((5, 5, 5), (5, 6, 6))  # refused after a region was applied: the error stays
        assert panel.status_level == "error" and "is empty or inverted along x" in panel.status
        assert view.regions[-1].rule == "user box" and view.regions[-1].state == "ready"
        assert view.boxes[-1].rule == "user box"
        panel.set_region_box(False)
        assert view.boxes[-1] is None
        src.finish()
        assert view.boxes[-1] is None  # stays hidden on this page
        panel.set_region_box(True)
        assert view.boxes[-1] is src.info
        assert panel.reset_region() and "back to automatic" in panel.status and src.asked[-1] is None
        src.finish("out of memory")
        assert panel.status_level == "error" and "could not prepare" in panel.status and "out of memory" in panel.status
    finally:
        panel.close()


def test_box_edges_are_the_twelve_edges():
    from cinenerf_ns.viewer.region_ui import box_edges

    lo, hi = np.array([0.0, -1.0, 2.0]), np.array([1.0, 1.0, 5.0])
    e = box_edges(lo, hi)
    assert e.shape == (12, 2, 3)
    d = np.abs(e[:, 1] - e[:, 0])
    assert np.all((d > 0).sum(1) == 1)  # each along one axis, as long as the box's side
    for axis in range(3):
        along = d[:, axis] > 0
        assert along.sum() == 4 and np.allclose(d[along, axis], hi[axis] - lo[axis])
    assert len({tuple(np.round(np.sort(x, 0).ravel(), 9)) for x in e}) == 12  # no edge twice
    assert np.all((e == lo) | (e == hi))  # corners only


def test_panel_without_a_region_source_says_so(tmp_path):
    panel = CinePanel(FakeBackend(), FakeView(), PanelConfig(data_dir=tmp_path))
    try:
        panel.region_changed()  # nothing to show, no error
        assert not panel.apply_region((0, 0, 0), (1, 1, 1)) and "has no planning region to set" in panel.status
    finally:
        panel.close()


def test_the_fold_and_the_box_on_a_viser_server(tmp_path):
    import viser
    from test_viser_ui import free_port

    from cinenerf_ns.viewer.backend import FunctionBackend, SceneGaussians
    from cinenerf_ns.viewer.viser_ui import attach_cine_panel

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    src = FakeRegion()
    backend = FunctionBackend(SceneGaussians(np.random.default_rng(0).uniform(-1, 1, (50, 3))),
                              lambda *a, **k: [], None, region_source=src)
    panels = attach_cine_panel(server, backend, PanelConfig(data_dir=tmp_path, autoplay=False))
    panel = panels.server_panel()
    ui = panel.view
    try:
        names = lambda: sorted(h.name for h in ui.region._nodes)  # noqa: E731
        assert ui.region.folder.visible
        assert names() == ["/cine/region/box", "/cine/region/label"]
        assert ui.region.lo.value == (0.0, 0.0, 0.0) and ui.region.hi.value == (1.0, 1.0, 1.0)
        assert "chosen by: automatic: dense content" in ui.region.rule_text and ui.region.reset.disabled
        ui.region.lo.value, ui.region.hi.value = (0.25, 0.0, 0.0), (1.0, 2.0, 1.0)
        assert panel.apply_region(ui.region.lo.value, ui.region.hi.value)
        assert "preparing" in ui.region.rule_text
        src.finish()  # every page's fold and box follow (the listener ClientPanels adds)
        assert "chosen by: user box" in ui.region.rule_text and not ui.region.reset.disabled
        edges = ui.region._nodes[0].points / ui.scale  # [12, 2, 3]: the box's edges
        np.testing.assert_allclose(edges.reshape(-1, 3).min(0), [0.25, 0.0, 0.0], atol=1e-6)
        np.testing.assert_allclose(edges.reshape(-1, 3).max(0), [1.0, 2.0, 1.0], atol=1e-6)
        panel.set_region_box(False)
        assert names() == []
        ui.region.show.value = True  # server-side: no callback; the panel's own call draws it again
        panel.set_region_box(True)
        assert names() == ["/cine/region/box", "/cine/region/label"]
    finally:
        panels.close()
        server.stop()


def test_a_compact_export_stores_the_region_and_the_viewer_plans_in_it(tmp_path):
    from test_standalone import room_splat, viewer_for

    from cinenerf_ns.method.checkpoint import SplatCheckpoint, export_compact, load_compact
    from cinenerf_ns.method.scene_files import CheckpointError

    room, sp = room_splat()
    lo, hi = np.asarray(room.free_lo) + 0.05, np.asarray(room.free_hi) - 0.05
    path = export_compact(SplatCheckpoint(sp), tmp_path / "scene.npz", planning_region=(lo, hi))
    v = viewer_for(str(path), tmp_path, output_dir=tmp_path / "out")
    p = v.panels.server_panel()
    try:
        assert v.planner.wait_ready(60), p.status
        info = v.planner.region_info()
        assert info.rule == "stored in the export" and not info.automatic
        assert np.all(info.lo <= lo + 1e-6) and np.all(info.hi >= hi - 1e-6)
        assert wait_for(lambda: "chosen by: stored in the export" in p.status), p.status
        assert "chosen by: stored in the export" in p.view.region.rule_text
        assert p.reset_region() and v.planner.wait_ready(60)
        assert wait_for(lambda: "chosen by: automatic: " in p.status), p.status
        # the details fold: the scene's load and the latest preparation (the new region's), not every one so far
        assert wait_for(lambda: "chosen by: automatic: " in p.view.details_text), p.view.details_text
        assert p.view.details_text.count("Planner prepared in") == 1 and "Scene loaded in" in p.view.details_text
    finally:
        v.close()
    # a damaged stored region is refused when the file loads, naming the field
    import json
    import zipfile

    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    info = json.loads(str(arrays["info_json"]))
    info["planning_region"] = {"lo": [0, 0, 0], "hi": [1, -1, 1]}
    arrays["info_json"] = np.array(json.dumps(info))
    bad = tmp_path / "bad.npz"
    np.savez(bad, **arrays)
    assert zipfile.is_zipfile(bad)
    with pytest.raises(CheckpointError, match=r"info_json's planning_region is empty or inverted along y"):
        load_compact(bad)


def test_plans_wait_for_a_region_being_prepared(room_planner):
    r, planner, _, _ = room_planner
    gate = threading.Event()
    orig = planner._prepare_now

    def slow(gen, config):
        gate.wait(30)
        orig(gen, config)

    planner._prepare_now = slow
    try:
        lo, hi = np.asarray(r.free_lo) + 0.02, np.asarray(r.free_hi) - 0.02
        info = planner.set_region((lo, hi))
        assert not planner.ready and not planner.wait_ready(0.05)
        done = []
        th = threading.Thread(target=lambda: done.append(planner.plan((lo + hi) / 2, hi - 0.1, seed=0)))
        th.start()
        th.join(0.2)
        assert not done  # waiting for the region's preparation
        gate.set()
        th.join(60)
        assert done and planner.region_info().generation == info.generation
        assert planner.planner.config.bounds is not None
    finally:
        planner._prepare_now = orig
        planner.set_region(None)
        planner.wait_ready(60)


def test_ns_viewer_backend_keeps_the_region_for_every_training_step(tmp_path):
    """The live-model backend (ns-viewer's panel): before the first Plan the region is only asked for; the planner of
    each step plans in it; the planner in use prepares a new one in the background; bad boxes are refused."""
    from test_nerfstudio_panel import TinySplatModel

    from cinenerf_ns.viewer.nerfstudio_panel import SplatModelBackend

    model = TinySplatModel(n=400)
    backend = SplatModelBackend(model, planner_config=PlannerConfig(grid_resolution=24, candidate_workers=0))
    src, view = backend.region_source, RegionView()
    panel = CinePanel(backend, view, PanelConfig(data_dir=tmp_path, autoplay=False))
    panel.region_source = src
    src.add_region_listener(panel.region_changed)
    try:
        info = src.region_info()
        assert info.state == "later" and info.automatic and info.lo is None
        assert not panel.apply_region((0, 0, 0), (1, -1, 1)) and "is empty or inverted along y" in panel.status
        assert panel.apply_region((-0.8, -0.8, -0.8), (0.8, 0.8, 0.8))
        assert panel.status_level == "info" and "the next Plan prepares the planner for it" in panel.status
        assert view.regions[-1].rule == "user box" and view.regions[-1].state == "later"
        shots = backend.plan(np.array([0.5, 0.5, 0.5]), np.zeros(3), start=None, seed=0, n_candidates=1)
        got = src.region_info()
        assert got.state == "ready" and got.rule == "user box" and view.regions[-1].state == "ready"
        assert np.all(got.lo <= -0.8 + 1e-9) and np.all(got.hi >= 0.8 - 1e-9) and np.all(got.hi < 0.9)
        assert np.all(shots[0].positions >= got.lo - 1e-9) and np.all(shots[0].positions <= got.hi + 1e-9)
        with pytest.raises(InvalidInputError, match="lies outside the scene"):  # the planner in use checks it
            src.set_region(((5, 5, 5), (6, 6, 6)))
        assert panel.reset_region() and "preparing the planner" in panel.status
        planner = backend._cache["planner"][1]
        assert planner.wait_ready(60) and src.region_info().rule.startswith("automatic: ")
        assert wait_for(lambda: panel.status_level == "ok" and "chosen by: automatic: " in panel.status), panel.status
        model.step = 1  # training went on: the next Plan's planner keeps the automatic region
        backend.plan(np.array([0.5, 0.5, 0.5]), np.zeros(3))
        assert backend._cache["planner"][1] is not planner and src.region_info().automatic
    finally:
        panel.close()


def test_two_pages_one_region_through_the_guard(tmp_path):
    """Pages speak viser's protocol (no browser): one page types corners and clicks Apply region; the guard lets finite
    corners through and refuses NaN; the other page's fold follows when the region is prepared."""
    import viser
    from raw_client import RawClient
    from test_viser_guard import open_page, panel_of
    from test_viser_ui import free_port

    from cinenerf_ns.viewer.viser_guard import guard_server
    from cinenerf_ns.viewer.viser_ui import attach_cine_panel

    port = free_port()
    server = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    guard = guard_server(server, "127.0.0.1")
    backend, src = FakeBackend(), FakeRegion()
    backend.region_source = src
    panels = attach_cine_panel(server, backend, PanelConfig(data_dir=tmp_path, autoplay=False))
    pages = []
    try:
        a, b = (open_page(lambda: pages.append(RawClient(port)) or pages[-1]) for _ in range(2))
        pa, pb = panel_of(panels, a), panel_of(panels, b)
        before = sum(guard.refused.values())
        a.set_value("Low corner", [0.0, float("nan"), 0.0], "GuiVector3Message")
        assert wait_for(lambda: sum(guard.refused.values()) > before)
        a.set_value("Low corner", [0.5, 0.0, 0.0], "GuiVector3Message")
        a.set_value("High corner", [1.5, 1.0, 2.0], "GuiVector3Message")
        assert wait_for(lambda: pa.view.region.hi.value == (1.5, 1.0, 2.0) and pa.view.region.lo.value[0] == 0.5)
        a.click("Apply region")
        assert wait_for(lambda: src.asked and pa.status_level == "busy"), pa.status
        np.testing.assert_allclose(src.asked[-1][0], [0.5, 0, 0])
        src.finish()
        assert "chosen by: user box" in pb.view.region.rule_text and pb.view.region.hi.value == (1.5, 1.0, 2.0)
        assert "chosen by: user box" in pa.status and pa.status_level == "ok"
    finally:
        for c in pages:
            c.close()
        panels.close()
        server.stop()
