"""A headless Chromium driven over the DevTools protocol on a pipe (no WebDriver, no
websocket, no browser download): for the operator console's browser test, its
screenshot and the latency benchmark with browsers connected.

Chromium (Debian's ``chromium``, :data:`CHROMIUM`) is started with
``--remote-debugging-pipe``: it reads JSON commands, each ended by a NUL byte, on its
file descriptor 3 and writes the answers and events on its descriptor 4.  One page is
opened (``Target.createTarget``) and attached in flat mode (``sessionId``); console
messages, uncaught exceptions and log entries (failed loads, refused connections,
Content-Security-Policy violations) are collected in :attr:`Browser.errors`.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import tempfile
import threading
import time

__all__ = ["CHROMIUM", "FLAGS", "Browser", "chromium_path"]

CHROMIUM = "/usr/bin/chromium"
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars",
         "--disable-extensions", "--mute-audio", "--remote-debugging-pipe")


def _stderr():
    """Chromium's stderr: discarded, or inherited with SHIPSTAR_CDP_DEBUG=1."""
    return None if os.environ.get("SHIPSTAR_CDP_DEBUG") else subprocess.DEVNULL


def chromium_path() -> str | None:
    """Debian's chromium if it is installed, else one on PATH, else None."""
    if os.path.exists(CHROMIUM):
        return CHROMIUM
    return shutil.which("chromium") or shutil.which("chromium-browser")


class Browser:
    """One headless Chromium with one page.

    Parameters
    ----------
    url : str
        Opened at the start.
    width, height : int
        The page's viewport (CSS px).
    binary : str, optional
    nice : int
        Added to the browser's niceness (a benchmark's stand-in for a browser on another
        computer: it takes what the measurement leaves of the cores).
    """

    def __init__(self, url: str, width: int = 1280, height: int = 900, binary: str | None = None, nice: int = 0):
        binary = binary or chromium_path()
        if binary is None:
            raise FileNotFoundError(f"no chromium at {CHROMIUM} or on PATH")
        self._profile = tempfile.TemporaryDirectory(prefix="shipstar-chromium-")
        to_child_r, self._to_child = os.pipe()
        self._from_child, from_child_w = os.pipe()

        import fcntl

        # above 4, so that the dup2 onto 3 and 4 in the child can clobber neither
        high_r, high_w = (fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10) for fd in (to_child_r, from_child_w))
        os.close(to_child_r)
        os.close(from_child_w)
        to_child_r, from_child_w = high_r, high_w

        def fds():                                     # runs in the child, before the exec
            os.dup2(to_child_r, 3)                     # dup2 leaves 3 and 4 inheritable
            os.dup2(from_child_w, 4)
            if nice:
                os.nice(nice)

        self.proc = subprocess.Popen([binary, *FLAGS, f"--user-data-dir={self._profile.name}",
                                      f"--window-size={width},{height}", "about:blank"],
                                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=_stderr(),
                                     preexec_fn=fds, close_fds=False)   # PEP 446: only fds 3, 4 inherited
        os.close(to_child_r)
        os.close(from_child_w)
        self._next_id = 0
        self._lock = threading.Lock()
        self._answers: dict = {}
        self._cond = threading.Condition()
        self.events: list = []
        self.errors: list = []
        self._reader = threading.Thread(target=self._read, name="shipstar-cdp", daemon=True)
        self._reader.start()
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        for domain in ("Runtime", "Log", "Page"):
            self.call(f"{domain}.enable", session=True)
        self.call("Emulation.setDeviceMetricsOverride", session=True, width=width, height=height,
                  deviceScaleFactor=1, mobile=False)
        if url != "about:blank":
            self.navigate(url)

    # -- the pipe ------------------------------------------------------------------------------
    def _read(self) -> None:
        buf = b""
        while True:
            try:
                data = os.read(self._from_child, 1 << 16)
            except OSError:
                data = b""
            if not data:
                with self._cond:
                    self._answers[None] = "closed"
                    self._cond.notify_all()
                return
            buf += data
            while b"\0" in buf:
                raw, buf = buf.split(b"\0", 1)
                msg = json.loads(raw)
                if "id" in msg:
                    with self._cond:
                        self._answers[msg["id"]] = msg
                        self._cond.notify_all()
                else:
                    self._event(msg)

    def _event(self, msg: dict) -> None:
        method, p = msg.get("method", ""), msg.get("params", {})
        self.events.append(method)
        if len(self.events) > 1000:
            del self.events[:500]
        if method == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            self.errors.append("console.error: " + " ".join(str(a.get("value", a.get("description", "")))
                                                            for a in p.get("args", [])))
        elif method == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            self.errors.append("exception: " + str(d.get("exception", {}).get("description") or d.get("text")))
        elif method == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
            e = p["entry"]
            self.errors.append(f"log ({e.get('source')}): {e.get('text')} {e.get('url', '')}".strip())

    def call(self, method: str, *, session: bool = False, timeout_s: float = 30.0, **params) -> dict:
        """Send one command and wait for its answer; raises RuntimeError on an error answer."""
        with self._lock:
            self._next_id += 1
            mid = self._next_id
            msg = {"id": mid, "method": method, "params": params}
            if session:
                msg["sessionId"] = self.session
            os.write(self._to_child, json.dumps(msg).encode() + b"\0")
        end = time.monotonic() + timeout_s
        with self._cond:
            while mid not in self._answers:
                if None in self._answers:
                    raise RuntimeError(f"chromium closed the pipe before answering {method}")
                left = end - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no answer to {method} in {timeout_s:g} s")
                self._cond.wait(left)
            answer = self._answers.pop(mid)
        if "error" in answer:
            raise RuntimeError(f"{method}: {answer['error']}")
        return answer.get("result", {})

    # -- the page ------------------------------------------------------------------------------
    def navigate(self, url: str) -> None:
        self.call("Page.navigate", session=True, url=url)

    def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page (JSON-able; promises awaited)."""
        r = self.call("Runtime.evaluate", session=True, expression=expression, returnByValue=True,
                      awaitPromise=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"{expression!r}: {r['exceptionDetails'].get('text')}")
        return r.get("result", {}).get("value")

    def wait_for(self, expression: str, timeout_s: float = 30.0, period_s: float = 0.1):
        """Evaluate ``expression`` until it is truthy; returns its value (TimeoutError if never)."""
        end = time.monotonic() + timeout_s
        value = None
        while time.monotonic() < end:
            try:
                value = self.evaluate(expression)
            except RuntimeError:
                value = None
            if value:
                return value
            time.sleep(period_s)
        raise TimeoutError(f"{expression!r} still {value!r} after {timeout_s:g} s")

    def screenshot(self, path) -> None:
        """A PNG of the whole page."""
        size = self.evaluate("[document.documentElement.scrollWidth, document.documentElement.scrollHeight]")
        r = self.call("Page.captureScreenshot", session=True, format="png", captureBeyondViewport=True,
                      clip={"x": 0, "y": 0, "width": size[0], "height": size[1], "scale": 1})
        with open(path, "wb") as fh:
            fh.write(base64.b64decode(r["data"]))

    def close(self) -> None:
        try:
            self.call("Browser.close", timeout_s=5.0)
        except (RuntimeError, TimeoutError, OSError):
            pass
        try:
            self.proc.wait(10.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10.0)
        for fd in (self._to_child, self._from_child):
            try:
                os.close(fd)
            except OSError:
                pass
        self._reader.join(2.0)
        self._profile.cleanup()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
