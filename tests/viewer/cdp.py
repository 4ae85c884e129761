"""A minimal Chrome DevTools Protocol driver for headless Chromium (no playwright/selenium needed:
only the ``websockets`` package, already a viser dependency)."""
from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

CHROMIUM = os.environ.get("CINENERF_CHROMIUM", "/usr/bin/chromium")
FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--no-first-run",
    "--enable-unsafe-swiftshader",  # software WebGL so the splat is drawn without a GPU
    # software WebGL draws every frame on the CPU, all the time a page is open: 800x500 (the panel keeps its desktop
    # layout) costs Chromium about 2/3 of the CPU of 1280x800 (plan-fly test on the 2-core box: 20 s against 30 s)
    "--window-size=800,500",
]


class Chromium:
    def __init__(self, url: str, timeout: float = 30.0) -> None:
        from websockets.sync.client import connect

        self.profile = tempfile.mkdtemp(prefix="cine-chromium-")
        self.proc = subprocess.Popen(
            [CHROMIUM, *FLAGS, "--remote-debugging-port=0", f"--user-data-dir={self.profile}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
        port_file = Path(self.profile) / "DevToolsActivePort"
        end = time.monotonic() + timeout
        while not port_file.exists() or not port_file.read_text().strip():
            if time.monotonic() > end or self.proc.poll() is not None:
                self.close()
                raise RuntimeError("Chromium did not start (no DevToolsActivePort)")
            time.sleep(0.05)
        port = int(port_file.read_text().split()[0])
        targets = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10).read())
        page = next(t for t in targets if t["type"] == "page")
        self.ws = connect(page["webSocketDebuggerUrl"], max_size=64 * 2**20, open_timeout=10)
        self._id = 0
        self.console: list = []  # (level, text) of every console message and uncaught exception of the page
        self.call("Page.enable")
        self.call("Runtime.enable")
        self.call("Page.navigate", url=url)

    def call(self, method: str, timeout: float = 30.0, **params: Any) -> dict:
        self._id += 1
        my = self._id
        self.ws.send(json.dumps({"id": my, "method": method, "params": params}))
        end = time.monotonic() + timeout
        while True:
            msg = json.loads(self.ws.recv(timeout=max(end - time.monotonic(), 0.01)))
            self._event(msg)
            if msg.get("id") == my:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    def _event(self, msg: dict) -> None:
        """Keep the page's console output (warnings and errors are what the tests check)."""
        method, params = msg.get("method"), msg.get("params", {})
        if method == "Runtime.consoleAPICalled":
            text = " ".join(str(a.get("value", a.get("description", ""))) for a in params.get("args", []))
            self.console.append((params.get("type", "log"), text))
        elif method == "Runtime.exceptionThrown":
            d = params.get("exceptionDetails", {})
            self.console.append(("exception", str(d.get("exception", {}).get("description") or d.get("text"))))

    def pump(self, seconds: float) -> None:
        """Read the page's events for ``seconds`` (console messages arrive only while something reads)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                self._event(json.loads(self.ws.recv(timeout=max(end - time.monotonic(), 0.01))))
            except TimeoutError:
                break

    def js(self, expression: str, timeout: float = 30.0) -> Any:
        r = self.call("Runtime.evaluate", timeout=timeout, expression=expression, returnByValue=True,
                      awaitPromise=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"JS error: {r['exceptionDetails']}")
        return r["result"].get("value")

    def wait_js(self, expression: str, timeout: float = 30.0, every: float = 0.1) -> Any:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            # the page's main thread may be busy for longer than one call's default (decoding a 400k-Gaussian splat
            # on a loaded 2-core box took over 30 s): each evaluation may use the whole time left
            v = self.js(expression, timeout=max(end - time.monotonic(), 1.0))
            if v:
                return v
            time.sleep(every)
        raise TimeoutError(f"timed out waiting for: {expression}")

    def frames(self, n: int, timeout: float = 60.0) -> None:
        """Returns once the page has drawn ``n`` more animation frames (requestAnimationFrame callbacks): "the page
        rendered for a while" as a count of frames, which a loaded box slows down but cannot cut short."""
        self.js(f"new Promise(done => {{ let k = {int(n)}; const f = () => (--k > 0 ? requestAnimationFrame(f) : "
                "done(true)); requestAnimationFrame(f); })", timeout=timeout)

    def insert_text(self, text: str) -> None:
        self.call("Input.insertText", text=text)

    def screenshot(self, path: Path) -> Path:
        data = self.call("Page.captureScreenshot", format="png")["data"]
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(base64.b64decode(data))
        return path

    def close(self) -> None:
        try:
            self.ws.close()
        except Exception:
            pass
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        shutil.rmtree(self.profile, ignore_errors=True)
