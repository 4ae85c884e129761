"""The viewer as a network service: a real viser server on 127.0.0.1 with the panel and the guard, driven by bare
websocket clients (raw_client.RawClient) that send what a browser page, or a hostile one, could send. Each page has its
own panel; a bad message from one page is dropped and breaks nothing; user text reaches no page as live markup."""
from __future__ import annotations

import html
import re

import numpy as np
import pytest
from _xdist import free_port
from hypothesis import given, settings, strategies as st
from raw_client import RawClient
from viewer_fakes import FakeBackend, wait_for as wait

from cinenerf_ns.viewer.conventions import viser_to_world
from cinenerf_ns.viewer.panel import PanelConfig
from cinenerf_ns.viewer.safe_text import MAX_TEXT_CHARS, client_path, md_code_block, md_escape
from cinenerf_ns.viewer.viser_guard import MAX_MESSAGE_BYTES, guard_server, origin_allowed
from cinenerf_ns.viewer.viser_ui import attach_cine_panel

PAYLOADS = [
    '<iframe srcdoc="<script>parent.document.title=1</script>">',
    "<style>*{color:red !important}</style>",
    "![x](http://evil.example/x.png)",
    "[click](javascript:alert(1))",
    "<img src=x onerror=alert(1)>",
    "http://evil.example/a.png www.evil.example",
    "# heading\n```\n<b>bold</b>\n```",
    "**bold** _em_ `code` | a | b |\n|---|---|",
]


# ----------------------------------------------------------------------------------------- markdown
def rendered(md_text: str) -> str:
    """``md_text`` rendered as CommonMark with raw HTML allowed (as viser's client renders markdown)."""
    from markdown_it import MarkdownIt

    return MarkdownIt("commonmark", {"html": True}).enable(["table", "strikethrough"]).render(md_text)


def assert_inert(md_text: str) -> None:
    """No element but paragraphs (and our own code blocks): no script, style, iframe, image, link, heading."""
    tags = set(re.findall(r"<\s*([a-zA-Z0-9]+)", rendered(md_text)))
    assert tags <= {"p", "pre", "code"}, (tags, md_text)


@pytest.mark.parametrize("payload", PAYLOADS)
def test_escaped_text_renders_as_itself(payload):
    out = rendered(md_escape(payload))
    assert re.findall(r"<\s*([a-zA-Z0-9]+)", out) == ["p"]  # one paragraph, nothing else
    flat = re.sub(r"\s+", " ", payload).strip()
    assert re.sub(r"\s+", " ", html.unescape(out[3:-5])).strip() == flat  # the very text, on one line


@settings(max_examples=200, deadline=None)
@given(st.text(alphabet=st.characters(codec="utf-8"), max_size=80))
def test_escaped_text_is_never_markup(text):
    out = rendered(md_escape(text))
    assert set(re.findall(r"<\s*/?\s*([a-zA-Z0-9]+)", out)) <= {"p"}
    flat = re.sub(r"\s+", " ", re.sub(r"[\x00-\x1f\x7f\u2028\u2029\u0085]", " ", text)).strip()
    got = re.sub(r"\s+", " ", html.unescape(re.sub(r"</?p>", "", out))).strip()
    assert got == flat.replace("\x00", "\ufffd")  # CommonMark replaces NUL; md_escape already removed it


def test_code_block_holds_any_command():
    cmd = "ns-render --load-config 'a ``` b'/config.yml"
    out = rendered(md_code_block(cmd))
    assert out.startswith("<pre><code>") and html.unescape(out[11:-14]).rstrip("\n") == cmd


def test_client_path_never_absolute(tmp_path):
    f = tmp_path / "out" / "camera_paths" / "x.json"
    assert client_path(f, tmp_path) == "out/camera_paths/x.json"
    assert client_path("/somewhere/else/x.json", tmp_path) == "x.json"


# ----------------------------------------------------------------------------------------- origin rule
@pytest.mark.parametrize("origin, host, bound, ok", [
    (None, "127.0.0.1:7007", "127.0.0.1", True),  # not a browser
    ("http://localhost:7007", "localhost:7007", "127.0.0.1", True),
    ("http://127.0.0.1:7007", "127.0.0.1:7007", "127.0.0.1", True),
    ("http://[::1]:7007", "[::1]:7007", "::1", True),
    ("http://evil.example", "127.0.0.1:7007", "127.0.0.1", False),
    ("http://evil.example:7007", "evil.example:7007", "0.0.0.0", False),  # DNS rebinding: same origin, a DNS name
    ("http://192.168.1.5:7007", "192.168.1.5:7007", "0.0.0.0", True),  # the page served from the LAN address
    ("http://192.168.1.6:7007", "192.168.1.5:7007", "0.0.0.0", False),
    ("http://10.0.0.2:7007", "10.0.0.9:7007", "10.0.0.2", True),  # the bound address
    ("null", "127.0.0.1:7007", "127.0.0.1", False),
])
def test_origin_rule(origin, host, bound, ok):
    assert origin_allowed(origin, host, bound) is ok


# ----------------------------------------------------------------------------------------- a served viewer
@pytest.fixture()
def served(tmp_path):
    import viser

    port = free_port()
    server = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    guard = guard_server(server, "127.0.0.1")
    backend = FakeBackend()
    panels = attach_cine_panel(server, backend, PanelConfig(data_dir=tmp_path, output_dir=tmp_path / "out",
                                                            autoplay=False))
    clients = []

    def connect(**kw) -> RawClient:
        c = RawClient(port, **kw)
        clients.append(c)
        return c

    yield port, server, panels, guard, backend, connect
    for c in clients:
        c.close()
    panels.close()
    server.stop()


def open_page(connect, position=(1.0, 2.0, 3.0), **kw) -> RawClient:
    c = connect(**kw)
    c.send_camera(position)
    assert c.wait(lambda: any(m.get("props", {}).get("label") == "Export camera path" for m in c.messages), 20), (
        "the page got no panel")
    return c


def panel_of(panels, page: RawClient):
    """The server's panel of ``page``: the one whose Go-to widget uuid the page was sent."""
    uuid = page.widget("Go to", "GuiTextMessage")["uuid"]

    def found():
        return [p for p in list(panels.panels.values()) if p.view.goto._impl.uuid == uuid]

    assert wait(lambda: len(found()) == 1)  # registered once built (its widgets may reach the page first)
    return found()[0]


def test_two_pages_plan_different_text_at_once(served):
    port, server, panels, guard, backend, connect = served
    a, b = open_page(connect, (1.0, 2.0, 3.0)), open_page(connect, (-4.0, 5.0, 6.0))
    assert wait(lambda: len(panels.panels) == 2)
    pa, pb = panel_of(panels, a), panel_of(panels, b)
    assert pa is not pb
    a.set_value("Go to", "chair", "GuiTextMessage")
    a.set_value("Look at", "lamp", "GuiTextMessage")
    a.set_value("Start at my camera", True, "GuiCheckboxMessage")
    b.set_value("Go to", "lamp", "GuiTextMessage")
    b.set_value("Look at", "chair", "GuiTextMessage")
    assert wait(lambda: pa.view.goto.value == "chair" and pb.view.goto.value == "lamp"
                and pa.view.from_camera.value and pb.view.look_at.value == "chair")
    a.send_camera((1.0, 2.0, 3.0))  # where each page's camera is now (a browser reports every move)
    b.send_camera((-4.0, 5.0, 6.0))
    assert wait(lambda: np.allclose(pb.view.client.camera.position, [-4.0, 5.0, 6.0]))
    a.click("Plan")
    b.click("Plan")
    assert wait(lambda: pa.state == "ready" and pb.state == "ready"), (pa.status, pb.status)
    assert pa._last_texts == ("chair", "lamp") and pb._last_texts == ("lamp", "chair")
    assert "go to 'chair'" in pa.status and "go to 'lamp'" in pb.status
    # "Start at my camera": the clicking page's own camera, not the first page's
    starts = [c["start"] for c in backend.plan_calls if c["start"] is not None]
    assert len(starts) == 1
    np.testing.assert_allclose(starts[0], viser_to_world(np.array([1.0, 2.0, 3.0]), panels.ui_kwargs["scale"]))
    # each page was sent its own status, never the other's
    a.pump(0.5)
    b.pump(0.5)
    sent_a, sent_b = " ".join(a.markdown_sent()), " ".join(b.markdown_sent())
    assert md_escape("go to 'chair'") in sent_a and md_escape("go to 'lamp'") not in sent_a
    assert md_escape("go to 'lamp'") in sent_b and md_escape("go to 'chair'") not in sent_b
    # each page its own drawing: the path nodes went to the page that planned it only (per-client scene)
    assert sum(m["type"] == "CatmullRomSplineMessage" for m in a.messages) >= 1
    assert pa.view.scene is not pb.view.scene
    # a page that leaves: its panel is closed and dropped; the other keeps working
    a.close()
    assert wait(lambda: len(panels.panels) == 1)
    b.click("Plan")
    assert wait(lambda: pb.state == "ready" and len(backend.plan_calls) == 3)


def test_user_text_reaches_no_page_as_markup(served):
    port, server, panels, guard, backend, connect = served
    a, b = open_page(connect), open_page(connect)
    pa = panel_of(panels, a)
    for payload in PAYLOADS:
        a.set_value("Go to", payload[:MAX_TEXT_CHARS], "GuiTextMessage")
        a.set_value("Look at", "lamp " + payload, "GuiTextMessage")
        assert wait(lambda: pa.view.goto.value == payload)
        a.click("Plan")
        assert wait(lambda: payload in pa.status and pa.state != "planning"), pa.status
        pa.export(payload)  # refused: not a plain file name; the status quotes it
    a.pump(1.0)
    b.pump(1.0)
    sent = a.markdown_sent() + b.markdown_sent()
    assert any(md_escape(PAYLOADS[0]) in s for s in a.markdown_sent())  # the text was shown, escaped
    for s in sent:
        assert_inert(s)


def test_hostile_messages_break_nothing(served):
    port, server, panels, guard, backend, connect = served
    a, b = open_page(connect), open_page(connect)
    pa, pb = panel_of(panels, a), panel_of(panels, b)
    plan, goto = a.widget("Plan", "GuiButtonMessage")["uuid"], a.widget("Go to", "GuiTextMessage")["uuid"]
    number = a.widget("Candidates", "GuiNumberMessage")["uuid"]
    box = a.widget("Start at my camera", "GuiCheckboxMessage")["uuid"]
    dropdown = a.widget("Candidate", "GuiDropdownMessage")["uuid"]
    n_cb = len(pa.view.plan_button._impl.update_cb)
    before = sum(guard.refused.values())
    a.send("GuiUpdateMessage", uuid=plan, updates={"update_cb": []})  # disabled Plan for everyone in viser 1.1.1
    a.send("GuiUpdateMessage", uuid=goto, updates={"value": "x", "visible": False})
    a.send("GuiUpdateMessage", uuid=goto, updates={"value": "x" * (MAX_TEXT_CHARS + 1)})
    a.send("GuiUpdateMessage", uuid=goto, updates={"value": 5})
    a.send("GuiUpdateMessage", uuid=number, updates={"value": float("nan")})
    a.send("GuiUpdateMessage", uuid=number, updates={"value": 1e9})
    a.send("GuiUpdateMessage", uuid=box, updates={"value": "yes"})
    a.send("GuiUpdateMessage", uuid=dropdown, updates={"value": "not an option"})
    a.send("FileTransferStartUpload", source_component_uuid=goto, transfer_uuid="t", filename="f.txt",
           mime_type="text/plain", part_count=1, size_bytes=3)
    a.send("FileTransferPart", source_component_uuid=goto, transfer_uuid="t", part_index=0, content=b"abc")
    a.send("ShareUrlRequest")
    a.send("GuiFormDirtyMessage", uuid=goto)
    a.send("ViewerCameraMessage", wxyz=[1.0, 0, 0, 0], position=[float("nan")] * 3, fov=1.0, near=0.01, far=100.0,
           image_height=480, image_width=640, look_at=[0.0, 0, 0], up_direction=[0.0, 0, 1])
    assert wait(lambda: sum(guard.refused.values()) - before >= 13), guard.refused
    assert len(pa.view.plan_button._impl.update_cb) == n_cb and pa.view.goto.value == ""
    assert isinstance(pa.view.goto.value, str) and pa.view.n_candidates.value == 3
    assert server._share_tunnel is None and not guard.refused_clients
    # both pages still plan
    for page, panel, text in ((a, pa, "chair"), (b, pb, "lamp")):
        page.set_value("Go to", text, "GuiTextMessage")
        page.set_value("Look at", "lamp" if text == "chair" else "chair", "GuiTextMessage")
        assert wait(lambda panel=panel, text=text: panel.view.goto.value == text)
        page.click("Plan")
        assert wait(lambda panel=panel: panel.state == "ready"), panel.status
    # malformed messages: refused by the guard, or (what viser cannot even decode) the sender's own connection ends
    n = sum(guard.refused.values())
    a.send("GuiUpdateMessage", uuid=[goto], updates={"value": "x"})  # not even a uuid
    assert wait(lambda: sum(guard.refused.values()) > n)
    a.send("ViewerCameraMessage", wxyz=1, position="here", fov=1.0, near=0.01, far=100.0, image_height=480,
           image_width=640, look_at=[0.0, 0, 0], up_direction=[0.0, 0, 1])
    # one oversized message closes that page's connection only
    a.send("GuiUpdateMessage", uuid=goto, updates={"value": "y" * (MAX_MESSAGE_BYTES + 10)})
    assert not a.wait(lambda: False, 5) and a.closed
    assert wait(lambda: len(panels.panels) == 1)
    b.click("Plan")
    assert wait(lambda: len(backend.plan_calls) == 3 and pb.state == "ready")


def test_a_page_from_another_origin_is_refused(served):
    port, server, panels, guard, backend, connect = served
    evil = connect(origin="http://evil.example")
    evil.send_camera()
    assert not evil.wait(lambda: False, 5) and evil.closed  # the server closed it
    assert panels.panels == {} and not server.get_clients()
    ok = open_page(connect, origin=f"http://localhost:{port}")
    assert wait(lambda: len(panels.panels) == 1) and not ok.closed


def test_the_overview_hides_the_ceiling_for_its_own_page_only(served):
    port, server, panels, guard, backend, connect = served
    node = server.scene.add_box("/ceiling", dimensions=(1.0, 1.0, 0.1))
    panels.overview_hides.append(node)
    a, b = open_page(connect), open_page(connect)
    pa = panel_of(panels, a)
    a.set_value("Top-down overview", True, "GuiCheckboxMessage")

    def hidden(page):
        return [m["visible"] for m in page.messages if m["type"] == "SetSceneNodeVisibilityMessage"
                and m["name"] == "/ceiling"]

    assert a.wait(lambda: hidden(a)[-1:] == [False]) and pa.view.overview_box.value
    n = len(hidden(a))
    b.pump(0.5)
    assert False not in hidden(b) and node.visible  # the other page, and the server's state, keep it
    a.set_value("Top-down overview", False, "GuiCheckboxMessage")
    assert a.wait(lambda: hidden(a)[n:] == [True])


def test_connections_beyond_the_limit_are_closed(served):
    port, server, panels, guard, backend, connect = served
    guard.max_connections = 2
    a, b = open_page(connect), open_page(connect)
    c = connect()
    c.send_camera()
    assert not c.wait(lambda: False, 5) and c.closed and len(panels.panels) == 2
    a.close()
    assert wait(lambda: len(panels.panels) == 1)
    d = open_page(connect)  # room again
    assert not d.closed and wait(lambda: len(panels.panels) == 2) and not b.closed
