"""ViserPanelUI on a real viser server (no browser): drawing per display option, corridor meshes,
candidate dropdown wiring; polytope meshes against their defining inequalities."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from _xdist import free_port
from viewer_fakes import line_shot

from cinenerf_ns.planner.corridor.polytope import Polytope
from cinenerf_ns.planner.corridor.safe_corridor import Corridor
from cinenerf_ns.viewer.backend import FunctionBackend, SceneGaussians
from cinenerf_ns.viewer.panel import PanelConfig
from cinenerf_ns.viewer.polytope_mesh import chebyshev_center, polytope_mesh
from cinenerf_ns.viewer.safe_text import md_escape
from cinenerf_ns.viewer.viser_ui import attach_cine_panel


def box(lo, hi):
    A = np.vstack([np.eye(3), -np.eye(3)])
    return A, np.r_[np.asarray(hi, float), -np.asarray(lo, float)]


def test_polytope_mesh_box_and_random():
    verts, faces = polytope_mesh(*box([0, 0, 0], [1, 2, 3]))
    assert len(verts) == 8 and len(faces) == 12
    np.testing.assert_allclose(np.sort(np.unique(verts.round(9), axis=0), axis=0).min(0), [0, 0, 0], atol=1e-9)
    rng = np.random.default_rng(0)
    A = rng.normal(size=(20, 3))
    A /= np.linalg.norm(A, axis=1, keepdims=True)
    b = rng.uniform(0.5, 1.0, 20)  # contains a ball around the origin: bounded
    verts, faces = polytope_mesh(A, b)
    assert np.all(A @ verts.T <= b[:, None] + 1e-9)  # every vertex satisfies A x <= b
    assert faces.max() < len(verts)
    c, r = chebyshev_center(A, b)
    assert r >= 0.5 - 1e-9 and np.all(A @ c + r <= b + 1e-9)
    assert polytope_mesh(*box([0, 0, 0], [-1, 1, 1])) is None  # empty
    assert polytope_mesh(np.eye(3), np.ones(3)) is None  # unbounded


@pytest.fixture()
def ui_panel(tmp_path):
    import viser

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    means = np.random.default_rng(0).uniform(-1, 1, (50, 3))
    mask = np.zeros(50, bool)
    mask[:5] = True
    boxes = [box([1, -0.2, 0.3], [2.1, 0.2, 0.7]), box([-0.1, -0.2, 0.3], [1.1, 0.2, 0.7])]
    corridor = Corridor([Polytope(torch.as_tensor(A), torch.as_tensor(b), torch.as_tensor(s)[None])
                         for (A, b), s in zip(boxes, ([1.5, 0, 0.5], [0.5, 0, 0.5]))],
                        torch.tensor([[2.0, 0, 0.5], [1, 0, 0.5], [0, 0, 0.5]], dtype=torch.float64))

    def plan(goal, look_at, start=None, seed=0, n_candidates=1):
        shots = [line_shot([2, 0, 0.5], [0, 0, 0.5], look_at) for _ in range(n_candidates)]
        shots[0].corridor = corridor
        return shots

    backend = FunctionBackend(SceneGaussians(means), plan, lambda text: (means[:5].mean(0), mask))
    panel = attach_cine_panel(server, backend, PanelConfig(data_dir=tmp_path, autoplay=False)).server_panel()
    yield panel, panel.view
    panel.close()
    server.stop()


def names(ui):
    return sorted(h.name for h in ui._nodes["shot"])


def test_drawing_follows_options(ui_panel):
    panel, ui = ui_panel
    assert panel.request_plan("thing", "0 -1 0", n_candidates=2).result(20) is not None, panel.status
    n = names(ui)
    assert "/cine/shot/path" in n and sum("frustum" in x for x in n) == 8
    assert not any("corridor" in x or "clearance" in x for x in n)
    tnames = sorted(h.name for h in ui._nodes["targets"])
    # matched objects are outlined (wireframe box + faint fill), never drawn as opaque blobs
    assert {"/cine/targets/0/outline", "/cine/targets/0/fill", "/cine/targets/1/outline"} <= set(tnames)
    assert not any("gaussians" in x or "centroid" in x for x in tnames)

    panel.set_display(show_corridor=True, show_clearance=True, show_path=False)
    n = names(ui)
    assert "/cine/shot/path" not in n and "/cine/shot/corridor_0" in n and "/cine/shot/corridor_1" in n
    assert [x for x in n if "clearance" in x] == ["/cine/shot/clearance_min"]  # one label, at the minimum
    panel.set_display(show_targets=False)
    assert ui._nodes["targets"] == []

    # candidate list in the dropdown; a server-side value change does not re-select
    assert ui.candidate.options[0].startswith("1: 1.0 s") and len(ui.candidate.options) == 2
    panel.select(1)
    assert panel.selected == 1
    ui.candidate.value = ui.candidate.options[0]  # server-side assignment: ignored by the callback
    assert panel.selected == 1


def test_status_and_play_buttons(ui_panel):
    panel, ui = ui_panel
    assert not ui.region.folder.visible  # a backend with no planning region: no fold for it
    panel.request_plan("", "x").result(10)
    assert ui.status_md.content.endswith(md_escape("'Go to' is empty: type an object (e.g. 'the chair') or coordinates "
                                                   "'x y z'"))
    panel.request_plan("thing", "0 -1 0").result(10)
    panel.play()
    assert ui.pause_button.visible and not ui.play_button.visible
    panel.pause()
    assert ui.play_button.visible and not ui.pause_button.visible
    assert ui.camera_position() is None and ui.set_camera(np.eye(4)[:3]) == 0  # no browser connected


def test_shot_ends_are_labelled_over_the_splat(ui_panel, monkeypatch):
    """viser 1.1.1 draws splats after lines, splines and frustums (and offers them no render order or depth test):
    only labels with depth_test=False come after the splat. The shot's start and end get such labels."""
    panel, ui = ui_panel
    calls = []
    real = ui.server.scene.add_label

    def record(name, text, **kw):
        calls.append((name, text, kw))
        return real(name, text, **kw)

    monkeypatch.setattr(ui.server.scene, "add_label", record)
    assert panel.request_plan("thing", "0 -1 0").result(20) is not None, panel.status
    ends = {name: (text, kw) for name, text, kw in calls if name in ("/cine/shot/start_label", "/cine/shot/end_label")}
    assert sorted(ends) == ["/cine/shot/end_label", "/cine/shot/start_label"]
    pos = np.asarray(panel.shot.positions)
    for (text, kw), want in ((ends["/cine/shot/start_label"], pos[0]), (ends["/cine/shot/end_label"], pos[-1])):
        assert kw["depth_test"] is False  # drawn over the splat
        np.testing.assert_allclose(kw["position"], want * ui.scale)
    assert ends["/cine/shot/start_label"][0] == "shot start" and ends["/cine/shot/end_label"][0] == "shot end"
    panel.set_display(show_path=False)  # the labels go with the path
    assert not any(x.endswith("_label") for x in names(ui))
