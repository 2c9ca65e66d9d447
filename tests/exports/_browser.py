"""A page in a real headless browser (Debian's chromium; CI installs it in .ci/run), driven
through the Chrome DevTools Protocol over ``--remote-debugging-pipe`` (no extra package):
evaluate script, move the mouse, press keys, take screenshots, and record the page's console
messages, uncaught errors and requests. WebGL is SwiftShader's (software) rendering."""

from __future__ import annotations

import base64
import fcntl
import io
import json
import os
import queue
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

CHROMIUM = Path("/usr/bin/chromium")
needs_chromium = pytest.mark.skipif(not CHROMIUM.exists(),
                                    reason="no /usr/bin/chromium (apt-get install chromium; .ci/run does)")
#: the window the pages are seen in (CSS pixels, device scale 1)
WIDTH, HEIGHT = 800, 600


class Browser:
    """One headless chromium with one page (use as a context manager)."""

    def __init__(self, profile: Path, timeout: float = 60.0) -> None:
        self.timeout = timeout
        commands_r, self._commands = os.pipe()
        self._replies, replies_w = os.pipe()

        def child_fds() -> None:  # chromium reads commands on fd 3 and writes replies on fd 4
            a = fcntl.fcntl(commands_r, fcntl.F_DUPFD_CLOEXEC, 10)
            b = fcntl.fcntl(replies_w, fcntl.F_DUPFD_CLOEXEC, 10)
            os.dup2(a, 3)
            os.dup2(b, 4)

        self.process = subprocess.Popen(
            [str(CHROMIUM), "--headless", "--no-sandbox", "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
             "--disable-quic", "--no-first-run", "--disable-background-networking", "--disable-component-update",
             "--disable-sync", "--remote-debugging-pipe", f"--user-data-dir={profile}",
             f"--window-size={WIDTH},{HEIGHT}", "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            close_fds=False, preexec_fn=child_fds)
        os.close(commands_r)
        os.close(replies_w)
        self._id = 0
        self._inbox: queue.Queue = queue.Queue()
        self.events: list[dict] = []
        threading.Thread(target=self._read, daemon=True).start()
        target = next(t for t in self.send("Target.getTargets")["targetInfos"] if t["type"] == "page")
        self.session = self.send("Target.attachToTarget", targetId=target["targetId"], flatten=True)["sessionId"]
        for domain in ("Page", "Runtime", "Log", "Network"):
            self.call(f"{domain}.enable")
        self.call("Emulation.setDeviceMetricsOverride", width=WIDTH, height=HEIGHT, deviceScaleFactor=1, mobile=False)

    def _read(self) -> None:
        buffer = b""
        with os.fdopen(self._replies, "rb", buffering=0) as replies:
            while chunk := replies.read(1 << 16):
                buffer += chunk
                *messages, buffer = buffer.split(b"\0")
                for message in messages:
                    self._inbox.put(json.loads(message))

    def send(self, method: str, session: str | None = None, **params) -> dict:
        """The result of one protocol command (of the browser, or of a session's target)."""
        self._id += 1
        message = {"id": self._id, "method": method, "params": params}
        if session:
            message["sessionId"] = session
        os.write(self._commands, json.dumps(message).encode() + b"\0")
        end = time.monotonic() + self.timeout
        while True:
            reply = self._inbox.get(timeout=max(end - time.monotonic(), 0.001))
            if reply.get("id") == self._id:
                assert "error" not in reply, (method, reply["error"])
                return reply.get("result", {})
            self.events.append(reply)

    def call(self, method: str, **params) -> dict:
        """A command to the page."""
        return self.send(method, self.session, **params)

    def pump(self) -> None:
        """Take in the events that arrived."""
        while not self._inbox.empty():
            self.events.append(self._inbox.get())

    def evaluate(self, expression: str):
        """The value of a script expression in the page (awaited if it is a promise)."""
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        assert "exceptionDetails" not in result, result["exceptionDetails"]
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout: float | None = None):
        """Evaluate until the expression's value is truthy; that value."""
        end = time.monotonic() + (timeout or self.timeout)
        while not (value := self.evaluate(expression)):
            assert time.monotonic() < end, f"timed out waiting for {expression}"
            time.sleep(0.05)
        return value

    def open(self, url: str) -> None:
        """Load a page afresh (another #fragment of the same page too) and wait until it has
        drawn (``data-drawn`` on its body)."""
        self.call("Page.navigate", url="about:blank")
        self.wait_for("location.href === 'about:blank' && document.readyState === 'complete'")
        self.call("Page.navigate", url=url)
        self.wait_for("document.readyState === 'complete' && document.body.dataset.drawn !== undefined")
        self.settle()

    def settle(self) -> None:
        """Wait until the page has shown two more frames (what it drew is on the screen)."""
        self.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")

    def mouse(self, x: float, y: float, kind: str = "mouseMoved", **params) -> None:
        self.call("Input.dispatchMouseEvent", type=kind, x=x, y=y, **params)
        self.settle()

    def key(self, key: str, code: int) -> None:
        for kind in ("keyDown", "keyUp"):
            self.call("Input.dispatchKeyEvent", type=kind, key=key, code=key, windowsVirtualKeyCode=code)
        self.settle()

    def screenshot(self, path: Path | None = None) -> np.ndarray:
        """The page as (H, W, 3) uint8 (also written to ``path``)."""
        png = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        if path is not None:
            path.write_bytes(png)
        with Image.open(io.BytesIO(png)) as image:
            return np.asarray(image.convert("RGB"))

    def console_errors(self) -> list[str]:
        """The page's console errors and warnings, and its uncaught exceptions."""
        self.pump()
        found = []
        for e in self.events:
            method, p = e.get("method"), e.get("params", {})
            if method == "Runtime.consoleAPICalled" and p["type"] in ("error", "warning", "assert"):
                found.append(" ".join(str(a.get("value", a.get("description"))) for a in p["args"]))
            elif method == "Runtime.exceptionThrown":
                found.append(json.dumps(p["exceptionDetails"])[:500])
            elif method == "Log.entryAdded" and p["entry"]["level"] == "error":
                found.append(p["entry"]["text"])
        return found

    def requests(self) -> list[str]:
        """The URLs the page requested."""
        self.pump()
        return [e["params"]["request"]["url"] for e in self.events if e.get("method") == "Network.requestWillBeSent"]

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc) -> None:
        self.timeout = 5
        try:
            self.send("Browser.close")
        except Exception:  # noqa: BLE001 - it may be gone already; it is killed below
            pass
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        os.close(self._commands)


def background(image: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of the page's background colour (#fafafa, within 3)."""
    return (np.abs(image.astype(int) - 0xFA) <= 3).all(axis=-1)
