"""How long a page takes to receive the scene while other pages are connected (issue 38: the 4th and 5th page took
63 s and 82 s on the 2-core box).

    .venv/bin/python benchmarks/bench_viewer_pages.py --load-config demo --pages 5

A real ``cinesplat-viewer`` (StandaloneViewer, the planner preparing on its thread as for a user) on 127.0.0.1; pages
are bare websocket clients (tests/viewer/raw_client.py) that read everything they are sent, on their own threads, and
stay connected. For page k: the time from opening the websocket to viser's end-of-replay marker (the splat and the
whole GUI received), and the longest websocket ping round trip of the first page meanwhile (a stall of the server).
Bytes received per page too. ``--planning``: each page, once open, presses Plan (its own panel, the scene's default
texts), so later pages open while plans run, as in the issue's five pages planning at once. No browser: what is
measured is the server's side (a browser's own WebGL work adds to it). Also runs on the viewer before per-page panels
(one shared ``viewer.panel``) for a before/after comparison.
"""
from __future__ import annotations

import argparse
import json
import socket
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.append(str(ROOT))  # after PYTHONPATH: another checkout can be measured
sys.path.insert(0, str(ROOT / "tests" / "viewer"))

from raw_client import RawClient  # noqa: E402

from cinenerf_ns.viewer.standalone import StandaloneConfig, StandaloneViewer  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Page:
    """A page that reads all it is sent on its own thread, noting when frames arrive."""

    def __init__(self, port: int) -> None:
        self.t_open = time.perf_counter()
        self.client = RawClient(port)
        self.client.send_camera()
        self.frames: list = []  # perf_counter of each frame
        self.nbytes = 0
        self.camera_moves = 0  # camera updates this page was sent (another page's animation included, before)
        self.t_replay_done = None
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        ws = self.client.ws
        while not self.stop.is_set():
            try:
                raw = ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            except Exception:  # noqa: BLE001 - closed
                return
            now = time.perf_counter()
            self.frames.append(now)
            self.nbytes += len(raw)
            inner = _inner(raw)
            self.camera_moves += inner.count(b"SetCameraPositionMessage")
            if self.t_replay_done is None and b"ReplayDoneMessage" in inner:
                self.t_replay_done = now

    def close(self) -> None:
        self.stop.set()
        self.thread.join(2)
        self.client.close()


def _inner(raw: bytes) -> bytes:
    import zstandard

    inner, size = int.from_bytes(raw[:8], "little"), int.from_bytes(raw[8:16], "little")
    return zstandard.ZstdDecompressor().decompress(raw[16:16 + size], max_output_size=inner)


def page_panels(viewer) -> list:
    """The pages' panels (before per-page panels: the one panel every page shared)."""
    panels = getattr(viewer, "panels", None)
    return list(panels.panels.values()) if panels is not None else [viewer.panel]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--load-config", default="demo")
    ap.add_argument("--pages", type=int, default=5)
    ap.add_argument("--timeout", type=float, default=180.0)
    ap.add_argument("--planning", action="store_true", help="each open page presses Plan")
    ap.add_argument("--out", type=Path, default=None, help="write the numbers as JSON here")
    args = ap.parse_args()

    t0 = time.perf_counter()
    fields = StandaloneConfig.__dataclass_fields__
    out = {"output_dir": Path("/tmp/bench_viewer_pages")} if "output_dir" in fields else {"data": Path("/tmp/bvp")}
    viewer = StandaloneViewer(StandaloneConfig(load_config=args.load_config, port=free_port(), host="127.0.0.1",
                                               **out))
    load_s = time.perf_counter() - t0
    port = viewer.server.get_port()
    pages, rows = [], []
    try:
        for k in range(args.pages):
            first = pages[0] if pages else None
            page = Page(port)
            pages.append(page)
            end = time.monotonic() + args.timeout
            rtts = []  # the first page's websocket ping round trips while this page opens: the server's stalls
            while page.t_replay_done is None and time.monotonic() < end:
                if first is None:
                    time.sleep(0.01)
                    continue
                t = time.perf_counter()
                if first.client.ws.ping().wait(args.timeout):
                    rtts.append(time.perf_counter() - t)
                time.sleep(0.05)
            done = page.t_replay_done
            rows.append({"page": k + 1, "open_to_scene_s": None if done is None else round(done - page.t_open, 3),
                         "mib_received": round(page.nbytes / 2**20, 2),
                         "first_page_ping_max_s": round(max(rtts), 3) if rtts else None,
                         "panels": len(page_panels(viewer))})
            print(json.dumps(rows[-1]), flush=True)
            if args.planning:
                time.sleep(0.2)  # its panel (built on viser's connect callback)
                for panel in page_panels(viewer):
                    if not panel.planned_before or not hasattr(viewer, "panels"):  # before: one panel for all
                        panel.request_plan(viewer.loaded.default_goto, viewer.loaded.default_look_at)
        if args.planning:
            for panel in page_panels(viewer):
                panel.wait_idle(args.timeout)
            time.sleep(2.0)  # the animations (autoplay) run on
            rows.append({"plans_ok": sum(p.state in ("ready", "playing") for p in page_panels(viewer)),
                         "camera_moves_sent_per_page": [p.camera_moves for p in pages]})
    finally:
        for p in pages:
            p.close()
        if not viewer.close(60):  # the planner's preparation or the text warm-up still runs: leave without them
            print(json.dumps(rows), flush=True)
            import os

            os._exit(0)
    result = {"load_config": args.load_config, "planning": args.planning,
              "gaussians": int(len(viewer.loaded.splat.means)), "viewer_load_s": round(load_s, 2), "pages": rows}
    print(json.dumps(result, indent=1))
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
