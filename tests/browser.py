"""A headless Chromium for the tests, driven through the DevTools protocol over a pipe
(``--remote-debugging-pipe``: JSON messages ended by NUL on file descriptors 3 and 4), so no
websocket client or browser-automation package is needed.

``Browser.visit(path)`` opens a page and reports what a reader would meet: console errors and
uncaught exceptions, failed loads, every request's URL, each image (loaded, its size) and each
video (whether ``play()`` resolved, ``readyState``, whether ``currentTime`` advanced), the table
cells that carry a number's source (``lfd.pages``), the links and the failures said.
"""

from __future__ import annotations

import json
import os
import select
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

#: Chromium's flags: headless, no sandbox (CI runs as root), nothing fetched on its own behalf
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-default-apps", "--mute-audio", "--autoplay-policy=no-user-gesture-required",
         "--remote-debugging-pipe")
TIMEOUT_S = 60.0

# In the page, once loaded: each image and video checked, each sourced table cell read.
PROBE = """(async () => {
  const sleep = ms => new Promise(r => setTimeout(r, ms));
  const images = [...document.images].map(i => ({src: i.getAttribute('src'), complete: i.complete,
                                                  width: i.naturalWidth, height: i.naturalHeight}));
  const videos = [];
  for (const v of document.querySelectorAll('video')) {
    const out = {src: v.getAttribute('src'), played: false, error: null};
    v.muted = true;
    try { await v.play(); out.played = true; } catch (e) { out.error = String(e); }
    const t0 = performance.now();
    while (out.played && v.currentTime <= 0 && performance.now() - t0 < 15000) await sleep(50);
    Object.assign(out, {readyState: v.readyState, currentTime: v.currentTime, width: v.videoWidth,
                        height: v.videoHeight, mediaError: v.error ? v.error.code : null});
    v.pause();
    videos.push(out);
  }
  const cells = [...document.querySelectorAll('td[data-source]')].map(td => ({
    source: td.dataset.source, value: td.dataset.value, scale: td.dataset.scale, text: td.textContent.trim(),
    best: td.classList.contains('best')}));
  const links = [...document.querySelectorAll('a[href]')].map(a => a.getAttribute('href'));
  const failures = [...document.querySelectorAll('.failures li')].map(li => li.textContent.trim());
  return JSON.stringify({images, videos, cells, links, failures, scripts: document.scripts.length,
                         title: document.title});
})()"""


def unavailable(reason: str) -> None:
    """Skip a browser test for ``reason``, or fail it under CI (``$CI`` is ``true``, as .ci/run and CI
    services set it), where Chromium is installed and a skipped browser test would pass unseen."""
    import pytest

    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(f"{reason}; under CI the browser tests must run, not skip")
    pytest.skip(reason)


def find_chromium() -> str | None:
    """The Chromium executable (Debian's ``chromium`` package), or None."""
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    return None


class Browser:
    """One headless Chromium process; ``close`` ends it."""

    def __init__(self, executable: str) -> None:
        self.profile = tempfile.mkdtemp(prefix="lfd-chromium-")
        to_browser, self._w = os.pipe()
        self._r, from_browser = os.pipe()

        def at_3_and_4() -> None:  # in the child: the pipe ends as fds 3 (commands) and 4 (replies)
            a, b = os.dup(to_browser), os.dup(from_browser)
            os.dup2(a, 3)
            os.dup2(b, 4)

        self.proc = subprocess.Popen([executable, *FLAGS, f"--user-data-dir={self.profile}", "about:blank"],
                                     preexec_fn=at_3_and_4, close_fds=False, stdin=subprocess.DEVNULL,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(to_browser)
        os.close(from_browser)
        self._buf = b""
        self._id = 0
        self.events: list[dict[str, Any]] = []

    def send(self, method: str, params: dict[str, Any] | None = None, session: str | None = None) -> dict[str, Any]:
        """Send one command and return its result (events that arrive meanwhile are kept)."""
        self._id += 1
        msg: dict[str, Any] = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        while True:
            reply = self._read()
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]
            self.events.append(reply)

    def _read(self) -> dict[str, Any]:
        while b"\0" not in self._buf:
            ready, _, _ = select.select([self._r], [], [], TIMEOUT_S)
            if not ready:
                raise TimeoutError(f"no reply from Chromium in {TIMEOUT_S:g} s")
            chunk = os.read(self._r, 1 << 16)
            if not chunk:
                raise EOFError("Chromium closed its pipe")
            self._buf += chunk
        msg, self._buf = self._buf.split(b"\0", 1)
        return json.loads(msg)

    def _wait_for(self, method: str, session: str) -> None:
        while not any(e.get("method") == method and e.get("sessionId") == session for e in self.events):
            self.events.append(self._read())

    def visit(self, path: Path) -> dict[str, Any]:
        """Open ``path`` in a new tab; what ``PROBE`` found, with ``errors`` (console errors,
        uncaught exceptions, failed loads) and ``requests`` (every URL the page asked for)."""
        target = self.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        self.events.clear()
        for domain in ("Runtime", "Log", "Page", "Network"):
            self.send(f"{domain}.enable", session=session)
        self.send("Page.navigate", {"url": Path(path).resolve().as_uri()}, session=session)
        self._wait_for("Page.loadEventFired", session)
        found = json.loads(self.send("Runtime.evaluate", {"expression": PROBE, "awaitPromise": True,
                                                          "returnByValue": True}, session=session)["result"]["value"])
        self.send("Target.closeTarget", {"targetId": target})
        mine = [e for e in self.events if e.get("sessionId") == session]
        errors = [json.dumps(e["params"])[:500] for e in mine if
                  (e["method"] == "Runtime.consoleAPICalled" and e["params"]["type"] in ("error", "assert"))
                  or e["method"] == "Runtime.exceptionThrown"
                  or (e["method"] == "Log.entryAdded" and e["params"]["entry"]["level"] == "error")
                  or e["method"] == "Network.loadingFailed"]
        requests = [e["params"]["request"]["url"] for e in mine if e["method"] == "Network.requestWillBeSent"]
        return {**found, "errors": errors, "requests": requests}

    def close(self) -> None:
        """End the browser and remove its profile."""
        try:
            self.send("Browser.close")
        except (OSError, EOFError, TimeoutError, RuntimeError):
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._w)
        os.close(self._r)
        shutil.rmtree(self.profile, ignore_errors=True)
