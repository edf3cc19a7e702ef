"""Headless Chromium driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``): no
websocket library needed. Enough of the protocol for the page tests: open a page, run a script,
drag the mouse, answer a request with a document of the test's own, take a screenshot, and collect
every console error, uncaught exception and failed load."""

from __future__ import annotations

import base64
import contextlib
import fcntl
import json
import os
import subprocess
import time
from pathlib import Path

PAGE_TIMEOUT_S = 60.0  # a page's scripts and its first polls, on a busy 2-core box
DRAG_STEPS = 10  # mouse moves per drag: the page sees a drag, not a jump
VIEWPORT = (1400, 1100)  # CSS pixels: the rig view and its table side by side


class Browser:
    """One headless Chromium with one page. Use as a context manager."""

    def __init__(self, chromium: str, profile: Path):
        to_chrome_r, to_chrome_w = os.pipe()
        from_chrome_r, from_chrome_w = os.pipe()

        def pipes():  # the protocol's fixed descriptors: the browser reads 3 and writes 4
            high = [fcntl.fcntl(fd, fcntl.F_DUPFD, 10) for fd in (to_chrome_r, from_chrome_w)]  # out of 3's and 4's way
            os.dup2(high[0], 3)
            os.dup2(high[1], 4)

        self.proc = subprocess.Popen(
            [chromium, "--headless", "--no-sandbox", "--no-first-run", "--disable-background-networking",
             "--disable-component-update", "--disable-sync", "--remote-debugging-pipe",
             f"--user-data-dir={profile}", "about:blank"],
            preexec_fn=pipes, pass_fds=(3, 4),  # noqa: PLW1509 - pipes() makes only fcntl/dup2 calls, safe beside threads
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(to_chrome_r)
        os.close(from_chrome_w)
        self._out = os.fdopen(to_chrome_w, "wb")
        self._in = os.fdopen(from_chrome_r, "rb")
        self._buffer = b""
        self._next = 0
        self._replies: dict[int, dict] = {}
        self.errors: list[str] = []
        self.fulfil: dict[str, dict] = {}  # URL -> JSON document answered instead of the server's
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        for domain in ("Page", "Runtime", "Log", "Network"):
            self.send(f"{domain}.enable")
        self.send("Emulation.setDeviceMetricsOverride", width=VIEWPORT[0], height=VIEWPORT[1], deviceScaleFactor=1,
                  mobile=False)

    # -- the protocol ------------------------------------------------------------------------
    def call(self, method: str, session: str | None = None, **params) -> dict:
        self._next += 1
        ident = self._next
        message = {"id": ident, "method": method, "params": params}
        if session:
            message["sessionId"] = session
        self._out.write(json.dumps(message).encode() + b"\0")
        self._out.flush()
        while ident not in self._replies:
            message = self._read()
            if "id" in message:  # a reply, maybe to an outer call while an event's own call waits
                self._replies[message["id"]] = message
            else:
                self._event(message)
        reply = self._replies.pop(ident)
        if "error" in reply:
            raise RuntimeError(f"{method}: {reply['error']}")
        return reply.get("result", {})

    def send(self, method: str, **params) -> dict:
        """A command to the page's session."""
        return self.call(method, self.session, **params)

    def _read(self) -> dict:
        while b"\0" not in self._buffer:
            chunk = os.read(self._in.fileno(), 1 << 16)
            if not chunk:
                raise RuntimeError("chromium closed the DevTools pipe")
            self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def _event(self, event: dict) -> None:
        method, params = event.get("method"), event.get("params", {})
        if method == "Runtime.exceptionThrown":
            self.errors.append(f"exception: {params['exceptionDetails'].get('exception', {}).get('description')}")
        elif method == "Runtime.consoleAPICalled" and params["type"] in ("error", "assert"):
            self.errors.append("console: " + " ".join(str(a.get("value", a.get("description"))) for a in params["args"]))
        elif method == "Log.entryAdded" and params["entry"]["level"] == "error":
            self.errors.append(f"log: {params['entry']['text']} {params['entry'].get('url', '')}")
        elif method == "Network.responseReceived" and params["response"]["status"] >= 400:
            self.errors.append(f"HTTP {params['response']['status']}: {params['response']['url']}")
        elif method == "Fetch.requestPaused":
            body = json.dumps(self.fulfil[params["request"]["url"]]).encode()
            self.call("Fetch.fulfillRequest", self.session, requestId=params["requestId"], responseCode=200,
                      responseHeaders=[{"name": "Content-Type", "value": "application/json"}],
                      body=base64.b64encode(body).decode())

    # -- what the tests do -------------------------------------------------------------------
    def answer(self, url: str, document: dict) -> None:
        """Answer every GET of ``url`` with ``document`` (JSON) instead of the server's."""
        self.fulfil[url] = document
        self.send("Fetch.enable", patterns=[{"urlPattern": u} for u in self.fulfil])

    def open(self, url: str) -> None:
        self.send("Page.navigate", url=url)

    def js(self, expression: str):
        """The value of a script in the page (promises awaited)."""
        reply = self.send("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in reply:
            raise AssertionError(f"{expression}: {reply['exceptionDetails']}")
        return reply["result"].get("value")

    def wait_for(self, expression: str, timeout_s: float = PAGE_TIMEOUT_S):
        """Poll a script until it is truthy; its value."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            value = self.js(expression)
            if value:
                return value
            time.sleep(0.05)
        raise AssertionError(f"the page never made {expression!r} true in {timeout_s} s; errors: {self.errors}")

    def drag(self, start: tuple[float, float], end: tuple[float, float], shift: bool = False) -> None:
        """Press the left button at ``start`` (CSS pixels of the viewport), move to ``end``, release."""
        modifiers = 8 if shift else 0
        self.send("Input.dispatchMouseEvent", type="mousePressed", x=start[0], y=start[1], button="left", buttons=1,
                  clickCount=1, modifiers=modifiers)
        for k in range(1, DRAG_STEPS + 1):
            x = start[0] + (end[0] - start[0]) * k / DRAG_STEPS
            y = start[1] + (end[1] - start[1]) * k / DRAG_STEPS
            self.send("Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y, button="left", buttons=1,
                      modifiers=modifiers)
        self.send("Input.dispatchMouseEvent", type="mouseReleased", x=end[0], y=end[1], button="left", buttons=0,
                  clickCount=1, modifiers=modifiers)

    def wheel(self, at: tuple[float, float], delta_y: float) -> None:
        self.send("Input.dispatchMouseEvent", type="mouseWheel", x=at[0], y=at[1], deltaX=0, deltaY=delta_y)

    def screenshot(self, path: Path) -> Path:
        data = self.send("Page.captureScreenshot", format="png", captureBeyondViewport=True)["data"]
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(base64.b64decode(data))
        return path

    def close(self) -> None:
        with contextlib.suppress(RuntimeError, OSError):
            self.call("Browser.close")
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)
        self._out.close()
        self._in.close()

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
