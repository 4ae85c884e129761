"""A bare viser websocket client for tests: speaks viser 1.1.1's wire format (client -> server: one msgpack dict per
message; server -> client: [8 bytes msgpack size][8 bytes zstd size][zstd msgpack {"messages": [...]}][binary
buffers]) with no browser, so tests can send what a hostile page could send and read what every page is sent.
Every wait is bounded by a deadline."""
from __future__ import annotations

import time
from typing import Any, Callable, Dict, List, Optional

import msgspec
import viser
import websockets.sync.client
import zstandard
from websockets.exceptions import ConnectionClosed


class RawClient:
    def __init__(self, port: int, origin: Optional[str] = None, host: str = "127.0.0.1") -> None:
        headers = {"Origin": origin} if origin is not None else None
        self.ws = websockets.sync.client.connect(
            f"ws://{host}:{port}", subprotocols=[f"viser-v{viser.__version__}"], additional_headers=headers,
            max_size=None, open_timeout=10, origin=None)
        self.messages: List[Dict[str, Any]] = []
        self.closed = False

    def send(self, type: str, **fields: Any) -> None:
        try:
            self.ws.send(msgspec.msgpack.encode({"type": type, **fields}))
        except ConnectionClosed:  # the server closed this page
            self.closed = True

    def send_camera(self, position=(1.0, 2.0, 3.0)) -> None:
        """The first camera message: viser counts the page as connected from here (on_client_connect runs)."""
        self.send("ViewerCameraMessage", wxyz=[1.0, 0.0, 0.0, 0.0], position=list(position), fov=1.0, near=0.01,
                  far=100.0, image_height=480, image_width=640, look_at=[0.0, 0.0, 0.0], up_direction=[0.0, 0.0, 1.0])

    def pump(self, seconds: float) -> None:
        """Read what the server sends for ``seconds``."""
        self.wait(lambda: False, seconds)

    def wait(self, pred: Callable[[], bool], timeout: float = 10.0) -> bool:
        """Read frames until ``pred()`` (True) or the deadline (False) or the connection closes (False)."""
        end = time.monotonic() + timeout
        while not pred():
            left = end - time.monotonic()
            if left <= 0 or self.closed:
                return False
            try:
                raw = self.ws.recv(timeout=min(left, 0.2))
            except TimeoutError:
                continue
            except ConnectionClosed:
                self.closed = True
                return False
            if isinstance(raw, bytes):
                inner, size = int.from_bytes(raw[:8], "little"), int.from_bytes(raw[8:16], "little")
                payload = zstandard.ZstdDecompressor().decompress(raw[16:16 + size], max_output_size=inner)
                self.messages.extend(msgspec.msgpack.decode(payload)["messages"])
        return True

    # ------------------------------------------------------------------ what the page was sent
    def widget(self, label: str, kind: Optional[str] = None) -> Dict[str, Any]:
        """The creation message of the last widget labelled ``label`` (of type ``kind``, e.g. "GuiTextMessage")."""
        found = [m for m in self.messages if isinstance(m.get("props"), dict) and m["props"].get("label") == label
                 and (kind is None or m["type"] == kind)]
        assert found, f"no widget labelled {label!r} was sent"
        return found[-1]

    def markdown_sent(self) -> List[str]:
        """Every markdown text this page was sent: widget creations and content updates."""
        out = []
        for m in self.messages:
            if m["type"] == "GuiMarkdownMessage":
                out.append(m["props"].get("_markdown", ""))
            elif m["type"] == "GuiUpdateMessage" and "_markdown" in m.get("updates", {}):
                out.append(m["updates"]["_markdown"])
        return out

    def set_value(self, label: str, value: Any, kind: Optional[str] = None) -> None:
        self.send("GuiUpdateMessage", uuid=self.widget(label, kind)["uuid"], updates={"value": value})

    def click(self, label: str) -> None:
        self.set_value(label, True, "GuiButtonMessage")

    def close(self) -> None:
        try:
            self.ws.close()
        except Exception:  # noqa: BLE001 - already closed by the server
            pass
